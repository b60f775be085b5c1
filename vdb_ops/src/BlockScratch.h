// isouq: the block layer shared by the mesher and the hidden-feature pass (SPEC §9;
// DESIGN.md "Pass structure"): 8^3 blocks aligned with the grid's leaves, the set of blocks to
// visit with a lookup from block to index, and a block's values gathered with a halo into a small
// dense array with bit rows (one bit per z) of inside and active voxels. Internal to vdb_ops.
#pragma once

#include "FreshPages.h"

#include <openvdb/openvdb.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <optional>
#include <vector>

namespace isouq {
namespace mc_internal {

using openvdb::Coord;
using openvdb::CoordBBox;

constexpr int kBlockDim = 8;

inline int voxelOffset(int x, int y, int z) { return (x << 6) | (y << 3) | z; }

enum RegionSide : std::uint8_t { kAllOutside = 0, kAllInside = 1, kMixed = 2 };

/// dst[i] = src[i] for i < n <= 8, inlined (a call to memmove costs more than the copy).
inline void copyRow(float* dst, const float* src, int n)
{
    switch (n) {
    case 8: std::memcpy(dst, src, 8 * sizeof(float)); return;
    case 2: std::memcpy(dst, src, 2 * sizeof(float)); return;
    case 1: dst[0] = src[0]; return;
    case 3: std::memcpy(dst, src, 3 * sizeof(float)); return;
    default: for (int i = 0; i < n; ++i) dst[i] = src[i];
    }
}

/// Bit z set when v[z] >= k, for z < n <= 16 (four at a time with SSE2: v must be readable up
/// to a multiple of 4 past n, which the windows' row padding guarantees).
inline std::uint32_t insideBits(const float* v, int n, float k)
{
    std::uint32_t bits = 0;
#ifdef __SSE2__
    const __m128 kk = _mm_set1_ps(k);
    for (int z = 0; z < n; z += 4)
        bits |= std::uint32_t(_mm_movemask_ps(_mm_cmpge_ps(_mm_loadu_ps(v + z), kk))) << z;
    return bits & ((1u << n) - 1u);
#else
    for (int z = 0; z < n; ++z) bits |= std::uint32_t(v[z] >= k) << z;
    return bits;
#endif
}

/// insideBits of n <= 8 values of a leaf row: four at a time only for a whole row (a part may
/// end at the leaf buffer's end).
inline std::uint32_t leafRowInside(const float* v, int n, float k)
{
    if (n == kBlockDim) return insideBits(v, n, k);
    std::uint32_t bits = 0;
    for (int z = 0; z < n; ++z) bits |= std::uint32_t(v[z] >= k) << z;
    return bits;
}

/// One voxel per block (coordinates >> 3), value = block index. Small internal nodes (8^3
/// children rather than OpenVDB's 32^3 and 16^3) keep a small grid's index to a few pages,
/// which matters when meshing interactively (page faults are expensive here).
using BlockIndexTree = openvdb::tree::Tree4<std::int32_t, 3, 3, 3>::Type;

/// The blocks to visit, in a deterministic order, and a lookup from block to index.
struct BlockSet {
    PageVector<Coord> origins;
    BlockIndexTree index{-1};

    std::int32_t find(const Coord& origin) const { return index.getValue(origin >> 3); }

