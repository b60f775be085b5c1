// isouq: what the three parts of the hidden-feature pass share (paper sec. 4.2; SPEC §4;
// docs/hidden-features.md). HiddenDetect.cc finds the cells to refine, HiddenPatches.cc meshes
// refined and transition cells, HiddenFeatures.cc joins them to the standard mesh. Internal to
// vdb_ops.
#pragma once

#include "isouq/HiddenFeatures.h"
#include "isouq/Progress.h"

#include "BlockScratch.h"

#include <openvdb/thread/Threading.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <vector>

namespace isouq {
namespace hidden_internal {

using openvdb::Coord;
using openvdb::CoordBBox;
using mc_internal::BlockIndexTree;
using mc_internal::BlockSet;
using mc_internal::kBlockDim;

constexpr int kMaxSubdivisions = 64;

/// A vertex of a new triangle. The top two bits say what it is:
///  kFineRef:   the crossing of a subcell edge, by its index in the patch's crossings;
///  kCoarseRef: the standard vertex of a grid edge, (x, y, z, axis) of its lower voxel, relative
///              to the voxel origin;
///  kCentreRef: a fan centre, by its index in the patch that made it.
using Ref = std::uint64_t;
constexpr Ref kFineRef = 0, kCoarseRef = Ref(1) << 62, kCentreRef = Ref(2) << 62, kKindMask = Ref(3) << 62;
constexpr int kCoordBits = 20;

/// Packs lattice points into keys (the fine key of a subcell edge is (x, y, z, axis) of its lower
/// point on the fine lattice m * voxel + sub, 20 bits each); the origins make every coordinate of
/// the refined region fit.
struct Packer {
    Coord fineOrigin, voxelOrigin;

    static Ref pack(const Coord& rel, int axis)
    {
        return (Ref(std::uint32_t(rel[0])) << 42) | (Ref(std::uint32_t(rel[1])) << 22) |
               (Ref(std::uint32_t(rel[2])) << 2) | Ref(axis);
    }
    static Coord unpack(Ref r)
    {
        const Ref mask = (Ref(1) << kCoordBits) - 1;
        return Coord(int((r >> 42) & mask), int((r >> 22) & mask), int((r >> 2) & mask));
    }
    static int axisOf(Ref r) { return int(r & 3); }
    Ref fine(const Coord& p, int axis) const { return kFineRef | pack(p - fineOrigin, axis); }
    Coord finePoint(Ref r) const { return unpack(r) + fineOrigin; }
    Ref coarse(const Coord& v, int axis) const { return kCoarseRef | pack(v - voxelOrigin, axis); }
    bool coarseFits(const Coord& v) const
    {
        for (int i = 0; i < 3; ++i)
            if (v[i] - voxelOrigin[i] < 0 || v[i] - voxelOrigin[i] >= (1 << kCoordBits)) return false;
        return true;
    }
};

struct FineCrossing {
    Ref key;
    float t;            // along the subcell edge from its lower point
    std::uint32_t slot; // where its global vertex index goes (set when the patches are merged)
};

/// What one chunk of refined or transition cells adds. Triangles face from inside (>= k)
/// towards outside, as the case tables' do.
struct Patch {
    std::vector<FineCrossing> crossings; // the crossings its triangles and loops use (kFineRef)
    std::vector<std::array<Ref, 3>> triangles;
    std::vector<Ref> members;              // transition loops: their vertices,
    std::vector<std::uint32_t> memberEnds; // one end per loop (= per fan centre)
    std::vector<Coord> centreCells;        // the transition cell of each loop
};

/// Runs body(i) for i in [0, count) in parallel (or serially), polling the interrupter.
template <typename Body>
void forEach(std::size_t count, std::size_t grain, bool threaded,
    openvdb::util::NullInterrupter* interrupter, Body&& body)
{
    std::atomic<bool> stop{false};
    auto range = [&](const tbb::blocked_range<std::size_t>& r) {
        if (stop.load(std::memory_order_relaxed)) return;
        if (openvdb::util::wasInterrupted(interrupter)) {
            stop = true;
            openvdb::thread::cancelGroupExecution();
            return;
        }
        for (std::size_t i = r.begin(); i < r.end(); ++i) body(i);
    };
    const tbb::blocked_range<std::size_t> all(0, count, std::max<std::size_t>(grain, 1));
    if (threaded) tbb::parallel_for(all, range);
    else range(all);
    if (stop) throw InterruptedError();
}

/// Runs body(begin, end) over [0, count) in chunks of @a chunk (per-thread state is then looked up
/// once per chunk, not once per item).
template <typename Body>
void forEachChunk(std::size_t count, std::size_t chunk, bool threaded, openvdb::util::NullInterrupter* interrupter,
    Body&& body)
{
    forEach((count + chunk - 1) / chunk, 1, threaded, interrupter,
        [&](std::size_t c) { body(c * chunk, std::min(count, (c + 1) * chunk)); });
}

/// One bit per cell of every block of a BlockSet: word x of a block holds bits y * 8 + z (the
/// leaf order of OpenVDB, so iterating bits visits cells in x, y, z order).
class BlockCells {
public:
    using Words = std::array<std::uint64_t, kBlockDim>;

