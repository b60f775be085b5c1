// isouq: marching cubes with hidden features (paper sec. 4.2; SPEC §4, §6; docs/hidden-features.md).
//
// Passes, each parallel over a list whose order depends only on the grid:
//   detect:     per 8^3 block holding a meshed cell, gather values and active states with a halo,
//               apply the slope rule to the 12 edges of each cell, and keep the flagged cells
//               whose tricubic crosses k (and that pass the filter) as the refined set R;
//   refine:     per refined cell, marching cubes on its m^3 subcells (tricubic corner values);
//   transition: per unrefined cell sharing a face or an edge with R (the set T), the loops of its
//               faces' segments, each fanned to its centre (the paper's fan patch);
//   merge:      the standard mesh's triangles of cells outside R and T, then the new triangles;
//               new vertices are keyed by their subcell edge on the fine lattice m * voxel + sub,
//               sorted and shared, so neighbours meet exactly and no hash map is needed.
// Why no cracks: a face shared by R and T is cut by the same subface rule on the same tricubic
// values on both sides; a face of T with a refined edge is cut by the face-consistent rule
// (McTables.h) on the crossings of that edge's subdivision; a face between T and an ordinary
// cell has no refined edge (else that cell would be in T) and is cut exactly as marching cubes
// cuts it. Every crossing is the start of one face segment and the end of another, so the
// segments of a transition cell form closed loops.
#include "isouq/HiddenFeatures.h"
#include "isouq/McTables.h"
#include "isouq/Tricubic.h"

#include <openvdb/thread/Threading.h>
#include <openvdb/tools/Morphology.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <tuple>

namespace isouq {
namespace hidden_internal {

using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::Vec3d;
using Accessor = openvdb::tree::ValueAccessor<const openvdb::FloatTree>;

constexpr int kBlock = 8;
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
/// point on the fine lattice m * voxel + sub, 20 bits each); the origins make every coordinate of the refined region fit.
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
    std::vector<Ref> members;             // transition loops: their vertices,
    std::vector<std::uint32_t> memberEnds; // one end per loop (= per fan centre)
    std::vector<Coord> centreCells;        // the transition cell of each loop
};

using CellSet = openvdb::BoolTree;
using CellSetAccessor = openvdb::tree::ValueAccessor<const CellSet>;

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

std::optional<CoordBBox> dataBoundsOf(const openvdb::FloatGrid& grid, const MeshSettings& settings)
{
    if (settings.dataBounds) return settings.dataBounds;
    auto lo = grid.getMetadata<openvdb::Vec3IMetadata>(kDataBoundsMinMeta);
    auto hi = grid.getMetadata<openvdb::Vec3IMetadata>(kDataBoundsMaxMeta);
    if (!lo || !hi) return std::nullopt;
    return CoordBBox(Coord(lo->value()), Coord(hi->value()));
}

/// Origins of the 8^3 blocks that own a cell with an active corner, in tree order: blocks of
/// leaves with an active voxel and their - neighbours, and the blocks along active tiles' borders
/// (a tile's interior is constant: nothing turns there).
std::vector<Coord> blockOrigins(const openvdb::FloatTree& tree)
{
    openvdb::BoolTree coarse(false);
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
        if (leaf->isEmpty()) continue;
        const Coord b = leaf->origin() >> 3;
        coarse.fill(CoordBBox(b.offsetBy(-1), b), true, true);
    }
    auto tile = tree.cbeginValueOn();
    tile.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile) {
        CoordBBox box;
        tile.getBoundingBox(box);
        const Coord lo = box.min() >> 3, hi = box.max() >> 3;
        coarse.fill(CoordBBox(lo.offsetBy(-1), hi.offsetBy(1)), true, true);
        if (hi[0] - lo[0] >= 2 && hi[1] - lo[1] >= 2 && hi[2] - lo[2] >= 2)
            coarse.fill(CoordBBox(lo.offsetBy(1), hi.offsetBy(-1)), false, false);
    }
    coarse.voxelizeActiveTiles();
    std::vector<Coord> origins;
    for (auto v = coarse.cbeginValueOn(); v; ++v) origins.push_back(v.getCoord() << 3);
    return origins;
}

/// Values and active states of the voxels [-1, 10)^3 around a block: every corner and tricubic
/// stencil of the block's cells and of their neighbours. One leaf probe per neighbouring block.
/// Per-cell states are kept as rows of bits along z (bit z + 1 for z in [-1, 10) unless said).
class Window {
public:
    static constexpr int kLo = -1, kWidth = 11;