    /// The block at @a origin and its + neighbours: out[dx][dy][dz] is the index of the block at
    /// origin + 8 (dx, dy, dz), -1 where there is none (the blocks a block's triangles use).
    void plusNeighbours(const Coord& origin, std::int32_t (&out)[2][2][2]) const
    {
        for (int dx = 0; dx < 2; ++dx)
            for (int dy = 0; dy < 2; ++dy)
                for (int dz = 0; dz < 2; ++dz) out[dx][dy][dz] = find(origin.offsetBy(8 * dx, 8 * dy, 8 * dz));
    }
};

/// Which blocks around a leaf with an active voxel are visited: all 26 neighbours (the mesher:
/// cells with an active corner and the edges they use lie within one voxel of it), or only the
/// 7 below (cells with an active corner, owned by the block of their lower corner).
enum class BlockReach { Around, Below };

/// Marks in @a coarse the blocks around (or up to) the blocks @a leafBlocks (leaf origins >> 3):
/// only their value masks, as the blocks' values are set when they are numbered. The coarse
/// leaves the marks fall in are made first, on one thread (a tree grows on one thread); then
/// every thread ORs each leaf block's 3 x 3 (or 2 x 2) z-rows of bits into them, one 64-bit word
/// (an x-slice of a coarse leaf) at a time, atomically, as neighbouring leaf blocks share words.
inline void markBlocks(const PageVector<Coord>& leafBlocks, BlockIndexTree& coarse, BlockReach reach, bool threaded)
{
    using CoarseLeaf = BlockIndexTree::LeafNodeType;
    static_assert(CoarseLeaf::LOG2DIM == 3, "a coarse leaf's x-slice is one 64-bit mask word");
    const int to = reach == BlockReach::Around ? 1 : 0;
    // The coarse leaves [lo >> 3, hi >> 3] (one or two per axis) that [b - 1, b + to] reaches.
    auto forEachLeaf = [&](const Coord& b, auto&& f) {
        const Coord lo = b.offsetBy(-1), hi = b.offsetBy(to), cLo = lo >> 3, cHi = hi >> 3;
        for (int cx = cLo[0]; cx <= cHi[0]; ++cx)
            for (int cy = cLo[1]; cy <= cHi[1]; ++cy)
                for (int cz = cLo[2]; cz <= cHi[2]; ++cz) f(Coord(cx * 8, cy * 8, cz * 8), lo, hi);
    };
    {
        openvdb::tree::ValueAccessor<BlockIndexTree, false> acc(coarse);
        for (const Coord& b : leafBlocks)
            forEachLeaf(b, [&](const Coord& leaf, const Coord&, const Coord&) { acc.touchLeaf(leaf); });
    }
    auto mark = [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<BlockIndexTree, false> acc(coarse); // finds leaves; adds none
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            forEachLeaf(leafBlocks[i], [&](const Coord& leaf, const Coord& lo, const Coord& hi) {
                const Coord from = Coord::maxComponent(lo, leaf) - leaf;
                const Coord until = Coord::minComponent(hi, leaf.offsetBy(7)) - leaf;
                // Bit y * 8 + z of word x is voxel (x, y, z) of the coarse leaf.
                const std::uint64_t zRow = ((std::uint64_t(2) << (until[2] - from[2])) - 1) << from[2];
                std::uint64_t rows = 0;
                for (int y = from[1]; y <= until[1]; ++y) rows |= zRow << (8 * y);
                CoarseLeaf* node = acc.probeLeaf(leaf);
                for (int x = from[0]; x <= until[0]; ++x)
                    __atomic_fetch_or(&node->getValueMask().template getWord<std::uint64_t>(x), rows, __ATOMIC_RELAXED);
            });
        }
    };
    const tbb::blocked_range<std::size_t> all(0, leafBlocks.size(), 1024);
    if (threaded) tbb::parallel_for(all, mark);
    else mark(all);
}

template <typename TreeT>
void buildBlockSet(const TreeT& tree, BlockSet& blocks, bool threaded, BlockReach reach = BlockReach::Around)
{
    using LeafT = typename TreeT::LeafNodeType;
    BlockIndexTree& coarse = blocks.index;
    // The 27 blocks around (or the 8 up to) each leaf, marked in the coarse tree (markBlocks): on
    // a small grid this is several times cheaper than a tools::dilateActiveValues of the leaves'
    // blocks, which it equals (the coarse tree has no tiles yet; issue 12, "Small-grid latency").
    PageVector<const LeafT*> leaves;
    reserveFresh(leaves, tree.leafCount(), threaded);
    tree.getNodes(leaves);
    PageVector<Coord> leafBlocks;
    resizeForFill(leafBlocks, leaves.size(), threaded);
    auto origins = [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i)
            leafBlocks[i] = leaves[i]->isEmpty() ? Coord::max() : leaves[i]->origin() >> 3;
    };
    const tbb::blocked_range<std::size_t> allLeaves(0, leaves.size(), 1024);
    if (threaded) tbb::parallel_for(allLeaves, origins);
    else origins(allLeaves);
    leafBlocks.erase(std::remove(leafBlocks.begin(), leafBlocks.end(), Coord::max()), leafBlocks.end());
    markBlocks(leafBlocks, coarse, reach, threaded);
    bool tiles = false;
    // Active tiles: only the blocks within one voxel of a tile's border can hold a crossing
    // between the tile and its surroundings; the tile's interior is constant and is skipped.
    typename TreeT::ValueOnCIter tile = tree.cbeginValueOn();
    tile.setMaxDepth(TreeT::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile) {
        tiles = true;
        CoordBBox box;
        tile.getBoundingBox(box);
        const Coord lo = box.min() >> 3, hi = box.max() >> 3;
        coarse.fill(CoordBBox(lo.offsetBy(-1), hi.offsetBy(1)), 0, true);
        if (hi[0] - lo[0] >= 2 && hi[1] - lo[1] >= 2 && hi[2] - lo[2] >= 2)
            coarse.fill(CoordBBox(lo.offsetBy(1), hi.offsetBy(-1)), -1, false);
    }
    if (tiles) coarse.voxelizeActiveTiles(threaded); // without tile fills there are no tiles
    // Number the blocks in the coarse tree's order (the same whatever the threads): each coarse
    // leaf's first index is the count of blocks in the leaves before it.
    std::vector<BlockIndexTree::LeafNodeType*> coarseLeaves;
    coarse.getNodes(coarseLeaves);
    std::vector<std::int32_t> first(coarseLeaves.size() + 1, 0);
    for (std::size_t i = 0; i < coarseLeaves.size(); ++i)
        first[i + 1] = first[i] + std::int32_t(coarseLeaves[i]->onVoxelCount());
    resizeForFill(blocks.origins, std::size_t(first.back()), threaded);
    auto number = [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            std::int32_t next = first[i];
            for (auto v = coarseLeaves[i]->beginValueOn(); v; ++v) {
                v.setValue(next);
                const Coord b = v.getCoord(); // * 8, not << 3: a left shift of a negative int is UB in C++17
                blocks.origins[std::size_t(next++)] = Coord(b[0] * 8, b[1] * 8, b[2] * 8);
            }
        }
    };
    const tbb::blocked_range<std::size_t> all(0, coarseLeaves.size(), 16);
    if (threaded) tbb::parallel_for(all, number);
    else number(all);
}

