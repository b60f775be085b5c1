// isouq: which cells the hidden-feature pass refines (paper sec. 4.2; SPEC §4;
// docs/hidden-features.md "Detection").
//
// Per 8^3 block holding a meshed cell (in parallel; the result is in block order), the block's
// values [-1, 10)^3 are gathered (BlockScratch.h) and turned into bit rows along z: the slope
// rule flags a cell when one of its 12 edges' three slopes rise and fall. A flagged cell whose
// 18 face and edge neighbours are meshed is refined when the tricubic interpolant crosses k in
// it (and, with the filter, reveals a sign its corners hide or decides an ambiguous case).
// Deciding that means refining the cell; exact bounds (they never reject a cell the refinement
// would keep) settle almost every cell first:
//   Lebesgue:  per block, the tricubic stays within 1.25^3 times its stencil's half range of the
//              stencil's mid range, and every stencil lies in the block's window;
//   curvature: the tricubic differs from the trilinear interpolant by at most
//              c1 (1.25^2 S_x + 1.25 S_y + S_z), c1 = 1 / (9 sqrt 3), S_a the largest sums of two
//              |second differences| along a (the cubic's error term), and the trilinear one keeps
//              the corners' least distance to k (likewise on the edges and faces the filter reads);
//   Bernstein: the hull of the 64 Bernstein coefficients, in float and then in double.
#include "HiddenInternal.h"

#include "isouq/McTables.h"
#include "isouq/Tricubic.h"

#include <tbb/enumerable_thread_specific.h>

#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <algorithm>
#include <cmath>

namespace isouq {
namespace hidden_internal {
namespace {

/// max over t in [0, 1] of t (1 - t) (2 - t) / 6: |cubic - linear| <= c1 (|D0| + |D1|) on an
/// interval whose two second differences are D0 and D1.
constexpr float kCubicErrorConstant = 0.0641500299f;
/// Relative slack of the float bounds (their rounding is below 1e-5 of the stencil's magnitude).
constexpr double kBoundSlack = 1e-4;

/// Bits i < n <= 12 where a[i] > b[i] (rise) and a[i] < b[i] (fall): the signs of a - b.
inline void compareRows(const float* a, const float* b, int n, std::uint32_t& rise, std::uint32_t& fall)
{
    rise = fall = 0;
#ifdef __SSE2__
    for (int i = 0; i < n; i += 4) { // reads up to 3 values past n (BlockScratch's padding)
        const __m128 va = _mm_loadu_ps(a + i), vb = _mm_loadu_ps(b + i);
        rise |= std::uint32_t(_mm_movemask_ps(_mm_cmpgt_ps(va, vb))) << i;
        fall |= std::uint32_t(_mm_movemask_ps(_mm_cmplt_ps(va, vb))) << i;
    }
    rise &= (1u << n) - 1u;
    fall &= (1u << n) - 1u;
#else
    for (int i = 0; i < n; ++i) {
        rise |= std::uint32_t(a[i] > b[i]) << i;
        fall |= std::uint32_t(a[i] < b[i]) << i;
    }
#endif
}

/// Per marching-cubes case: whether its surface has several pieces in the cell (an ambiguous
/// configuration: how they connect is the interpolant's to decide). A case's loops each fan into
/// length - 2 triangles, so loops = (crossing edges - triangles) / 2.
constexpr std::array<bool, 256> kSeveralPieces = [] {
    std::array<bool, 256> out{};
    for (int c = 0; c < 256; ++c)
        out[std::size_t(c)] = __builtin_popcount(kMcCases.crossingEdges[std::size_t(c)]) -
                                  kMcCases.triangleCount[std::size_t(c)] >= 4;
    return out;
}();

/// min and max as the vector instructions compute them (GCC vectorises these; std::min's
/// reference form sometimes stays a branch). NaN handling is irrelevant where they are used: a
/// window with a NaN has infinite slack.
inline float minf(float a, float b) { return a < b ? a : b; }
inline float maxf(float a, float b) { return a > b ? a : b; }

/// Bits i < n <= 8 where !(a[i] > b[i]) (a NaN compares as not above: the bounds then keep).
inline std::uint32_t notAboveBits(const float* a, const float* b, int n)
{
#ifdef __SSE2__
    const int lo = _mm_movemask_ps(_mm_cmpngt_ps(_mm_loadu_ps(a), _mm_loadu_ps(b)));
    const int hi = _mm_movemask_ps(_mm_cmpngt_ps(_mm_loadu_ps(a + 4), _mm_loadu_ps(b + 4)));
    return std::uint32_t(lo | hi << 4) & ((1u << n) - 1u);
#else
    std::uint32_t bits = 0;
    for (int i = 0; i < n; ++i) bits |= std::uint32_t(!(a[i] > b[i])) << i;
    return bits;
#endif
}

/// The least and greatest of v[i], i < n; NaN values make both NaN.
inline std::pair<float, float> valueRange(const float* v, int n)
{
    float lo = std::numeric_limits<float>::infinity(), hi = -lo;
    bool nan = false;
    int i = 0;
#ifdef __SSE2__
    __m128 least = _mm_set1_ps(lo), most = _mm_set1_ps(hi), unordered = _mm_setzero_ps();
    for (; i + 4 <= n; i += 4) {
        const __m128 x = _mm_loadu_ps(v + i);
        least = _mm_min_ps(x, least);
        most = _mm_max_ps(x, most);
        unordered = _mm_or_ps(unordered, _mm_cmpunord_ps(x, x));
    }
    alignas(16) float lanes[8];
    _mm_store_ps(lanes, least);
    _mm_store_ps(lanes + 4, most);
    for (int j = 0; j < 4; ++j) lo = std::min(lo, lanes[j]), hi = std::max(hi, lanes[4 + j]);
    nan = _mm_movemask_ps(unordered) != 0;
#endif
    for (; i < n; ++i) {
        nan |= std::isnan(v[i]);
        lo = std::min(lo, v[i]), hi = std::max(hi, v[i]);
    }
    if (nan) lo = hi = std::numeric_limits<float>::quiet_NaN();
    return {lo, hi};
}

/// A block's values [-1, 10)^3 and what detection derives from them. Per-cell states are rows of
/// bits along z: bit z + 1 for z in [-1, 10), or bit z for the block's cells z in [0, 8).
class DetectWindow {
public:
    DetectWindow(const openvdb::FloatTree& tree, const BlockIndexTree& index) : mBlock(tree, index, -1, 11) {}

