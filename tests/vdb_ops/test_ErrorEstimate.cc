// Tests for isouq/ErrorEstimate.h (SPEC §3). Truths: polynomials whose interpolation error
// is known in closed form, roots placed by construction, bracketed roots of analytic
// functions, point-plane distances.
#include <isouq/EdgeInterp.h>
#include <isouq/ErrorEstimate.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <vector>

using namespace isouq;

namespace {

using Stencil = std::array<double, 6>;

template <typename F>
Stencil sampleNodes(F g)
{
    Stencil f;
    for (int j = 0; j < 6; ++j) f[j] = g(double(j - 2));
    return f;
}

/// Root of g in [a, b] by bisection, g(a) and g(b) of opposite signs.
template <typename F>
double bisectRoot(F g, double a, double b)
{
    const bool aPositive = g(a) > 0.0;
    for (int it = 0; it < 200; ++it) {
        const double m = 0.5 * (a + b);
        if (m <= a || m >= b) break;
        if ((g(m) > 0.0) == aPositive) a = m; else b = m;
    }
    return 0.5 * (a + b);
}

/// q(t) = (t - theta)(1 + g (t - m)^2) prod_l (1 + d_l t): root theta in (0,1), no other
/// root on [-2,3] (|d_l| < 1/3), leading coefficient g prod d_l.
struct Factored {
    double theta, g, m;
    std::vector<double> d;
    double operator()(double t) const
    {
        double v = (t - theta) * (1.0 + g * (t - m) * (t - m));
        for (double dl : d) v *= 1.0 + dl * t;
        return v;
    }
    double leading() const
    {
        double c = g;
        for (double dl : d) c *= dl;
        return c;
    }
};

Factored randomFactored(std::mt19937& rng, int extraFactors)
{
    std::uniform_real_distribution<double> u(0.0, 1.0);
    Factored q{0.02 + 0.96 * u(rng), 0.05 + 0.5 * u(rng), -2.0 + 5.0 * u(rng), {}};
    for (int l = 0; l < extraFactors; ++l) q.d.push_back((u(rng) < 0.5 ? -1 : 1) * (0.02 + 0.3 * u(rng)));
    return q;
}

/// Largest |q''| on [0,1] by a dense scan of second differences.
template <typename F>
double maxSecondDerivative(F q)
{
    double best = 0.0;
    const double s = 1e-3;
    for (int l = 0; l <= 1000; ++l) {
        const double t = l * 1e-3;
        best = std::max(best, std::abs(q(t + s) - 2 * q(t) + q(t - s)) / (s * s));
    }
    return best * 1.01;
}

} // namespace

TEST_CASE("ErrorEstimate: e and e_b on a quadratic follow the closed form", "[estimate][linear]")
{
    // f = a x^2 + b x + c: every second divided difference is a and U[i,i+1] = a(2x_i + h) + b,
    // so e = |a (x - x_i)(x - x_{i+1})| / |U[i,i+1]|; the true error is
    // |x* - x| = |a (x - x_i)(x - x_{i+1})| / |a (x + x*) + b|. Both slopes are f' inside the
    // edge, so |e - true| <= true |a| h / |U[i,i+1]|.
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int tested = 0;
    for (int n = 0; n < 2000; ++n) {
        const double a = (u(rng) < 0.5 ? -1 : 1) * (0.1 + 5 * u(rng)), b = 10 * (u(rng) - 0.5), c = u(rng);
        const double h = 0.01 + 0.5 * u(rng), xi = 6 * (u(rng) - 0.5), theta = 0.01 + 0.98 * u(rng);
        const double vertex = -b / (2 * a);
        if (vertex > xi - 0.1 * h && vertex < xi + 1.1 * h) continue; // monotone on the edge
        auto f = [&](double x) { return a * x * x + b * x + c; };
        const double xStar = xi + theta * h, k = f(xStar);
        const Stencil s = sampleNodes([&](double t) { return f(xi + t * h); });
        const double t = LinearEdge::crossing(s, kStencilAll, k).t, x = xi + t * h;
        const auto err = linearError(s, kStencilAll, t, h);
        const double slope = a * (2 * xi + h) + b, omega = std::abs((x - xi) * (x - xi - h));
        CHECK(err.estimate == Approx(std::abs(a) * omega / std::abs(slope)).epsilon(1e-6));
        CHECK(err.bound == Approx(std::abs(a) * h * h / std::abs(slope)).epsilon(1e-6));
        const double trueErr = std::abs(xStar - x);
        REQUIRE(trueErr == Approx(std::abs(a) * omega / std::abs(a * (x + xStar) + b)).epsilon(1e-6).margin(1e-14));
        CHECK(std::abs(err.estimate - trueErr) <= trueErr * std::abs(a) * h / std::abs(slope) * 1.000001 + 1e-14);
        CHECK(err.bound >= 4 * err.estimate);
        ++tested;
    }
    CHECK(tested > 1000);
}