/// A block's values with a halo, and bit rows (one bit per z) of which voxels are inside
/// (>= isovalue) and active, and of which cells are meshed and cross. Coordinates are relative
/// to the block origin and range over [lo, lo + width); everything stays in cache.
template <typename TreeT>
class BlockScratch {
public:
    using LeafT = typename TreeT::LeafNodeType;

    /// The window [-halo, 8 + halo)^3.
    BlockScratch(const TreeT& tree, const BlockIndexTree& blockIndex, int halo)
        : BlockScratch(tree, blockIndex, -halo, kBlockDim + 2 * halo)
    {
    }
    /// The window [lo, lo + width)^3, lo in [-8, 0], lo + width in [8, 16].
    BlockScratch(const TreeT& tree, const BlockIndexTree& blockIndex, int lo, int width)
        : mAccessor(tree), mBlockIndex(blockIndex), mLo(lo), mWidth(width),
          mValues(std::size_t(mWidth) * mWidth * mWidth + kRowPadding), mInsideRows(std::size_t(mWidth) * mWidth),
          mActiveRows(mInsideRows.size())
    {
    }

    int index(int x, int y, int z) const { return ((x - mLo) * mWidth + (y - mLo)) * mWidth + (z - mLo); }
    float value(int x, int y, int z) const { return mValues[index(x, y, z)]; }
    /// The value of (x, y, z) in memory; stride(axis) floats apart along an axis.
    const float* at(int x, int y, int z) const { return &mValues[std::size_t(index(x, y, z))]; }
    int stride(int axis) const { return axis == 0 ? mWidth * mWidth : axis == 1 ? mWidth : 1; }
    bool isActive(int x, int y, int z) const { return (activeRow(x, y) >> (z - mLo)) & 1u; }

    /// Which side of the isovalue the 8^3 region at @a origin lies on: a cheap summary that lets
    /// a block whose whole neighbourhood is on one side be skipped without gathering it.
    std::uint8_t regionSide(const Coord& origin, float isovalue)
    {
        if (const LeafT* leaf = mAccessor.probeConstLeaf(origin)) {
            const float* v = leaf->buffer().data();
            unsigned inside = 0;
            for (int i = 0; i < 512; ++i) inside += v[i] >= isovalue;
            return inside == 0 ? kAllOutside : inside == 512 ? kAllInside : kMixed;
        }
        return mAccessor.getValue(origin) >= isovalue ? kAllInside : kAllOutside;
    }

