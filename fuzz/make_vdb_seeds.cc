// Writes small valid .vdb files into the folder given as argv[1]: seeds for fuzz_vdb that
// reach past the header into every part of a grid (docs/hardening.md). A level-set sphere, a
// fog ball, a double grid, a grid with an active tile, half-float storage, each compression
// (active mask, zip, blosc), two grids in one file and file metadata.
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdio>
#include <string>

namespace {

void write(const std::string& path, const openvdb::GridPtrVec& grids, std::uint32_t compression,
    bool fileMeta = false)
{
    openvdb::io::File file(path);
    file.setCompression(compression);
    openvdb::MetaMap meta;
    if (fileMeta) meta.insertMeta("creator", openvdb::StringMetadata("isouq fuzz seeds"));
    file.write(grids, meta);
    file.close();
}

} // namespace

int main(int argc, char** argv)
{
    if (argc != 2) {
        std::fprintf(stderr, "usage: make_vdb_seeds FOLDER\n");
        return 2;
    }
    openvdb::initialize();
    const std::string dir = argv[1];
    using namespace openvdb;

    // Every grid lies inside one root child (coordinates 0..4095): each root child costs 8 KiB
    // of masks, and inputs are capped at 64 KiB.
    FloatGrid::Ptr sphere = FloatGrid::create(2.0f); // a narrow-band level set, radius 4, band 2
    sphere->setName("surface");
    sphere->setGridClass(GRID_LEVEL_SET);
    {
        auto acc = sphere->getAccessor();
        for (int i = 12; i <= 28; ++i)
            for (int j = 12; j <= 28; ++j)
                for (int k = 12; k <= 28; ++k) {
                    const float d = std::sqrt(float((i - 20) * (i - 20) + (j - 20) * (j - 20) + (k - 20) * (k - 20))) - 4.0f;
                    if (std::abs(d) < 2.0f) acc.setValue(Coord(i, j, k), d);
                }
    }

    FloatGrid::Ptr fog = FloatGrid::create(0.0f);
    fog->setName("density");
    fog->setGridClass(GRID_FOG_VOLUME);
    {
        auto acc = fog->getAccessor();
        for (int i = -3; i <= 3; ++i)
            for (int j = -3; j <= 3; ++j)
                for (int k = -3; k <= 3; ++k)
                    if (i * i + j * j + k * k <= 9) acc.setValue(Coord(i + 16, j + 16, k + 16), 1.0f - float(i * i + j * j + k * k) / 9.0f);
    }
    fog->setTransform(math::Transform::createLinearTransform(0.5));

    DoubleGrid::Ptr doubles = DoubleGrid::create(-1.0);
    doubles->setName("doubles");
    doubles->tree().setValue(Coord(1, 2, 3), 2.5);
    doubles->tree().setValue(Coord(2, 2, 3), -0.5);

    FloatGrid::Ptr tile = FloatGrid::create(0.0f);
    tile->setName("tile");
    tile->tree().addTile(1, Coord(0), 1.0f, true); // one active 8^3 tile
    tile->tree().setValue(Coord(9, 0, 0), 0.5f);

    FloatGrid::Ptr half = sphere->deepCopy();
    half->setName("half");
    half->setSaveFloatAsHalf(true);

    Vec3SGrid::Ptr vectors = Vec3SGrid::create();
    vectors->setName("velocity");
    vectors->tree().setValue(Coord(0), Vec3s(1, 2, 3));

    // COMPRESS_NONE would store every internal-node value (128 KiB and more): zip instead.
    write(dir + "/sphere_mask.vdb", {sphere}, io::COMPRESS_ACTIVE_MASK);
    write(dir + "/sphere_zip.vdb", {sphere}, io::COMPRESS_ZIP | io::COMPRESS_ACTIVE_MASK);
    write(dir + "/sphere_zip_nomask.vdb", {sphere}, io::COMPRESS_ZIP);
    write(dir + "/sphere_blosc.vdb", {sphere}, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK);
    write(dir + "/fog_mask.vdb", {fog}, io::COMPRESS_ACTIVE_MASK, true);
    write(dir + "/doubles.vdb", {doubles}, io::COMPRESS_ACTIVE_MASK);
    write(dir + "/tile.vdb", {tile}, io::COMPRESS_ACTIVE_MASK);
    write(dir + "/half.vdb", {half}, io::COMPRESS_ACTIVE_MASK);
    write(dir + "/vector_then_fog.vdb", {vectors, fog}, io::COMPRESS_ZIP, true);
    return 0;
}