    void gather(const Accessor& acc, const Coord& origin, float k)
    {
        for (int bx = -1; bx <= 1; ++bx)
            for (int by = -1; by <= 1; ++by)
                for (int bz = -1; bz <= 1; ++bz) gatherBlock(acc, origin, bx, by, bz);
        slopeRows();
        stateRows(k);
    }
    /// Bits z of the block's cells (x, y, 0..7) that the slope rule flags (SPEC §4): a cell turns
    /// when one of its 12 edges does, and an edge when its three slopes rise and fall.
    std::uint32_t turningCells(int x, int y) const
    {
        auto edges = [this](int axis, int ex, int ey) { // bits z of the edges (ex, ey, z) that turn
            std::uint32_t rise, fall;
            if (axis == 2) {
                const std::uint32_t r = mRise[2][ex + 1][ey + 1], f = mFall[2][ex + 1][ey + 1];
                rise = r | r >> 1 | r >> 2; // slopes z - 1, z, z + 1 at bits z, z + 1, z + 2
                fall = f | f >> 1 | f >> 2;
            } else {
                const int dx = axis == 0, dy = axis == 1;
                rise = fall = 0;
                for (int s = -1; s <= 1; ++s) {
                    rise |= mRise[axis][ex + s * dx + 1][ey + s * dy + 1] >> 1;
                    fall |= mFall[axis][ex + s * dx + 1][ey + s * dy + 1] >> 1;
                }
            }
            return rise & fall;
        };
        const std::uint32_t alongZ = edges(2, x, y) | edges(2, x + 1, y) | edges(2, x, y + 1) | edges(2, x + 1, y + 1);
        const std::uint32_t across = edges(0, x, y) | edges(0, x, y + 1) | edges(1, x, y) | edges(1, x + 1, y);
        return (alongZ | across | across >> 1) & 0xffu;
    }
    /// Bits z of the block's cells (x, y, 0..7) that are meshed (an active corner, SPEC §1).
    std::uint32_t meshedCells(int x, int y) const { return (mMeshed[x + 1][y + 1] >> 1) & 0xffu; }
    /// Bits z of the block's cells (x, y, 0..7) whose 18 face and edge neighbours are meshed.
    std::uint32_t meshedAround(int x, int y) const
    {
        std::uint32_t all = ~0u;
        for (int dx = -1; dx <= 1; ++dx)
            for (int dy = -1; dy <= 1; ++dy) {
                const std::uint32_t r = mMeshed[x + dx + 1][y + dy + 1];
                all &= dx != 0 && dy != 0 ? r >> 1 : r & r >> 1 & r >> 2;
            }
        return all & 0xffu;
    }
    /// Bits z of the block's cells (x, y, 0..7) whose corners lie on both sides of k.
    std::uint32_t straddlingCells(int x, int y) const
    {
        std::uint32_t in = ~0u, out = ~0u;
        for (int dx = 0; dx <= 1; ++dx)
            for (int dy = 0; dy <= 1; ++dy) {
                in &= mInside[x + dx + 1][y + dy + 1];
                out &= ~mInside[x + dx + 1][y + dy + 1];
            }
        return ~((in & in >> 1) | (out & out >> 1)) >> 1 & 0xffu;
    }
    float value(int x, int y, int z) const { return mValue[index(x, y, z)]; }
    /// The 4x4x4 stencil of the cell (x, y, z) (Tricubic.h layout).
    void stencil(int x, int y, int z, float* out) const
    {
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b) std::copy_n(&mValue[index(x + a - 1, y + b - 1, z - 1)], 4, out + 16 * a + 4 * b);
    }
    /// The least and greatest value of every cell's stencil, separably (z, then y, then x).
    void stencilRanges()
    {
        float lo[kWidth][kWidth][kBlock], hi[kWidth][kWidth][kBlock];
        for (int x = 0; x < kWidth; ++x)
            for (int y = 0; y < kWidth; ++y) {
                const float* row = &mValue[std::size_t((x * kWidth + y) * kWidth)];
                for (int z = 0; z < kBlock; ++z) {
                    lo[x][y][z] = std::min(std::min(row[z], row[z + 1]), std::min(row[z + 2], row[z + 3]));
                    hi[x][y][z] = std::max(std::max(row[z], row[z + 1]), std::max(row[z + 2], row[z + 3]));
                }
            }
        for (int x = 0; x < kWidth; ++x)
            for (int y = 0; y < kBlock; ++y)
                for (int z = 0; z < kBlock; ++z) {
                    lo[x][y][z] = std::min(std::min(lo[x][y][z], lo[x][y + 1][z]), std::min(lo[x][y + 2][z], lo[x][y + 3][z]));
                    hi[x][y][z] = std::max(std::max(hi[x][y][z], hi[x][y + 1][z]), std::max(hi[x][y + 2][z], hi[x][y + 3][z]));
                }
        for (int x = 0; x < kBlock; ++x)
            for (int y = 0; y < kBlock; ++y)
                for (int z = 0; z < kBlock; ++z) {
                    mLow[x][y][z] = std::min(std::min(lo[x][y][z], lo[x + 1][y][z]), std::min(lo[x + 2][y][z], lo[x + 3][y][z]));
                    mHigh[x][y][z] = std::max(std::max(hi[x][y][z], hi[x + 1][y][z]), std::max(hi[x + 2][y][z], hi[x + 3][y][z]));
                }
    }
    /// After stencilRanges: the least and greatest value of the stencil of the cell (x, y, z).
    float stencilLow(int x, int y, int z) const { return mLow[x][y][z]; }
    float stencilHigh(int x, int y, int z) const { return mHigh[x][y][z]; }

private:
    static int index(int x, int y, int z) { return ((x - kLo) * kWidth + (y - kLo)) * kWidth + (z - kLo); }

    void gatherBlock(const Accessor& acc, const Coord& origin, int bx, int by, int bz)
    {
        const int lo[3] = {std::max(kLo, 8 * bx), std::max(kLo, 8 * by), std::max(kLo, 8 * bz)};
        const int hi[3] = {std::min(kLo + kWidth, 8 * bx + 8), std::min(kLo + kWidth, 8 * by + 8),
            std::min(kLo + kWidth, 8 * bz + 8)};
        if (lo[0] >= hi[0] || lo[1] >= hi[1] || lo[2] >= hi[2]) return;
        const Coord nOrigin = origin.offsetBy(8 * bx, 8 * by, 8 * bz);
        if (const auto* leaf = acc.probeConstLeaf(nOrigin)) {
            for (int x = lo[0]; x < hi[0]; ++x)
                for (int y = lo[1]; y < hi[1]; ++y)
                    for (int z = lo[2]; z < hi[2]; ++z) {
                        const openvdb::Index n = openvdb::FloatTree::LeafNodeType::coordToOffset(
                            Coord(x - 8 * bx, y - 8 * by, z - 8 * bz));
                        mValue[index(x, y, z)] = leaf->getValue(n);
                        mActive[index(x, y, z)] = leaf->isValueOn(n);
                    }
            return;
        }
        float tileValue = 0.0f;
        const bool tileActive = acc.probeValue(nOrigin, tileValue);
        for (int x = lo[0]; x < hi[0]; ++x)
            for (int y = lo[1]; y < hi[1]; ++y)
                for (int z = lo[2]; z < hi[2]; ++z) {
                    mValue[index(x, y, z)] = tileValue;
                    mActive[index(x, y, z)] = tileActive;
                }
    }

    /// Sign rows of the slopes f(v + e_axis) - f(v): [axis][x + 1][y + 1], bit z + 1, for v in
    /// [-1, 9)^3 (z slopes: bit z + 1 of row (x, y) compares z + 1 with z).
    void slopeRows()
    {
        for (int axis = 0; axis < 3; ++axis)
            for (int x = -1; x < 9; ++x)
                for (int y = -1; y < 9; ++y) {
                    std::uint32_t rise = 0, fall = 0;
                    for (int z = -1; z < 9; ++z) {
                        const float d = value(x + (axis == 0), y + (axis == 1), z + (axis == 2)) - value(x, y, z);
                        rise |= std::uint32_t(d > 0) << (z + 1);
                        fall |= std::uint32_t(d < 0) << (z + 1);
                    }
                    mRise[axis][x + 1][y + 1] = rise;
                    mFall[axis][x + 1][y + 1] = fall;
                }
    }

    /// Inside (value >= k) rows of the voxels, and meshed rows of the cells [-1, 9)^3.
    void stateRows(float k)
    {
        std::uint32_t active[kWidth][kWidth];
        for (int x = 0; x < kWidth; ++x)
            for (int y = 0; y < kWidth; ++y) {
                std::uint32_t in = 0, on = 0;
                for (int z = 0; z < kWidth; ++z) {
                    const int i = (x * kWidth + y) * kWidth + z;
                    in |= std::uint32_t(mValue[std::size_t(i)] >= k) << z;
                    on |= std::uint32_t(mActive[std::size_t(i)]) << z;
                }
                mInside[x][y] = in;
                active[x][y] = on;
            }
        for (int x = 0; x < kWidth - 1; ++x)
            for (int y = 0; y < kWidth - 1; ++y) {
                const std::uint32_t r = active[x][y] | active[x + 1][y] | active[x][y + 1] | active[x + 1][y + 1];
                mMeshed[x][y] = (r | r >> 1) & 0x3ffu;
            }
    }

    std::array<float, kWidth * kWidth * kWidth> mValue{};
    std::array<bool, kWidth * kWidth * kWidth> mActive{};
    std::uint32_t mRise[3][10][10], mFall[3][10][10];
    std::uint32_t mInside[kWidth][kWidth], mMeshed[kWidth - 1][kWidth - 1];
    float mLow[kBlock][kBlock][kBlock], mHigh[kBlock][kBlock][kBlock];
};