    /// False when the block and its + neighbours, whose inside bits gatherBitsAndClassify reads,
    /// lie on the same side of the isovalue: then no owned edge crosses and no cell is a candidate.
    bool mayCross(const Coord& origin, float isovalue, const PageVector<std::uint8_t>& sides)
    {
        int seen = -1;
        for (int bx = 0; bx <= 1; ++bx)
            for (int by = 0; by <= 1; ++by)
                for (int bz = 0; bz <= 1; ++bz) {
                    const Coord o = origin.offsetBy(bx * kBlockDim, by * kBlockDim, bz * kBlockDim);
                    const std::int32_t b = mBlockIndex.getValue(o >> 3);
                    const int side = b >= 0 ? sides[std::size_t(b)] : regionSide(o, isovalue);
                    if (side == kMixed || (seen >= 0 && side != seen)) return true;
                    seen = side;
                }
        return false;
    }

    /// Copies values and active states of [lo, lo + width)^3 around @a origin, one leaf probe
    /// per neighbouring block (a missing leaf is a constant tile or background), and classifies
    /// the cells with minimum corner in [-1, 8)^3: a cell is a candidate when it is meshed (an
    /// active corner, minimum corner inside @a cellBox if given) and its corners straddle k.
    /// Returns false when no cell crosses.
    bool gatherAndClassify(const Coord& origin, float isovalue, const std::optional<CoordBBox>& cellBox)
    {
        gather(origin, isovalue);
        return classify(origin, cellBox, std::max(mLo, -1)).anyCandidate;
    }

    /// For the count pass, which reads no values: the active bits of the window [-1, 9)^3 (halo
    /// 1), from the leaves' masks alone, and the inside bits of [0, 9)^3, from the block and its
    /// + neighbours. That is all an owned edge's vertex and a cell [0, 8)^3 depend on (an edge
    /// that crosses straddles in each of its four cells, so those at -1 need only be meshed):
    /// the - neighbours' values are never read. Returns false when no cell is meshed.
    bool gatherBitsAndClassify(const Coord& origin, float isovalue, const std::optional<CoordBBox>& cellBox)
    {
        clearRows();
        for (int bx = firstBlock(); bx <= lastBlock(); ++bx)
            for (int by = firstBlock(); by <= lastBlock(); ++by)
                for (int bz = firstBlock(); bz <= lastBlock(); ++bz) {
                    if (bx < 0 || by < 0 || bz < 0) gatherNeighbour<Gather::ActiveBits>(origin, bx, by, bz, isovalue);
                    else gatherNeighbour<Gather::InsideBits>(origin, bx, by, bz, isovalue);
                }
        return classify(origin, cellBox, 0).anyMeshed;
    }

    /// Copies values and active states of [lo, lo + width)^3 around @a origin, and the inside
    /// bits of the voxels [-1, 9)^3 (those of the cells [-1, 8)^3).
    void gather(const Coord& origin, float isovalue)
    {
        clearRows();
        for (int bx = firstBlock(); bx <= lastBlock(); ++bx)
            for (int by = firstBlock(); by <= lastBlock(); ++by)
                for (int bz = firstBlock(); bz <= lastBlock(); ++bz)
                    gatherNeighbour<Gather::Values>(origin, bx, by, bz, isovalue);
        // Cells read the inside bits of voxels [-1, 9)^3 only; the rest is stencil.
        for (int x = std::max(mLo, -1); x < std::min(mLo + mWidth, kBlockDim + 1); ++x)
            for (int y = std::max(mLo, -1); y < std::min(mLo + mWidth, kBlockDim + 1); ++y) {
                const int row = (x - mLo) * mWidth + (y - mLo);
                mInsideRows[std::size_t(row)] = insideBits(&mValues[std::size_t(row * mWidth)], mWidth, isovalue);
            }
    }

    /// Floats after the last row, so a row may be read four values at a time past its end.
    static constexpr int kRowPadding = 4;

    int lo() const { return mLo; }
    /// The values of the row (x, y): z from lo() on, width() of them.
    const float* row(int x, int y) const { return &mValues[std::size_t(index(x, y, mLo))]; }
    /// Bits z - lo() of the row (x, y): inside (x, y in [-1, 9) only) and active voxels.
    std::uint32_t insideRow(int x, int y) const { return mInsideRows[(x - mLo) * mWidth + (y - mLo)]; }
    std::uint32_t activeRow(int x, int y) const { return mActiveRows[(x - mLo) * mWidth + (y - mLo)]; }

