// isouq nodes: the SPEC §8 summary of a mesh.
#include "isouq/nodes/Summary.h"

#include <isouq/Columns.h>
#include <isouq/MeshTopology.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace isouq::nodes {

void StatisticsSums::add(const float* values, std::size_t n)
{
    double lo_ = lo, hi_ = hi, sum_ = sum, sumSq_ = sumSq;
    std::size_t count_ = count;
    for (std::size_t i = 0; i < n; ++i) {
        const float v = values[i];
        if (!std::isfinite(v)) continue;
        lo_ = std::min(lo_, double(v));
        hi_ = std::max(hi_, double(v));
        sum_ += v;
        sumSq_ += double(v) * v;
        ++count_;
    }
    lo = lo_, hi = hi_, sum = sum_, sumSq = sumSq_, count = count_;
}

void StatisticsSums::join(const StatisticsSums& next)
{
    lo = std::min(lo, next.lo), hi = std::max(hi, next.hi);
    sum += next.sum, sumSq += next.sumSq, count += next.count;
}

nlohmann::json StatisticsSums::result() const
{
    if (count == 0) return {{"min", nullptr}, {"max", nullptr}, {"mean", nullptr}, {"rms", nullptr}, {"count", 0}};
    return {{"min", lo}, {"max", hi}, {"mean", sum / double(count)}, {"rms", std::sqrt(sumSq / double(count))},
        {"count", count}};
}

nlohmann::json statistics(const std::vector<float>& values)
{
    return sumByChunks<StatisticsSums>(values.size(), [&](StatisticsSums& part, std::size_t first, std::size_t count) {
        part.add(values.data() + first, count);
    }).result();
}

nlohmann::json summaryCounts(std::size_t vertices, std::size_t triangles, const MeshTopologyStats& topo)
{
    return {{"vertices", vertices}, {"triangles", triangles}, {"boundary_edges", topo.boundaryEdges},
        {"non_manifold_edges", topo.nonManifoldEdges}, {"components", topo.components},
        {"degenerate_triangles", topo.degenerateTriangles}, {"area", topo.area},
        {"enclosed_volume", topo.enclosedVolume}};
}

nlohmann::json summarizeMesh(const Mesh& mesh)
{
    nlohmann::json s = summaryCounts(mesh.positions.size(), mesh.triangles.size(), measureTopology(mesh));
    for (const ColumnInfo& c : columnTable())
        if (const auto* column = c.summary ? mesh.vertexAttributes.find<float>(c.name) : nullptr)
            s[std::string(c.name)] = statistics(*column);
    return s;
}

} // namespace isouq::nodes
