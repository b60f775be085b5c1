// isouq: sparse primal marching cubes (SPEC §1, §8, §9; DESIGN.md "Pass structure").
//
// Blocks are 8^3 regions aligned with the grid's leaves. The block set is every block within one
// voxel of an active voxel or of the border of an active tile, so every cell with an active corner
// and every edge such a cell uses is owned by exactly one block: cells and edges are owned by the
// block holding their lower corner (SPEC §9). Two passes over the blocks, both parallel:
//   count: gather the block's values with a halo into a small dense array, classify cells, and
//          record which owned edges carry a vertex (a 1536-bit mask) and how many triangles it has;
//   fill:  after a prefix sum (parallel, of integers: the same offsets for any thread count),
//          write each block's vertices and triangles at its offsets.
// A vertex's global index is its block's offset plus the rank of its bit in the block's mask, so
// the output never depends on the thread count and needs no hash map.
#include "MeshPasses.h"
#include "Stage.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_scan.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>

namespace isouq {
namespace mc_internal {

constexpr openvdb::Index64 kSerialLeaves = 32; // fewer leaves: one thread (bench/README.md)
constexpr std::size_t kScanGrain = 16384;        // blocks per task of the parallel prefix sums

/// Stage wall times of IsosurfaceMesher::StageTimes: lap(t) sets t to the time since the last lap.
class StageClock {
public:
    explicit StageClock(IsosurfaceMesher::StageTimes& times) { times = {}; }
    void lap(double& ms)
    {
        const auto now = std::chrono::steady_clock::now();
        ms = std::chrono::duration<double, std::milli>(now - mLast).count();
        mLast = now;
    }

private:
    std::chrono::steady_clock::time_point mLast = std::chrono::steady_clock::now();
};

} // namespace mc_internal

namespace mc_internal {
/// What an IsosurfaceMesher keeps between calls.
struct MesherBuffers {
    PageVector<std::uint8_t> sides;
    PageVector<BlockCounts> counts;
    PageVector<std::uint64_t> vertexOffsets, triangleOffsets;
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
    const bool flip = flipsTriangles(grid, settings);
    const bool provenance = settings.provenance || settings.uncertainty;

    const InterrupterStage stage(interrupter, "Meshing");

    // Small grids run serially: waking the worker threads for each pass costs more than a few
    // hundred blocks take (issue 12, "Small-grid latency").
    const bool threaded = settings.threaded && grid.tree().leafCount() >= kSerialLeaves;
    StageClock clock(mStageTimes);
    BlockSet blocks;
    buildBlockSet(grid.tree(), blocks, threaded);
    clock.lap(mStageTimes.blocks);
    throwIfInterrupted(interrupter);
    const std::size_t blockCount = blocks.origins.size();
    // Counting reads one voxel beyond the block (gatherBitsAndClassify); the fill, fillWindow.
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> scratch(
        std::cref(grid.tree()), std::cref(blocks.index), 1);
    const FillWindow window = fillWindow(settings);
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> stencilScratch(std::cref(grid.tree()),
        std::cref(blocks.index), window.lo, window.width);
    std::atomic<std::size_t> done{0};
    const std::size_t work = 3 * blockCount;

    // Which side of the isovalue each block lies on, so blocks far from the surface cost little.
    PageVector<std::uint8_t>& sides = buffers.sides;
    assignFresh(sides, blockCount, std::uint8_t(0), threaded);
    forEachBlock(blockCount, threaded, interrupter, done, work, [&](std::size_t b) {
        sides[b] = scratch.local().regionSide(blocks.origins[b], isovalue);
    });
    clock.lap(mStageTimes.sides);

    // Count pass: per block its counts; the edge masks of non-empty blocks go to per-thread lists.
    PageVector<BlockCounts>& counts = buffers.counts;
    assignFresh(counts, blockCount, BlockCounts{}, threaded);
    FoundMasks found;
    forEachBlock(blockCount, threaded, interrupter, done, work, [&](std::size_t b) {
        countPassBlock(scratch.local(), blocks, b, isovalue, cellBox, sides, counts[b], found);
    });
    clock.lap(mStageTimes.count);

    // Prefix sums: each block's place in the output. Integer sums, so a parallel scan gives the
    // same offsets as a serial loop whatever the thread count.
    PageVector<std::uint64_t>& vertexOffsets = buffers.vertexOffsets;
    PageVector<std::uint64_t>& triangleOffsets = buffers.triangleOffsets;
    resizeForFill(vertexOffsets, blockCount + 1, threaded);
    resizeForFill(triangleOffsets, blockCount + 1, threaded);
    struct Sums {
        std::uint64_t vertices = 0, triangles = 0;
    };
    auto scan = [&](const tbb::blocked_range<std::size_t>& r, Sums sum, bool final) {
        for (std::size_t b = r.begin(); b < r.end(); ++b) {
            if (final) {
                vertexOffsets[b] = sum.vertices;
                triangleOffsets[b] = sum.triangles;
            }
            sum.vertices += counts[b].vertices;
            sum.triangles += counts[b].triangles;
        }
        return sum;
    };
    const tbb::blocked_range<std::size_t> allBlocks(0, blockCount, kScanGrain);
    const Sums total = threaded && blockCount >= 2 * kScanGrain
        ? tbb::parallel_scan(allBlocks, Sums{}, scan, [](const Sums& a, const Sums& b) {
              return Sums{a.vertices + b.vertices, a.triangles + b.triangles};
          })
        : scan(allBlocks, Sums{}, true);
    vertexOffsets[blockCount] = total.vertices;
    triangleOffsets[blockCount] = total.triangles;
    // The masks stay in the count pass's lists, which live to the end of this call; each block
    // points at its own (no copy; a reused mesher's pointers are set again by the next call).
    EdgeMasks& masks = buffers.masks;
    assignFresh(masks.byBlock, blockCount, static_cast<const EdgeMask*>(nullptr), threaded);
    auto pointAtMasks = [&](auto& lists) {
        for (const auto& list : lists)
            list.forEach([&](const FoundMask& f) { masks.byBlock[std::size_t(f.block)] = &f.mask; });
    };
    if (threaded) tbb::parallel_for(found.range(1), pointAtMasks);
    else pointAtMasks(found);
    if (vertexOffsets[blockCount] > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    checkMeshFits(vertexOffsets[blockCount], triangleOffsets[blockCount], settings, provenance);
    clock.lap(mStageTimes.offsets);

    const WorldMap toWorld(grid.transform());
    mesh.indexToWorld = toWorld.rowMajor();
    const VertexColumns columns = VertexColumns::allocate(mesh, vertexOffsets[blockCount],
        triangleOffsets[blockCount], provenance, settings, threaded);
    clock.lap(mStageTimes.allocate);
    const VertexContext context{isovalue, toWorld, grid.transform().voxelSize(), bounds,
        settings.stencil, settings.method, settings.uncertainty};

    // Fill pass.
    const FillTarget target{masks, vertexOffsets, 0, context, columns, flip};
    forEachBlock(blockCount, threaded, interrupter, done, work, [&](std::size_t b) {
        if (counts[b].empty()) return;
        fillPassBlock(stencilScratch.local(), blocks, b, counts[b], cellBox, target,
            mesh.triangles.data() + triangleOffsets[b]);
    });
    clock.lap(mStageTimes.fill);
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