    explicit BlockCells(std::size_t blockCount) : mWords(blockCount) {}

    static std::uint64_t bit(const Coord& local) { return std::uint64_t(1) << (local[1] * 8 + local[2]); }
    void set(std::int32_t block, const Coord& local) { mWords[std::size_t(block)][std::size_t(local[0])] |= bit(local); }
    bool test(std::int32_t block, const Coord& local) const
    {
        return (mWords[std::size_t(block)][std::size_t(local[0])] & bit(local)) != 0;
    }
    const Words& words(std::int32_t block) const { return mWords[std::size_t(block)]; }

private:
    std::vector<Words> mWords;
};

/// The block of a cell and the cell's place in it, remembering the last block (the cells looked
/// up one after another are mostly in one block). Cheap to make: its accessor is not registered
/// with the index tree, which nothing changes while blocks are looked up.
class BlockFinder {
public:
    explicit BlockFinder(const BlockSet& blocks) : mIndex(blocks.index) {}

    /// The block index of @a cell's block (-1 if the set has no such block).
    std::int32_t find(const Coord& cell)
    {
        const Coord block = cell >> 3;
        if (block != mLastBlock) {
            mLastBlock = block;
            mLast = mIndex.getValue(block);
        }
        return mLast;
    }
    static Coord local(const Coord& cell) { return Coord(cell[0] & 7, cell[1] & 7, cell[2] & 7); }

private:
    openvdb::tree::ValueAccessor<const BlockIndexTree, /*IsSafe=*/false> mIndex;
    Coord mLastBlock{std::numeric_limits<openvdb::Int32>::max()};
    std::int32_t mLast = -1;
};

/// The offsets of a cell's 18 face and edge neighbours.
constexpr std::array<std::array<int, 3>, 18> kFaceEdgeNeighbours = [] {
    std::array<std::array<int, 3>, 18> out{};
    int n = 0;
    for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dz = -1; dz <= 1; ++dz) {
                const int l1 = (dx != 0) + (dy != 0) + (dz != 0);
                if (l1 == 1 || l1 == 2) out[std::size_t(n++)] = {dx, dy, dz};
            }
    return out;
}();

/// Detection (SPEC §4, HiddenDetect.cc): the cells to refine, in block order then x, y, z, of
/// the blocks [blockBegin, blockEnd) of the set (a piece's, SPEC §9; all by default).
struct Detection {
    std::vector<Coord> refined;
    std::size_t cellsTotal = 0, cellsFlagged = 0;
};
Detection detectRefinedCells(const openvdb::FloatTree& tree, const BlockSet& blocks, float k,
    const std::optional<CoordBBox>& dataBounds, const HiddenFeatureSettings& hidden, bool threaded,
    openvdb::util::NullInterrupter* interrupter, std::size_t blockBegin = 0,
    std::size_t blockEnd = std::numeric_limits<std::size_t>::max());

/// The surface of the refined cells (subcell marching cubes) and of the transition cells (fan
/// patches), HiddenPatches.cc: one Patch per chunk of cells, refined chunks first, each list in
/// its order; refinedChunks says where the transition chunks start.
struct ReplacedSurface {
    std::vector<Patch> patches;
    std::size_t refinedChunks = 0;
};
ReplacedSurface meshReplacedCells(const openvdb::FloatTree& tree, const BlockSet& blocks,
    const std::vector<Coord>& refined, const BlockCells& refinedCells, const std::vector<Coord>& transition,
    const Packer& packer, int m, float k, bool threaded, openvdb::util::NullInterrupter* interrupter);

} // namespace hidden_internal
} // namespace isouq