    /// Bits z + 1 of the candidate cells (x, y, -1..7), for x, y in [-1, 8).
    std::uint32_t cellRow(int x, int y) const { return mCellRows[(x + 1) * 9 + (y + 1)]; }
    /// Bits z + 1 of the meshed cells (x, y, -1..7), for x, y in [-1, 8): cells with an active
    /// corner, inside the cell box; set by gatherBitsAndClassify.
    std::uint32_t meshedRow(int x, int y) const { return mMeshedRows[(x + 1) * 9 + (y + 1)]; }
    /// Bits z of the inside voxels (x, y, 0..8), for x, y in [0, 9).
    std::uint32_t insideFromZero(int x, int y) const { return insideRow(x, y) >> -mLo; }

    /// The marching-cubes case of cell (x, y, z), from the inside bit rows.
    int cubeCase(int x, int y, int z) const
    {
        const int shift = z - mLo;
        const std::uint32_t r00 = insideRow(x, y) >> shift, r10 = insideRow(x + 1, y) >> shift;
        const std::uint32_t r11 = insideRow(x + 1, y + 1) >> shift, r01 = insideRow(x, y + 1) >> shift;
        return int((r00 & 1) | (r10 & 1) << 1 | (r11 & 1) << 2 | (r01 & 1) << 3 | (r00 & 2) << 3 |
                   (r10 & 2) << 4 | (r11 & 2) << 5 | (r01 & 2) << 6);
    }

private:
    using Index = openvdb::Index;

    int firstBlock() const { return (mLo - (kBlockDim - 1)) / kBlockDim; } // floor(lo / 8)
    int lastBlock() const { return (mLo + mWidth - 1) / kBlockDim; }

    void clearRows()
    {
        std::fill(mInsideRows.begin(), mInsideRows.end(), 0u);
        std::fill(mActiveRows.begin(), mActiveRows.end(), 0u);
    }

    /// What gatherNeighbour copies besides the active bits: the values (their inside bits are
    /// taken later, for the cells' voxels only), the inside bits alone, or nothing.
    enum class Gather { Values, InsideBits, ActiveBits };

    /// The active bits, and what @a kWhat names, of the part of the window in neighbour block
    /// (bx, by, bz).
    template <Gather kWhat>
    void gatherNeighbour(const Coord& origin, int bx, int by, int bz, float isovalue)
    {
        // Locals, not members, in the loops: stores to the uint32 rows could alias the ints.
        const int lo = mLo, width = mWidth, hi = lo + width;
        const int x0 = std::max(lo, bx * kBlockDim), x1 = std::min(hi, (bx + 1) * kBlockDim);
        const int y0 = std::max(lo, by * kBlockDim), y1 = std::min(hi, (by + 1) * kBlockDim);
        const int z0 = std::max(lo, bz * kBlockDim), z1 = std::min(hi, (bz + 1) * kBlockDim);
        if (x0 >= x1 || y0 >= y1 || z0 >= z1) return;
        const int zCount = z1 - z0, zShift = z0 - lo;
        const std::uint32_t zRun = (1u << zCount) - 1u;
        float* values = mValues.data();
        std::uint32_t* activeRows = mActiveRows.data();
        std::uint32_t* insideRows = mInsideRows.data();
        const Coord nOrigin = origin.offsetBy(bx * kBlockDim, by * kBlockDim, bz * kBlockDim);
        if (const LeafT* leaf = mAccessor.probeConstLeaf(nOrigin)) {
            const float* buffer = kWhat == Gather::ActiveBits ? nullptr : leaf->buffer().data();
            const auto& mask = leaf->getValueMask();
            for (int x = x0; x < x1; ++x)
                for (int y = y0; y < y1; ++y) {
                    const int src = voxelOffset(x - bx * kBlockDim, y - by * kBlockDim, z0 - bz * kBlockDim);
                    const int row = (x - lo) * width + (y - lo);
                    if constexpr (kWhat == Gather::Values) copyRow(values + row * width + zShift, buffer + src, zCount);
                    if constexpr (kWhat == Gather::InsideBits)
                        insideRows[row] |= leafRowInside(buffer + src, zCount, isovalue) << zShift;
                    // Mask word x holds the active bits of rows y = 0..7, z = 0..7 in bits 8y + z.
                    const auto word = mask.template getWord<std::uint64_t>(Index(src >> 6));
                    activeRows[row] |= (std::uint32_t(word >> (src & 63)) & zRun) << zShift;
                }
        } else {
            float tileValue;
            const bool tileActive = mAccessor.probeValue(nOrigin, tileValue);
            const std::uint32_t active = tileActive ? zRun << zShift : 0u;
            const std::uint32_t inside = tileValue >= isovalue ? zRun << zShift : 0u;
            for (int x = x0; x < x1; ++x)
                for (int y = y0; y < y1; ++y) {
                    const int row = (x - lo) * width + (y - lo);
                    if constexpr (kWhat == Gather::Values) std::fill_n(values + row * width + zShift, zCount, tileValue);
                    if constexpr (kWhat == Gather::InsideBits) insideRows[row] |= inside;
                    activeRows[row] |= active;
                }
        }
    }