    void gather(const Coord& origin, float k)
    {
        mBlock.gather(origin, k);
        mK = k;
        slopeRows();
        stateRows();
        mHaveCurvature = mHaveBoundary = false;
        const auto [lo, hi] = valueRange(mBlock.row(-1, -1), 11 * 11 * 11);
        mMagnitude = std::isnan(lo) ? std::numeric_limits<double>::infinity()
                                    : std::max(std::abs(double(lo)), std::abs(double(hi)));
        // Lebesgue: a cell's tricubic stays within 1.25^3 times its stencil's half range of the
        // stencil's mid range, and every stencil's range lies in the window's.
        const double mid = 0.5 * (double(lo) + double(hi)), reach = 1.953125 * 0.5 * (double(hi) - double(lo));
        mFarFromK = std::abs(double(k) - mid) > reach + boundSlack();
    }
    /// No cell of the block has corners on both sides of k or a tricubic reaching k (a window
    /// with a non-finite value never is).
    bool farFromK() const { return mFarFromK; }

    /// Bits z of the block's cells (x, y, 0..7) that the slope rule flags (SPEC §4): a cell turns
    /// when one of its 12 edges does, and an edge when its three slopes rise and fall.
    std::uint32_t turningCells(int x, int y) const
    {
        const std::uint32_t alongZ = mTurning[2][x][y] | mTurning[2][x + 1][y] | mTurning[2][x][y + 1] | mTurning[2][x + 1][y + 1];
        const std::uint32_t across = mTurning[0][x][y] | mTurning[0][x][y + 1] | mTurning[1][x][y] | mTurning[1][x + 1][y];
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
    /// The marching-cubes case of the block's cell (x, y, z) (McTables.h corner order).
    int cubeCase(int x, int y, int z) const
    {
        int cubeCase = 0;
        for (int c = 0; c < 8; ++c) {
            const auto& o = kMcCornerOffset[std::size_t(c)];
            cubeCase |= int((mInside[x + o.x + 1][y + o.y + 1] >> (z + o.z + 1)) & 1u) << c;
        }
        return cubeCase;
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

    float value(int x, int y, int z) const { return mBlock.value(x, y, z); }
    /// The 4x4x4 stencil of the cell (x, y, z) (Tricubic.h layout).
    void stencil(int x, int y, int z, float* out) const
    {
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b) std::copy_n(rowFrom(x + a - 1, y + b - 1, z - 1), 4, out + 16 * a + 4 * b);
    }

    /// The largest |value| of the block's window (infinity if one is not finite).
    double magnitude() const { return mMagnitude; }

    /// Bits z of the block's cells (x, y, 0..7) whose corners' least distance to k is within the
    /// cell's curvature bound (and boundSlack): the only cells whose tricubic may cross k without their
    /// corners straddling it.
    std::uint32_t nearCells(int x, int y)
    {
        if (!mHaveCurvature) curvature();
        return mNear[x][y];
    }
    /// Slack for the float bounds (kBoundSlack of the window's magnitude and k's).
    double boundSlack() const { return kBoundSlack * (2.0 * mMagnitude + std::abs(double(mK))); }

private:
    /// The row (x, y) from z on.
    const float* rowFrom(int x, int y, int z) const { return mBlock.row(x, y) + (z - mBlock.lo()); }

    /// Sign rows of the slopes f(v + e_axis) - f(v): [axis][x + 1][y + 1], bit z + 1, for v in
    /// [-1, 9)^3.
    void slopeRows()
    {
        for (int axis = 0; axis < 3; ++axis)
            for (int x = -1; x < 9; ++x)
                for (int y = -1; y < 9; ++y)
                    compareRows(rowFrom(x + (axis == 0), y + (axis == 1), -1 + (axis == 2)), rowFrom(x, y, -1), 10,
                        mRise[axis][x + 1][y + 1], mFall[axis][x + 1][y + 1]);
        // Bits z of the block's cell edges along each axis (from voxels [0, 9)^3, [0, 8) along the
        // axis) that turn: their three slopes (from one voxel below to one above) rise and fall.
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < 9; ++y) {
                const std::uint32_t r = mRise[2][x + 1][y + 1], f = mFall[2][x + 1][y + 1];
                mTurning[2][x][y] = (r | r >> 1 | r >> 2) & (f | f >> 1 | f >> 2); // slopes z - 1, z, z + 1
                for (int axis = 0; axis < 2; ++axis) {
                    const int dx = axis == 0, dy = axis == 1;
                    if ((dx && x == 8) || (dy && y == 8)) continue; // the cells' edges stop at 8
                    std::uint32_t rise = 0, fall = 0;
                    for (int s = -1; s <= 1; ++s) {
                        rise |= mRise[axis][x + s * dx + 1][y + s * dy + 1] >> 1;
                        fall |= mFall[axis][x + s * dx + 1][y + s * dy + 1] >> 1;
                    }
                    mTurning[axis][x][y] = rise & fall;
                }
            }
    }

