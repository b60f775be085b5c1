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

TEST_CASE("Diagnostics: the value scan equals a walk of OpenVDB's value iterators", "[diagnostics]")
{
    // Truth: every active value from cbeginValueOn in leaf order, then the active tiles. Leaves
    // fully active (the scan's lanes) and partly active, whose inactive values lie far outside.
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(0.5f);
    std::uint32_t state = 12345;
    auto next = [&] { return state = state * 1664525u + 1013904223u; };
    for (int leaf = 0; leaf < 40; ++leaf) {
        const Coord origin(8 * (leaf % 7), 8 * (leaf / 7), -16);
        for (int i = 0; i < 512; ++i) {
            const Coord ijk = origin + Coord(i >> 6, (i >> 3) & 7, i & 7);
            const float value = float(int(next() % 20001) - 10000) / 997.0f;
            if (leaf % 3 != 0 || next() % 4 == 0) grid->tree().setValue(ijk, value);
            else grid->tree().setValueOff(ijk, 1.0e6f); // inactive values are not data
        }
    }
    grid->tree().addTile(/*level=*/1, Coord(800, 0, 0), 42.0f, /*active=*/true);
    auto truth = [](const openvdb::FloatGrid& g) {
        isouq::ActiveValueScan scan;
        std::uint64_t index = 0;
        for (auto leaf = g.tree().cbeginLeaf(); leaf; ++leaf, ++index)
            for (auto it = leaf->cbeginValueOn(); it; ++it) scan.add(*it, index, it.getCoord(), 1);
        auto tile = g.tree().cbeginValueOn();
        tile.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
        for (; tile; ++tile) scan.add(*tile, index, tile.getCoord(), tile.getVoxelCount());
        return scan;
    };
    auto same = [](const isouq::ActiveValueScan& a, const isouq::ActiveValueScan& b) {
        CHECK(a.min == b.min);
        CHECK(a.max == b.max);
        CHECK(a.nonFinite == b.nonFinite);
        CHECK(a.firstLeaf == b.firstLeaf);
        CHECK(a.first == b.first);
        CHECK((a.firstValue == b.firstValue || (std::isnan(a.firstValue) && std::isnan(b.firstValue))));
    };
    same(isouq::scanActiveValues(*grid), truth(*grid));
    CHECK(isouq::scanActiveValues(*grid).max == 42.0f); // the tile

    // Non-finite values in a fully active leaf and in a partly active one, each after finite ones.
    grid->tree().setValue(Coord(8, 0, -16) + Coord(5, 6, 7), kNaN); // leaf 1: fully active
    grid->tree().setValue(Coord(8, 0, -16) + Coord(7, 7, 7), -kInf);
    grid->tree().setValue(Coord(0, 8, -16) + Coord(3, 3, 3), kInf); // leaf 7: partly active
    const isouq::ActiveValueScan scan = isouq::scanActiveValues(*grid);
    same(scan, truth(*grid));
    CHECK(scan.nonFinite == 3);
    CHECK(std::isfinite(scan.min));
    CHECK(std::isfinite(scan.max));
}
