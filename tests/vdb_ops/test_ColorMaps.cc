// Tests of isouq/ColorMaps.h: the anchors are hit exactly, colours move monotonically along
// the maps, and the red/green/blue/quality columns follow the measure.
#include <isouq/ColorMaps.h>
#include <isouq/Columns.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <limits>

using isouq::ColorMap;
using isouq::Rgb8;

TEST_CASE("ColorMaps: ends and middle of each map are its published anchors", "[color]")
{
    CHECK(isouq::colorAt(ColorMap::Viridis, 0.0) == Rgb8{0x44, 0x01, 0x54});
    CHECK(isouq::colorAt(ColorMap::Viridis, 0.5) == Rgb8{0x21, 0x91, 0x8c});
    CHECK(isouq::colorAt(ColorMap::Viridis, 1.0) == Rgb8{0xfd, 0xe7, 0x25});
    CHECK(isouq::colorAt(ColorMap::Coolwarm, 0.0) == Rgb8{0x3b, 0x4c, 0xc0});
    CHECK(isouq::colorAt(ColorMap::Coolwarm, 0.5) == Rgb8{0xdd, 0xdc, 0xdc});
    CHECK(isouq::colorAt(ColorMap::Coolwarm, 1.0) == Rgb8{0xb4, 0x04, 0x26});
    CHECK(isouq::colorAt(ColorMap::Gray, 0.5) == Rgb8{128, 128, 128});
    // Outside [0, 1] clamps.
    CHECK(isouq::colorAt(ColorMap::Viridis, -3.0) == isouq::colorAt(ColorMap::Viridis, 0.0));
    CHECK(isouq::colorAt(ColorMap::Viridis, 7.0) == isouq::colorAt(ColorMap::Viridis, 1.0));
}

TEST_CASE("ColorMaps: viridis brightens and gray rises monotonically", "[color]")
{
    // Viridis is designed with monotone lightness; its sRGB green channel rises throughout.
    Rgb8 previous = isouq::colorAt(ColorMap::Viridis, 0.0);
    int g = 0;
    for (int i = 1; i <= 1000; ++i) {
        const Rgb8 c = isouq::colorAt(ColorMap::Viridis, i / 1000.0);
        CHECK(c[1] >= previous[1]);
        previous = c;
        const Rgb8 gray = isouq::colorAt(ColorMap::Gray, i / 1000.0);
        CHECK(gray[0] >= g);
        CHECK(std::abs(gray[0] - 255.0 * i / 1000.0) <= 0.5);
        g = gray[0];
    }
}

TEST_CASE("ColorMaps: names round trip", "[color]")
{
    for (ColorMap m : isouq::kAllColorMaps) CHECK(isouq::colorMapFromString(isouq::toString(m)) == m);
    CHECK_FALSE(isouq::colorMapFromString("jet"));
}

TEST_CASE("ColorMaps: the columns follow the measure over the range", "[color]")
{
    isouq::Mesh mesh;
    mesh.positions.resize(5);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    mesh.vertexAttributes.add<float>(isouq::col::kErrEst, 5) = {0.0f, 1.0f, 2.0f, nan, 10.0f};
    isouq::addColorColumns(mesh, isouq::col::kErrEst, ColorMap::Gray, 0.0, 2.0);
    const auto& a = mesh.vertexAttributes;
    CHECK(*a.find<std::uint8_t>(isouq::col::kRed) == std::vector<std::uint8_t>{0, 128, 255, 128, 255});
    CHECK(*a.find<std::uint8_t>(isouq::col::kBlue) == *a.find<std::uint8_t>(isouq::col::kRed));
    const auto& q = *a.find<float>(isouq::col::kQuality);
    CHECK(q[2] == 2.0f);
    CHECK(std::isnan(q[3]));

    SECTION("a zero-width range gives the middle colour")
    {
        isouq::addColorColumns(mesh, isouq::col::kErrEst, ColorMap::Viridis, 1.0, 1.0);
        CHECK((*a.find<std::uint8_t>(isouq::col::kGreen))[0] == isouq::colorAt(ColorMap::Viridis, 0.5)[1]);
    }
    SECTION("the measure may be quality itself")
    {
        isouq::addColorColumns(mesh, isouq::col::kQuality, ColorMap::Gray, 0.0, 10.0);
        CHECK(*a.find<std::uint8_t>(isouq::col::kRed) == std::vector<std::uint8_t>{0, 26, 51, 128, 255});
    }
    SECTION("bad arguments")
    {
        CHECK_THROWS_AS(isouq::addColorColumns(mesh, "nope", ColorMap::Gray, 0.0, 1.0), std::invalid_argument);
        CHECK_THROWS_AS(isouq::addColorColumns(mesh, isouq::col::kErrEst, ColorMap::Gray, 1.0, 0.0),
            std::invalid_argument);
        CHECK_THROWS_AS(isouq::addColorColumns(mesh, isouq::col::kErrEst, ColorMap::Gray, 0.0, INFINITY),
            std::invalid_argument);
    }
}