    /// Inside rows of the voxels [-1, 9)^2 and meshed rows of the cells [-1, 9)^2, bit z + 1
    /// (the window starts at z = -1, so its rows already have that layout).
    void stateRows()
    {
        for (int x = -1; x < 9; ++x)
            for (int y = -1; y < 9; ++y) {
                mInside[x + 1][y + 1] = mBlock.insideRow(x, y);
                const std::uint32_t r = mBlock.activeRow(x, y) | mBlock.activeRow(x + 1, y) |
                                        mBlock.activeRow(x, y + 1) | mBlock.activeRow(x + 1, y + 1);
                mMeshed[x + 1][y + 1] = (r | r >> 1) & 0x3ffu;
            }
    }

    /// |Second differences| along each axis (at [0, 9) along it, [-1, 10) across), cellReach of
    /// the block's cells from their separable maxima, and the near-k rows.
    void curvature()
    {
        // |D_x| at x in [0, 9), y in [-1, 10); |D_y| at x in [-1, 10), y in [0, 9); |D_z| at x, y,
        // z in [0, 9). Rows of 12 (one past the window's 11, never read) so the loops vectorise.
        for (int x = 0; x < 9; ++x)
            for (int y = -1; y < 10; ++y) {
                const float *m = rowFrom(x - 1, y, -1), *c = rowFrom(x, y, -1), *p = rowFrom(x + 1, y, -1);
                float* d = mSecond[0][x + 1][y + 1];
                for (int i = 0; i < 12; ++i) d[i] = std::abs(m[i] - 2.0f * c[i] + p[i]);
            }
        for (int x = -1; x < 10; ++x)
            for (int y = 0; y < 9; ++y) {
                const float *m = rowFrom(x, y - 1, -1), *c = rowFrom(x, y, -1), *p = rowFrom(x, y + 1, -1);
                float* d = mSecond[1][x + 1][y + 1];
                for (int i = 0; i < 12; ++i) d[i] = std::abs(m[i] - 2.0f * c[i] + p[i]);
            }
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < 9; ++y) {
                const float* c = rowFrom(x, y, -1);
                float* d = mSecond[2][x + 1][y + 1];
                for (int i = 1; i < 13; ++i) d[i] = std::abs(c[i - 1] - 2.0f * c[i] + c[i + 1]);
            }
        // S_x: per x node (0..8), the max of |D_x| over the cell's 4x4 (y, z) window.
        float windowZ[9][11][kBlockDim], acrossX[9][kBlockDim][kBlockDim];
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < 11; ++y) {
                const float* d = mSecond[0][x + 1][y];
                for (int z = 0; z < kBlockDim; ++z)
                    windowZ[x][y][z] = maxf(maxf(d[z], d[z + 1]), maxf(d[z + 2], d[z + 3]));
            }
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < kBlockDim; ++y)
                for (int z = 0; z < kBlockDim; ++z)
                    acrossX[x][y][z] = maxf(maxf(windowZ[x][y][z], windowZ[x][y + 1][z]),
                        maxf(windowZ[x][y + 2][z], windowZ[x][y + 3][z]));
        // S_y: per (x, y) node, the max of |D_y| over the cell's four z nodes.
        float acrossY[9][9][kBlockDim];
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < 9; ++y) {
                const float* d = mSecond[1][x + 1][y + 1];
                for (int z = 0; z < kBlockDim; ++z)
                    acrossY[x][y][z] = maxf(maxf(d[z], d[z + 1]), maxf(d[z + 2], d[z + 3]));
            }
        for (int x = 0; x < kBlockDim; ++x)
            for (int y = 0; y < kBlockDim; ++y) {
                const float *z00 = mSecond[2][x + 1][y + 1] + 1, *z10 = mSecond[2][x + 2][y + 1] + 1;
                const float *z01 = mSecond[2][x + 1][y + 2] + 1, *z11 = mSecond[2][x + 2][y + 2] + 1;
                for (int z = 0; z < kBlockDim; ++z) {
                    const float sx = acrossX[x][y][z] + acrossX[x + 1][y][z];
                    const float sy = maxf(acrossY[x][y][z] + acrossY[x][y + 1][z],
                        acrossY[x + 1][y][z] + acrossY[x + 1][y + 1][z]);
                    const float sz = maxf(maxf(z00[z] + z00[z + 1], z10[z] + z10[z + 1]),
                        maxf(z01[z] + z01[z + 1], z11[z] + z11[z + 1]));
                    mReach[x][y][z] = kCubicErrorConstant * (1.5625f * sx + 1.25f * sy + sz);
                }
            }
        // The corners' least |f - k| per cell, separably (z, y, x), against the reach. In float:
        // its rounding is far inside boundSlack.
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < 9; ++y) {
                const float* c = rowFrom(x, y, 0);
                for (int z = 0; z < 12; ++z) mDistance[x][y][z] = std::abs(c[z] - mK);
                for (int z = 0; z < kBlockDim; ++z) mPairZ[x][y][z] = minf(mDistance[x][y][z], mDistance[x][y][z + 1]);
            }
        for (int x = 0; x < 9; ++x)
            for (int y = 0; y < kBlockDim; ++y)
                for (int z = 0; z < kBlockDim; ++z) mFaceX[x][y][z] = minf(mPairZ[x][y][z], mPairZ[x][y + 1][z]);
        const float slack = mSlack = float(boundSlack());
        for (int x = 0; x < kBlockDim; ++x)
            for (int y = 0; y < kBlockDim; ++y) {
                float least[kBlockDim];
                for (int z = 0; z < kBlockDim; ++z) {
                    least[z] = minf(mFaceX[x][y][z], mFaceX[x + 1][y][z]);
                    mReach[x][y][z] += slack; // from here on, the reach with the slack
                }
                mNear[x][y] = notAboveBits(least, mReach[x][y], kBlockDim);
            }
        mHaveCurvature = true;
    }

