// isouq: sparse primal marching cubes (SPEC §1, §8, §9; DESIGN.md "Pass structure").
//
// Blocks are 8^3 regions aligned with the grid's leaves. The block set is every block within one
// voxel of an active voxel or of the border of an active tile, so every cell with an active corner
// and every edge such a cell uses is owned by exactly one block: cells and edges are owned by the
// block holding their lower corner (SPEC §9). Two passes over the blocks, both parallel:
//   count: gather the block's values with a halo into a small dense array, classify cells, and
//          record which owned edges carry a vertex (a 1536-bit mask) and how many triangles it has;
//   fill:  after a serial prefix sum, write each block's vertices and triangles at its offsets.
// A vertex's global index is its block's offset plus the rank of its bit in the block's mask, so
// the output never depends on the thread count and needs no hash map.
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

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>

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

/// The edge masks of the non-empty blocks, found by block index.
struct EdgeMasks {
    std::vector<EdgeMask> masks;
    std::vector<std::int32_t> slot; // per block: index into masks, or -1

    const EdgeMask& of(std::int32_t block) const { return masks[std::size_t(slot[std::size_t(block)])]; }
};


/// Calls @a body(x, y, z, cubeCase) for each candidate cell with x, y, z >= @a from (-1 or 0).
template <typename ScratchT, typename Body>
void forEachCandidateCell(const ScratchT& s, int from, Body&& body)
{
    for (int x = from; x < kBlockDim; ++x)
        for (int y = from; y < kBlockDim; ++y) {
            std::uint32_t cells = s.cellRow(x, y);
            if (from == 0) cells &= ~1u;
            for (; cells; cells &= cells - 1) {
                const int z = __builtin_ctz(cells) - 1;
                body(x, y, z, s.cubeCase(x, y, z));
            }
        }
}

/// Count pass for one block: which owned edges carry a vertex, and the block's triangle count.
/// An edge carries a vertex when it crosses and at least one of its four cells is meshed.
template <typename TreeT>
void countBlock(const BlockScratch<TreeT>& s, EdgeMask& mask, BlockCounts& counts)
{
    mask = EdgeMask{};
    counts = BlockCounts{};
    forEachCandidateCell(s, -1, [&](int x, int y, int z, int cubeCase) {
        if (x >= 0 && y >= 0 && z >= 0) counts.triangles += kMcCases.triangleCount[cubeCase];
        const std::uint16_t crossing = kMcCases.crossingEdges[cubeCase];
        for (int e = 0; e < 12; ++e) {
            if (!((crossing >> e) & 1)) continue;
            const McEdge& edge = kMcEdges[e];
            const int vx = x + edge.dx, vy = y + edge.dy, vz = z + edge.dz;
            if (vx < 0 || vy < 0 || vz < 0 || vx >= kBlockDim || vy >= kBlockDim || vz >= kBlockDim)
                continue; // owned by another block
            const int bit = 3 * voxelOffset(vx, vy, vz) + edge.axis;
            mask.bits[bit >> 6] |= std::uint64_t(1) << (bit & 63);
        }
    });
    std::uint32_t total = 0;
    for (int w = 0; w < kWords; ++w) {
        mask.rankBase[w] = std::uint16_t(total);
        total += std::uint32_t(__builtin_popcountll(mask.bits[w]));
    }
    counts.vertices = total;
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
    const EdgeMasks& masks, const std::vector<std::uint64_t>& vertexOffsets)
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
    const EdgeMasks& masks, const std::vector<std::uint64_t>& vertexOffsets, bool flip, openvdb::Vec3I* out)
{
    forEachCandidateCell(s, 0, [&](int x, int y, int z, int cubeCase) {
        const auto& edges = kMcCases.triangleEdges[cubeCase];
        for (int t = 0; t < kMcCases.triangleCount[cubeCase]; ++t) {
            const std::uint32_t a = vertexOf(x, y, z, edges[3 * t], neighbours, masks, vertexOffsets);
            const std::uint32_t b = vertexOf(x, y, z, edges[3 * t + 1], neighbours, masks, vertexOffsets);
            const std::uint32_t c = vertexOf(x, y, z, edges[3 * t + 2], neighbours, masks, vertexOffsets);
            *out++ = flip ? openvdb::Vec3I(a, c, b) : openvdb::Vec3I(a, b, c);
        }
    });
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
    const tbb::blocked_range<std::size_t> all(0, count, 16);
    if (threaded) tbb::parallel_for(all, range);
    else range(all);
    if (stop) throw InterruptedError();
}