/// Bits z (0..7) of the row origin + (x, y, z) whose cells [c + lo, c + hi] lie in @a box.
inline std::uint32_t boxRow(const std::optional<CoordBBox>& box, const Coord& origin, int x, int y, int lo, int hi)
{
    if (!box) return 0xffu;
    const Coord c = origin.offsetBy(x, y, 0);
    for (int a = 0; a < 2; ++a)
        if (c[a] + lo < box->min()[a] || c[a] + hi > box->max()[a]) return 0;
    std::uint32_t bits = 0;
    for (int z = 0; z < kBlock; ++z)
        bits |= std::uint32_t(c[2] + z + lo >= box->min()[2] && c[2] + z + hi <= box->max()[2]) << z;
    return bits;
}

/// Index of sub-point (p, q, r) in refineCell's output.
inline std::size_t subIndex(int p, int q, int r, int n) { return std::size_t((p * n + q) * n + r); }

/// Whether the subdivision values lie on both sides of k (the tricubic surface passes through).
bool crosses(const std::vector<double>& sub, double k)
{
    bool in = false, out = false;
    for (double v : sub) (v >= k ? in : out) = true;
    return in && out;
}

/// The filter: some element of the cell (the cell, a face or an edge) has all its corners on one
/// side of k and a subdivision value on the other: the tricubic shows what the corners hide.
bool reveals(const std::vector<double>& sub, int m, double k)
{
    const int n = m + 1;
    // Each axis of an element is fixed at 0, fixed at m, or free (0..m); corners are skipped.
    for (int sx = 0; sx < 3; ++sx)
        for (int sy = 0; sy < 3; ++sy)
            for (int sz = 0; sz < 3; ++sz) {
                if (sx < 2 && sy < 2 && sz < 2) continue;
                const int s[3] = {sx, sy, sz};
                int lo[3], hi[3], step[3];
                for (int a = 0; a < 3; ++a) {
                    lo[a] = s[a] == 1 ? m : 0;
                    hi[a] = s[a] == 0 ? 0 : m;
                    step[a] = m;
                }
                int corners = 0, inside = 0;
                for (int p = lo[0]; p <= hi[0]; p += step[0])
                    for (int q = lo[1]; q <= hi[1]; q += step[1])
                        for (int r = lo[2]; r <= hi[2]; r += step[2]) {
                            ++corners;
                            inside += sub[subIndex(p, q, r, n)] >= k;
                        }
                if (inside != 0 && inside != corners) continue;
                const bool cornersInside = inside != 0;
                for (int p = lo[0]; p <= hi[0]; ++p)
                    for (int q = lo[1]; q <= hi[1]; ++q)
                        for (int r = lo[2]; r <= hi[2]; ++r)
                            if ((sub[subIndex(p, q, r, n)] >= k) != cornersInside) return true;
            }
    return false;
}

/// Whether the Bernstein hull [lo, hi] (cubicRange, Tricubic.h) lets the interpolant reach both
/// sides of k; the slack covers rounding, so a false answer is exact.
inline bool mayCross(const std::pair<double, double>& range, double k)
{
    const double slack = 1e-9 * (std::abs(range.first) + std::abs(range.second) + std::abs(k));
    return range.first - slack < k && range.second + slack >= k;
}

/// reveals() for a cell whose corners straddle k (the cell itself then hides nothing), without
/// refining all of it: each edge and face whose corners lie on one side is evaluated only when
/// the Bernstein hull of its grid line or plane reaches k. The values are refineCell's
/// (Tricubic.h), so the answer is reveals()'.
bool boundaryReveals(const float* stencil, const std::vector<CubicWeights>& w, int m, double k)
{
    bool cornerInside[2][2][2];
    for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
            for (int c = 0; c < 2; ++c) cornerInside[a][b][c] = double(stencil[16 * (1 + a) + 4 * (1 + b) + 1 + c]) >= k;
    for (int sx = 0; sx < 3; ++sx)
        for (int sy = 0; sy < 3; ++sy)
            for (int sz = 0; sz < 3; ++sz) {
                const int s[3] = {sx, sy, sz};
                const int free = (sx == 2) + (sy == 2) + (sz == 2);
                if (free == 0 || free == 3) continue;
                int node[3][2], local[3][2];
                for (int a = 0; a < 3; ++a) { // stencil index range and sub-point range per axis
                    node[a][0] = s[a] == 2 ? 0 : 1 + s[a];
                    node[a][1] = s[a] == 2 ? 3 : 1 + s[a];
                    local[a][0] = s[a] == 1 ? m : 0;
                    local[a][1] = s[a] == 0 ? 0 : m;
                }
                int corners = 0, inside = 0;
                for (int a = s[0] == 1; a <= (s[0] != 0); ++a)
                    for (int b = s[1] == 1; b <= (s[1] != 0); ++b)
                        for (int c = s[2] == 1; c <= (s[2] != 0); ++c) {
                            ++corners;
                            inside += cornerInside[a][b][c];
                        }
                if (inside != 0 && inside != corners) continue;
                std::ptrdiff_t strides[2];
                int dims = 0;
                for (int a = 0; a < 3; ++a)
                    if (s[a] == 2) strides[dims++] = a == 0 ? 16 : a == 1 ? 4 : 1;
                if (!mayCross(cubicRange(stencil + 16 * node[0][0] + 4 * node[1][0] + node[2][0], strides, dims), k))
                    continue;
                const bool cornersInside = inside != 0;
                for (int p = local[0][0]; p <= local[0][1]; ++p)
                    for (int q = local[1][0]; q <= local[1][1]; ++q)
                        for (int r = local[2][0]; r <= local[2][1]; ++r)
                            if ((tricubic(stencil, w[std::size_t(p)], w[std::size_t(q)], w[std::size_t(r)]) >= k) !=
                                cornersInside)
                                return true;
            }
    return false;
}

/// The 4x4x4 voxels around the cell at @a c (Tricubic.h layout).
void gatherStencil(const Accessor& acc, const Coord& c, float* stencil)
{
    for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
            for (int d = 0; d < 4; ++d) stencil[16 * a + 4 * b + d] = acc.getValue(c.offsetBy(a - 1, b - 1, d - 1));
}

inline Coord times(const Coord& c, int s) { return Coord(c[0] * s, c[1] * s, c[2] * s); }
/// (to - from) / m: a unit step along a cell edge whose ends are in sub-point units.
inline Coord unitStep(const Coord& from, const Coord& to, int m)
{
    return Coord((to[0] - from[0]) / m, (to[1] - from[1]) / m, (to[2] - from[2]) / m);
}

/// Local corner c of a cell, in sub-point units (0 or m per axis).
inline Coord cornerLocal(int c, int m)
{
    const auto& o = kMcCornerOffset[std::size_t(c)];
    return Coord(o.x * m, o.y * m, o.z * m);
}

/// Tricubic values at the sub-points (local coordinates 0..m) of one cell: all of them for a
/// refined cell, those on the given faces and edges (and the corners) for a transition cell.
/// Either way a value is the one refineCell gives, bit for bit (Tricubic.h).
class CellValues {
public:
    CellValues(int m, double k, const Packer& packer) : mM(m), mN(m + 1), mK(k), mPacker(packer)
    {
        for (int s = 0; s <= m; ++s) mWeights.push_back(cubicWeights(s, m));
    }