public:
    /// Per element of the block's cells (12 edges, 6 faces), rows of bits: the element's corners
    /// lie on one side of k and its curvature bound (edges: the cubic's along it; faces: the
    /// cell's, which holds on its faces) reaches k. Edges along axis a from voxel v:
    /// mEdgeRows[a][v_x][v_y] bit v_z; faces of cell c across axis a at side s: mFaceRows[2a + s]
    /// [c_x][c_y] bit c_z.
    void boundaryRows()
    {
        if (!mHaveCurvature) curvature();
        for (int x = 0; x < kBlockDim; ++x)
            for (int y = 0; y < 9; ++y)
                for (int z = 0; z < kBlockDim; ++z) mFaceY[x][y][z] = minf(mPairZ[x][y][z], mPairZ[x + 1][y][z]);
        for (int x = 0; x < kBlockDim; ++x)
            for (int y = 0; y < kBlockDim; ++y)
                for (int z = 0; z < 12; ++z)
                    mFaceZ[x][y][z] = minf(minf(mDistance[x][y][z], mDistance[x + 1][y][z]),
                        minf(mDistance[x][y + 1][z], mDistance[x + 1][y + 1][z]));
        const float slack = float(boundSlack());
        auto in = [this](int x, int y) { return mInside[x + 1][y + 1] >> 1; }; // bit z: voxel z
        for (int axis = 0; axis < 3; ++axis)
            for (int x = 0; x < 9 - (axis == 0); ++x)
                for (int y = 0; y < 9 - (axis == 1); ++y) {
                    const int x1 = x + (axis == 0), y1 = y + (axis == 1), dz = axis == 2, n = 9 - dz;
                    const float *d0 = mDistance[x][y], *d1 = mDistance[x1][y1] + dz;
                    const float *a0 = mSecond[axis][x + 1][y + 1] + 1, *a1 = mSecond[axis][x1 + 1][y1 + 1] + 1 + dz;
                    float least[9], reach[9];
                    for (int z = 0; z < n; ++z) {
                        least[z] = minf(d0[z], d1[z]);
                        reach[z] = kCubicErrorConstant * (a0[z] + a1[z]) + slack;
                    }
                    std::uint32_t near = notAboveBits(least, reach, kBlockDim);
                    if (n > kBlockDim) near |= std::uint32_t(!(least[8] > reach[8])) << 8;
                    const std::uint32_t same = ~(in(x, y) ^ (in(x1, y1) >> dz));
                    mEdgeRows[axis][x][y] = near & same & 0x1ffu;
                }
        for (int x = 0; x < kBlockDim; ++x)
            for (int y = 0; y < kBlockDim; ++y) {
                const float* reach = mReach[x][y]; // with the slack (curvature)
                const std::uint32_t near[6] = {notAboveBits(mFaceX[x][y], reach, kBlockDim),
                    notAboveBits(mFaceX[x + 1][y], reach, kBlockDim), notAboveBits(mFaceY[x][y], reach, kBlockDim),
                    notAboveBits(mFaceY[x][y + 1], reach, kBlockDim), notAboveBits(mFaceZ[x][y], reach, kBlockDim),
                    notAboveBits(mFaceZ[x][y] + 1, reach, kBlockDim)};
                // Faces whose four corners lie on one side: across x and y from the corner rows,
                // across z from the four rows at z (side 0) or z + 1 (side 1).
                auto oneSide = [](std::uint32_t a, std::uint32_t b) { // rows' voxels z, z + 1
                    const std::uint32_t all = a & a >> 1 & b & b >> 1, none = ~(a | a >> 1 | b | b >> 1);
                    return all | none;
                };
                const std::uint32_t r00 = in(x, y), r10 = in(x + 1, y), r01 = in(x, y + 1), r11 = in(x + 1, y + 1);
                const std::uint32_t allZ = r00 & r10 & r01 & r11, noneZ = ~(r00 | r10 | r01 | r11);
                const std::uint32_t same[6] = {oneSide(r00, r01), oneSide(r10, r11), oneSide(r00, r10), oneSide(r01, r11),
                    allZ | noneZ, (allZ | noneZ) >> 1};
                for (int f = 0; f < 6; ++f) mFaceRows[f][x][y] = near[f] & same[f] & 0xffu;
            }
        mHaveBoundary = true;
    }
    /// Bits z of the block's cells (x, y, 0..7) with an element boundaryRows keeps.
    std::uint32_t boundaryCells(int x, int y)
    {
        if (!mHaveBoundary) boundaryRows();
        std::uint32_t any = 0;
        for (int f = 0; f < 6; ++f) any |= mFaceRows[f][x][y];
        for (int d = 0; d < 2; ++d) {
            any |= (mEdgeRows[0][x][y + d] | mEdgeRows[0][x][y + d] >> 1 | mEdgeRows[1][x + d][y] |
                    mEdgeRows[1][x + d][y] >> 1);
            for (int e = 0; e < 2; ++e) any |= mEdgeRows[2][x + d][y + e];
        }
        return any & 0xffu;
    }
    /// Whether boundaryRows keeps the edge of the cell (x, y, z) along @a axis at offsets @a du,
    /// @a dv on the next two axes, or the face across @a axis at @a side.
    bool edgeKept(int x, int y, int z, int axis, int du, int dv) const
    {
        int o[3] = {0, 0, 0};
        o[(axis + 1) % 3] = du, o[(axis + 2) % 3] = dv;
        return (mEdgeRows[axis][x + o[0]][y + o[1]] >> (z + o[2])) & 1u;
    }
    bool faceKept(int x, int y, int z, int axis, int side) const { return (mFaceRows[2 * axis + side][x][y] >> z) & 1u; }
    /// After curvature(): whether the bicubic on the face of the cell (x, y, z) across @a normal
    /// at @a side may reach k by the face's own bound, tighter than the cell's:
    /// (P_u - L_u) P_w + L_u (P_w - L_w) with u, w its axes, so c1 (1.25 (the largest |D_u| over
    /// the 4 w lines at both u nodes) + the larger over the u nodes of |D_w| at both w nodes).
    bool faceMayReach(int x, int y, int z, int normal, int side) const
    {
        auto a = [this](int axis, int vx, int vy, int vz) { return mSecond[axis][vx + 1][vy + 1][vz + 1]; };
        float acrossU[2] = {0.0f, 0.0f}, alongW = 0.0f, least = std::numeric_limits<float>::max();
        for (int i = 0; i < 2; ++i) {
            for (int j = -1; j <= 2; ++j)
                acrossU[i] = maxf(acrossU[i], normal == 0 ? a(1, x + side, y + i, z + j)
                                              : normal == 1 ? a(0, x + i, y + side, z + j)
                                                            : a(0, x + i, y + j, z + side));
            alongW = maxf(alongW, normal == 0 ? a(2, x + side, y + i, z) + a(2, x + side, y + i, z + 1)
                                  : normal == 1 ? a(2, x + i, y + side, z) + a(2, x + i, y + side, z + 1)
                                                : a(1, x + i, y, z + side) + a(1, x + i, y + 1, z + side));
            for (int j = 0; j < 2; ++j) // the face's corners
                least = minf(least, normal == 0 ? mDistance[x + side][y + i][z + j]
                                    : normal == 1 ? mDistance[x + i][y + side][z + j]
                                                  : mDistance[x + i][y + j][z + side]);
        }
        return !(least > kCubicErrorConstant * (1.25f * (acrossU[0] + acrossU[1]) + alongW) + mSlack);
    }

