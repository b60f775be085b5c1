// Tests for isouq/Diagnostics.h: each check against a grid built to fail exactly that check.
#include <isouq/Diagnostics.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <limits>

using Catch::Matchers::Contains;
using isouq::checkScalarVolume;
using openvdb::Coord;

namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

/// Active voxels 0..1 on a 10^3 box: value (x + y + z) / 27.
openvdb::FloatGrid::Ptr rampGrid()
{
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName("ramp");
    for (int x = 0; x < 10; ++x)
        for (int y = 0; y < 10; ++y)
            for (int z = 0; z < 10; ++z) grid->tree().setValue(Coord(x, y, z), float(x + y + z) / 27.0f);
    return grid;
}

void checkOneLine(const std::string& message)
{
    CHECK(!message.empty());
    CHECK(message.find('\n') == std::string::npos);
    CHECK(message.find("error:") == std::string::npos); // the CLI adds the prefix
}

} // namespace

TEST_CASE("Diagnostics: a clean grid passes", "[diagnostics]")
{
    auto grid = rampGrid();
    CHECK(checkScalarVolume(*grid, std::nullopt) == "");
    CHECK(checkScalarVolume(*grid, 0.5f) == "");
    CHECK(checkScalarVolume(*grid, 0.0f) == "");  // the range is inclusive
    CHECK(checkScalarVolume(*grid, 1.0f) == "");
    grid->tree().setValueOff(Coord(20, 20, 20), kNaN); // inactive values are not data
    CHECK(checkScalarVolume(*grid, 0.5f) == "");
}

TEST_CASE("Diagnostics: an empty grid", "[diagnostics][errors]")
{
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(1.0f);
    grid->tree().setValueOff(Coord(1, 2, 3), 5.0f);
    const std::string message = checkScalarVolume(*grid, kNaN); // empty is checked first
    checkOneLine(message);
    CHECK_THAT(message, Contains("no active voxels or tiles"));
}

TEST_CASE("Diagnostics: non-finite active values, how many and where the first is",
    "[diagnostics][errors]")
{
    auto grid = rampGrid();
    grid->tree().setValue(Coord(7, 8, 9), kNaN);
    grid->tree().setValue(Coord(3, 4, 5), -kInf);
    grid->tree().setValue(Coord(600, 0, 0), kNaN); // another leaf, later in tree order
    const std::string message = checkScalarVolume(*grid, 0.5f);
    checkOneLine(message);
    CHECK_THAT(message, Contains("grid 'ramp'") && Contains("has 3 active non-finite"));
    CHECK_THAT(message, Contains("-inf") && Contains("[3, 4, 5]"));
}

TEST_CASE("Diagnostics: a non-finite active tile counts its voxels", "[diagnostics][errors]")
{
    auto grid = rampGrid();
    grid->tree().addTile(/*level=*/1, Coord(800, 0, 0), kInf, /*active=*/true);
    const std::string message = checkScalarVolume(*grid, std::nullopt);
    checkOneLine(message);
    CHECK_THAT(message, Contains("has 512 active non-finite") && Contains("[800, 0, 0]"));
}

TEST_CASE("Diagnostics: a bad transform", "[diagnostics][errors]")
{
    auto grid = rampGrid();
    grid->setTransform(openvdb::math::Transform::createLinearTransform(std::nan("")));
    const std::string message = checkScalarVolume(*grid, 0.5f);
    checkOneLine(message);
    CHECK_THAT(message, Contains("bad transform") && Contains("voxel size nan"));
}

TEST_CASE("Diagnostics: an isovalue outside the data range, or not finite", "[diagnostics][errors]")
{
    auto grid = rampGrid();
    std::string message = checkScalarVolume(*grid, 2.0f);
    checkOneLine(message);
    CHECK_THAT(message, Contains("isovalue 2 is outside") && Contains("[0, 1]"));
    message = checkScalarVolume(*grid, -0.001f);
    CHECK_THAT(message, Contains("outside") && Contains("[0, 1]"));
    message = checkScalarVolume(*grid, kNaN);
    checkOneLine(message);
    CHECK_THAT(message, Contains("isovalue nan is not finite"));
}