TEST_CASE("ErrorEstimate: e_b >= e and missing neighbours", "[estimate][linear]")
{
    std::mt19937 rng(12);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int n = 0; n < 5000; ++n) {
        std::array<float, 6> f;
        for (auto& v : f) v = 4000 * u(rng);
        if (f[2] == f[3]) continue;
        const float t = u(rng), h = 0.1f + u(rng);
        const auto mask = std::uint8_t(0x0C | (n % 4) | ((n / 4 % 4) << 4));
        const auto err = linearError(f, mask, t, h);
        const bool left = mask & 0x02, right = mask & 0x10;
        const double dl = std::abs(double(f[3]) - 2.0 * f[2] + f[1]), dr = std::abs(double(f[4]) - 2.0 * f[3] + f[2]);
        const double slope = std::abs(double(f[3]) - f[2]);
        if (!left && !right) {
            CHECK(std::isnan(err.estimate));
            CHECK(std::isnan(err.bound));
            continue;
        }
        const double d2 = left && right ? std::max(dl, dr) : left ? dl : dr;
        CHECK(err.bound == Approx(h * d2 / (2 * slope)).epsilon(1e-5));
        CHECK(err.estimate == Approx(h * d2 / (2 * slope) * t * (1 - t)).epsilon(1e-5));
        CHECK(err.bound >= err.estimate);
    }
}

TEST_CASE("ErrorEstimate: cubic estimate on quartics", "[estimate][cubic]")
{
    // For a quartic q with leading coefficient c4, q - p3 = c4 (t+1) t (t-1) (t-2) exactly and
    // Delta^4 q = 24 c4, so the estimate is h |c4 omega(t_c)| / |Delta q|; the truth is
    // h |c4 omega(t_c)| / |q'(eta)|, eta in [0,1]: |est/true - 1| <= max|q''| / |Delta q|.
    std::mt19937 rng(13);
    for (int n = 0; n < 1000; ++n) {
        const Factored q = randomFactored(rng, 1);
        const Stencil f = sampleNodes(q);
        const double h = 0.25, slope = std::abs(f[3] - f[2]);
        const double tc = CubicEdge::crossing(f, kStencilAll, 0.0).t;
        const double omega = std::abs((tc + 1) * tc * (tc - 1) * (tc - 2));
        const double est = cubicErrorEstimate(f, kStencilAll, tc, h);
        CHECK(est == Approx(h * std::abs(q.leading()) * omega / slope).epsilon(1e-9));
        const double trueErr = h * std::abs(tc - q.theta);
        CHECK(std::abs(est - trueErr) <= trueErr * maxSecondDerivative(q) / slope + 1e-15);
        // one of f_{i-2}, f_{i+3} suffices; without both, or without f_{i-1}, it is unknown
        CHECK(cubicErrorEstimate(f, std::uint8_t(0x1F), tc, h) == Approx(est).epsilon(1e-9));
        CHECK(cubicErrorEstimate(f, std::uint8_t(0x3E), tc, h) == Approx(est).epsilon(1e-9));
        CHECK(std::isnan(cubicErrorEstimate(f, std::uint8_t(0x1E), tc, h)));
        CHECK(std::isnan(cubicErrorEstimate(f, std::uint8_t(0x3D), tc, h)));
    }
}

TEST_CASE("ErrorEstimate: WENO estimate on quintics", "[estimate][weno]")
{
    // Delta^5 q = 120 c5 for a quintic: the estimate is h |c5| max(|omega_a|, |omega_b|) / |Delta q|
    // with the nodal polynomials of the quartics on -2..2 and -1..3.
    std::mt19937 rng(14);
    for (int n = 0; n < 1000; ++n) {
        const Factored q = randomFactored(rng, 2);
        const Stencil f = sampleNodes(q);
        const double h = 0.5, t = 0.001 * (n % 1000);
        const double wa = std::abs((t + 2) * (t + 1) * t * (t - 1) * (t - 2));
        const double wb = std::abs((t + 1) * t * (t - 1) * (t - 2) * (t - 3));
        CHECK(wenoErrorEstimate(f, kStencilAll, t, h) ==
              Approx(h * std::abs(q.leading()) * std::max(wa, wb) / std::abs(f[3] - f[2])).epsilon(1e-8).margin(1e-300));
        CHECK(std::isnan(wenoErrorEstimate(f, std::uint8_t(0x1F), t, h)));
    }
}

TEST_CASE("ErrorEstimate: spread and surface distance", "[estimate]")
{
    const auto spread = crossingSpread(0.2, 0.5, 0.45, 2.0);
    CHECK(spread.dLc == Approx(0.6));
    CHECK(spread.dLw == Approx(0.5));
    CHECK(spread.dCw == Approx(0.1));
    CHECK(spread.maxVar == Approx(0.6));
    // A point on the plane n.x = 0, moved by delta along axis a, is |n_a| delta / |n| from it.
    std::mt19937 rng(15);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int l = 0; l < 100; ++l) {
        const double n[3] = {u(rng), u(rng), u(rng)}, delta = 3 * u(rng);
        const int axis = l % 3;
        const double p[3] = {n[1] - n[2], n[2] - n[0], n[0] - n[1]}; // on the plane: n.p = 0
        double moved[3] = {p[0], p[1], p[2]};
        moved[axis] += delta;
        const double norm = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const double distance = std::abs(n[0] * moved[0] + n[1] * moved[1] + n[2] * moved[2]) / norm;
        const double cosine = edgeNormalCosine(n[axis], n[0], n[1], n[2]);
        CHECK(surfaceDistance(std::abs(delta), cosine) == Approx(distance).margin(1e-12));
    }
    CHECK(edgeNormalCosine(0.0, 0.0, 0.0, 0.0) == 1.0);
}