private:

    mc_internal::BlockScratch<openvdb::FloatTree> mBlock;
    std::uint32_t mRise[3][10][10], mFall[3][10][10];
    std::uint32_t mTurning[3][9][9]; // per axis and edge row (x, y): bits z of the turning edges
    std::uint32_t mInside[10][10], mMeshed[10][10];
    bool mHaveCurvature = false, mHaveBoundary = false, mFarFromK = false;
    float mK = 0.0f;
    double mMagnitude = 0.0;
    std::uint32_t mNear[kBlockDim][kBlockDim];
    // Least |f - k|: at voxels [0, 9)^3 (rows padded to 12), over z pairs, over faces across x,
    // y and z (z: padded).
    float mDistance[9][9][12], mPairZ[9][9][kBlockDim];
    float mFaceX[9][kBlockDim][kBlockDim], mFaceY[kBlockDim][9][kBlockDim], mFaceZ[kBlockDim][kBlockDim][12];
    std::uint32_t mEdgeRows[3][9][9], mFaceRows[6][kBlockDim][kBlockDim];
    float mSlack = 0.0f; // boundSlack, once curvature ran
    float mSecond[3][11][11][13]; // [axis][x + 1][y + 1][z + 1]
    float mReach[kBlockDim][kBlockDim][kBlockDim]; // per cell: its curvature bound plus boundSlack
};