/// Refuses, before allocating it, a mesh that needs more memory than there is (SPEC §10
/// "Errors"): a small file can describe a huge surface (one active 4096^3 tile).
inline void checkMeshFits(std::uint64_t vertices, std::uint64_t triangles, const MeshSettings& settings, bool provenance)
{
    // positions; edge_i/j/k, edge_axis, t_linear; err_est, err_bound; 11 high-order columns.
    std::uint64_t perVertex = 12 + (provenance ? 17 : 0);
    if (settings.uncertainty) perVertex += 8 + (settings.highOrder ? 45 : 0);
    const std::uint64_t bytes = vertices * perVertex + triangles * 12;
    using memory_internal::gib;
    const std::uint64_t available = memory_internal::availableMemory();
    if (available == 0 || bytes <= available) return;
    throw InputError("the mesh would have " + std::to_string(vertices) + " vertices and " +
        std::to_string(triangles) + " triangles, " + gib(bytes) + " GiB, more than the " + gib(available) +
        " GiB of memory available");
}

} // namespace mc_internal

namespace mc_internal {
/// What an IsosurfaceMesher keeps between calls.
struct MesherBuffers {
    std::vector<std::uint8_t> sides;
    std::vector<BlockCounts> counts;
    std::vector<std::uint64_t> vertexOffsets, triangleOffsets;
    EdgeMasks masks;
};
} // namespace mc_internal

IsosurfaceMesher::IsosurfaceMesher(const MeshSettings& settings)
    : mSettings(settings), mBuffers(std::make_unique<mc_internal::MesherBuffers>())
{
}

IsosurfaceMesher::~IsosurfaceMesher() = default;