    void refineAll(const Coord& cell, const float* stencil)
    {
        mCell = cell;
        refineCell(stencil, mM, mValues, mWorkspace);
    }

    void refineParts(const Coord& cell, const float* stencil, const bool (&faces)[6], const bool (&edges)[12])
    {
        mCell = cell;
        mValues.resize(std::size_t(mN) * mN * mN);
        for (int c = 0; c < 8; ++c) evaluate(stencil, cornerLocal(c, mM));
        for (int f = 0; f < 6; ++f) {
            if (!faces[f]) continue;
            const int axis = f / 2, u = (axis + 1) % 3, v = (axis + 2) % 3;
            Coord p;
            p[axis] = (f % 2) * mM;
            for (p[u] = 0; p[u] <= mM; ++p[u])
                for (p[v] = 0; p[v] <= mM; ++p[v]) evaluate(stencil, p);
        }
        for (int e = 0; e < 12; ++e) {
            if (!edges[e]) continue;
            const McEdge& edge = kMcEdges[std::size_t(e)];
            Coord p(edge.dx * mM, edge.dy * mM, edge.dz * mM);
            for (p[edge.axis] = 0; p[edge.axis] <= mM; ++p[edge.axis]) evaluate(stencil, p);
        }
    }

    const Coord& cell() const { return mCell; }
    int m() const { return mM; }
    double value(const Coord& local) const { return mValues[subIndex(local[0], local[1], local[2], mN)]; }
    bool inside(const Coord& local) const { return value(local) >= mK; }
    Coord fine(const Coord& local) const { return times(mCell, mM) + local; }

    /// The crossing of the subcell edge from sub-point @a lo along @a axis: keyed by its lower
    /// fine point and axis, linear (SPEC §2 on the subcell edge, from its lower point). Every
    /// cell sharing the edge computes it from the same values, so the same bits.
    FineCrossing crossing(const Coord& lo, int axis) const
    {
        Coord hi = lo;
        hi[axis] += 1;
        const double f0 = value(lo), f1 = value(hi);
        const double t = std::clamp((mK - f0) / (f1 - f0), 0.0, 1.0);
        return FineCrossing{mPacker.fine(fine(lo), axis), float(t), 0};
    }

    /// Appends every crossing subcell edge of the cell to @a out; crossingRef then finds them.
    void writeCrossings(std::vector<FineCrossing>& out)
    {
        mEdgeRefs.resize(3 * std::size_t(mN) * mN * mN);
        for (int axis = 0; axis < 3; ++axis) {
            Coord hiBound(mM, mM, mM);
            hiBound[axis] = mM - 1;
            Coord p;
            for (p[0] = 0; p[0] <= hiBound[0]; ++p[0])
                for (p[1] = 0; p[1] <= hiBound[1]; ++p[1])
                    for (p[2] = 0; p[2] <= hiBound[2]; ++p[2]) {
                        Coord q = p;
                        q[axis] += 1;
                        if (inside(p) == inside(q)) continue;
                        mEdgeRefs[3 * subIndex(p[0], p[1], p[2], mN) + std::size_t(axis)] = kFineRef | Ref(out.size());
                        out.push_back(crossing(p, axis));
                    }
        }
    }
    /// The Ref of a crossing writeCrossings appended.
    Ref crossingRef(const Coord& lo, int axis) const
    {
        return mEdgeRefs[3 * subIndex(lo[0], lo[1], lo[2], mN) + std::size_t(axis)];
    }

private:
    void evaluate(const float* stencil, const Coord& p)
    {
        mValues[subIndex(p[0], p[1], p[2], mN)] = tricubic(stencil, mWeights[std::size_t(p[0])],
            mWeights[std::size_t(p[1])], mWeights[std::size_t(p[2])]);
    }

    int mM, mN;
    double mK;
    const Packer& mPacker;
    Coord mCell;
    std::vector<CubicWeights> mWeights;
    std::vector<double> mValues;
    std::vector<Ref> mEdgeRefs; // per (sub-point, axis) of a refined cell: its crossing's Ref
    TricubicWorkspace mWorkspace;
};

/// Marching cubes on the m^3 subcells of a refined cell (McTables.h, inside is >= k).
void meshRefinedCell(CellValues& cv, Patch& patch)
{
    const int m = cv.m();
    cv.writeCrossings(patch.crossings);
    for (int p = 0; p < m; ++p)
        for (int q = 0; q < m; ++q)
            for (int r = 0; r < m; ++r) {
                const Coord base(p, q, r);
                int cubeCase = 0;
                for (int c = 0; c < 8; ++c) {
                    const auto& o = kMcCornerOffset[std::size_t(c)];
                    cubeCase |= int(cv.inside(base.offsetBy(o.x, o.y, o.z))) << c;
                }
                const int count = kMcCases.triangleCount[std::size_t(cubeCase)];
                if (count == 0) continue;
                std::array<Ref, 12> keys{};
                const std::uint16_t crossing = kMcCases.crossingEdges[std::size_t(cubeCase)];
                for (int e = 0; e < 12; ++e) {
                    if (!((crossing >> e) & 1)) continue;
                    const McEdge& edge = kMcEdges[std::size_t(e)];
                    keys[std::size_t(e)] = cv.crossingRef(base.offsetBy(edge.dx, edge.dy, edge.dz), edge.axis);
                }
                const auto& edges = kMcCases.triangleEdges[std::size_t(cubeCase)];
                for (int t = 0; t < count; ++t)
                    patch.triangles.push_back({keys[std::size_t(edges[3 * t])],
                        keys[std::size_t(edges[3 * t + 1])], keys[std::size_t(edges[3 * t + 2])]});
            }
}

/// Which faces (-x, +x, -y, +y, -z, +z) and edges of the unrefined cell @a u a refined cell
/// shares.
void refinedParts(const Coord& u, CellSetAccessor& refined, bool (&faces)[6], bool (&edges)[12])
{
    for (int f = 0; f < 6; ++f) {
        Coord across = u;
        across[f / 2] += (f % 2) ? 1 : -1;
        faces[f] = refined.isValueOn(across);
    }
    for (int e = 0; e < 12; ++e) {
        const McEdge& edge = kMcEdges[std::size_t(e)];
        const Coord v = u.offsetBy(edge.dx, edge.dy, edge.dz);
        const int a1 = (edge.axis + 1) % 3, a2 = (edge.axis + 2) % 3;
        edges[e] = false;
        for (int d1 = 0; d1 < 2; ++d1)
            for (int d2 = 0; d2 < 2; ++d2) {
                Coord c = v;
                c[a1] -= d1;
                c[a2] -= d2;
                if (c != u && refined.isValueOn(c)) edges[e] = true;
            }
    }
}

/// The surface of a transition cell: segments on its six faces (walked counter-clockwise from
/// outside, each entering crossing joined to the next leaving one, McTables.h's rule), chained
/// into loops, each fanned to its centre.
struct FaceCrossing {
    Ref key;
    bool enters;
};
/// Per-thread buffers of meshTransitionCell.
struct TransitionScratch {
    std::vector<std::pair<Ref, Ref>> segments;
    std::vector<FaceCrossing> walk;
    std::vector<std::uint8_t> used;
    std::vector<std::size_t> loop;
    std::vector<Ref> edgeRefs;          // per (sub-point, axis): its crossing's Ref, once made
    std::vector<std::size_t> edgesMade; // the entries to clear for the next cell
};

