// isouq: edge-crossing interpolation methods (paper sec. 3.2-3.4, SPEC §2).
//
// Header-only, no OpenVDB: the mesher calls these per crossing edge in its hot loop. Each
// method is a trait in the manner of OpenVDB's Interpolation.h samplers, with static name(),
// radius() (voxels read beyond each end of the edge), order() (order of the crossing error in
// h with the full stencil) and crossing(). The derivations are in docs/interpolation.md.
//
// Stencil: f[0..5] = f_{i-2}, f_{i-1}, f_i, f_{i+1}, f_{i+2}, f_{i+3} along the edge's axis;
// bit j of `available` says f[j] exists (f[2], f[3] always do). Precondition: f[2] and f[3]
// are on opposite sides of k under "value >= k is inside". The result t in [0,1] is the
// crossing's parameter from x_i to x_{i+1}; `order` is the order actually used after fallback.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

namespace isouq {

/// Interpolation method for the crossing of an isosurface with a cell edge (SPEC §2).
enum class EdgeMethod { Linear, Cubic, Weno, WenoPaper };

inline std::string toString(EdgeMethod m)
{
    switch (m) {
    case EdgeMethod::Linear: return "linear";
    case EdgeMethod::Cubic: return "cubic";
    case EdgeMethod::Weno: return "weno";
    case EdgeMethod::WenoPaper: return "weno-paper";
    }
    return "linear";
}

inline std::string toMenuName(EdgeMethod m)
{
    switch (m) {
    case EdgeMethod::Linear: return "Linear";
    case EdgeMethod::Cubic: return "Cubic (4-point Lagrange)";
    case EdgeMethod::Weno: return "WENO (6th order)";
    case EdgeMethod::WenoPaper: return "WENO (paper's constant weights)";
    }
    return "Linear";
}

/// Parses "linear", "cubic", "weno" or "weno-paper"; nullopt for anything else.
inline std::optional<EdgeMethod> edgeMethodFromString(std::string_view s)
{
    if (s == "linear") return EdgeMethod::Linear;
    if (s == "cubic") return EdgeMethod::Cubic;
    if (s == "weno") return EdgeMethod::Weno;
    if (s == "weno-paper") return EdgeMethod::WenoPaper;
    return std::nullopt;
}

/// Availability mask with all six stencil values f_{i-2..i+3} present.
inline constexpr std::uint8_t kStencilAll = 0x3F;

/// A crossing: parameter t in [0,1] along the edge and the order actually used.
template <typename RealT = float>
struct EdgeCrossingT {
    RealT t;
    std::uint8_t order;
};
using EdgeCrossing = EdgeCrossingT<float>;

namespace edge_interp_internal {

inline bool hasAll(std::uint8_t available, std::uint8_t bits) { return (available & bits) == bits; }
inline constexpr std::uint8_t bit(int j) { return std::uint8_t(1u << j); }

/// A polynomial through both edge ends in "edge form" (docs/interpolation.md):
/// p(t) = f_i + d t + t(t-1)(alpha + beta t), d = f_{i+1} - f_i. Every candidate of SPEC §2
/// has this form, so every convex combination equals f_i at t=0 and f_{i+1} at t=1.
struct EdgePoly {
    double alpha = 0.0;
    double beta = 0.0;
};

/// Stencil values in double with the edge's slope and the divided differences
/// r_m = f[x_i, x_{i+1}, x_{i+m}] in t units, m = j - 2 the node of f[j].
struct EdgeStencil {
    double f[6];
    double d;
    double r(int j) const
    {
        const double m = j - 2;
        return (f[j] - f[2] - d * m) / (m * (m - 1.0));
    }
};

template <typename ValueT>
inline EdgeStencil makeStencil(const std::array<ValueT, 6>& v)
{
    EdgeStencil s{};
    for (int j = 0; j < 6; ++j) s.f[j] = double(v[j]);
    s.d = s.f[3] - s.f[2];
    return s;
}

/// The edge-form polynomial through the edge ends and stencil values f[ja], f[jb]
/// (a cubic; with ja == jb the quadratic through f[ja]).
inline EdgePoly edgePolyThrough(const EdgeStencil& s, int ja, int jb)
{
    const double ra = s.r(ja);
    if (ja == jb) return {ra, 0.0};
    const double beta = (ra - s.r(jb)) / double(ja - jb);
    return {ra - beta * (ja - 2), beta};
}

/// Cubic Lagrange candidates of SPEC §2: S1 = i-2..i+1, S2 = i-1..i+2, S3 = i..i+3.
inline EdgePoly cubicS1(const EdgeStencil& s) { return edgePolyThrough(s, 1, 0); }
inline EdgePoly cubicS2(const EdgeStencil& s) { return edgePolyThrough(s, 1, 4); }
inline EdgePoly cubicS3(const EdgeStencil& s) { return edgePolyThrough(s, 4, 5); }
/// Quadratic candidates of WENO4: i-1..i+1 and i..i+2.
inline EdgePoly quadLeft(const EdgeStencil& s) { return edgePolyThrough(s, 1, 1); }
inline EdgePoly quadRight(const EdgeStencil& s) { return edgePolyThrough(s, 4, 4); }

/// Value of an edge-form polynomial at t.
inline double evalEdgePoly(const EdgePoly& p, double fi, double d, double t)
{
    return fi + d * t + t * (t - 1.0) * (p.alpha + p.beta * t);
}

/// Jiang-Shu indicator sum_{l=1..3} int_0^1 (p^(l))^2 dt of p = a0 + a1 t + a2 t^2 + a3 t^3
/// (SPEC §2); a quadratic is the case a3 = 0.
inline double smoothness(const EdgePoly& p, double d)
{
    const double a1 = d - p.alpha, a2 = p.alpha - p.beta, a3 = p.beta;
    return a1 * a1 + 2.0 * a1 * a2 + 2.0 * a1 * a3 + (16.0 / 3.0) * a2 * a2 + 15.0 * a2 * a3 +
           (249.0 / 5.0) * a3 * a3;
}

/// Linear weights as quadratics g(t) = c[0] + c[1] t + c[2] t^2.
using Quadratic = std::array<double, 3>;
/// WENO6: g1 = (2-t)(3-t)/20, g2 = (3-t)(t+2)/10, g3 = (t+1)(t+2)/20 (SPEC §2).
inline constexpr Quadratic kWeno6Linear[3] = {
    {6.0 / 20.0, -5.0 / 20.0, 1.0 / 20.0}, {6.0 / 10.0, 1.0 / 10.0, -1.0 / 10.0},
    {2.0 / 20.0, 3.0 / 20.0, 1.0 / 20.0}};
/// WENO4: (2-t)/3 and (1+t)/3 (SPEC §2 fallback).
inline constexpr Quadratic kWeno4Linear[2] = {{2.0 / 3.0, -1.0 / 3.0, 0.0}, {1.0 / 3.0, 1.0 / 3.0, 0.0}};
/// The paper's constant weights 1/10, 3/5, 3/10 (paper sec. 3.4).
inline constexpr Quadratic kWenoPaperLinear[3] = {{0.1, 0.0, 0.0}, {0.6, 0.0, 0.0}, {0.3, 0.0, 0.0}};
/// A single polynomial.
inline constexpr Quadratic kSingle[1] = {{1.0, 0.0, 0.0}};

inline double evalQuadratic(const Quadratic& g, double t) { return g[0] + t * (g[1] + t * g[2]); }

/// p(t) - k = N(t) / D(t) with D(t) = sum_j c_j g_j(t) > 0 on [0,1]: monomial coefficients of
/// N (degree <= 5) and D(0), D(1), so the end values N(0) = D(0)(f_i-k), N(1) = D(1)(f_{i+1}-k)
/// keep their exact signs.
struct Numerator {
    double a[6];
    double d0, d1;
};

/// Combines candidates p_j with weights c_j g_j(t) / sum_l c_l g_l(t) (c_j > 0).
inline Numerator combine(const EdgeStencil& s, double k, const EdgePoly* p, const Quadratic* g,
    const double* c, int n)
{
    // N = D (F0 + d t) + (t^2 - t) M with M = sum_j c_j g_j (alpha_j + beta_j t).
    double dq[3] = {0, 0, 0}, m[4] = {0, 0, 0, 0};
    for (int j = 0; j < n; ++j) {
        for (int l = 0; l < 3; ++l) {
            const double cg = c[j] * g[j][l];
            dq[l] += cg;
            m[l] += cg * p[j].alpha;
            m[l + 1] += cg * p[j].beta;
        }
    }
    const double f0 = s.f[2] - k;
    Numerator num{{dq[0] * f0, dq[0] * s.d + dq[1] * f0 - m[0], dq[1] * s.d + dq[2] * f0 + m[0] - m[1],
                      dq[2] * s.d + m[1] - m[2], m[2] - m[3], m[3]},
        dq[0], dq[0] + dq[1] + dq[2]};
    return num;
}

/// Normalised nonlinear factors c_j = ((eps + b_min) / (eps + b_j))^2 in (0,1], with
/// eps = 1e-6 R^2 and R the range of the values the candidates read (SPEC §2).
inline void nonlinearFactors(const EdgeStencil& s, int jLo, int jHi, const EdgePoly* p, int n, double* c)
{
    double lo = s.f[jLo], hi = s.f[jLo];
    for (int j = jLo + 1; j <= jHi; ++j) {
        lo = std::min(lo, s.f[j]);
        hi = std::max(hi, s.f[j]);
    }
    const double eps = std::max(1e-6 * (hi - lo) * (hi - lo), std::numeric_limits<double>::min());
    double b[3], bMin = std::numeric_limits<double>::max();
    for (int j = 0; j < n; ++j) bMin = std::min(bMin, b[j] = smoothness(p[j], s.d));
    for (int j = 0; j < n; ++j) {
        const double q = (eps + bMin) / (eps + b[j]);
        c[j] = q * q;
    }
}

// ---- roots of N on [0,1] ------------------------------------------------------------------

inline constexpr int kMaxSubdivision = 16; ///< isolation down to intervals of 2^-16
inline constexpr int kMaxRoots = 8;

struct RootList {
    double t[kMaxRoots];
    int count = 0;
    void push(double x)
    {
        if (count < kMaxRoots) t[count++] = x;
    }
};

/// N(t) and N'(t), with t^2 and t^4 splitting each into independent pairs (Estrin's scheme:
/// half the dependency chain of Horner's, which the root finding waited on; issue 12).
inline double evaluate(const double* a, double t, double& derivative)
{
    const double t2 = t * t, t4 = t2 * t2;
    derivative = (a[1] + 2.0 * a[2] * t) + t2 * (3.0 * a[3] + 4.0 * a[4] * t) + t4 * (5.0 * a[5]);
    return (a[0] + a[1] * t) + t2 * (a[2] + a[3] * t) + t4 * (a[4] + a[5] * t);
}

/// The single root of N in (lo, hi), N having the sign of sLo just right of lo: Newton steps
/// kept inside the shrinking bracket, bisection when a step leaves it or stalls. Newton's error
/// after a step is about C step^2, C estimated from the last two steps; once that is below a
/// tenth of tol the step is taken without evaluating N again to see it.
inline double solveBracketed(const double* a, double lo, double hi, double sLo, double x, double tol)
{
    double stepOld = hi - lo;
    bool newtonOld = false;
    for (int it = 0; it < 64; ++it) {
        double dp;
        const double p = evaluate(a, x, dp);
        if (p == 0.0) return x;
        if ((p > 0.0) == (sLo > 0.0)) lo = x; else hi = x;
        double step = p / dp;
        double next = x - step;
        const bool newton = next > lo && next < hi && std::abs(step) <= 0.5 * std::abs(stepOld);
        if (!newton) {
            next = 0.5 * (lo + hi);
            step = x - next;
        }
        if (std::abs(step) <= tol || hi - lo <= tol) return next;
        if (newton && newtonOld && std::abs(step) * step * step < 0.1 * tol * stepOld * stepOld)
            return next;
        stepOld = step;
        newtonOld = newton;
        x = next;
    }
    return x;
}

/// de Casteljau split of degree-5 Bernstein coefficients at the middle.
inline void splitHalf(const double* b, double* left, double* right)
{
    double w[6];
    std::copy(b, b + 6, w);
    for (int r = 0; r < 6; ++r) {
        left[r] = w[0];
        right[5 - r] = w[5 - r];
        for (int j = 0; j < 5 - r; ++j) w[j] = 0.5 * (w[j] + w[j + 1]);
    }
}

/// Appends, in increasing order, the roots of N in the open interval (lo, hi), where b holds
/// N's Bernstein coefficients on [lo, hi]. The number of sign changes of b bounds the number of
/// roots and has its parity (Descartes); one sign change means exactly one simple root.
inline void isolateRoots(const double* a, const double* b, double lo, double hi, int depth,
    double tol, RootList& roots)
{
    int changes = 0, first = 0, last = 5;
    if (b[0] != 0.0 && b[1] != 0.0 && b[2] != 0.0 && b[3] != 0.0 && b[4] != 0.0 && b[5] != 0.0) {
        for (int j = 0; j < 5; ++j) changes += (b[j] > 0.0) != (b[j + 1] > 0.0);
    } else { // exact zeros do not count (Descartes)
        first = last = -1;
        for (int j = 0; j < 6; ++j) {
            if (b[j] == 0.0) continue;
            if (last >= 0 && (b[j] > 0.0) != (b[last] > 0.0)) ++changes;
            if (first < 0) first = j;
            last = j;
        }
    }
    if (changes == 0) return;
    if (changes == 1) {
        const bool endsNonZero = b[0] != 0.0 && b[5] != 0.0;
        const double guess = endsNonZero ? lo + (hi - lo) * b[0] / (b[0] - b[5]) : 0.5 * (lo + hi);
        roots.push(solveBracketed(a, lo, hi, b[first], guess, tol));
        return;
    }
    if (depth == kMaxSubdivision) { // a cluster narrower than 2^-16: one root if N changes sign
        if ((b[first] > 0.0) != (b[last] > 0.0)) roots.push(0.5 * (lo + hi));
        return;
    }
    double left[6], right[6];
    splitHalf(b, left, right);
    const double mid = 0.5 * (lo + hi);
    isolateRoots(a, left, lo, mid, depth + 1, tol, roots);
    if (left[5] == 0.0) roots.push(mid);
    isolateRoots(a, right, mid, hi, depth + 1, tol, roots);
}

/// Monomial to degree-5 Bernstein coefficients on [0,1]: b_j = sum_{l<=j} C(j,l)/C(5,l) a_l.
inline void toBernstein(const double* a, double* b)
{
    b[0] = a[0];
    b[1] = a[0] + 0.2 * a[1];
    b[2] = a[0] + 0.4 * a[1] + 0.1 * a[2];
    b[3] = a[0] + 0.6 * a[1] + 0.3 * a[2] + 0.1 * a[3];
    b[4] = a[0] + 0.8 * a[1] + 0.6 * a[2] + 0.4 * a[3] + 0.2 * a[4];
    b[5] = a[0] + a[1] + a[2] + a[3] + a[4] + a[5];
}

/// The crossing of p = k on [0,1]: every root of N, then the median (Fuhrmann et al. 2015, as
/// in paper sec. 3.4). With an even count (only when an end value equals k) the middle root
/// nearer the linear crossing tLinear is taken.
inline double edgeRoot(const Numerator& num, double f0, double f1, double tLinear, double tol)
{
    double b[6];
    toBernstein(num.a, b);
    b[0] = num.d0 * f0; // exact end values, not rounded sums
    b[5] = num.d1 * f1;
    RootList roots;
    if (b[0] == 0.0) roots.push(0.0);
    isolateRoots(num.a, b, 0.0, 1.0, 0, tol, roots);
    if (b[5] == 0.0) roots.push(1.0);
    if (roots.count == 0) return tLinear; // only without a sign change (precondition broken)
    const int mid = roots.count / 2;
    if (roots.count % 2 == 1) return roots.t[mid];
    const double lower = roots.t[mid - 1], upper = roots.t[mid];
    return std::abs(upper - tLinear) < std::abs(lower - tLinear) ? upper : lower;
}

/// Linear crossing in [0,1] from f_i - k and f_{i+1} - k (SPEC §2).
inline double linearT(double f0, double f1)
{
    const double t = f0 / (f0 - f1);
    return t >= 0.0 && t <= 1.0 ? t : 0.5; // outside only if the precondition is broken
}

/// Crossing of the combination of n candidates with linear weights g and factors c.
inline double combinedCrossing(const EdgeStencil& s, double k, const EdgePoly* p, const Quadratic* g,
    const double* c, int n, double tol)
{
    const double f0 = s.f[2] - k, f1 = s.f[3] - k;
    return edgeRoot(combine(s, k, p, g, c, n), f0, f1, linearT(f0, f1), tol);
}

/// Crossing of one polynomial in edge form.
inline double polyCrossing(const EdgeStencil& s, double k, const EdgePoly& p, double tol)
{
    const double one = 1.0;
    return combinedCrossing(s, k, &p, kSingle, &one, 1, tol);
}

/// Nonlinear-weight crossing over the candidates reading f[jLo..jHi].
inline double wenoCrossing(const EdgeStencil& s, double k, const EdgePoly* p, const Quadratic* g,
    int n, int jLo, int jHi, double tol)
{
    double c[3];
    nonlinearFactors(s, jLo, jHi, p, n, c);
    return combinedCrossing(s, k, p, g, c, n, tol);
}

inline constexpr std::uint8_t kCentre4 = bit(1) | bit(2) | bit(3) | bit(4); // i-1..i+2
inline constexpr std::uint8_t kRight4 = bit(2) | bit(3) | bit(4) | bit(5);  // i..i+3
inline constexpr std::uint8_t kLeft4 = bit(0) | bit(1) | bit(2) | bit(3);   // i-2..i+1

/// Cubic chain: centred cubic on i-1..i+2, else one-sided on i..i+3, else on i-2..i+1, else linear.
inline std::pair<double, std::uint8_t> cubicChain(const EdgeStencil& s, std::uint8_t available,
    double k, double tol)
{
    if (hasAll(available, kCentre4)) return {polyCrossing(s, k, cubicS2(s), tol), 4};
    if (hasAll(available, kRight4)) return {polyCrossing(s, k, cubicS3(s), tol), 4};
    if (hasAll(available, kLeft4)) return {polyCrossing(s, k, cubicS1(s), tol), 4};
    return {linearT(s.f[2] - k, s.f[3] - k), 2};
}

/// WENO chain below the full stencil: WENO4 on i-1..i+2, else the cubic chain (SPEC §2).
inline std::pair<double, std::uint8_t> weno4Chain(const EdgeStencil& s, std::uint8_t available,
    double k, double tol)
{
    if (hasAll(available, kCentre4)) {
        const EdgePoly p[2] = {quadLeft(s), quadRight(s)};
        return {wenoCrossing(s, k, p, kWeno4Linear, 2, 1, 4, tol), 4};
    }
    return cubicChain(s, available, k, tol);
}

template <typename ValueT>
inline EdgeCrossingT<ValueT> result(std::pair<double, std::uint8_t> r)
{
    return {static_cast<ValueT>(std::clamp(r.first, 0.0, 1.0)), r.second};
}

template <typename ValueT>
inline double tolerance() { return double(std::numeric_limits<ValueT>::epsilon()); }

} // namespace edge_interp_internal

/// Linear interpolation between the edge ends (paper sec. 3.2).
struct LinearEdge {
    static const char* name() { return "linear"; }
    static int radius() { return 0; }
    static int order() { return 2; }
    template <typename ValueT>
    static EdgeCrossingT<ValueT> crossing(const std::array<ValueT, 6>& f, std::uint8_t, ValueT k)
    {
        const double t = edge_interp_internal::linearT(double(f[2]) - double(k), double(f[3]) - double(k));
        return {static_cast<ValueT>(t), 2};
    }
};

/// 4-point Lagrange cubic on i-1..i+2 (paper sec. 3.3 as SPEC §2 fixes it; not Catmull-Rom).
/// Fallback: one-sided cubic on i..i+3, then on i-2..i+1, then linear.
struct CubicEdge {
    static const char* name() { return "cubic"; }
    static int radius() { return 1; }
    static int order() { return 4; }
    template <typename ValueT>
    static EdgeCrossingT<ValueT> crossing(const std::array<ValueT, 6>& f, std::uint8_t available, ValueT k)
    {
        using namespace edge_interp_internal;
        return result<ValueT>(cubicChain(makeStencil(f), available, double(k), tolerance<ValueT>()));
    }
};

namespace edge_interp_internal {
/// Nonlinear-weight combination of the three cubic candidates with linear weights @a g when all
/// six values exist (reported as order @a fullOrder); WENO4 and the cubic chain otherwise.
template <typename ValueT>
inline EdgeCrossingT<ValueT> wenoFamilyCrossing(const std::array<ValueT, 6>& f, std::uint8_t available,
    ValueT k, const Quadratic* g, std::uint8_t fullOrder)
{
    const EdgeStencil s = makeStencil(f);
    const double tol = tolerance<ValueT>();
    if (!hasAll(available, kStencilAll)) return result<ValueT>(weno4Chain(s, available, double(k), tol));
    const EdgePoly p[3] = {cubicS1(s), cubicS2(s), cubicS3(s)};
    return result<ValueT>({wenoCrossing(s, double(k), p, g, 3, 0, 5, tol), fullOrder});
}
} // namespace edge_interp_internal

/// WENO with t-dependent linear weights: sixth order on smooth data, non-oscillatory at jumps
/// (paper sec. 3.4 made consistent, SPEC §2). Fallback: WENO4, then the cubic chain.
struct WenoEdge {
    static const char* name() { return "weno"; }
    static int radius() { return 2; }
    static int order() { return 6; }
    template <typename ValueT>
    static EdgeCrossingT<ValueT> crossing(const std::array<ValueT, 6>& f, std::uint8_t available, ValueT k)
    {
        using namespace edge_interp_internal;
        return wenoFamilyCrossing(f, available, k, kWeno6Linear, 6);
    }
};

/// The paper's WENO as printed: constant weights 1/10, 3/5, 3/10 on the same cubic candidates,
/// fourth order (SPEC §2, reproduction only). Fallback as WenoEdge.
struct WenoPaperEdge {
    static const char* name() { return "weno-paper"; }
    static int radius() { return 2; }
    static int order() { return 4; }
    template <typename ValueT>
    static EdgeCrossingT<ValueT> crossing(const std::array<ValueT, 6>& f, std::uint8_t available, ValueT k)
    {
        using namespace edge_interp_internal;
        return wenoFamilyCrossing(f, available, k, kWenoPaperLinear, 4);
    }
};

/// The crossing by the method chosen at run time.
template <typename ValueT>
inline EdgeCrossingT<ValueT> edgeCrossing(EdgeMethod method, const std::array<ValueT, 6>& f,
    std::uint8_t available, ValueT k)
{
    switch (method) {
    case EdgeMethod::Linear: return LinearEdge::crossing(f, available, k);
    case EdgeMethod::Cubic: return CubicEdge::crossing(f, available, k);
    case EdgeMethod::Weno: return WenoEdge::crossing(f, available, k);
    case EdgeMethod::WenoPaper: return WenoPaperEdge::crossing(f, available, k);
    }
    return LinearEdge::crossing(f, available, k);
}

} // namespace isouq
