// Tests of meshing in pieces (SPEC §9, §10 "MPI"; Bricks.h) against the one-process mesher as
// the truth: the pieces of a BrickPlan, meshed one after another in this process with the words
// a piece would receive from the others, and joined end to end, equal extractIsosurface's mesh
// exactly (every vertex, every column, every triangle index), for level sets, fog-like fields,
// active tiles and every method setting.
#include <isouq/Bricks.h>
#include <isouq/MarchingCubes.h>

#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <variant>

using namespace isouq;

namespace {

/// Meshes every piece of a plan of @a pieces as the ranks would, and joins the pieces.
Mesh meshInPieces(const openvdb::FloatGrid& grid, const MeshSettings& settings, int pieces)
{
    const BrickPlan plan(grid, pieces);
    std::vector<std::unique_ptr<BrickMesher>> meshers;
    for (int p = 0; p < pieces; ++p) {
        meshers.push_back(std::make_unique<BrickMesher>(grid, settings, plan, p));
        meshers.back()->count();
    }
    std::uint64_t vertices = 0, triangles = 0, total = 0;
    for (auto& m : meshers) total += m->vertexCount();
    for (auto& m : meshers) {
        m->setOffsets(vertices, triangles, total);
        vertices += m->vertexCount();
        triangles += m->triangleCount();
    }
    Mesh whole;
    for (int p = 0; p < pieces; ++p) {
        for (std::int64_t b : meshers[std::size_t(p)]->foreignBlocks()) {
            const int owner = plan.pieceOfBlock(b);
            REQUIRE(owner > p); // + neighbours come later in the block order
            std::uint64_t words[BrickMesher::kBlockWords];
            meshers[std::size_t(owner)]->describeBlock(b, words);
            meshers[std::size_t(p)]->learnBlock(b, words);
        }
        Mesh piece;
        meshers[std::size_t(p)]->fill(piece);
        REQUIRE(piece.vertexCount() == meshers[std::size_t(p)]->vertexCount());
        whole.indexToWorld = piece.indexToWorld;
        whole.positions.insert(whole.positions.end(), piece.positions.begin(), piece.positions.end());
        whole.triangles.insert(whole.triangles.end(), piece.triangles.begin(), piece.triangles.end());
        for (const Attribute& a : piece.vertexAttributes.columns())
            std::visit([&](const auto& values) {
                using T = typename std::decay_t<decltype(values)>::value_type;
                std::vector<T>* column = whole.vertexAttributes.find<T>(a.name);
                if (!column) column = &whole.vertexAttributes.add<T>(a.name, 0);
                column->insert(column->end(), values.begin(), values.end());
            }, a.data);
    }
    return whole;
}

/// Bitwise equality of two float columns (NaN where the other has the same NaN).
template <typename T>
bool sameBits(const std::vector<T>& a, const std::vector<T>& b)
{
    return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

void requireSame(const Mesh& one, const Mesh& joined)
{
    REQUIRE(joined.positions.size() == one.positions.size());
    REQUIRE(joined.triangles.size() == one.triangles.size());
    REQUIRE(sameBits(one.positions, joined.positions));
    REQUIRE(sameBits(one.triangles, joined.triangles));
    REQUIRE(joined.vertexAttributes.columns().size() == one.vertexAttributes.columns().size());
    for (const Attribute& a : one.vertexAttributes.columns()) {
        INFO("column " << a.name);
        std::visit([&](const auto& values) {
            using T = typename std::decay_t<decltype(values)>::value_type;
            const std::vector<T>* other = joined.vertexAttributes.find<T>(a.name);
            REQUIRE(other);
            REQUIRE(sameBits(values, *other));
        }, a.data);
    }
}

openvdb::FloatGrid::Ptr sphere(float radius)
{
    return openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(radius, openvdb::Vec3f(0.3f, -0.2f, 0.1f), 1.0f, 3.0f);
}

/// A fog-like grid: a smooth bump with two lobes, every voxel of a box active.
openvdb::FloatGrid::Ptr fog()
{
    auto grid = openvdb::FloatGrid::create(0.0f);
    auto acc = grid->getAccessor();
    for (int x = -20; x < 28; ++x)
        for (int y = -17; y < 19; ++y)
            for (int z = -9; z < 23; ++z) {
                const double a = std::exp(-((x - 6.0) * (x - 6.0) + y * y + (z - 5.0) * (z - 5.0)) / 60.0);
                const double b = std::exp(-((x + 9.0) * (x + 9.0) + (y - 4.0) * (y - 4.0) + z * z) / 30.0);
                acc.setValue(openvdb::Coord(x, y, z), float(a + 0.8 * b));
            }
    return grid;
}

} // namespace

TEST_CASE("Bricks: pieces of a level set join into the one-process mesh", "[bricks][mpi]")
{
    const auto grid = sphere(23.0f);
    MeshSettings settings;
    settings.provenance = true;
    settings.uncertainty = GENERATE(false, true);
    settings.method = GENERATE(EdgeMethod::Linear, EdgeMethod::Weno);
    const Mesh one = extractIsosurface(*grid, settings);
    REQUIRE(one.triangles.size() > 1000);
    for (int pieces : {1, 2, 3, 5, 8}) {
        INFO(pieces << " pieces, uncertainty " << settings.uncertainty);
        requireSame(one, meshInPieces(*grid, settings, pieces));
    }
}

TEST_CASE("Bricks: pieces of a fog volume and of active tiles join into the one-process mesh", "[bricks][mpi]")
{
    MeshSettings settings;
    settings.provenance = true;
    settings.uncertainty = true;
    settings.isovalue = 0.35f;
    SECTION("fog")
    {
        const auto grid = fog();
        const Mesh one = extractIsosurface(*grid, settings);
        REQUIRE(one.triangles.size() > 500);
        for (int pieces : {2, 4, 7}) requireSame(one, meshInPieces(*grid, settings, pieces));
    }
    SECTION("tiles")
    {
        // Two active 8^3 tiles of 1 and a voxel: crossings only on the tiles' shells (SPEC §1).
        auto grid = openvdb::FloatGrid::create(0.0f);
        grid->tree().addTile(1, openvdb::Coord(0), 1.0f, true);
        grid->tree().addTile(1, openvdb::Coord(16, 8, 0), 1.0f, true);
        grid->tree().setValue(openvdb::Coord(40, 3, 5), 1.0f);
        settings.isovalue = 0.5f;
        const Mesh one = extractIsosurface(*grid, settings);
        REQUIRE(one.triangles.size() > 100);
        for (int pieces : {2, 3, 6}) requireSame(one, meshInPieces(*grid, settings, pieces));
    }
}

TEST_CASE("Bricks: a plan balances the active voxels and covers the block order", "[bricks][mpi]")
{
    const auto grid = sphere(40.0f);
    const BrickPlan plan(*grid, 4);
    REQUIRE(plan.begin(0) == 0);
    REQUIRE(plan.end(3) == plan.blockCount());
    std::uint64_t total = 0;
    for (int p = 0; p < 4; ++p) {
        REQUIRE(plan.end(p) >= plan.begin(p));
        if (p > 0) REQUIRE(plan.begin(p) == plan.end(p - 1));
        total += plan.weight(p);
    }
    REQUIRE(total == grid->activeVoxelCount() + plan.blockCount());
    // Each cut is within one block's weight (at most 513) of its target.
    for (int p = 0; p < 4; ++p) REQUIRE(std::abs(double(plan.weight(p)) - double(total) / 4) <= 2 * 513);
    for (std::size_t b = 0; b < plan.blockCount(); b += 97) REQUIRE(plan.blockOf(plan.origin(b)) == std::int64_t(b));
}

TEST_CASE("Bricks: a plan of the topology alone equals the grid's plan", "[bricks][mpi]")
{
    // A raw scan read by pieces has only its leaves' value masks on every piece (loadDensePiece).
    auto grid = sphere(30.0f);
    grid->tree().addTile(1, openvdb::Coord(200, 0, 0), 1.0f, true); // an active tile's shell too
    const openvdb::MaskTree topology(grid->tree(), false, openvdb::TopologyCopy());
    for (int pieces : {1, 3, 5}) {
        const BrickPlan fromGrid(*grid, pieces), fromTopology(topology, pieces);
        REQUIRE(fromTopology.blockCount() == fromGrid.blockCount());
        for (int p = 0; p < pieces; ++p) {
            REQUIRE(fromTopology.begin(p) == fromGrid.begin(p));
            REQUIRE(fromTopology.end(p) == fromGrid.end(p));
            REQUIRE(fromTopology.weight(p) == fromGrid.weight(p));
        }
        for (std::size_t b = 0; b < fromGrid.blockCount(); ++b) REQUIRE(fromTopology.origin(b) == fromGrid.origin(b));
    }
}