namespace {

struct EstimateRun {
    double trueLinear = 0, e = 0, eb = 0, best = 0, trueCubic = 0, eCubic = 0, trueWeno = 0, eWeno = 0;
    double relE = 0, relBest = 0; // RMS of (estimate - true) / true for the linear crossing
    int edges = 0;
};

template <typename F, typename DF>
EstimateRun estimateRun(F f, DF df, double h)
{
    EstimateRun r;
    const int n = int(std::lround(3.0 / h));
    std::vector<double> v(n + 1);
    for (int j = 0; j <= n; ++j) v[j] = f(-1.0 + j * h);
    auto sq = [](double x) { return x * x; };
    for (int kk = 0; kk < 401; ++kk) {
        const double k = -1.0 + kk * 0.005;
        for (int i = 2; i + 3 <= n; ++i) {
            if ((v[i] >= k) == (v[i + 1] >= k)) continue;
            const double x0 = -1.0 + i * h;
            const double xs = bisectRoot([&](double x) { return f(x) - k; }, x0, x0 + h);
            if (std::abs(df(xs)) < 0.5) continue;
            const Stencil s = {v[i - 2], v[i - 1], v[i], v[i + 1], v[i + 2], v[i + 3]};
            const double tl = LinearEdge::crossing(s, kStencilAll, k).t, tc = CubicEdge::crossing(s, kStencilAll, k).t,
                         tw = WenoEdge::crossing(s, kStencilAll, k).t;
            const auto lin = linearError(s, kStencilAll, tl, h);
            const double trueL = std::abs(x0 + tl * h - xs), best = crossingDistance(tl, tc, h);
            r.trueLinear += sq(trueL);
            r.e += sq(lin.estimate);
            r.eb += sq(lin.bound);
            r.best += sq(best);
            r.trueCubic += sq(x0 + tc * h - xs);
            r.eCubic += sq(cubicErrorEstimate(s, kStencilAll, tc, h));
            r.trueWeno += sq(x0 + tw * h - xs);
            r.eWeno += sq(wenoErrorEstimate(s, kStencilAll, tw, h));
            if (trueL > 1e-3 * h * h) { // away from the roots of f'' where the error vanishes
                r.relE += sq(lin.estimate / trueL - 1);
                r.relBest += sq(best / trueL - 1);
            }
            ++r.edges;
        }
    }
    for (double* p : {&r.trueLinear, &r.e, &r.eb, &r.best, &r.trueCubic, &r.eCubic, &r.trueWeno, &r.eWeno,
                      &r.relE, &r.relBest})
        *p = std::sqrt(*p / r.edges);
    return r;
}

} // namespace

TEST_CASE("ErrorEstimate: estimates track measured errors on smooth functions", "[estimate][slow]")
{
    // SPEC §3's claim: e tracks the measured linear error, e_b overestimates it (e_b >= 4 e).
    // err_best's relative error is O(h^2), e's O(h). The cubic estimate is the cubic's own
    // error term; the WENO one is one order pessimistic, so it bounds WENO's error.
    auto f = [](double x) { return std::sin(3 * x) + 0.3 * x; };
    auto df = [](double x) { return 3 * std::cos(3 * x) + 0.3; };
    EstimateRun runs[4];
    for (int l = 0; l < 4; ++l) runs[l] = estimateRun(f, df, 1.0 / (32 << l));
    for (int l = 0; l < 4; ++l) {
        const EstimateRun& r = runs[l];
        INFO("h = 1/" << (32 << l) << ": rms true linear " << r.trueLinear << " e " << r.e << " e_b " << r.eb
                      << " err_best " << r.best << " | rel e " << r.relE << " rel best " << r.relBest
                      << " | cubic true " << r.trueCubic << " est " << r.eCubic << " | weno true " << r.trueWeno
                      << " est " << r.eWeno);
        CHECK(r.e / r.trueLinear == Approx(1.0).margin(0.1));
        CHECK(r.eb / r.trueLinear >= 4.0);
        CHECK(r.best / r.trueLinear == Approx(1.0).margin(0.01));
        CHECK(r.relBest < r.relE);
        CHECK(r.eCubic / r.trueCubic == Approx(1.0).margin(0.1));
        CHECK(r.eWeno >= r.trueWeno);
        if (l > 0) CHECK(runs[l - 1].relBest / r.relBest >= 3.0); // O(h^2)
    }
}
