// isouq: edge use counts by a bucket sort on the lower vertex index, components by union-find
// over vertices, area and enclosed volume in double (MeshTopology.h).
#include "isouq/MeshTopology.h"

#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace isouq {
namespace topology_internal {

void checkIndices(const Mesh& mesh)
{
    const std::size_t nv = mesh.vertexCount();
    for (std::size_t f = 0; f < mesh.triangleCount(); ++f)
        for (int c = 0; c < 3; ++c)
            if (mesh.triangles[f][c] >= nv)
                throw std::invalid_argument("triangle " + std::to_string(f) + " names vertex " +
                    std::to_string(mesh.triangles[f][c]) + " of " + std::to_string(nv));
}

/// Sorts the upper ends of the edges that share one lower end: short runs (the usual 2-4
/// edges) by insertion, long fans by std::sort.
void sortBucket(std::uint32_t* first, std::uint32_t* last)
{
    if (last - first > 16) {
        std::sort(first, last);
        return;
    }
    for (std::uint32_t* i = first + 1; i < last; ++i)
        for (std::uint32_t* j = i; j > first && j[-1] > j[0]; --j) std::swap(j[-1], j[0]);
}

/// Counts edges by use: each undirected edge (a, b), a < b, goes into the bucket of a as b
/// (a counting sort on a); sorting each small bucket makes equal edges adjacent runs.
void countEdges(const Mesh& mesh, MeshTopologyStats& stats)
{
    const std::size_t nv = mesh.vertexCount();
    std::vector<std::size_t> start(nv + 1, 0);
    auto forEachEdge = [&](auto&& visit) {
        for (const openvdb::Vec3I& t : mesh.triangles)
            for (int c = 0; c < 3; ++c) {
                const std::uint32_t a = t[c], b = t[(c + 1) % 3];
                if (a != b) visit(std::min(a, b), std::max(a, b));
            }
    };
    forEachEdge([&](std::uint32_t lo, std::uint32_t) { ++start[lo + 1]; });
    for (std::size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
    std::vector<std::uint32_t> upper(start[nv]);
    {
        std::vector<std::size_t> next(start.begin(), start.end() - 1);
        forEachEdge([&](std::uint32_t lo, std::uint32_t hi) { upper[next[lo]++] = hi; });
    }
    for (std::size_t v = 0; v < nv; ++v) {
        std::uint32_t* first = upper.data() + start[v];
        std::uint32_t* last = upper.data() + start[v + 1];
        sortBucket(first, last);
        while (first < last) {
            std::uint32_t* run = first + 1;
            while (run < last && *run == *first) ++run;
            const std::ptrdiff_t uses = run - first;
            ++stats.edges;
            if (uses == 1) ++stats.boundaryEdges;
            if (uses > 2) ++stats.nonManifoldEdges;
            first = run;
        }
    }
}

/// Area, enclosed volume (divergence theorem: the signed tetrahedra to a centre) and
/// degenerate triangles, in double.
void measureGeometry(const Mesh& mesh, MeshTopologyStats& stats)
{
    if (mesh.positions.empty()) return;
    std::array<double, 3> lo, hi, centre;
    for (int c = 0; c < 3; ++c) lo[c] = hi[c] = mesh.positions[0][c];
    for (const openvdb::Vec3s& p : mesh.positions)
        for (int c = 0; c < 3; ++c) {
            lo[c] = std::min(lo[c], double(p[c]));
            hi[c] = std::max(hi[c], double(p[c]));
        }
    for (int c = 0; c < 3; ++c) centre[c] = 0.5 * (lo[c] + hi[c]);
    GeometrySums sums;
    addTriangleGeometry(mesh.positions, mesh.triangles.data(), mesh.triangles.data() + mesh.triangles.size(), centre, sums);
    stats.area = sums.area;
    stats.enclosedVolume = std::abs(sums.signedVolume);
    stats.degenerateTriangles = sums.degenerate;
}

/// Union-find over vertices with path halving; the smaller index becomes the root.
class VertexSets {
public:
    explicit VertexSets(std::size_t n) : mParent(n)
    {
        for (std::size_t i = 0; i < n; ++i) mParent[i] = static_cast<std::uint32_t>(i);
    }
    std::uint32_t find(std::uint32_t v)
    {
        while (mParent[v] != v) v = mParent[v] = mParent[mParent[v]];
        return v;
    }
    void join(std::uint32_t a, std::uint32_t b)
    {
        a = find(a);
        b = find(b);
        if (a < b) mParent[b] = a;
        else if (b < a) mParent[a] = b;
    }

private:
    std::vector<std::uint32_t> mParent;
};

std::vector<std::uint32_t> labelTriangles(const Mesh& mesh, std::size_t& components)
{
    VertexSets sets(mesh.vertexCount());
    for (const openvdb::Vec3I& t : mesh.triangles) {
        sets.join(t[0], t[1]);
        sets.join(t[0], t[2]);
    }
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> labelOfRoot(mesh.vertexCount(), kNone);
    std::vector<std::uint32_t> labels(mesh.triangleCount());
    components = 0;
    for (std::size_t f = 0; f < labels.size(); ++f) {
        std::uint32_t& label = labelOfRoot[sets.find(mesh.triangles[f][0])];
        if (label == kNone) label = static_cast<std::uint32_t>(components++);
        labels[f] = label;
    }
    return labels;
}

} // namespace topology_internal

void addTriangleGeometry(const std::vector<openvdb::Vec3s>& positions, const openvdb::Vec3I* first,
    const openvdb::Vec3I* last, const std::array<double, 3>& centre, GeometrySums& sums)
{
    double area = sums.area, volume = sums.signedVolume;
    for (; first != last; ++first) {
        const openvdb::Vec3I& t = *first;
        double q[3][3];
        for (int v = 0; v < 3; ++v)
            for (int c = 0; c < 3; ++c) q[v][c] = double(positions[t[v]][c]) - centre[c];
        const double e1[3] = {q[1][0] - q[0][0], q[1][1] - q[0][1], q[1][2] - q[0][2]};
        const double e2[3] = {q[2][0] - q[0][0], q[2][1] - q[0][1], q[2][2] - q[0][2]};
        const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0]};
        const double twiceArea = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        area += 0.5 * twiceArea;
        // q0 . (q1 x q2) = q0 . (e1 x e2), so the normal is reused.
        volume += (q[0][0] * n[0] + q[0][1] * n[1] + q[0][2] * n[2]) / 6.0;
        if (twiceArea == 0 || t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) ++sums.degenerate;
    }
    sums.area = area;
    sums.signedVolume = volume;
}

MeshTopologyStats measureTopology(const Mesh& mesh) { return measureTopology(mesh, nullptr, true); }

MeshTopologyStats measureTopology(const Mesh& mesh, std::vector<std::uint32_t>* labels, bool geometry)
{
    using namespace topology_internal;
    checkIndices(mesh);
    MeshTopologyStats stats;
    // Three independent passes writing disjoint fields of stats.
    tbb::parallel_invoke([&] { countEdges(mesh, stats); },
        [&] {
            std::vector<std::uint32_t> l = labelTriangles(mesh, stats.components);
            if (labels) *labels = std::move(l);
        },
        [&] { if (geometry) measureGeometry(mesh, stats); });
    return stats;
}

std::vector<std::uint32_t> componentLabels(const Mesh& mesh)
{
    topology_internal::checkIndices(mesh);
    std::size_t components = 0;
    return topology_internal::labelTriangles(mesh, components);
}

std::vector<std::size_t> componentTriangleCounts(const std::vector<std::uint32_t>& labels)
{
    std::vector<std::size_t> counts;
    for (std::uint32_t label : labels) {
        if (label >= counts.size()) counts.resize(std::size_t(label) + 1, 0);
        ++counts[label];
    }
    return counts;
}

} // namespace isouq
