// isouq: per-vertex error estimates of edge crossings (paper sec. 4.1, SPEC §3, §6).
//
// Header-only, no OpenVDB, allocation-free: the mesher calls these per crossing edge with the
// same stencil as EdgeInterp.h (f[0..5] = f_{i-2..i+3}, bit j of `available` for f[j]), the
// crossings t in [0,1] and the voxel spacing h along the edge's axis. Results are in world
// units. The derivations are in docs/error-estimates.md.
//
// All estimates share one form, the next term of Newton's interpolation error: a method
// interpolating on nodes S has f(x) - p(x) = f[S, x] prod_{s in S}(x - x_s); f[S, x] is
// replaced by the divided difference on S plus one more node (the larger of the two choices),
// and the value error becomes a crossing error by dividing by the slope U[i,i+1].
// Where the extra nodes are missing the estimate is NaN ("unknown", never 0).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace isouq {

/// The paper's estimate e (`err_est`) and the standard bound e_b (`err_bound`) of the linear
/// crossing (SPEC §3).
template <typename RealT = float>
struct LinearErrorT {
    RealT estimate;
    RealT bound;
};
using LinearError = LinearErrorT<float>;

/// Pairwise distances of the methods' crossings and their maximum (`d_lc d_lw d_cw max_var`).
template <typename RealT = float>
struct CrossingSpreadT {
    RealT dLc, dLw, dCw, maxVar;
};
using CrossingSpread = CrossingSpreadT<float>;

namespace error_estimate_internal {

inline bool hasAll(std::uint8_t available, std::uint8_t bits) { return (available & bits) == bits; }

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// n-th forward difference starting at f[j0]: sum_l (-1)^(n-l) C(n,l) f[j0+l].
template <typename ValueT>
inline double forwardDifference(const std::array<ValueT, 6>& f, int j0, int n)
{
    static constexpr double sBinom[6][6] = {{1, 0, 0, 0, 0, 0}, {1, 1, 0, 0, 0, 0},
        {1, 2, 1, 0, 0, 0}, {1, 3, 3, 1, 0, 0}, {1, 4, 6, 4, 1, 0}, {1, 5, 10, 10, 5, 1}};
    double sum = 0.0;
    for (int l = 0; l <= n; ++l) sum += ((n - l) % 2 ? -1.0 : 1.0) * sBinom[n][l] * double(f[j0 + l]);
    return sum;
}

/// Largest |n-th difference| over the windows of n+1 nodes starting at j0 in [jLo, jHi] that
/// are available; NaN when none is.
template <typename ValueT>
inline double largestDifference(const std::array<ValueT, 6>& f, std::uint8_t available, int n, int jLo, int jHi)
{
    double best = kNaN;
    for (int j0 = jLo; j0 <= jHi; ++j0) {
        const auto window = std::uint8_t(((1u << (n + 1)) - 1u) << j0);
        if (!hasAll(available, window)) continue;
        const double d = std::abs(forwardDifference(f, j0, n));
        best = std::isnan(best) ? d : std::max(best, d);
    }
    return best;
}

/// prod over nodes m in [mLo, mHi] of (t - m): the nodal polynomial in t units.
inline double nodal(double t, int mLo, int mHi)
{
    double p = 1.0;
    for (int m = mLo; m <= mHi; ++m) p *= t - m;
    return p;
}

/// h |Delta^n f| / (n! |f_{i+1} - f_i|): world length per unit of the nodal polynomial.
template <typename ValueT>
inline double newtonScale(const std::array<ValueT, 6>& f, double difference, int n, double h)
{
    static constexpr double sFactorial[6] = {1, 1, 2, 6, 24, 120};
    return h * difference / (sFactorial[n] * std::abs(double(f[3]) - double(f[2])));
}

} // namespace error_estimate_internal

