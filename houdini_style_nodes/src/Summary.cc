// isouq nodes: the SPEC §8 summary of a mesh.
#include "isouq/nodes/Summary.h"

#include <isouq/MeshTopology.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace isouq::nodes {
namespace {

/// Per-vertex measures whose statistics the summary reports (SPEC §6, §8).
const char* const kSummaryMeasures[] = {"err_est", "err_bound", "err_best", "d_lc", "d_lw", "d_cw",
    "max_var", "err_true_linear", "err_true_cubic", "err_true_weno", "err_true_weno_paper",
    "dist_true", "compare_dist"};

} // namespace

nlohmann::json statistics(const std::vector<float>& values)
{
    double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0, sumSq = 0;
    std::size_t n = 0;
    for (float v : values) {
        if (!std::isfinite(v)) continue;
        lo = std::min(lo, double(v));
        hi = std::max(hi, double(v));
        sum += v;
        sumSq += double(v) * v;
        ++n;
    }
    if (n == 0) return {{"min", nullptr}, {"max", nullptr}, {"mean", nullptr}, {"rms", nullptr}, {"count", 0}};
    return {{"min", lo}, {"max", hi}, {"mean", sum / double(n)}, {"rms", std::sqrt(sumSq / double(n))},
        {"count", n}};
}

nlohmann::json summarizeMesh(const Mesh& mesh)
{
    const MeshTopologyStats topo = measureTopology(mesh);
    nlohmann::json s;
    s["vertices"] = mesh.positions.size();
    s["triangles"] = mesh.triangles.size();
    s["boundary_edges"] = topo.boundaryEdges;
    s["non_manifold_edges"] = topo.nonManifoldEdges;
    s["components"] = topo.components;
    s["degenerate_triangles"] = topo.degenerateTriangles;
    s["area"] = topo.area;
    s["enclosed_volume"] = topo.enclosedVolume;
    for (const char* name : kSummaryMeasures)
        if (const auto* column = mesh.vertexAttributes.find<float>(name)) s[name] = statistics(*column);
    return s;
}

} // namespace isouq::nodes
