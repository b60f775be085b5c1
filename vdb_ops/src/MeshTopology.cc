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

/// The triangles of a Mesh, or of a TriangleChunks (fetched a chunk at a time into a buffer):
/// forEach(visit) calls visit(f, triangle) in order.
struct MeshTriangles {
    const Mesh& mesh;
    std::size_t vertexCount() const { return mesh.vertexCount(); }
    std::size_t count() const { return mesh.triangleCount(); }
    template <typename Visit>
    void forEach(Visit&& visit) const
    {
        for (std::size_t f = 0; f < mesh.triangles.size(); ++f) visit(f, mesh.triangles[f]);
    }
};

struct ChunkedTriangles {
    const TriangleChunks& chunks;
    std::size_t vertexCount() const { return chunks.vertexCount; }
    std::size_t count() const { return chunks.triangleCount; }
    template <typename Visit>
    void forEach(Visit&& visit) const
    {
        constexpr std::size_t kChunk = 4096;
        std::vector<openvdb::Vec3I> buffer(std::min(kChunk, chunks.triangleCount));
        for (std::size_t first = 0; first < chunks.triangleCount; first += kChunk) {
            const std::size_t n = std::min(kChunk, chunks.triangleCount - first);
            chunks.fetch(first, n, buffer.data());
            for (std::size_t i = 0; i < n; ++i) visit(first + i, buffer[i]);
        }
    }
};

template <typename Triangles>
void checkIndices(const Triangles& triangles)
{
    const std::size_t nv = triangles.vertexCount();
    triangles.forEach([&](std::size_t f, const openvdb::Vec3I& t) {
        for (int c = 0; c < 3; ++c)
            if (t[c] >= nv)
                throw std::invalid_argument("triangle " + std::to_string(f) + " names vertex " +
                    std::to_string(t[c]) + " of " + std::to_string(nv));
    });
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
template <typename Triangles>
void countEdges(const Triangles& triangles, MeshTopologyStats& stats)
{
    const std::size_t nv = triangles.vertexCount();
    std::vector<std::size_t> start(nv + 1, 0);
    auto forEachEdge = [&](auto&& visit) {
        triangles.forEach([&](std::size_t, const openvdb::Vec3I& t) {
            for (int c = 0; c < 3; ++c) {
                const std::uint32_t a = t[c], b = t[(c + 1) % 3];
                if (a != b) visit(std::min(a, b), std::max(a, b));
            }
        });
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
    const GeometrySums sums = sumByChunks<GeometrySums>(mesh.triangles.size(),
        [&](GeometrySums& part, std::size_t first, std::size_t count) {
            addTriangleGeometry([&](std::uint32_t v) -> const openvdb::Vec3s& { return mesh.positions[v]; },
                mesh.triangles.data() + first, mesh.triangles.data() + first + count, centre, part);
        });
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

template <typename Triangles>
std::vector<std::uint32_t> labelTriangles(const Triangles& triangles, std::size_t& components)
{
    VertexSets sets(triangles.vertexCount());
    triangles.forEach([&](std::size_t, const openvdb::Vec3I& t) {
        sets.join(t[0], t[1]);
        sets.join(t[0], t[2]);
    });
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> labelOfRoot(triangles.vertexCount(), kNone);
    std::vector<std::uint32_t> labels(triangles.count());
    components = 0;
    triangles.forEach([&](std::size_t f, const openvdb::Vec3I& t) {
        std::uint32_t& label = labelOfRoot[sets.find(t[0])];
        if (label == kNone) label = static_cast<std::uint32_t>(components++);
        labels[f] = label;
    });
    return labels;
}

/// Edges and components, and the geometry when @a mesh is given.
template <typename Triangles>
MeshTopologyStats measure(const Triangles& triangles, std::vector<std::uint32_t>* labels, const Mesh* mesh)
{
    checkIndices(triangles);
    MeshTopologyStats stats;
    // Three independent passes writing disjoint fields of stats.
    tbb::parallel_invoke([&] { countEdges(triangles, stats); },
        [&] {
            std::vector<std::uint32_t> l = labelTriangles(triangles, stats.components);
            if (labels) *labels = std::move(l);
        },
        [&] { if (mesh) measureGeometry(*mesh, stats); });
    return stats;
}

} // namespace topology_internal

MeshTopologyStats measureTopology(const Mesh& mesh) { return measureTopology(mesh, nullptr, true); }

MeshTopologyStats measureTopology(const Mesh& mesh, std::vector<std::uint32_t>* labels, bool geometry)
{
    return topology_internal::measure(topology_internal::MeshTriangles{mesh}, labels, geometry ? &mesh : nullptr);
}

MeshTopologyStats measureTopology(const TriangleChunks& triangles, std::vector<std::uint32_t>* labels)
{
    return topology_internal::measure(topology_internal::ChunkedTriangles{triangles}, labels, nullptr);
}

std::vector<std::uint32_t> componentLabels(const Mesh& mesh)
{
    const topology_internal::MeshTriangles triangles{mesh};
    topology_internal::checkIndices(triangles);
    std::size_t components = 0;
    return topology_internal::labelTriangles(triangles, components);
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