/// Bits z (0..7) of the row origin + (x, y, z) whose cells [c + lo, c + hi] lie in @a box.
inline std::uint32_t boxRow(const std::optional<CoordBBox>& box, const Coord& origin, int x, int y, int lo, int hi)
{
    if (!box) return 0xffu;
    const Coord c = origin.offsetBy(x, y, 0);
    for (int a = 0; a < 2; ++a)
        if (c[a] + lo < box->min()[a] || c[a] + hi > box->max()[a]) return 0;
    std::uint32_t bits = 0;
    for (int z = 0; z < kBlockDim; ++z)
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
                int lo[3], hi[3];
                for (int a = 0; a < 3; ++a) {
                    lo[a] = s[a] == 1 ? m : 0;
                    hi[a] = s[a] == 0 ? 0 : m;
                }
                int corners = 0, inside = 0;
                for (int p = lo[0]; p <= hi[0]; p += m)
                    for (int q = lo[1]; q <= hi[1]; q += m)
                        for (int r = lo[2]; r <= hi[2]; r += m) {
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

/// Whether the element of a cell given by @a s (per axis: 0 or 1 fixed at that side, 2 free; an
/// edge or a face), whose corners all lie on the side @a cornersInside, has a subdivision value
/// on the other side. Evaluated only when the Bernstein hull of its grid line or plane reaches k;
/// the values are refineCell's (Tricubic.h).
bool elementHidesSign(const float* stencil, const int (&s)[3], bool cornersInside,
    const std::vector<CubicWeights>& weights, int m, double k)
{
    int node[3], local[3][2];
    std::ptrdiff_t strides[2];
    int dims = 0;
    for (int a = 0; a < 3; ++a) { // first stencil index and sub-point range per axis
        node[a] = s[a] == 2 ? 0 : 1 + s[a];
        local[a][0] = s[a] == 1 ? m : 0;
        local[a][1] = s[a] == 0 ? 0 : m;
        if (s[a] == 2) strides[dims++] = a == 0 ? 16 : a == 1 ? 4 : 1;
    }
    if (!mayCross(cubicRange(stencil + 16 * node[0] + 4 * node[1] + node[2], strides, dims), k)) return false;
    if (dims == 2) { // a face: its values separably (refineFace, the same bits)
        int axis = 0;
        while (s[axis] == 2) ++axis;
        double partial[4 * (kMaxSubdivisions + 1)], values[(kMaxSubdivisions + 1) * (kMaxSubdivisions + 1)];
        refineFace(stencil, axis, s[axis], weights, partial, values);
        for (int i = 0; i < (m + 1) * (m + 1); ++i)
            if ((values[i] >= k) != cornersInside) return true;
        return false;
    }
    for (int p = local[0][0]; p <= local[0][1]; ++p)
        for (int q = local[1][0]; q <= local[1][1]; ++q)
            for (int r = local[2][0]; r <= local[2][1]; ++r)
                if ((tricubic(stencil, weights[std::size_t(p)], weights[std::size_t(q)], weights[std::size_t(r)]) >= k) !=
                    cornersInside)
                    return true;
    return false;
}

/// reveals() for the cell (x, y, z) of @a w whose corners straddle k (the cell itself then hides
/// nothing), without refining all of it: only the edges and faces boundaryRows keeps are
/// evaluated (the stencil is copied to @a stencil then).
bool boundaryReveals(DetectWindow& w, int x, int y, int z, float* stencil, const std::vector<CubicWeights>& weights,
    int m, double k)
{
    bool haveStencil = false;
    auto reveals = [&](const int (&s)[3], int cornerX, int cornerY, int cornerZ) {
        if (!haveStencil) {
            w.stencil(x, y, z, stencil);
            haveStencil = true;
        }
        return elementHidesSign(stencil, s, double(w.value(cornerX, cornerY, cornerZ)) >= k, weights, m, k);
    };
    for (int axis = 0; axis < 3; ++axis) {
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        for (int du = 0; du < 2; ++du)
            for (int dv = 0; dv < 2; ++dv) { // the edge along axis at offsets du, dv
                if (!w.edgeKept(x, y, z, axis, du, dv)) continue;
                int s[3];
                s[axis] = 2, s[u] = du, s[v] = dv;
                if (reveals(s, x + (s[0] == 1), y + (s[1] == 1), z + (s[2] == 1))) return true;
            }
        for (int side = 0; side < 2; ++side) { // the face across axis at side
            if (!w.faceKept(x, y, z, axis, side) || !w.faceMayReach(x, y, z, axis, side)) continue;
            int s[3] = {2, 2, 2};
            s[axis] = side;
            if (reveals(s, x + (s[0] == 1), y + (s[1] == 1), z + (s[2] == 1))) return true;
        }
    }
    return false;
}

} // namespace

Detection detectRefinedCells(const openvdb::FloatTree& tree, const BlockSet& blocks, float k,
    const std::optional<CoordBBox>& dataBounds, const HiddenFeatureSettings& hidden, bool threaded,
    openvdb::util::NullInterrupter* interrupter, std::size_t blockBegin, std::size_t blockEnd)
{
    blockEnd = std::min(blockEnd, blocks.origins.size());
    blockBegin = std::min(blockBegin, blockEnd);
    const int m = hidden.subdivisions;
    struct BlockResult {
        std::size_t total = 0, flagged = 0;
        std::vector<Coord> refined;
    };
    std::vector<BlockResult> results(blockEnd - blockBegin);
    struct Scratch {
        DetectWindow window;
        TricubicWorkspace workspace;
        std::vector<double> sub;
        std::vector<CubicWeights> weights;
    };
    std::vector<CubicWeights> weights;
    for (int s = 0; s <= m; ++s) weights.push_back(cubicWeights(s, m));
    tbb::enumerable_thread_specific<Scratch> scratches(
        [&] { return Scratch{DetectWindow(tree, blocks.index), {}, {}, weights}; });
    forEach(results.size(), 4, threaded, interrupter, [&](std::size_t b) {
        const Coord& origin = blocks.origins[blockBegin + b];
        // Cells are counted only when all their corners are in the data box.
        if (dataBounds && !CoordBBox(dataBounds->min(), dataBounds->max().offsetBy(-1))
                              .hasOverlap(CoordBBox(origin, origin.offsetBy(kBlockDim - 1))))
            return;
        Scratch& scratch = scratches.local();
        DetectWindow& w = scratch.window;
        w.gather(origin, k);
        BlockResult& out = results[b];
        const bool farFromK = w.farFromK();
        // Every stencil of the block's cells, [origin - 1, origin + 9], in the data box: no row
        // needs boxRow.
        const bool inBox = !dataBounds || dataBounds->isInside(CoordBBox(origin.offsetBy(-1), origin.offsetBy(kBlockDim + 1)));
        float stencil[64];
        for (int x = 0; x < kBlockDim; ++x)
            for (int y = 0; y < kBlockDim; ++y) {
                const std::uint32_t cells = w.meshedCells(x, y) & (inBox ? 0xffu : boxRow(dataBounds, origin, x, y, 0, 1));
                out.total += std::size_t(__builtin_popcount(cells));
                // The rule reads one voxel beyond each edge: cells whose stencil leaves the data are
                // never flagged.
                std::uint32_t flagged = cells & w.turningCells(x, y);
                if (!inBox) flagged &= boxRow(dataBounds, origin, x, y, -1, 2);
                out.flagged += std::size_t(__builtin_popcount(flagged));
                // Transition cells must be meshed too, so the refinement stops one cell short of the
                // border of the active region (where a sparse surface ends anyway).
                if (farFromK) continue; // counted; nothing to refine
                flagged &= w.meshedAround(x, y);
                const std::uint32_t straddling = w.straddlingCells(x, y);
                // The filter keeps a straddling cell whose case has several pieces (the tricubic
                // decides how they connect) or one of whose edges or faces may hide a sign.
                std::uint32_t severalPieces = 0;
                if (hidden.filter && (flagged & straddling)) {
                    for (std::uint32_t c = flagged & straddling; c; c &= c - 1)
                        if (kSeveralPieces[std::size_t(w.cubeCase(x, y, __builtin_ctz(c)))]) severalPieces |= c & -c;
                    flagged &= ~straddling | severalPieces | w.boundaryCells(x, y);
                }
                for (; flagged; flagged &= flagged - 1) {
                    const int z = __builtin_ctz(flagged);
                    if ((straddling >> z) & 1u) {
                        if (hidden.filter && !((severalPieces >> z) & 1u) &&
                            !boundaryReveals(w, x, y, z, stencil, scratch.weights, m, k))
                            continue;
                    } else {
                        if (!((w.nearCells(x, y) >> z) & 1u)) continue; // the curvature bound
                        w.stencil(x, y, z, stencil);
                        // The float hull first: its margin (100x its rounding, Tricubic.h, plus
                        // mayCross's slack) leaves every decision to the double hull's.
                        const auto rough = roughTricubicRange(stencil);
                        const double margin = 1e-3 * (2.0 * w.magnitude() + std::abs(double(k)));
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
    Detection detection;
    for (const BlockResult& r : results) {
        detection.cellsTotal += r.total;
        detection.cellsFlagged += r.flagged;
        detection.refined.insert(detection.refined.end(), r.refined.begin(), r.refined.end());
    }
    return detection;
}

} // namespace hidden_internal
} // namespace isouq
