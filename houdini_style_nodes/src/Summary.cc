// isouq nodes: the SPEC §8 summary of a mesh.
#include "isouq/nodes/Summary.h"

#include <isouq/Columns.h>
#include <isouq/MeshTopology.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace isouq::nodes {

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
    for (const ColumnInfo& c : columnTable())
        if (const auto* column = c.summary ? mesh.vertexAttributes.find<float>(c.name) : nullptr)
            s[std::string(c.name)] = statistics(*column);
    return s;
}

} // namespace isouq::nodes