    /// Whether classify found any candidate cell, and any meshed cell.
    struct Classified {
        bool anyCandidate = false, anyMeshed = false;
    };
    /// Meshed cells (an active corner; minimum corner inside @a cellBox if given) and, among
    /// them, candidates (corners straddling k), of the cells with minimum corner in [from, 8)^3,
    /// from = max(lo, -1); candidates only from @a insideFrom on (where the inside bits are).
    Classified classify(const Coord& origin, const std::optional<CoordBBox>& cellBox, int insideFrom)
    {
        // Cells (x, y, -1..7) use voxel bits z - lo and z - lo + 1: bit z + 1 is cell z.
        const int shift = -1 - mLo;
        auto align = [shift](std::uint32_t bits) { return shift >= 0 ? bits >> shift : bits << -shift; };
        const int from = std::max(mLo, -1);
        std::uint32_t cellMask = (1u << (kBlockDim + 1)) - 1u;
        int xLo = from, xHi = kBlockDim - 1, yLo = from, yHi = kBlockDim - 1;
        if (cellBox) {
            const Coord lo = cellBox->min() - origin, hi = cellBox->max() - origin;
            xLo = std::max(xLo, lo[0]), xHi = std::min(xHi, hi[0]);
            yLo = std::max(yLo, lo[1]), yHi = std::min(yHi, hi[1]);
            const int zLo = std::max(-1, lo[2]), zHi = std::min(kBlockDim - 1, hi[2]);
            cellMask = zLo > zHi ? 0u : (((2u << (zHi + 1)) - 1u) & ~((1u << (zLo + 1)) - 1u));
        }
        const std::uint32_t candidateMask = cellMask & ~((1u << (insideFrom + 1)) - 1u);
        mCellRows.fill(0u);
        mMeshedRows.fill(0u);
        Classified found;
        for (int x = xLo; x <= xHi; ++x)
            for (int y = yLo; y <= yHi; ++y) {
                const std::uint32_t act4 = activeRow(x, y) | activeRow(x + 1, y) |
                                           activeRow(x, y + 1) | activeRow(x + 1, y + 1);
                const std::uint32_t meshed = align(act4 | (act4 >> 1)) & cellMask;
                mMeshedRows[(x + 1) * 9 + (y + 1)] = meshed;
                found.anyMeshed |= meshed != 0;
                if (x < insideFrom || y < insideFrom) continue;
                const std::uint32_t in4 = insideRow(x, y) & insideRow(x + 1, y) &
                                          insideRow(x, y + 1) & insideRow(x + 1, y + 1);
                const std::uint32_t any4 = insideRow(x, y) | insideRow(x + 1, y) |
                                           insideRow(x, y + 1) | insideRow(x + 1, y + 1);
                const std::uint32_t cells = align(any4 | (any4 >> 1)) & ~align(in4 & (in4 >> 1)) & meshed & candidateMask;
                mCellRows[(x + 1) * 9 + (y + 1)] = cells;
                found.anyCandidate |= cells != 0;
            }
        return found;
    }

    // Not registered with the trees (a registration per scratch and call is a locked hash-map
    // insert): the trees are not changed while a scratch reads them.
    openvdb::tree::ValueAccessor<const TreeT, false> mAccessor;
    openvdb::tree::ValueAccessor<const BlockIndexTree, false> mBlockIndex;
    int mLo, mWidth;
    std::vector<float> mValues;
    std::vector<std::uint32_t> mInsideRows; // per (x, y): bit z - lo set when value >= isovalue
    std::vector<std::uint32_t> mActiveRows; // per (x, y): bit z - lo set when active
    std::array<std::uint32_t, 81> mCellRows{};   // per cell row (x, y) in [-1, 8)^2: candidates
    std::array<std::uint32_t, 81> mMeshedRows{}; // the same: meshed cells
};

} // namespace mc_internal
} // namespace isouq
