// Tests of isouq/Tricubic.h: exactness on tricubic polynomials (independent truth: the
// polynomial itself), the closed-form Lagrange weights, and the restriction property that keeps
// refined neighbours bitwise equal on their shared face and edge (SPEC §4).
#include <isouq/Tricubic.h>

#include <catch2/catch.hpp>

#include <array>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

using isouq::cubicWeights;
using isouq::cubicWeightsAt;
using isouq::refineCell;
using isouq::tricubic;

namespace {

/// p(x, y, z) = sum a[i][j][l] x^i y^j z^l, i, j, l <= 3.
struct Tricubic {
    double a[4][4][4];
    double operator()(double x, double y, double z) const
    {
        double s = 0;
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j)
                for (int l = 0; l < 4; ++l) s += a[i][j][l] * std::pow(x, i) * std::pow(y, j) * std::pow(z, l);
        return s;
    }
};

/// The stencil of the cell at the origin: p at (a - 1, b - 1, c - 1).
std::array<double, 64> stencilOf(const Tricubic& p)
{
    std::array<double, 64> s{};
    for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
            for (int c = 0; c < 4; ++c) s[16 * a + 4 * b + c] = p(a - 1, b - 1, c - 1);
    return s;
}

} // namespace

TEST_CASE("Tricubic: the weights are the 4-point Lagrange basis", "[tricubic]")
{
    // At the nodes the basis is the identity; the weights sum to 1 and reproduce t, t^2, t^3.
    for (int node = -1; node <= 2; ++node) {
        const auto w = cubicWeightsAt(node);
        for (int j = 0; j < 4; ++j) CHECK(w.w[j] == (j == node + 1 ? 1.0 : 0.0));
    }
    CHECK(cubicWeightsAt(0.0).node == 1);
    CHECK(cubicWeightsAt(1.0).node == 2);
    CHECK(cubicWeightsAt(0.5).node == -1);
    for (double t : {0.1, 0.25, 0.5, 0.77, 0.9}) {
        const auto w = cubicWeightsAt(t);
        for (int power = 0; power <= 3; ++power) {
            double s = 0;
            for (int j = 0; j < 4; ++j) s += w.w[j] * std::pow(j - 1, power);
            CHECK(s == Approx(std::pow(t, power)).margin(1e-15));
        }
    }
}

TEST_CASE("Tricubic: reproduces tricubic polynomials exactly", "[tricubic]")
{
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int trial = 0; trial < 20; ++trial) {
        Tricubic p;
        double scale = 0;
        for (auto& plane : p.a)
            for (auto& row : plane)
                for (auto& v : row) scale += std::abs(v = u(rng));
        const auto stencil = stencilOf(p);
        // Coefficients times powers of at most 2^3 per axis: values up to 512 * scale; double
        // rounding of 64-term sums stays below 1e-12 of that.
        const double tolerance = 1e-12 * 512 * scale;
        for (int i = 0; i < 20; ++i) {
            const double x = u(rng) * 0.5 + 0.5, y = u(rng) * 0.5 + 0.5, z = u(rng) * 0.5 + 0.5;
            CHECK(tricubic(stencil.data(), cubicWeightsAt(x), cubicWeightsAt(y), cubicWeightsAt(z)) ==
                  Approx(p(x, y, z)).margin(tolerance));
        }
        const int m = 1 + trial % 7;
        std::vector<double> sub;
        refineCell(stencil.data(), m, sub);
        REQUIRE(sub.size() == std::size_t((m + 1) * (m + 1) * (m + 1)));
        for (int a = 0; a <= m; ++a)
            for (int b = 0; b <= m; ++b)
                for (int c = 0; c <= m; ++c) {
                    const double v = sub[std::size_t((a * (m + 1) + b) * (m + 1) + c)];
                    CHECK(v == Approx(p(double(a) / m, double(b) / m, double(c) / m)).margin(tolerance));
                    // refineCell and tricubic do the same sums.
                    CHECK(v == tricubic(stencil.data(), cubicWeights(a, m), cubicWeights(b, m), cubicWeights(c, m)));
                }
    }
}