void meshTransitionCell(const CellValues& cv, const bool (&faceRefined)[6], const bool (&edgeRefined)[12],
    const Packer& packer, TransitionScratch& scratch, Patch& patch)
{
    using mc_tables_internal::edgeBetween;
    using mc_tables_internal::kFaceCorners;
    const int m = cv.m();
    const Coord& u = cv.cell();
    using Crossing = FaceCrossing;
    std::vector<std::pair<Ref, Ref>>& segments = scratch.segments;
    segments.clear();
    // A subcell edge is walked from two subfaces (or two faces): one Ref for both.
    constexpr Ref kNoRef = ~Ref(0);
    const std::size_t n = std::size_t(m + 1);
    if (scratch.edgeRefs.size() != 3 * n * n * n) scratch.edgeRefs.assign(3 * n * n * n, kNoRef);
    for (std::size_t i : scratch.edgesMade) scratch.edgeRefs[i] = kNoRef;
    scratch.edgesMade.clear();
    auto fineRef = [&](const Coord& a, const Coord& b) {
        const Coord& lo = a < b ? a : b;
        int axis = 0;
        while (a[axis] == b[axis]) ++axis;
        const std::size_t slot = 3 * subIndex(lo[0], lo[1], lo[2], int(n)) + std::size_t(axis);
        Ref& r = scratch.edgeRefs[slot];
        if (r == kNoRef) {
            r = kFineRef | Ref(patch.crossings.size());
            patch.crossings.push_back(cv.crossing(lo, axis));
            scratch.edgesMade.push_back(slot);
        }
        return r;
    };
    auto pairUp = [&segments](const std::vector<Crossing>& walk) {
        for (std::size_t i = 0; i < walk.size(); ++i) {
            if (!walk[i].enters) continue;
            for (std::size_t j = 1; j < walk.size(); ++j) {
                const Crossing& next = walk[(i + j) % walk.size()];
                if (!next.enters) {
                    segments.emplace_back(walk[i].key, next.key);
                    break;
                }
            }
        }
    };
    std::vector<Crossing>& walk = scratch.walk;
    for (int f = 0; f < 6; ++f) {
        const auto& loop = kFaceCorners[std::size_t(f)];
        if (faceRefined[f]) {
            // A face shared with a refined cell: its m x m subfaces, walked the same way.
            const Coord c0 = cornerLocal(loop[0], m);
            const Coord ds = unitStep(c0, cornerLocal(loop[1], m), m), dt = unitStep(c0, cornerLocal(loop[3], m), m);
            for (int s = 0; s < m; ++s)
                for (int t = 0; t < m; ++t) {
                    const Coord corner[4] = {c0 + times(ds, s) + times(dt, t), c0 + times(ds, s + 1) + times(dt, t),
                        c0 + times(ds, s + 1) + times(dt, t + 1), c0 + times(ds, s) + times(dt, t + 1)};
                    walk.clear();
                    for (int i = 0; i < 4; ++i) {
                        const Coord& a = corner[i];
                        const Coord& b = corner[(i + 1) % 4];
                        if (cv.inside(a) != cv.inside(b)) walk.push_back({fineRef(a, b), cv.inside(b)});
                    }
                    pairUp(walk);
                }
            continue;
        }
        walk.clear();
        for (int i = 0; i < 4; ++i) {
            const int ca = loop[std::size_t(i)], cb = loop[std::size_t((i + 1) % 4)];
            const int e = edgeBetween(ca, cb);
            const Coord a = cornerLocal(ca, m), b = cornerLocal(cb, m);
            if (edgeRefined[e]) { // the subdivision of a refined cell's edge, walked from a to b
                const Coord step = unitStep(a, b, m);
                for (int s = 0; s < m; ++s) {
                    const Coord p = a + times(step, s), q = a + times(step, s + 1);
                    if (cv.inside(p) != cv.inside(q)) walk.push_back({fineRef(p, q), cv.inside(q)});
                }
            } else if (cv.inside(a) != cv.inside(b)) { // the standard vertex of this grid edge
                const McEdge& edge = kMcEdges[std::size_t(e)];
                walk.push_back({packer.coarse(u.offsetBy(edge.dx, edge.dy, edge.dz), edge.axis), cv.inside(b)});
            }
        }
        pairUp(walk);
    }
    // Chain the segments into loops (each key starts one segment and ends one) and fan them. A
    // loop of two is the same chord along one refined edge from both faces: it encloses nothing
    // (the surfaces of the cells beyond those faces meet along that chord) and is skipped.
    std::vector<std::uint8_t>& used = scratch.used;
    used.assign(segments.size(), 0);
    std::vector<std::size_t>& loop = scratch.loop;
    for (std::size_t first = 0; first < segments.size(); ++first) {
        if (used[first]) continue;
        loop.clear();
        for (std::size_t s = first; !used[s];) {
            used[s] = 1;
            loop.push_back(s);
            for (std::size_t n = 0; n < segments.size(); ++n)
                if (segments[n].first == segments[s].second) {
                    s = n;
                    break;
                }
        }
        if (loop.size() < 3) continue;
        const Ref centre = kCentreRef | Ref(patch.memberEnds.size());
        for (std::size_t s : loop) {
            patch.members.push_back(segments[s].first);
            patch.triangles.push_back({centre, segments[s].first, segments[s].second});
        }
        patch.memberEnds.push_back(std::uint32_t(patch.members.size()));
        patch.centreCells.push_back(u);
    }
}

/// Which cell a standard triangle comes from: the one cell holding its three grid edges.
std::optional<Coord> cellOfTriangle(const std::array<Coord, 3>& voxel, const std::array<int, 3>& axis)
{
    auto holds = [](const Coord& cell, const Coord& v, int a) {
        const Coord d = v - cell;
        for (int i = 0; i < 3; ++i)
            if (d[i] < 0 || d[i] > 1 || (i == a && d[i] != 0)) return false;
        return true;
    };
    const int a1 = (axis[0] + 1) % 3, a2 = (axis[0] + 2) % 3;
    for (int d1 = 0; d1 < 2; ++d1)
        for (int d2 = 0; d2 < 2; ++d2) {
            Coord c = voxel[0];
            c[a1] -= d1;
            c[a2] -= d2;
            if (holds(c, voxel[1], axis[1]) && holds(c, voxel[2], axis[2])) return c;
        }
    return std::nullopt;
}

} // namespace hidden_internal

