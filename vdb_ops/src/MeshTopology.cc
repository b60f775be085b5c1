// isouq: edge use counts by a counting sort on the lower vertex index, components by union-find
// over vertices, area and enclosed volume in double (MeshTopology.h); every pass in parallel
// parts of the triangles, the results the same whatever the thread count.
#include "isouq/MeshTopology.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>

namespace isouq {
namespace topology_internal {

constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

/// The triangles of a Mesh, or of a TriangleChunks (fetched a chunk at a time into a buffer):
/// forRows(first, last, visit) calls visit(f, triangle) for f in [first, last), in order, and may
/// run on several threads at once.
struct MeshTriangles {
    const Mesh& mesh;
    std::size_t vertexCount() const { return mesh.vertexCount(); }
    std::size_t count() const { return mesh.triangleCount(); }
    template <typename Visit>
    void forRows(std::size_t first, std::size_t last, Visit&& visit) const
    {
        for (std::size_t f = first; f < last; ++f) visit(f, mesh.triangles[f]);
    }
};

struct ChunkedTriangles {
    const TriangleChunks& chunks;
    std::size_t vertexCount() const { return chunks.vertexCount; }
    std::size_t count() const { return chunks.triangleCount; }
    template <typename Visit>
    void forRows(std::size_t first, std::size_t last, Visit&& visit) const
    {
        constexpr std::size_t kChunk = 4096;
        std::vector<openvdb::Vec3I> buffer(std::min(kChunk, last - first));
        for (; first < last; first += kChunk) {
            const std::size_t n = std::min(kChunk, last - first);
            chunks.fetch(first, n, buffer.data());
            for (std::size_t i = 0; i < n; ++i) visit(first + i, buffer[i]);
        }
    }
};

/// @a n values of T left unset (each pass writes before it reads): no serial zero fill, and
/// the pages are first touched by the pass that writes them, on its threads.
template <typename T>
std::unique_ptr<T[]> unsetArray(std::size_t n)
{
    return std::unique_ptr<T[]>(new T[n]);
}

/// The triangles in at most kMaxParts parts of at least kPartRows rows, each pass over them
/// running the parts in parallel.
struct Parts {
    static constexpr std::size_t kPartRows = std::size_t(1) << 15, kMaxParts = 256;
    std::size_t rows, size, count;
    explicit Parts(std::size_t n)
        : rows(n), size(std::max(kPartRows, (n + kMaxParts - 1) / kMaxParts)), count((n + size - 1) / size) {}
    std::size_t first(std::size_t p) const { return p * size; }
    std::size_t last(std::size_t p) const { return std::min(rows, (p + 1) * size); }
    /// body(p) for every part, in parallel.
    template <typename Body>
    void each(const Body& body) const
    {
        tbb::parallel_for(std::size_t(0), count, [&](std::size_t p) { body(p); });
    }
};

/// Edges counted by their uses (SPEC §8 `boundary_edges`, `non_manifold_edges`).
struct EdgeTally {
    std::size_t edges = 0, boundary = 0, nonManifold = 0;
    void add(std::size_t uses) { ++edges, boundary += uses == 1, nonManifold += uses > 2; }
    void join(const EdgeTally& next) { edges += next.edges, boundary += next.boundary, nonManifold += next.nonManifold; }
};

/// Tallies the upper ends of the edges that share one lower end: a long fan sorted into runs of
/// equal ends; the usual few (each edge twice in a closed mesh) by comparing each end with the
/// later ones without branches, blanking the repeats with 0 (an upper end is never 0).
void tallyBucket(std::uint32_t* first, std::uint32_t* last, EdgeTally& tally)
{
    if (last - first > 16) {
        std::sort(first, last);
        for (std::uint32_t* run = first; first < last; first = run) {
            while (run < last && *run == *first) ++run;
            tally.add(std::size_t(run - first));
        }
        return;
    }
    for (; first < last; ++first) {
        const std::uint32_t b = *first;
        if (b == 0) continue;
        std::size_t uses = 1;
        for (std::uint32_t* j = first + 1; j < last; ++j) {
            const bool same = *j == b;
            uses += same;
            *j = same ? 0 : *j;
        }
        tally.add(uses);
    }
}

/// Counts edges by use: each undirected edge (a, b), a < b, is stored as b with a's offset in
/// its range of kRange vertices, grouped by range (a counting sort on the range: count() and
/// place() part by part); then tally() has each range, in parallel, sort its edges by a (a
/// counting sort on the offset) and tally each a's bucket, and frees the edges.
class EdgeCounter {
public:
    EdgeCounter(std::size_t vertices, const Parts& parts)
        : mParts(parts.count), mRanges((vertices + kRange - 1) / kRange), mAt(mRanges * mParts + 1, 0) {}