template <typename GridT>
void IsosurfaceMesher::operator()(const GridT& grid, Mesh& mesh, openvdb::util::NullInterrupter* interrupter)
{
    using namespace mc_internal;
    const MeshSettings& settings = mSettings;
    MesherBuffers& buffers = *mBuffers;
    using TreeT = typename GridT::TreeType;
    static_assert(std::is_floating_point<typename GridT::ValueType>::value,
        "extractIsosurface needs a scalar floating-point grid");
    if (!std::isfinite(settings.isovalue))
        OPENVDB_THROW(openvdb::ValueError, "the isovalue must be a finite number");

    const float isovalue = settings.isovalue;
    const std::optional<CoordBBox> bounds = dataBoundsOf(grid, settings);
    const std::optional<CoordBBox> cellBox = meshedCellBox(bounds, settings.brick);
    const bool levelSet = grid.getGridClass() == openvdb::GRID_LEVEL_SET;
    const bool flip = settings.orientation == Orientation::TowardsHigher ||
                      (settings.orientation == Orientation::Auto && levelSet);
    const bool provenance = settings.provenance || settings.uncertainty;

    if (interrupter) interrupter->start("Meshing");
    struct EndGuard {
        openvdb::util::NullInterrupter* i;
        ~EndGuard() { if (i) i->end(); }
    } endGuard{interrupter};

    BlockSet blocks;
    buildBlockSet(grid.tree(), blocks, settings.threaded);
    throwIfInterrupted(interrupter);
    const std::size_t blockCount = blocks.origins.size();
    // Classifying cells reads one voxel beyond the block; high-order stencils three (SPEC §2).
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> scratch(
        std::cref(grid.tree()), std::cref(blocks.index), 1);
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> stencilScratch(
        std::cref(grid.tree()), std::cref(blocks.index), settings.uncertainty ? 3 : 1);
    std::atomic<std::size_t> done{0};
    const std::size_t work = 3 * blockCount;

    // Which side of the isovalue each block lies on, so blocks far from the surface cost little.
    std::vector<std::uint8_t>& sides = buffers.sides;
    sides.assign(blockCount, 0);
    forEachBlock(blockCount, settings.threaded, interrupter, done, work, [&](std::size_t b) {
        sides[b] = scratch.local().regionSide(blocks.origins[b], isovalue);
    });

    // Count pass: per block its counts; the edge masks of non-empty blocks go to per-thread lists.
    std::vector<BlockCounts>& counts = buffers.counts;
    counts.assign(blockCount, BlockCounts{});
    tbb::enumerable_thread_specific<std::vector<std::pair<std::int32_t, EdgeMask>>> found;
    forEachBlock(blockCount, settings.threaded, interrupter, done, work, [&](std::size_t b) {
        BlockScratch<TreeT>& s = scratch.local();
        if (!s.mayCross(blocks.origins[b], isovalue, sides)) return;
        if (!s.gatherAndClassify(blocks.origins[b], isovalue, cellBox)) return;
        EdgeMask mask;
        countBlock(s, mask, counts[b]);
        if (!counts[b].empty()) found.local().emplace_back(std::int32_t(b), mask);
    });

    // Serial prefix sums: each block's place in the output, independent of the thread count.
    std::vector<std::uint64_t>& vertexOffsets = buffers.vertexOffsets;
    std::vector<std::uint64_t>& triangleOffsets = buffers.triangleOffsets;
    vertexOffsets.assign(blockCount + 1, 0);
    triangleOffsets.assign(blockCount + 1, 0);
    EdgeMasks& masks = buffers.masks;
    masks.slot.assign(blockCount, -1);
    std::int32_t nonEmpty = 0;
    for (std::size_t b = 0; b < blockCount; ++b) {
        vertexOffsets[b + 1] = vertexOffsets[b] + counts[b].vertices;
        triangleOffsets[b + 1] = triangleOffsets[b] + counts[b].triangles;
        if (!counts[b].empty()) masks.slot[b] = nonEmpty++;
    }
    masks.masks.resize(std::size_t(nonEmpty));
    for (auto& list : found) {
        for (const auto& [block, mask] : list) masks.masks[std::size_t(masks.slot[std::size_t(block)])] = mask;
        list = {};
    }
    if (vertexOffsets[blockCount] > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    checkMeshFits(vertexOffsets[blockCount], triangleOffsets[blockCount], settings, provenance);

    const WorldMap toWorld(grid.transform());
    mesh.indexToWorld = toWorld.rowMajor();
    mesh.positions.resize(vertexOffsets[blockCount]);
    mesh.triangles.resize(triangleOffsets[blockCount]);
    const VertexColumns columns = VertexColumns::allocate(mesh, provenance, settings);
    const VertexContext context{isovalue, toWorld, grid.transform().voxelSize(), bounds,
        settings.stencil, settings.method, settings.uncertainty};

    // Fill pass.
    forEachBlock(blockCount, settings.threaded, interrupter, done, work, [&](std::size_t b) {
        if (counts[b].empty()) return;
        const Coord& origin = blocks.origins[b];
        BlockScratch<TreeT>& s = stencilScratch.local();
        s.gatherAndClassify(origin, isovalue, cellBox);
        fillVertices(s, origin, masks.of(std::int32_t(b)), vertexOffsets[b], context, columns);
        if (counts[b].triangles == 0) return;
        std::int32_t neighbours[2][2][2];
        for (int dx = 0; dx < 2; ++dx)
            for (int dy = 0; dy < 2; ++dy)
                for (int dz = 0; dz < 2; ++dz)
                    neighbours[dx][dy][dz] = blocks.find(origin.offsetBy(8 * dx, 8 * dy, 8 * dz));
        fillTriangles(s, neighbours, masks, vertexOffsets, flip, mesh.triangles.data() + triangleOffsets[b]);
    });
}

template void IsosurfaceMesher::operator()<openvdb::FloatGrid>(
    const openvdb::FloatGrid&, Mesh&, openvdb::util::NullInterrupter*);

template <typename GridT>
Mesh extractIsosurface(const GridT& grid, const MeshSettings& settings,
    openvdb::util::NullInterrupter* interrupter)
{
    Mesh mesh;
    IsosurfaceMesher mesher(settings);
    mesher(grid, mesh, interrupter);
    return mesh;
}


template Mesh extractIsosurface<openvdb::FloatGrid>(
    const openvdb::FloatGrid&, const MeshSettings&, openvdb::util::NullInterrupter*);

} // namespace isouq