Mesh addHiddenFeatures(const openvdb::FloatGrid& grid, const Mesh& standard, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* statsOut, openvdb::util::NullInterrupter* interrupter)
{
    using namespace hidden_internal;
    const int m = hidden.subdivisions;
    if (m < 1 || m > kMaxSubdivisions)
        OPENVDB_THROW(openvdb::ValueError, "hidden features: subdivisions must be between 1 and 64 (got "
                                               + std::to_string(m) + ")");
    if (!std::isfinite(settings.isovalue))
        OPENVDB_THROW(openvdb::ValueError, "the isovalue must be a finite number");
    const auto* edgeI = standard.vertexAttributes.find<std::int32_t>("edge_i");
    const auto* edgeJ = standard.vertexAttributes.find<std::int32_t>("edge_j");
    const auto* edgeK = standard.vertexAttributes.find<std::int32_t>("edge_k");
    const auto* edgeAxis = standard.vertexAttributes.find<std::uint8_t>("edge_axis");
    if (!edgeI || !edgeJ || !edgeK || !edgeAxis)
        OPENVDB_THROW(openvdb::ValueError,
            "hidden features: the standard mesh needs provenance (edge_i edge_j edge_k edge_axis)");

    if (interrupter) interrupter->start("Hidden features");
    struct EndGuard {
        openvdb::util::NullInterrupter* i;
        ~EndGuard() { if (i) i->end(); }
    } endGuard{interrupter};

    const float k = settings.isovalue;
    const std::optional<CoordBBox> bounds = dataBoundsOf(grid, settings);
    const bool threaded = settings.threaded;
    const openvdb::FloatTree& tree = grid.tree();
    tbb::enumerable_thread_specific<Accessor> accessors([&tree] { return Accessor(tree); });

    // Detect (SPEC §4): per block, the slope rule on each meshed cell, then whether the tricubic
    // crosses k there (and the filter).
    const std::vector<Coord> origins = blockOrigins(tree);
    struct BlockResult {
        std::size_t total = 0, flagged = 0;
        std::vector<Coord> refined;
    };
    std::vector<BlockResult> blockResults(origins.size());
    struct DetectScratch {
        Window window;
        TricubicWorkspace workspace;
        std::vector<double> sub;
        std::vector<CubicWeights> weights;
    };
    std::vector<CubicWeights> weights;
    for (int s = 0; s <= m; ++s) weights.push_back(cubicWeights(s, m));
    tbb::enumerable_thread_specific<DetectScratch> detectScratch(DetectScratch{Window(), {}, {}, weights});
    forEach(origins.size(), 4, threaded, interrupter, [&](std::size_t b) {
        const Coord& origin = origins[b];
        DetectScratch& scratch = detectScratch.local();
        Window& w = scratch.window;
        w.gather(accessors.local(), origin, k);
        BlockResult& out = blockResults[b];
        float stencil[64];
        bool haveRanges = false; // stencilRanges only in blocks with a non-straddling candidate
        for (int x = 0; x < kBlock; ++x)
            for (int y = 0; y < kBlock; ++y) {
                const std::uint32_t cells = w.meshedCells(x, y) & boxRow(bounds, origin, x, y, 0, 1);
                out.total += std::size_t(__builtin_popcount(cells));
                // The rule reads one voxel beyond each edge: cells whose stencil leaves the data are
                // never flagged.
                std::uint32_t flagged = cells & boxRow(bounds, origin, x, y, -1, 2) & w.turningCells(x, y);
                out.flagged += std::size_t(__builtin_popcount(flagged));
                // Transition cells must be meshed too, so the refinement stops one cell short of the
                // border of the active region (where a sparse surface ends anyway).
                flagged &= w.meshedAround(x, y);
                const std::uint32_t straddling = w.straddlingCells(x, y);
                for (; flagged; flagged &= flagged - 1) {
                    const int z = __builtin_ctz(flagged);
                    if ((straddling >> z) & 1u) {
                        if (hidden.filter) {
                            w.stencil(x, y, z, stencil);
                            if (!boundaryReveals(stencil, scratch.weights, m, k)) continue;
                        }
                    } else {
                        // The tricubic stays within 1.25^3 (its Lebesgue constant) times the stencil's
                        // half range of the stencil's mid range: beyond that it cannot reach k.
                        if (!haveRanges) {
                            w.stencilRanges();
                            haveRanges = true;
                        }
                        const double lo = w.stencilLow(x, y, z), hi = w.stencilHigh(x, y, z);
                        const double mid = 0.5 * (lo + hi), reach = 1.953125 * 0.5 * (hi - lo);
                        if (std::abs(double(k) - mid) > reach) continue;
                        w.stencil(x, y, z, stencil);
                        // The float hull first: its margin (100x its rounding, Tricubic.h, plus
                        // mayCross's slack) leaves every decision to the double hull's.
                        const auto rough = roughTricubicRange(stencil);
                        const double margin = 1e-3 * (std::abs(lo) + std::abs(hi) + std::abs(double(k)));
                        if (double(rough.first) - margin >= k || double(rough.second) + margin < k) continue;
                        if (!mayCross(tricubicRange(stencil), double(k))) continue;
                        refineCell(stencil, m, scratch.sub, scratch.workspace);
                        if (!crosses(scratch.sub, k)) continue;
                        if (hidden.filter && !reveals(scratch.sub, m, k)) continue;
                    }
                    out.refined.push_back(origin.offsetBy(x, y, z));
                }
            }
    });
    HiddenFeatureStats stats;
    std::vector<Coord> refined;
    CellSet refinedSet(false);
    for (const BlockResult& r : blockResults) {
        stats.cellsTotal += r.total;
        stats.cellsFlagged += r.flagged;
        refined.insert(refined.end(), r.refined.begin(), r.refined.end());
        for (const Coord& c : r.refined) refinedSet.setValueOn(c, true);
    }
    blockResults.clear();
    stats.cellsRefined = refined.size();

    // Transition cells: unrefined cells sharing a face or an edge with a refined one, in tree order.
    CellSet replacedSet = refinedSet;
    openvdb::tools::dilateActiveValues(replacedSet, 1, openvdb::tools::NN_FACE_EDGE, openvdb::tools::IGNORE_TILES,
        threaded);
    std::vector<Coord> transition;
    {
        CellSetAccessor isRefined(refinedSet);
        for (auto v = replacedSet.cbeginValueOn(); v; ++v)
            if (!isRefined.isValueOn(v.getCoord())) transition.push_back(v.getCoord());
    }
    stats.cellsTransition = transition.size();
    if (statsOut) *statsOut = stats;
    throwIfInterrupted(interrupter);

    Mesh mesh;
    if (refined.empty()) { // nothing refined: the standard mesh, all of it standard
        mesh = standard;
        mesh.vertexAttributes.add<std::uint8_t>("hidden", mesh.vertexCount());
        mesh.faceAttributes.add<std::uint8_t>("hidden", mesh.triangleCount());
        return mesh;
    }
    CoordBBox region;
    refinedSet.evalActiveVoxelBoundingBox(region);
    Packer packer;
    packer.voxelOrigin = region.min().offsetBy(-1);
    packer.fineOrigin = times(packer.voxelOrigin, m);
    for (int i = 0; i < 3; ++i)
        if (std::int64_t(region.dim()[i] + 3) * m >= (std::int64_t(1) << kCoordBits))
            OPENVDB_THROW(openvdb::ValueError, "hidden features: the refined cells span more than 2^20 / "
                                                   + std::to_string(m) + " voxels; use fewer subdivisions");

    // Refine and transition, in chunks of cells; chunk order is cell order.
    constexpr std::size_t kChunk = 32;
    const std::size_t refinedChunks = (refined.size() + kChunk - 1) / kChunk;
    const std::size_t transitionChunks = (transition.size() + kChunk - 1) / kChunk;
    std::vector<Patch> patches(refinedChunks + transitionChunks);
    struct CellScratch {
        CellValues values;
        CellSetAccessor refined;
        TransitionScratch transition;
    };
    tbb::enumerable_thread_specific<CellScratch> cellScratch(
        [&] { return CellScratch{CellValues(m, double(k), packer), CellSetAccessor(refinedSet), {}}; });
    forEach(patches.size(), 1, threaded, interrupter, [&](std::size_t chunk) {
        const bool isRefined = chunk < refinedChunks;
        const std::vector<Coord>& cells = isRefined ? refined : transition;
        const std::size_t first = (isRefined ? chunk : chunk - refinedChunks) * kChunk;
        const std::size_t last = std::min(cells.size(), first + kChunk);
        CellScratch& scratch = cellScratch.local();
        float stencil[64];
        bool faces[6], edges[12];
        for (std::size_t i = first; i < last; ++i) {
            gatherStencil(accessors.local(), cells[i], stencil);
            if (isRefined) {
                scratch.values.refineAll(cells[i], stencil);
                meshRefinedCell(scratch.values, patches[chunk]);
            } else {
                refinedParts(cells[i], scratch.refined, faces, edges);
                scratch.values.refineParts(cells[i], stencil, faces, edges);
                meshTransitionCell(scratch.values, faces, edges, packer, scratch.transition, patches[chunk]);
            }
        }
    });

    // New vertices: subcell-edge crossings, sorted by key and shared (every cell that uses a
    // crossing writes it bit for bit); fineIndex maps each patch's crossing to its vertex.
    std::vector<std::size_t> crossingOffset(patches.size() + 1, 0);
    for (std::size_t c = 0; c < patches.size(); ++c)
        crossingOffset[c + 1] = crossingOffset[c] + patches[c].crossings.size();
    if (crossingOffset.back() > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    std::vector<FineCrossing> fine(crossingOffset.back());
    forEach(patches.size(), 1, threaded, nullptr, [&](std::size_t c) {
        std::vector<FineCrossing>& from = patches[c].crossings;
        for (std::size_t i = 0; i < from.size(); ++i) {
            fine[crossingOffset[c] + i] = from[i];
            fine[crossingOffset[c] + i].slot = std::uint32_t(crossingOffset[c] + i);
        }
        std::vector<FineCrossing>().swap(from);
    });
    auto byKey = [](const FineCrossing& a, const FineCrossing& b) { return a.key < b.key; };
    if (threaded) tbb::parallel_sort(fine.begin(), fine.end(), byKey);
    else std::sort(fine.begin(), fine.end(), byKey);
    std::vector<std::uint32_t> fineIndex(fine.size());
    std::size_t fineCount = 0;
    for (std::size_t i = 0; i < fine.size(); ++i) {
        if (i == 0 || fine[i].key != fine[fineCount - 1].key) fine[fineCount++] = fine[i];
        fineIndex[fine[i].slot] = std::uint32_t(fineCount - 1);
    }
    fine.resize(fineCount);

    // Standard vertices used by transition loops, found by their grid edge.
    std::vector<Ref> coarse;
    for (std::size_t c = refinedChunks; c < patches.size(); ++c)
        for (Ref r : patches[c].members)
            if ((r & kKindMask) == kCoarseRef) coarse.push_back(r);
    std::sort(coarse.begin(), coarse.end());
    coarse.erase(std::unique(coarse.begin(), coarse.end()), coarse.end());
    const std::size_t standardVertices = standard.vertexCount();
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> coarseVertex(coarse.size(), kNone);
    forEach(standardVertices, 4096, threaded, nullptr, [&](std::size_t v) {
        const Coord voxel((*edgeI)[v], (*edgeJ)[v], (*edgeK)[v]);
        if (!packer.coarseFits(voxel)) return;
        const Ref key = packer.coarse(voxel, (*edgeAxis)[v]);
        const auto it = std::lower_bound(coarse.begin(), coarse.end(), key);
        if (it != coarse.end() && *it == key) coarseVertex[std::size_t(it - coarse.begin())] = std::uint32_t(v);
    });
    for (std::uint32_t v : coarseVertex)
        if (v == kNone) throw std::logic_error("hidden features: a transition cell's grid edge has no standard vertex");

    // Standard triangles of cells outside R and T stay.
    std::vector<std::uint8_t> keep(standard.triangleCount(), 1);
    tbb::enumerable_thread_specific<CellSetAccessor> replacedAccessors([&] { return CellSetAccessor(replacedSet); });
    forEach(standard.triangleCount(), 4096, threaded, interrupter, [&](std::size_t t) {
        CellSetAccessor& replaced = replacedAccessors.local();
        std::array<Coord, 3> voxel;
        std::array<int, 3> axis;
        const std::size_t v0 = standard.triangles[t][0];
        voxel[0] = Coord((*edgeI)[v0], (*edgeJ)[v0], (*edgeK)[v0]);
        // The cell lies within one voxel below voxel[0] on each axis: inside voxel[0]'s leaf when
        // no coordinate is a multiple of 8, and then an empty leaf region settles it.
        if ((voxel[0].x() & 7) && (voxel[0].y() & 7) && (voxel[0].z() & 7)) {
            const auto* leaf = replaced.probeConstLeaf(voxel[0]);
            if (leaf ? leaf->isEmpty() : !replaced.isValueOn(voxel[0])) return;
        }
        for (int i = 0; i < 3; ++i) {
            const std::size_t v = standard.triangles[t][i];
            voxel[std::size_t(i)] = Coord((*edgeI)[v], (*edgeJ)[v], (*edgeK)[v]);
            axis[std::size_t(i)] = (*edgeAxis)[v];
        }
        const std::optional<Coord> cell = cellOfTriangle(voxel, axis);
        if (cell && replaced.isValueOn(*cell)) keep[t] = 0;
    });

    // Vertex numbering: used standard vertices in their order, then fine vertices, then centres.
    std::vector<std::uint32_t> remap(standardVertices, 0);
    for (std::size_t t = 0; t < keep.size(); ++t)
        if (keep[t])
            for (int i = 0; i < 3; ++i) remap[standard.triangles[t][i]] = 1;
    for (std::uint32_t v : coarseVertex) remap[v] = 1;
    std::vector<std::uint32_t> kept;
    for (std::size_t v = 0; v < standardVertices; ++v) {
        remap[v] = remap[v] ? std::uint32_t(kept.size()) : kNone;
        if (remap[v] != kNone) kept.push_back(std::uint32_t(v));
    }
    std::vector<std::size_t> centreOffset(patches.size() + 1, 0), triangleOffset(patches.size() + 1, 0);
    std::size_t keptTriangles = 0;
    for (std::uint8_t f : keep) keptTriangles += f;
    triangleOffset[0] = keptTriangles;
    for (std::size_t c = 0; c < patches.size(); ++c) {
        centreOffset[c + 1] = centreOffset[c] + patches[c].memberEnds.size();
        triangleOffset[c + 1] = triangleOffset[c] + patches[c].triangles.size();
    }
    const std::size_t fineBase = kept.size(), centreBase = fineBase + fine.size();
    const std::size_t vertexCount = centreBase + centreOffset.back();
    if (vertexCount > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    auto indexOf = [&](Ref r, std::size_t chunk) -> std::uint32_t {
        switch (r & kKindMask) {
        case kFineRef: return std::uint32_t(fineBase + fineIndex[crossingOffset[chunk] + std::size_t(r)]);
        case kCoarseRef:
            return remap[coarseVertex[std::size_t(std::lower_bound(coarse.begin(), coarse.end(), r) - coarse.begin())]];
        default: return std::uint32_t(centreBase + centreOffset[chunk] + std::size_t(r & ~kKindMask));
        }
    };

    // Positions: standard, then fine (index space (P + t e_axis) / m), then fan centres.
    mesh.indexToWorld = standard.indexToWorld;
    mesh.positions.resize(vertexCount);
    for (std::size_t i = 0; i < kept.size(); ++i) mesh.positions[i] = standard.positions[kept[i]];
    const openvdb::math::Transform& xform = grid.transform();
    forEach(fine.size(), 4096, threaded, nullptr, [&](std::size_t i) {
        const Coord p = packer.finePoint(fine[i].key);
        Vec3d index(p[0], p[1], p[2]);
        index[Packer::axisOf(fine[i].key)] += double(fine[i].t);
        mesh.positions[fineBase + i] = openvdb::Vec3s(xform.indexToWorld(index / double(m)));
    });
    // Triangles: kept standard ones, then refined cells', then transition cells'.
    const bool levelSet = grid.getGridClass() == openvdb::GRID_LEVEL_SET;
    const bool flip = settings.orientation == Orientation::TowardsHigher ||
                      (settings.orientation == Orientation::Auto && levelSet);
    mesh.triangles.resize(triangleOffset.back());
    std::size_t n = 0;
    for (std::size_t t = 0; t < keep.size(); ++t) {
        if (!keep[t]) continue;
        const openvdb::Vec3I& tri = standard.triangles[t];
        mesh.triangles[n++] = openvdb::Vec3I(remap[tri[0]], remap[tri[1]], remap[tri[2]]);
    }
    forEach(patches.size(), 1, threaded, nullptr, [&](std::size_t c) {
        const Patch& p = patches[c];
        openvdb::Vec3I* out = mesh.triangles.data() + triangleOffset[c];
        for (const auto& tri : p.triangles) {
            const std::uint32_t a = indexOf(tri[0], c), b = indexOf(tri[1], c), d = indexOf(tri[2], c);
            *out++ = flip ? openvdb::Vec3I(a, d, b) : openvdb::Vec3I(a, b, d);
        }
        for (std::size_t l = 0; l < p.memberEnds.size(); ++l) {
            const std::uint32_t begin = l == 0 ? 0 : p.memberEnds[l - 1], end = p.memberEnds[l];
            Vec3d sum(0.0);
            for (std::uint32_t j = begin; j < end; ++j) sum += Vec3d(mesh.positions[indexOf(p.members[j], c)]);
            mesh.positions[centreBase + centreOffset[c] + l] = openvdb::Vec3s(sum / double(end - begin));
        }
    });

    // Attributes (SPEC §6): standard columns copied; refined vertices as the header documents.
    for (const Attribute& column : standard.vertexAttributes.columns()) {
        std::visit([&](const auto& src) {
            using T = typename std::decay_t<decltype(src)>::value_type;
            std::vector<T>& dst = mesh.vertexAttributes.add<T>(column.name, vertexCount);
            for (std::size_t i = 0; i < kept.size(); ++i) dst[i] = src[kept[i]];
            T fill{};
            if constexpr (std::is_floating_point_v<T>) fill = std::numeric_limits<T>::quiet_NaN();
            std::fill(dst.begin() + std::ptrdiff_t(fineBase), dst.end(), fill);
        }, column.data);
    }
    if (auto* ei = mesh.vertexAttributes.find<std::int32_t>("edge_i")) {
        auto& ej = *mesh.vertexAttributes.find<std::int32_t>("edge_j");
        auto& ek = *mesh.vertexAttributes.find<std::int32_t>("edge_k");
        auto& ea = *mesh.vertexAttributes.find<std::uint8_t>("edge_axis");
        auto floorDiv = [m](int v) { return v >= 0 ? v / m : -((-v + m - 1) / m); };
        for (std::size_t i = 0; i < fine.size(); ++i) {
            const Coord p = packer.finePoint(fine[i].key);
            (*ei)[fineBase + i] = floorDiv(p[0]);
            ej[fineBase + i] = floorDiv(p[1]);
            ek[fineBase + i] = floorDiv(p[2]);
            ea[fineBase + i] = std::uint8_t(Packer::axisOf(fine[i].key));
        }
        for (std::size_t c = refinedChunks; c < patches.size(); ++c)
            for (std::size_t l = 0; l < patches[c].memberEnds.size(); ++l) {
                const std::size_t v = centreBase + centreOffset[c] + l;
                const Coord& cell = patches[c].centreCells[l];
                (*ei)[v] = cell[0];
                ej[v] = cell[1];
                ek[v] = cell[2];
                ea[v] = 255;
            }
    }
    auto& hiddenVertex = mesh.vertexAttributes.add<std::uint8_t>("hidden", vertexCount);
    std::fill(hiddenVertex.begin() + std::ptrdiff_t(fineBase), hiddenVertex.end(), std::uint8_t(1));
    for (const Attribute& column : standard.faceAttributes.columns()) {
        std::visit([&](const auto& src) {
            using T = typename std::decay_t<decltype(src)>::value_type;
            std::vector<T>& dst = mesh.faceAttributes.add<T>(column.name, mesh.triangleCount());
            std::size_t f = 0;
            for (std::size_t t = 0; t < keep.size(); ++t)
                if (keep[t]) dst[f++] = src[t];
        }, column.data);
    }
    auto& hiddenFace = mesh.faceAttributes.add<std::uint8_t>("hidden", mesh.triangleCount());
    std::fill(hiddenFace.begin() + std::ptrdiff_t(keptTriangles), hiddenFace.end(), std::uint8_t(1));
    return mesh;
}

Mesh extractWithHiddenFeatures(const openvdb::FloatGrid& grid, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* stats, openvdb::util::NullInterrupter* interrupter)
{
    if (hidden.subdivisions < 1 || hidden.subdivisions > hidden_internal::kMaxSubdivisions)
        OPENVDB_THROW(openvdb::ValueError, "hidden features: subdivisions must be between 1 and 64 (got "
                                               + std::to_string(hidden.subdivisions) + ")");
    MeshSettings withProvenance = settings;
    withProvenance.provenance = true;
    const Mesh standard = extractIsosurface(grid, withProvenance, interrupter);
    Mesh mesh = addHiddenFeatures(grid, standard, settings, hidden, stats, interrupter);
    if (!settings.provenance && !settings.uncertainty) { // the columns the caller asked for
        auto& columns = mesh.vertexAttributes.columns();
        columns.erase(std::remove_if(columns.begin(), columns.end(), [](const Attribute& a) {
            return a.name == "edge_i" || a.name == "edge_j" || a.name == "edge_k" || a.name == "edge_axis" ||
                   a.name == "t_linear";
        }), columns.end());
    }
    return mesh;
}

} // namespace isouq
