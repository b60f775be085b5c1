// isouq: the tricubic Lagrange interpolant on the 4x4x4 voxels around a cell (paper sec. 4.2,
// SPEC §4), used to refine cells that may hide a feature.
//
// Along each axis the weights are those of the 4-point Lagrange cubic on the nodes -1, 0, 1, 2
// (the SPEC §2 cubic, so every view agrees). Evaluation is a tensor product summed in one fixed
// order (z innermost, then y, then x), and at a node (t = 0 or 1) the axis reads that node's
// value instead of summing with weights 0 and 1. Hence a point on a cell face is computed from
// that grid plane's 4x4 values alone, and a point on a cell edge from that grid line's four
// values alone, by the same operations in every cell that shares the face or edge: two refined
// neighbours agree bitwise on their shared face (SPEC §4 "useful property").
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <utility>
#include <vector>

namespace isouq {

/// Weights of the 4-point Lagrange cubic on the nodes -1, 0, 1, 2 at one parameter t.
struct CubicWeights {
    int node = -1;              ///< 1 when t = 0, 2 when t = 1 (stencil index); -1 otherwise
    std::array<double, 4> w{};  ///< used when node < 0
};

/// Lagrange weights at @a t (any real t; t = 0 and t = 1 select the node exactly).
inline CubicWeights cubicWeightsAt(double t)
{
    CubicWeights c;
    if (t == 0.0) c.node = 1;
    else if (t == 1.0) c.node = 2;
    c.w = {-t * (t - 1.0) * (t - 2.0) / 6.0, (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0,
        -(t + 1.0) * t * (t - 2.0) / 2.0, (t + 1.0) * t * (t - 1.0) / 6.0};
    return c;
}

/// Weights at the subdivision point t = s / m, 0 <= s <= m.
inline CubicWeights cubicWeights(int s, int m) { return cubicWeightsAt(double(s) / double(m)); }

namespace tricubic_internal {

/// sum_j w_j v[j * stride], or the node's value: the one contraction every evaluation uses.
template <typename T>
inline double contract(const CubicWeights& c, const T* v, std::ptrdiff_t stride)
{
    if (c.node >= 0) return double(v[c.node * stride]);
    double sum = 0.0;
    for (int j = 0; j < 4; ++j) sum += c.w[j] * double(v[j * stride]);
    return sum;
}

/// In place: the values of the Lagrange cubic at -1, 0, 1, 2 (stride @a s) become its Bernstein
/// coefficients on [0, 1]: b0 = f(0), b1 = f(0) + f'(0) / 3, b2 = f(1) - f'(1) / 3, b3 = f(1).
/// Real is double, or float for the rough hull (roughTricubicRange).
template <typename Real>
inline void toBernstein(Real* v, std::ptrdiff_t s)
{
    const Real v0 = v[0], v1 = v[s], v2 = v[2 * s], v3 = v[3 * s];
    v[0] = v1;
    constexpr Real kNinth = Real(1.0 / 9.0), kSixth5 = Real(5.0 / 6.0), kThird = Real(1.0 / 3.0),
                   kEighteenth = Real(1.0 / 18.0);
    v[s] = kSixth5 * v1 + kThird * v2 - kNinth * v0 - kEighteenth * v3;
    v[2 * s] = kThird * v1 + kSixth5 * v2 - kEighteenth * v0 - kNinth * v3;
    v[3 * s] = v2;
}

} // namespace tricubic_internal

namespace tricubic_internal {

/// cubicRange with the dimension known at compile time, so the loops unroll and vectorise;
/// computed in Real (double, or float for roughTricubicRange).
template <int Dims, typename T, typename Real = double>
std::pair<Real, Real> cubicRangeOf(const T* base, const std::ptrdiff_t* strides)
{
    constexpr int n1 = Dims > 1 ? 4 : 1, n2 = Dims > 2 ? 4 : 1, count = 4 * n1 * n2;
    const std::ptrdiff_t s1 = Dims > 1 ? strides[1] : 0, s2 = Dims > 2 ? strides[2] : 0;
    Real c[count];
    for (int a = 0; a < 4; ++a)
        for (int b = 0; b < n1; ++b)
            for (int d = 0; d < n2; ++d) c[(a * n1 + b) * n2 + d] = Real(base[a * strides[0] + b * s1 + d * s2]);
    constexpr int step[3] = {n1 * n2, n2, 1};
    for (int axis = 0; axis < Dims; ++axis)
        for (int block = 0; block < count; block += 4 * step[axis])
            for (int j = block; j < block + step[axis]; ++j) toBernstein(c + j, step[axis]);
    Real lo[4] = {c[0], c[1], c[2], c[3]}, hi[4] = {c[0], c[1], c[2], c[3]}; // four independent chains
    for (int j = 4; j < count; j += 4)
        for (int l = 0; l < 4; ++l) {
            lo[l] = c[j + l] < lo[l] ? c[j + l] : lo[l];
            hi[l] = c[j + l] > hi[l] ? c[j + l] : hi[l];
        }
    return {std::min(std::min(lo[0], lo[1]), std::min(lo[2], lo[3])),
        std::max(std::max(hi[0], hi[1]), std::max(hi[2], hi[3]))};
}

} // namespace tricubic_internal

/// Bounds [lo, hi] of the tensor-product Lagrange cubic over its cell [0, 1]^dims (dims 1, 2 or
/// 3; 4^dims values at base[a * strides[0] + b * strides[1] + c * strides[2]]): the least and
/// greatest Bernstein coefficient (the polynomial lies in their convex hull). Exact but for
/// rounding; used to skip cells, faces and edges the interpolant cannot take across k.
template <typename T>
std::pair<double, double> cubicRange(const T* base, const std::ptrdiff_t* strides, int dims)
{
    using tricubic_internal::cubicRangeOf;
    return dims == 1 ? cubicRangeOf<1>(base, strides)
                     : dims == 2 ? cubicRangeOf<2>(base, strides) : cubicRangeOf<3>(base, strides);
}

/// tricubicRange of a float stencil computed in float, twice as many lanes per vector: each
/// bound is within 1e-5 (|lo| + |hi|) of tricubicRange's for stencil values in [lo, hi] (three
/// passes of 4-term sums, weights summing to 4/3 in magnitude, about 30 float roundings of the
/// largest value), so a margin above that makes it a cheap first test (HiddenFeatures.cc).
inline std::pair<float, float> roughTricubicRange(const float* stencil)
{
    const std::ptrdiff_t strides[3] = {16, 4, 1};
    return tricubic_internal::cubicRangeOf<3, float, float>(stencil, strides);
}

/// cubicRange of the tricubic on a stencil (tricubic()'s layout).
template <typename T>
std::pair<double, double> tricubicRange(const T* stencil)
{
    const std::ptrdiff_t strides[3] = {16, 4, 1};
    return cubicRange(stencil, strides, 3);
}

/// The tricubic at one point. @a stencil holds f(i-1+a, j-1+b, k-1+c) at index 16a + 4b + c for
/// the cell between voxels ijk and ijk+1; the weights give the point's local coordinates.
template <typename T>
double tricubic(const T* stencil, const CubicWeights& wx, const CubicWeights& wy, const CubicWeights& wz)
{
    using tricubic_internal::contract;
    double alongY[4];
    for (int a = 0; a < 4; ++a) {
        if (wx.node >= 0 && a != wx.node) continue;
        double alongZ[4];
        for (int b = 0; b < 4; ++b) {
            if (wy.node >= 0 && b != wy.node) continue;
            alongZ[b] = contract(wz, stencil + 16 * a + 4 * b, 1);
        }
        alongY[a] = contract(wy, alongZ, 1);
    }
    return contract(wx, alongY, 1);
}

/// Values of the tricubic at the (m+1)^2 points of the cell face across @a axis at @a side (0 or
/// 1), written to out[s * (m+1) + t] for the point whose free axes (in x, y, z order) are at
/// s / m and t / m. The same sums as tricubic() at those points, in its order, so the same bits;
/// the inner sums are shared between points. @a weights are cubicWeights(s, m), s = 0..m;
/// @a partial is scratch of 4 (m+1) values.
template <typename T>
void refineFace(const T* stencil, int axis, int side, const std::vector<CubicWeights>& weights,
    double* partial, double* out)
{
    using tricubic_internal::contract;
    const int n = int(weights.size()), node = 1 + side;
    for (int i = 0; i < 4; ++i) // the plane's lines along its last free axis, contracted per point
        for (int t = 0; t < n; ++t)
            partial[i * n + t] = axis == 0 ? contract(weights[std::size_t(t)], stencil + 16 * node + 4 * i, 1)
                               : axis == 1 ? contract(weights[std::size_t(t)], stencil + 16 * i + 4 * node, 1)
                                           : contract(weights[std::size_t(t)], stencil + 16 * i + node, 4);
    for (int s = 0; s < n; ++s)
        for (int t = 0; t < n; ++t) out[s * n + t] = contract(weights[std::size_t(s)], partial + t, n);
}

/// Scratch space of refineCell, reused between calls with the same m (no allocation per cell).
struct TricubicWorkspace {
    int m = 0;
    std::vector<CubicWeights> weights;
    std::vector<double> alongZ, alongY;
};

/// Values of the tricubic at the (m+1)^3 points (p, q, r) / m of the cell, written to
/// out[((p * (m+1)) + q) * (m+1) + r]. Separable: the same sums as tricubic(), reused.
template <typename T>
void refineCell(const T* stencil, int m, std::vector<double>& out, TricubicWorkspace& ws)
{
    using tricubic_internal::contract;
    const int n = m + 1;
    if (ws.m != m) {
        ws.m = m;
        ws.weights.resize(std::size_t(n));
        for (int s = 0; s < n; ++s) ws.weights[std::size_t(s)] = cubicWeights(s, m);
        // alongZ[(a*4 + b)*n + r], then alongY[(a*n + q)*n + r].
        ws.alongZ.resize(std::size_t(16 * n));
        ws.alongY.resize(std::size_t(4 * n * n));
    }
    const std::vector<CubicWeights>& w = ws.weights;
    double* alongZ = ws.alongZ.data();
    double* alongY = ws.alongY.data();
    for (int ab = 0; ab < 16; ++ab)
        for (int r = 0; r < n; ++r) alongZ[ab * n + r] = contract(w[std::size_t(r)], stencil + 4 * ab, 1);
    for (int a = 0; a < 4; ++a)
        for (int q = 0; q < n; ++q)
            for (int r = 0; r < n; ++r)
                alongY[(a * n + q) * n + r] = contract(w[std::size_t(q)], alongZ + 4 * a * n + r, n);
    out.resize(std::size_t(n) * n * n);
    for (int p = 0; p < n; ++p)
        for (int q = 0; q < n; ++q)
            for (int r = 0; r < n; ++r)
                out[std::size_t((p * n + q) * n + r)] = contract(w[std::size_t(p)], alongY + q * n + r, n * n);
}

template <typename T>
void refineCell(const T* stencil, int m, std::vector<double>& out)
{
    TricubicWorkspace ws;
    refineCell(stencil, m, out, ws);
}

} // namespace isouq