    /// Pass 1, part @a p's triangle @a t.
    void count(std::size_t p, const openvdb::Vec3I& t)
    {
        forEachEdge(t, [&](std::uint32_t lo, std::uint32_t) { ++mAt[lo / kRange * mParts + p + 1]; });
    }
    /// Between the passes.
    void allocate()
    {
        std::partial_sum(mAt.begin(), mAt.end(), mAt.begin()); // mAt[r * parts + p]: part p's first edge of range r
        mUpper = unsetArray<std::uint32_t>(mAt.back());
        mOffset = unsetArray<std::uint16_t>(mAt.back());
    }
    /// Pass 2: where part @a p's next edge of each range goes.
    std::vector<std::size_t> cursor(std::size_t p) const
    {
        std::vector<std::size_t> next(mRanges);
        for (std::size_t r = 0; r < mRanges; ++r) next[r] = mAt[r * mParts + p];
        return next;
    }
    void place(std::vector<std::size_t>& next, const openvdb::Vec3I& t)
    {
        forEachEdge(t, [&](std::uint32_t lo, std::uint32_t hi) {
            const std::size_t i = next[lo / kRange]++;
            mUpper[i] = hi;
            mOffset[i] = std::uint16_t(lo % kRange);
        });
    }
    EdgeTally tally()
    {
        std::vector<EdgeTally> tallies(mRanges);
        tbb::enumerable_thread_specific<std::pair<std::vector<std::size_t>, std::vector<std::uint32_t>>> scratch;
        tbb::parallel_for(std::size_t(0), mRanges, [&](std::size_t r) {
            const std::size_t first = mAt[r * mParts], last = mAt[(r + 1) * mParts];
            auto& [end, sorted] = scratch.local();
            end.assign(kRange + 1, 0); // end[a + 1] counts, then end[a] is where bucket a ends
            for (std::size_t i = first; i < last; ++i) ++end[mOffset[i] + 1u];
            std::partial_sum(end.begin(), end.end(), end.begin());
            sorted.resize(last - first);
            for (std::size_t i = first; i < last; ++i) sorted[end[mOffset[i]]++] = mUpper[i];
            EdgeTally tally; // a local, not tallies[r]: neighbouring ranges share a cache line
            for (std::size_t a = 0, begin = 0; a < kRange; begin = end[a++])
                tallyBucket(sorted.data() + begin, sorted.data() + end[a], tally);
            tallies[r] = tally;
        });
        mUpper.reset();
        mOffset.reset();
        EdgeTally sum;
        for (const EdgeTally& t : tallies) sum.join(t);
        return sum;
    }

private:
    static constexpr std::size_t kRange = std::size_t(1) << 16; // offsets fit 16 bits
    template <typename Visit>
    static void forEachEdge(const openvdb::Vec3I& t, const Visit& visit)
    {
        for (int c = 0; c < 3; ++c) {
            const std::uint32_t a = t[c], b = t[(c + 1) % 3];
            if (a != b) visit(std::min(a, b), std::max(a, b));
        }
    }
    std::size_t mParts, mRanges;
    std::vector<std::size_t> mAt;
    std::unique_ptr<std::uint32_t[]> mUpper;
    std::unique_ptr<std::uint16_t[]> mOffset;
};

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

/// Union-find over vertices, joined from several threads at once: a root is linked under a
/// smaller root by compare-and-swap (retried if it stopped being a root), paths are halved by
/// plain stores (any ancestor is a right parent, and parents only decrease), so each component's
/// root is its smallest vertex whatever the order of the joins.
class VertexSets {
public:
    explicit VertexSets(std::size_t n) : mSize(n), mParent(unsetArray<std::atomic<std::uint32_t>>(n))
    {
        tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) { mParent[i].store(std::uint32_t(i), kRelaxed); });
    }
    std::uint32_t find(std::uint32_t v)
    {
        for (std::uint32_t p = mParent[v].load(kRelaxed); p != v; p = mParent[v].load(kRelaxed)) {
            const std::uint32_t g = mParent[p].load(kRelaxed);
            if (g != p) mParent[v].store(g, kRelaxed);
            v = g;
        }
        return v;
    }
    std::size_t size() const { return mSize; }
    void join(std::uint32_t a, std::uint32_t b)
    {
        for (;;) {
            a = find(a), b = find(b);
            if (a == b) return;
            if (a < b) std::swap(a, b);
            std::uint32_t root = a;
            if (mParent[a].compare_exchange_strong(root, b, kRelaxed)) return;
        }
    }

private:
    static constexpr std::memory_order kRelaxed = std::memory_order_relaxed;
    std::size_t mSize;
    std::unique_ptr<std::atomic<std::uint32_t>[]> mParent;
};

