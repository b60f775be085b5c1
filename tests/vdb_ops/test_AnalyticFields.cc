// Tests for isouq/AnalyticFields.h: SPEC §5 formulas against values worked out by hand.
#include <isouq/AnalyticFields.h>

#include <catch2/catch.hpp>

#include <cmath>

using Catch::Matchers::WithinAbs;
using isouq::findAnalyticField;

namespace {

const isouq::AnalyticField& field(const char* name)
{
    const isouq::AnalyticField* f = findAnalyticField(name);
    REQUIRE(f != nullptr);
    return *f;
}

constexpr double kEps = 1e-14; // a few ulps of values of order 1..300

} // namespace

TEST_CASE("AnalyticFields: the SPEC §5 names, domains and isovalues", "[fields]")
{
    struct Expect { const char* name; double lo, hi, k; int n; };
    const Expect expected[] = {{"tangle", -1, 1, 0.1, 32}, {"torus", -1, 1, 0, 64},
        {"torus-paper", -1, 1, 0, 64}, {"marschner-lobb", -1, 1, 0.5, 64},
        {"teardrop", -1, 1, -0.001, 32}, {"tubey", -3, 3, 0, 32}, {"sphere", -1, 1, 0, 64}};
    REQUIRE(isouq::analyticFields().size() == std::size(expected));
    for (const Expect& e : expected) {
        const isouq::AnalyticField& f = field(e.name);
        CHECK(f.lo == e.lo);
        CHECK(f.hi == e.hi);
        CHECK(f.isovalue == e.k);
        CHECK(f.resolution == e.n);
    }
    CHECK(findAnalyticField("nope") == nullptr);
    CHECK(field("tangle").spacing(33) == 2.0 / 32.0);
}

TEST_CASE("AnalyticFields: tangle at known points", "[fields][tangle]")
{
    const auto& f = field("tangle");
    CHECK_THAT(f(0, 0, 0), WithinAbs(0.4, kEps));
    CHECK_THAT(f(1, 0, 0), WithinAbs(1.0 - (1.0 - 0.4), kEps));
    CHECK_THAT(f(0.5, 0.5, 0.5), WithinAbs(3 * 0.0625 - (0.75 - 0.4), kEps));
    CHECK_THAT(f(-1, 1, -1), WithinAbs(3.0 - 2.6, kEps));
}

TEST_CASE("AnalyticFields: torus is the standard torus, torus-paper the printed formula",
    "[fields][torus]")
{
    const auto& torus = field("torus");
    // tube radius 0.1 around the circle of radius 0.3 in the xy plane
    CHECK_THAT(torus(0.4, 0, 0), WithinAbs(0.0, kEps));
    CHECK_THAT(torus(0, 0.2, 0), WithinAbs(0.0, kEps));
    CHECK_THAT(torus(0.3 * std::cos(1.0), 0.3 * std::sin(1.0), 0.1), WithinAbs(0.0, kEps));
    CHECK_THAT(torus(0.3, 0, 0), WithinAbs(-0.01, kEps));
    CHECK_THAT(torus(0, 0, 0), WithinAbs(0.09 - 0.01, kEps));
    const auto& paper = field("torus-paper");
    CHECK_THAT(paper(0, 0, 0), WithinAbs(0.3 - 0.01, kEps));
    CHECK_THAT(paper(0.5, 0.5, 0.5), WithinAbs(0.3 - 0.5 + 0.25 - 0.01, kEps));
}

TEST_CASE("AnalyticFields: Marschner-Lobb at known points", "[fields][ml]")
{
    const auto& f = field("marschner-lobb");
    // r = 0: rho = cos(12 pi) = 1 -> (1 + 0.5) / 2.5
    CHECK_THAT(f(0, 0, 0), WithinAbs(0.6, kEps));
    // z = 1: sin(pi/2) = 1 -> 0.5 / 2.5
    CHECK_THAT(f(0, 0, 1), WithinAbs(0.2, kEps));
    // r = 1: cos(pi/2) = 0 -> rho = 1
    CHECK_THAT(f(0.6, 0.8, 0), WithinAbs(0.6, 1e-13));
    // cos(pi r / 2) = 1/24 -> rho = cos(pi/2) = 0 -> 1.25 / 2.5
    const double r = 2.0 / M_PI * std::acos(1.0 / 24.0);
    CHECK_THAT(f(r, 0, 0), WithinAbs(0.5, 1e-13));
}

TEST_CASE("AnalyticFields: teardrop and tubey by hand", "[fields][teardrop][tubey]")
{
    const auto& teardrop = field("teardrop");
    CHECK_THAT(teardrop(1, 0, 0), WithinAbs(1.0, kEps));
    CHECK_THAT(teardrop(-1, 0, 0), WithinAbs(0.0, kEps));
    CHECK_THAT(teardrop(0.5, 0.5, 0), WithinAbs(0.5 / 32 + 0.5 / 16 - 0.25, kEps));
    CHECK_THAT(teardrop(0, 0.3, 0.4), WithinAbs(-0.25, kEps));
    const auto& tubey = field("tubey");
    CHECK_THAT(tubey(0, 0, 0), WithinAbs(-4.0 + 1.0 + 1.0, kEps));
    CHECK_THAT(tubey(1, 0, 0), WithinAbs(-3.0 - 8.0 + 16.0 + 1.0, kEps));
    CHECK_THAT(tubey(1, 1, 1), WithinAbs(-8.0 + 5.0 + 3.0 - 16.0 + 256.0 + 1.0, 1e-12));
    // x = -1, y = z = 0: -3 - 4(-1 + 1) + 0 + 1
    CHECK_THAT(tubey(-1, 0, 0), WithinAbs(-2.0, kEps));
}

TEST_CASE("AnalyticFields: sphere is the signed distance to radius 0.75", "[fields][sphere]")
{
    const auto& f = field("sphere");
    CHECK_THAT(f(0, 0, 0), WithinAbs(-0.75, kEps));
    CHECK_THAT(f(0.75, 0, 0), WithinAbs(0.0, kEps));
    CHECK_THAT(f(0, -0.6, 0.8), WithinAbs(0.25, kEps));
}
