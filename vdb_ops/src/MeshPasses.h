// isouq (internal): the per-block passes of the mesher (DESIGN.md "Pass structure"), shared by
// the one-process mesher (MarchingCubes.cc) and the brick mesher of a piece of the block order
// (Bricks.cc, SPEC §9): edge masks, the count pass, the fill of vertices and triangles, and
// the memory check before the outputs are allocated.
#pragma once

#include "isouq/MarchingCubes.h"
#include "isouq/GridMetadata.h"
#include "isouq/McTables.h"

#include "BlockScratch.h"
#include "Memory.h"
#include "MeshVertices.h"

#include <openvdb/thread/Threading.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <deque>

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace isouq {
namespace mc_internal {

using openvdb::Coord;
using openvdb::CoordBBox;

constexpr int kWords = 3 * 512 / 64; // one bit per (voxel, axis) owned by a block

/// Which edges of a block carry a vertex: bit 3 * voxelOffset + axis. Kept from the count pass
/// to the fill pass for non-empty blocks only (most blocks of a narrow band are empty).
struct EdgeMask {
    std::array<std::uint64_t, kWords> bits{};
    std::array<std::uint16_t, kWords> rankBase{}; // set bits in the words before

    std::uint32_t rank(int bit) const
    {
        const int word = bit >> 6;
        const std::uint64_t below = (std::uint64_t(1) << (bit & 63)) - 1;
        return rankBase[word] + std::uint32_t(__builtin_popcountll(bits[word] & below));
    }
};

struct BlockCounts {
    std::uint32_t vertices = 0, triangles = 0;
    bool empty() const { return vertices == 0 && triangles == 0; }
};

/// A non-empty block's mask, as the count pass finds it; each thread appends to its own list.
struct FoundMask {
    std::int32_t block;
    EdgeMask mask;
};
using FoundMasks = tbb::enumerable_thread_specific<ChunkList<FoundMask>>;

/// The edge masks of the non-empty blocks, found by block index. The masks stay in the count
/// pass's per-thread lists (FoundMasks); a brick keeps its neighbours' in `owned`.
struct EdgeMasks {
    PageVector<const EdgeMask*> byBlock; // null for a block without vertices or triangles
    std::deque<EdgeMask> owned;          // a deque: pointers into it stay valid as it grows

    const EdgeMask& of(std::int32_t block) const { return *byBlock[std::size_t(block)]; }
    void own(std::int64_t block, const EdgeMask& mask)
    {
        owned.push_back(mask);
        byBlock[std::size_t(block)] = &owned.back();
    }
};


/// Calls @a body(x, y, z, cubeCase) for each candidate cell the block owns (x, y, z in [0, 8)).
template <typename ScratchT, typename Body>
void forEachOwnedCandidateCell(const ScratchT& s, Body&& body)
{
    for (int x = 0; x < kBlockDim; ++x)
        for (int y = 0; y < kBlockDim; ++y)
            for (std::uint32_t cells = s.cellRow(x, y) & ~1u; cells; cells &= cells - 1) { // bit z + 1: cell z
                const int z = __builtin_ctz(cells) - 1;
                body(x, y, z, s.cubeCase(x, y, z));
            }
}

/// Bit i of @a bits moved to bit 3 i, for 8 bits: a row of one axis's edges into EdgeMask order.
constexpr std::uint32_t spreadToThirds(std::uint32_t bits)
{
    std::uint32_t out = 0;
    for (int i = 0; i < 8; ++i) out |= ((bits >> i) & 1u) << (3 * i);
    return out;
}
inline constexpr auto kSpreadToThirds = [] {
    std::array<std::uint32_t, 256> table{};
    for (std::uint32_t b = 0; b < 256; ++b) table[b] = spreadToThirds(b);
    return table;
}();

/// Count pass for one block (after gatherBitsAndClassify): which owned edges carry a vertex, and
/// the block's triangle count. An edge carries a vertex when it crosses and at least one of its
/// four cells is meshed (every cell of a crossing edge straddles k, so it is a candidate then).
/// One row of eight voxels at a time: the crossings along each axis, and the meshed cells
/// around each edge, as bit rows.
template <typename TreeT>
void countBlock(const BlockScratch<TreeT>& s, EdgeMask& mask, BlockCounts& counts)
{
    mask = EdgeMask{};
    counts = BlockCounts{};
    forEachOwnedCandidateCell(s, [&](int, int, int, int cubeCase) { counts.triangles += kMcCases.triangleCount[cubeCase]; });
    constexpr std::uint32_t kRow = (1u << kBlockDim) - 1u;
    for (int x = 0; x < kBlockDim; ++x)
        for (int y = 0; y < kBlockDim; ++y) {
            // Bit z: voxels z and z + 1 (or the + neighbour along x, y) on either side of k.
            const std::uint32_t in = s.insideFromZero(x, y);
            const std::uint32_t crossX = (in ^ s.insideFromZero(x + 1, y)) & kRow;
            const std::uint32_t crossY = (in ^ s.insideFromZero(x, y + 1)) & kRow;
            const std::uint32_t crossZ = (in ^ (in >> 1)) & kRow;
            // Meshed rows: bit z + 1 is cell z. An x edge's cells are (x, y - 1..y, z - 1..z), a
            // y edge's (x - 1..x, y, z - 1..z), a z edge's (x - 1..x, y - 1..y, z).
            const std::uint32_t m = s.meshedRow(x, y), mBelowY = s.meshedRow(x, y - 1);
            const std::uint32_t mBelowX = s.meshedRow(x - 1, y), mBelowXY = s.meshedRow(x - 1, y - 1);
            const std::uint32_t aroundX = m | mBelowY, aroundY = m | mBelowX;
            const std::uint32_t vx = crossX & (aroundX | (aroundX >> 1));
            const std::uint32_t vy = crossY & (aroundY | (aroundY >> 1));
            const std::uint32_t vz = crossZ & ((m | mBelowY | mBelowX | mBelowXY) >> 1);
            if ((vx | vy | vz) == 0) continue;
            // Bits 3 * voxelOffset(x, y, z) + axis: 24 bits from 3 * voxelOffset(x, y, 0) on.
            const std::uint64_t bits = kSpreadToThirds[vx] | kSpreadToThirds[vy] << 1 | kSpreadToThirds[vz] << 2;
            const int at = 3 * voxelOffset(x, y, 0), word = at >> 6, shift = at & 63;
            mask.bits[word] |= bits << shift;
            if (shift > 64 - 24) mask.bits[word + 1] |= bits >> (64 - shift);
        }
    std::uint32_t total = 0;
    for (int w = 0; w < kWords; ++w) {
        mask.rankBase[w] = std::uint16_t(total);
        total += std::uint32_t(__builtin_popcountll(mask.bits[w]));
    }
    counts.vertices = total;
}

/// The fill pass's window [lo, lo + width)^3 around a block: the linear crossings and the
/// cells [0, 8)^3 read voxels [0, 9); the stencils f_{i-2..i+3} of the edges from voxels 0..7
/// read voxels -2..10 (SPEC §2).
struct FillWindow {
    int lo, width;
};
inline FillWindow fillWindow(const MeshSettings& settings)
{
    return settings.uncertainty ? FillWindow{-2, 13} : FillWindow{0, kBlockDim + 1};
}

/// Writes the block's vertices at @a offset, in the order of the bits of its edge mask.
template <typename TreeT>
void fillVertices(const BlockScratch<TreeT>& s, const Coord& origin, const EdgeMask& mask,
    std::size_t offset, const VertexContext& context, const VertexColumns& out)
{
    std::size_t n = offset;
    for (int w = 0; w < kWords; ++w) {
        for (std::uint64_t bits = mask.bits[w]; bits; bits &= bits - 1) {
            const int bit = 64 * w + __builtin_ctzll(bits);
            const int voxel = bit / 3;
            writeVertex(s, origin, voxel >> 6, (voxel >> 3) & 7, voxel & 7, bit % 3, n++, context, out);
        }
    }
}

/// Global vertex index of cube edge @a e of the cell at (x, y, z) in the block, using the block
/// and its + neighbours (neighbours[dx][dy][dz], dx, dy, dz in {0, 1}).
inline std::uint32_t vertexOf(int x, int y, int z, int e, const std::int32_t (&neighbours)[2][2][2],
    const EdgeMasks& masks, const PageVector<std::uint64_t>& vertexOffsets)
{
    const McEdge& edge = kMcEdges[e];
    const int vx = x + edge.dx, vy = y + edge.dy, vz = z + edge.dz;
    const int bx = vx >> 3, by = vy >> 3, bz = vz >> 3;
    const std::int32_t owner = neighbours[bx][by][bz];
    const int bit = 3 * voxelOffset(vx & 7, vy & 7, vz & 7) + edge.axis;
    return std::uint32_t(vertexOffsets[owner] + masks.of(owner).rank(bit));
}

template <typename TreeT>
void fillTriangles(const BlockScratch<TreeT>& s, const std::int32_t (&neighbours)[2][2][2],
    const EdgeMasks& masks, const PageVector<std::uint64_t>& vertexOffsets, bool flip, openvdb::Vec3I* out)
{
    forEachOwnedCandidateCell(s, [&](int x, int y, int z, int cubeCase) {
        const auto& edges = kMcCases.triangleEdges[cubeCase];
        for (int t = 0; t < kMcCases.triangleCount[cubeCase]; ++t) {
            const std::uint32_t a = vertexOf(x, y, z, edges[3 * t], neighbours, masks, vertexOffsets);
            const std::uint32_t b = vertexOf(x, y, z, edges[3 * t + 1], neighbours, masks, vertexOffsets);
            const std::uint32_t c = vertexOf(x, y, z, edges[3 * t + 2], neighbours, masks, vertexOffsets);
            *out++ = flip ? openvdb::Vec3I(a, c, b) : openvdb::Vec3I(a, b, c);
        }
    });
}

/// The count pass on block @a b, the same for the one-process mesher and a brick: its counts,
/// and its edge mask appended to the thread's list when the block has vertices or triangles.
/// Blocks that cannot cross (mayCross) or have no candidate cell are left at zero.
template <typename TreeT>
void countPassBlock(BlockScratch<TreeT>& s, const BlockSet& blocks, std::size_t b, float isovalue,
    const std::optional<CoordBBox>& cellBox, const PageVector<std::uint8_t>& sides, BlockCounts& counts,
    FoundMasks& found)
{
    const Coord& origin = blocks.origins[b];
    if (!s.mayCross(origin, isovalue, sides)) return;
    if (!s.gatherBitsAndClassify(origin, isovalue, cellBox)) return;
    EdgeMask mask;
    countBlock(s, mask, counts);
    if (!counts.empty()) found.local().push({std::int32_t(b), mask});
}

/// Where the fill pass writes: @a vertexOffsets[b] is block b's first vertex in the whole mesh,
/// which is row vertexOffsets[b] - firstVertex of @a columns (a brick's columns start at its
/// first vertex; the one-process mesher's at 0).
struct FillTarget {
    const EdgeMasks& masks;
    const PageVector<std::uint64_t>& vertexOffsets;
    std::uint64_t firstVertex;
    const VertexContext& context;
    const VertexColumns& columns;
    bool flip;
};

/// The fill pass on non-empty block @a b: its vertices, then its @a counts.triangles triangles
/// at @a triangles.
template <typename TreeT>
void fillPassBlock(BlockScratch<TreeT>& s, const BlockSet& blocks, std::size_t b, const BlockCounts& counts,
    const std::optional<CoordBBox>& cellBox, const FillTarget& to, openvdb::Vec3I* triangles)
{
    const Coord& origin = blocks.origins[b];
    s.gatherAndClassify(origin, to.context.isovalue, cellBox);
    fillVertices(s, origin, to.masks.of(std::int32_t(b)), to.vertexOffsets[b] - to.firstVertex, to.context,
        to.columns);
    if (counts.triangles == 0) return;
    std::int32_t neighbours[2][2][2];
    blocks.plusNeighbours(origin, neighbours);
    fillTriangles(s, neighbours, to.masks, to.vertexOffsets, to.flip, triangles);
}

/// Whether triangles are wound the other way (Orientation; level sets face outward by default).
template <typename GridT>
bool flipsTriangles(const GridT& grid, const MeshSettings& settings)
{
    return settings.orientation == Orientation::TowardsHigher ||
           (settings.orientation == Orientation::Auto && grid.getGridClass() == openvdb::GRID_LEVEL_SET);
}

template <typename GridT>
std::optional<CoordBBox> dataBoundsOf(const GridT& grid, const MeshSettings& settings)
{
    if (settings.dataBounds) return settings.dataBounds;
    return dataBounds(grid);
}

/// The box of minimum corners of the cells that may be meshed: all corners inside the data
/// bounds (min corner in [min, max - 1]), and min corner inside the brick (SPEC §9).
inline std::optional<CoordBBox> meshedCellBox(const std::optional<CoordBBox>& dataBounds,
    const std::optional<CoordBBox>& brick)
{
    std::optional<CoordBBox> box;
    if (dataBounds) box = CoordBBox(dataBounds->min(), dataBounds->max().offsetBy(-1));
    if (brick) {
        if (box) box->intersect(*brick);
        else box = brick;
    }
    return box;
}

/// Refuses, before allocating it, a mesh that needs more memory than there is (SPEC §10
/// "Errors"): a small file can describe a huge surface (one active 4096^3 tile).
inline void checkMeshFits(std::uint64_t vertices, std::uint64_t triangles, const MeshSettings& settings, bool provenance)
{
    // positions; edge_i/j/k, edge_axis, t_linear; err_est, err_bound; 11 high-order columns.
    std::uint64_t perVertex = 12 + (provenance ? 17 : 0);
    if (settings.uncertainty) perVertex += 8 + (settings.highOrder ? 45 : 0);
    const std::uint64_t bytes = vertices * perVertex + triangles * 12;
    // Small meshes skip reading /proc/meminfo, a cost comparable to meshing a 32^3 grid.
    if (bytes < (std::uint64_t(16) << 20)) return;
    using memory_internal::gib;
    const std::uint64_t available = memory_internal::availableMemory();
    if (available == 0 || bytes <= available) return;
    throw InputError("the mesh would have " + std::to_string(vertices) + " vertices and " +
        std::to_string(triangles) + " triangles, " + gib(bytes) + " GiB, more than the " + gib(available) +
        " GiB of memory available");
}

/// Runs @a body(i) for every block in parallel (or serially), polling the interrupter.
template <typename Body>
void forEachBlock(std::size_t count, bool threaded, openvdb::util::NullInterrupter* interrupter,
    std::atomic<std::size_t>& done, std::size_t total, Body&& body)
{
    std::atomic<bool> stop{false};
    auto range = [&](const tbb::blocked_range<std::size_t>& r) {
        if (stop.load(std::memory_order_relaxed)) return;
        const std::size_t before = done.fetch_add(r.size(), std::memory_order_relaxed);
        if (openvdb::util::wasInterrupted(interrupter, int(100 * before / std::max<std::size_t>(total, 1)))) {
            stop = true;
            openvdb::thread::cancelGroupExecution();
            return;
        }
        for (std::size_t i = r.begin(); i < r.end(); ++i) body(i);
    };
    const tbb::blocked_range<std::size_t> all(0, count, 2);
    if (threaded) tbb::parallel_for(all, range);
    else range(all);
    if (stop) throw InterruptedError();
}

} // namespace mc_internal
} // namespace isouq