/// Per triangle, its component numbered in the order of their first triangles, from each
/// triangle's first corner in @a labels (replaced): the roots of the triangles, then per root the
/// first part it appears in (an atomic minimum), the roots numbered within that part in order,
/// and the parts' counts added up in order. Returns the number of components.
std::size_t numberComponents(VertexSets& sets, const Parts& parts, std::vector<std::uint32_t>& labels)
{
    const auto firstPart = unsetArray<std::atomic<std::uint32_t>>(sets.size());
    const auto local = unsetArray<std::uint32_t>(sets.size()); // a root's number within its first part
    tbb::parallel_for(std::size_t(0), sets.size(), [&](std::size_t v) {
        firstPart[v].store(kNone, std::memory_order_relaxed);
        local[v] = kNone;
    });
    parts.each([&](std::size_t p) {
        for (std::size_t f = parts.first(p); f < parts.last(p); ++f) {
            const std::uint32_t root = labels[f] = sets.find(labels[f]);
            std::uint32_t seen = firstPart[root].load(std::memory_order_relaxed);
            while (seen > p && !firstPart[root].compare_exchange_weak(seen, std::uint32_t(p), std::memory_order_relaxed)) {}
        }
    });
    std::vector<std::size_t> before(parts.count + 1, 0);
    parts.each([&](std::size_t p) {
        std::uint32_t n = 0;
        for (std::size_t f = parts.first(p); f < parts.last(p); ++f)
            if (const std::uint32_t root = labels[f]; firstPart[root].load(std::memory_order_relaxed) == p && local[root] == kNone)
                local[root] = n++;
        before[p + 1] = n;
    });
    std::partial_sum(before.begin(), before.end(), before.begin());
    parts.each([&](std::size_t p) {
        for (std::size_t f = parts.first(p); f < parts.last(p); ++f) {
            const std::uint32_t root = labels[f];
            labels[f] = std::uint32_t(before[firstPart[root].load(std::memory_order_relaxed)] + local[root]);
        }
    });
    return before.back();
}

/// The components of the sets: the roots among the vertices that triangles use (a root is the
/// smallest vertex of its set, so used itself).
std::size_t countComponents(VertexSets& sets, const std::atomic<bool>* used)
{
    return tbb::parallel_reduce(tbb::blocked_range<std::size_t>(0, sets.size()), std::size_t(0),
        [&](const tbb::blocked_range<std::size_t>& range, std::size_t n) {
            for (std::size_t v = range.begin(); v < range.end(); ++v)
                n += used[v].load(std::memory_order_relaxed) && sets.find(std::uint32_t(v)) == v;
            return n;
        },
        std::plus<>());
}