/// e and e_b of the linear crossing at tLinear (SPEC §3, paper eqs. approx_linear_error and
/// error_bound_approx): with rho = max(|U[i-1,i+1]|, |U[i,i+2]|) / |U[i,i+1]|,
/// e = rho |(x - x_i)(x - x_{i+1})| = rho h^2 t(1-t) and e_b = rho h^2, so e_b >= 4 e.
/// A missing f_{i-1} or f_{i+2} drops its divided difference; with both missing both are NaN.
template <typename ValueT>
inline LinearErrorT<ValueT> linearError(const std::array<ValueT, 6>& f, std::uint8_t available,
    ValueT tLinear, ValueT h)
{
    using namespace error_estimate_internal;
    const double d2 = largestDifference(f, available, 2, 1, 2);
    const double rhoH2 = newtonScale(f, d2, 2, double(h)); // rho h^2 = h |Delta^2 f| / (2 |Delta f|)
    const double t = double(tLinear);
    return {static_cast<ValueT>(rhoH2 * t * (1.0 - t)), static_cast<ValueT>(rhoH2)};
}

/// The Newton-term estimate of the cubic crossing at tCubic (4-point Lagrange on i-1..i+2):
/// h max|Delta^4 f| |(t+1) t (t-1) (t-2)| / (24 |f_{i+1} - f_i|), Delta^4 on i-2..i+2 or
/// i-1..i+3. NaN unless f_{i-1..i+2} and f_{i-2} or f_{i+3} exist.
template <typename ValueT>
inline ValueT cubicErrorEstimate(const std::array<ValueT, 6>& f, std::uint8_t available, ValueT tCubic, ValueT h)
{
    using namespace error_estimate_internal;
    const double d4 = largestDifference(f, available, 4, 0, 1);
    return static_cast<ValueT>(newtonScale(f, d4, 4, double(h)) * std::abs(nodal(double(tCubic), -1, 2)));
}

/// The Newton-term estimate for a WENO crossing at tWeno: the error term of the 5-point
/// quartics on i-2..i+2 and i-1..i+3, h |Delta^5 f| max|omega_5(t)| / (120 |f_{i+1} - f_i|).
/// It is one order pessimistic for sixth-order WENO on smooth data (a 7th value would be needed
/// for its own term) and tracks WENO's error where WENO drops to lower order. NaN unless all
/// six values exist.
template <typename ValueT>
inline ValueT wenoErrorEstimate(const std::array<ValueT, 6>& f, std::uint8_t available, ValueT tWeno, ValueT h)
{
    using namespace error_estimate_internal;
    const double d5 = largestDifference(f, available, 5, 0, 0);
    const double t = double(tWeno);
    const double omega = std::max(std::abs(nodal(t, -2, 2)), std::abs(nodal(t, -1, 3)));
    return static_cast<ValueT>(newtonScale(f, d5, 5, double(h)) * omega);
}

/// |x_a - x_b| = h |t_a - t_b| for two crossings on the same edge. With a = linear and b = the
/// next higher order (cubic, issue 3's `err_best`) it estimates the linear crossing's error with
/// relative accuracy O(h^2), against O(h) for e.
template <typename ValueT>
inline ValueT crossingDistance(ValueT tA, ValueT tB, ValueT h)
{
    return static_cast<ValueT>(double(h) * std::abs(double(tA) - double(tB)));
}

/// d_lc, d_lw, d_cw and their maximum max_var (SPEC §6).
template <typename ValueT>
inline CrossingSpreadT<ValueT> crossingSpread(ValueT tLinear, ValueT tCubic, ValueT tWeno, ValueT h)
{
    const ValueT dLc = crossingDistance(tLinear, tCubic, h), dLw = crossingDistance(tLinear, tWeno, h),
                 dCw = crossingDistance(tCubic, tWeno, h);
    return {dLc, dLw, dCw, std::max({dLc, dLw, dCw})};
}

/// |cos| of the angle between the edge (axis a) and the surface normal, from a gradient g
/// (e.g. central differences at the vertex): |g_a| / |g|; 1 when g = 0 (no direction known).
template <typename ValueT>
inline ValueT edgeNormalCosine(ValueT gAxis, ValueT gx, ValueT gy, ValueT gz)
{
    const double norm = std::sqrt(double(gx) * gx + double(gy) * gy + double(gz) * gz);
    if (!(norm > 0.0)) return ValueT(1);
    return static_cast<ValueT>(std::min(1.0, std::abs(double(gAxis)) / norm));
}

/// Distance to the surface of a vertex displaced by edgeDistance along its edge, to first
/// order (the surface as its tangent plane): edgeDistance * |cos(edge, normal)|.
template <typename ValueT>
inline ValueT surfaceDistance(ValueT edgeDistance, ValueT edgeNormalCos)
{
    return edgeDistance * edgeNormalCos;
}

} // namespace isouq