TEST_CASE("Tricubic: neighbours agree bitwise on shared faces and edges and read only that plane",
    "[tricubic][hidden]")
{
    // Random float data on a 6^3 grid; the cells at (1,1,1) and its neighbour along each axis.
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(-1000.0f, 1000.0f);
    std::vector<float> data(6 * 6 * 6);
    for (float& v : data) v = u(rng);
    auto at = [&](int x, int y, int z) { return data[std::size_t((x * 6 + y) * 6 + z)]; };
    auto stencilAt = [&](int x, int y, int z) {
        std::array<float, 64> s{};
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b)
                for (int c = 0; c < 4; ++c) s[16 * a + 4 * b + c] = at(x + a - 1, y + b - 1, z + c - 1);
        return s;
    };
    const int m = GENERATE(3, 4, 7);
    const int n = m + 1;
    auto idx = [n](int p, int q, int r) { return std::size_t((p * n + q) * n + r); };
    std::vector<double> lower, upper;
    refineCell(stencilAt(1, 1, 1).data(), m, lower);
    for (int axis = 0; axis < 3; ++axis) {
        INFO("axis " << axis << " m " << m);
        refineCell(stencilAt(1 + (axis == 0), 1 + (axis == 1), 1 + (axis == 2)).data(), m, upper);
        for (int s = 0; s <= m; ++s)
            for (int t = 0; t <= m; ++t) {
                int lo[3], hi[3];
                lo[axis] = m, hi[axis] = 0;
                lo[(axis + 1) % 3] = hi[(axis + 1) % 3] = s;
                lo[(axis + 2) % 3] = hi[(axis + 2) % 3] = t;
                const double a = lower[idx(lo[0], lo[1], lo[2])], b = upper[idx(hi[0], hi[1], hi[2])];
                CHECK(std::memcmp(&a, &b, sizeof(double)) == 0);
            }
    }
    // Diagonal neighbour across an edge: the cell at (2, 2, 1) shares the z edge at (2, 2).
    refineCell(stencilAt(2, 2, 1).data(), m, upper);
    for (int r = 0; r <= m; ++r) {
        const double a = lower[idx(m, m, r)], b = upper[idx(0, 0, r)];
        CHECK(std::memcmp(&a, &b, sizeof(double)) == 0);
    }
    // Changing every voxel off the plane x = 2 leaves the face x = 1 (local p = m) untouched.
    std::vector<double> before = lower;
    for (int y = 0; y < 6; ++y)
        for (int z = 0; z < 6; ++z)
            for (int x : {0, 1, 3})
                data[std::size_t((x * 6 + y) * 6 + z)] += 1.0f;
    refineCell(stencilAt(1, 1, 1).data(), m, lower);
    for (int q = 0; q <= m; ++q)
        for (int r = 0; r <= m; ++r) CHECK(lower[idx(m, q, r)] == before[idx(m, q, r)]);
}

TEST_CASE("Tricubic: cubicRange holds the interpolant and is the Bernstein hull", "[tricubic][bound]")
{
    // Truth: the polynomial itself on a 41^3 lattice of the cell (the tricubic reproduces it).
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int trial = 0; trial < 20; ++trial) {
        Tricubic p;
        for (auto& plane : p.a)
            for (auto& row : plane)
                for (double& v : row) v = u(rng);
        const std::array<double, 64> s = stencilOf(p);
        const auto [lo, hi] = isouq::tricubicRange(s.data());
        double least = 1e300, greatest = -1e300;
        for (int i = 0; i <= 40; ++i)
            for (int j = 0; j <= 40; ++j)
                for (int l = 0; l <= 40; ++l) {
                    const double v = p(i / 40.0, j / 40.0, l / 40.0);
                    least = std::min(least, v);
                    greatest = std::max(greatest, v);
                }
        CHECK(lo <= least + 1e-12);
        CHECK(hi >= greatest - 1e-12);
        // The face x = 0 (stencil a = 1, free y and z) and the edge x = y = 0 (free z).
        const std::ptrdiff_t face[2] = {4, 1}, edge[1] = {1};
        const auto [flo, fhi] = isouq::cubicRange(s.data() + 16, face, 2);
        const auto [elo, ehi] = isouq::cubicRange(s.data() + 16 + 4, edge, 1);
        for (int j = 0; j <= 40; ++j)
            for (int l = 0; l <= 40; ++l) {
                CHECK(p(0, j / 40.0, l / 40.0) >= flo - 1e-12);
                CHECK(p(0, j / 40.0, l / 40.0) <= fhi + 1e-12);
            }
        for (int l = 0; l <= 40; ++l) {
            CHECK(p(0, 0, l / 40.0) >= elo - 1e-12);
            CHECK(p(0, 0, l / 40.0) <= ehi + 1e-12);
        }
    }
    // Closed forms: x has Bernstein coefficients 0, 1/3, 2/3, 1 (range [0, 1], attained);
    // 4 x (1 - x) has 0, 4/3, 4/3, 0 (its hull reaches 4/3 above its maximum 1).
    Tricubic linear{}, bump{};
    linear.a[1][0][0] = 1;
    bump.a[1][0][0] = 4;
    bump.a[2][0][0] = -4;
    const std::array<double, 64> sl = stencilOf(linear), sb = stencilOf(bump);
    CHECK(isouq::tricubicRange(sl.data()).first == Approx(0.0).margin(1e-15));
    CHECK(isouq::tricubicRange(sl.data()).second == Approx(1.0).epsilon(1e-15));
    CHECK(isouq::tricubicRange(sb.data()).first == Approx(0.0).margin(1e-15));
    CHECK(isouq::tricubicRange(sb.data()).second == Approx(4.0 / 3.0).epsilon(1e-15));
}

TEST_CASE("Tricubic: the float hull is within its stated error of the double hull", "[tricubic][bound]")
{
    // roughTricubicRange's contract: each bound within 1e-5 (|lo| + |hi|) of tricubicRange's,
    // the margin HiddenFeatures.cc's early rejection relies on. Random stencils of several
    // magnitudes and offsets (CT-like values in the thousands included).
    std::mt19937 rng(11);
    for (const double scale : {1e-3, 1.0, 4000.0}) {
        std::uniform_real_distribution<double> u(-scale, scale);
        for (int trial = 0; trial < 2000; ++trial) {
            std::array<float, 64> s;
            const double offset = u(rng);
            for (float& v : s) v = float(offset + u(rng));
            const auto [lo, hi] = isouq::tricubicRange(s.data());
            const auto [roughLo, roughHi] = isouq::roughTricubicRange(s.data());
            const double tolerance = 1e-5 * (std::abs(lo) + std::abs(hi));
            CHECK(std::abs(double(roughLo) - lo) <= tolerance);
            CHECK(std::abs(double(roughHi) - hi) <= tolerance);
        }
    }
}