/// Edges (when @a edges) and components, and the geometry when @a mesh is given, in two passes
/// over the triangles (a TriangleChunks fetches each twice): the first checks indices, counts
/// edges per range and keeps each triangle's first corner for @a labels (else marks its corners used),
/// the second places the edges and joins the corners' sets; then the edge tally, and the
/// components (numbered, or counted) beside the geometry.
template <typename Triangles>
MeshTopologyStats measure(const Triangles& triangles, std::vector<std::uint32_t>* labels, const Mesh* mesh, bool edges)
{
    const std::size_t nv = triangles.vertexCount();
    const Parts parts(triangles.count());
    EdgeCounter counter(edges ? nv : 0, parts);
    std::vector<std::uint32_t> corner(labels ? parts.rows : 0); // each triangle's first corner, then its component
    const auto used = unsetArray<std::atomic<bool>>(labels ? 0 : nv);
    if (!labels) tbb::parallel_for(std::size_t(0), nv, [&](std::size_t v) { used[v].store(false, std::memory_order_relaxed); });
    std::vector<std::size_t> firstBad(parts.count, std::numeric_limits<std::size_t>::max());
    parts.each([&](std::size_t p) {
        triangles.forRows(parts.first(p), parts.last(p), [&](std::size_t f, const openvdb::Vec3I& t) {
            if (t[0] >= nv || t[1] >= nv || t[2] >= nv) {
                firstBad[p] = std::min(firstBad[p], f);
                return;
            }
            if (edges) counter.count(p, t);
            if (labels) corner[f] = t[0];
            else
                for (int c = 0; c < 3; ++c) used[t[c]].store(true, std::memory_order_relaxed);
        });
    });
    if (const std::size_t f = std::accumulate(firstBad.begin(), firstBad.end(), parts.rows,
            [](std::size_t a, std::size_t b) { return std::min(a, b); });
        f < parts.rows) {
        triangles.forRows(f, f + 1, [&](std::size_t, const openvdb::Vec3I& t) { // the lowest, as a serial scan
            const std::uint32_t v = t[0] >= nv ? t[0] : t[1] >= nv ? t[1] : t[2];
            throw std::invalid_argument("triangle " + std::to_string(f) + " names vertex " + std::to_string(v) +
                " of " + std::to_string(nv));
        });
    }
    if (edges) counter.allocate();
    VertexSets sets(nv);
    parts.each([&](std::size_t p) {
        std::vector<std::size_t> next = edges ? counter.cursor(p) : std::vector<std::size_t>();
        triangles.forRows(parts.first(p), parts.last(p), [&](std::size_t, const openvdb::Vec3I& t) {
            if (edges) counter.place(next, t);
            sets.join(t[0], t[1]);
            sets.join(t[0], t[2]);
        });
    });
    MeshTopologyStats stats;
    if (edges) { // first, so the edges are freed before the numbering allocates (a lower peak)
        const EdgeTally tally = counter.tally();
        stats.edges = tally.edges, stats.boundaryEdges = tally.boundary, stats.nonManifoldEdges = tally.nonManifold;
    }
    // Two independent steps writing disjoint fields of stats.
    tbb::parallel_invoke(
        [&] { stats.components = labels ? numberComponents(sets, parts, corner) : countComponents(sets, used.get()); },
        [&] { if (mesh) measureGeometry(*mesh, stats); });
    if (labels) *labels = std::move(corner);
    return stats;
}

} // namespace topology_internal

MeshTopologyStats measureTopology(const Mesh& mesh) { return measureTopology(mesh, nullptr, true); }

MeshTopologyStats measureTopology(const Mesh& mesh, std::vector<std::uint32_t>* labels, bool geometry)
{
    return topology_internal::measure(topology_internal::MeshTriangles{mesh}, labels, geometry ? &mesh : nullptr, true);
}

MeshTopologyStats measureTopology(const TriangleChunks& triangles, std::vector<std::uint32_t>* labels)
{
    return topology_internal::measure(topology_internal::ChunkedTriangles{triangles}, labels, nullptr, true);
}

std::vector<std::uint32_t> componentLabels(const Mesh& mesh)
{
    std::vector<std::uint32_t> labels;
    topology_internal::measure(topology_internal::MeshTriangles{mesh}, &labels, nullptr, false);
    return labels;
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
