// Tests for isouq/VolumeSources.h. Truths: bytes written or read directly by the test, hand
// formulas, brute force over every edge of the dense array, the data README's Otsu values.
#include <isouq/Diagnostics.h>
#include <isouq/GridMetadata.h>
#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>

#include "../TempDir.h"

#include <catch2/catch.hpp>
#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>

namespace fs = std::filesystem;
using isouq_test::TempDir;
using Catch::Matchers::Contains;
using Catch::Matchers::WithinAbs;
using isouq::KeepBlocks;
using isouq::VolumeRequest;
using openvdb::Coord;

namespace {

std::string dataPath(const std::string& name) { return std::string(ISOUQ_DATA_DIR) + "/" + name; }

std::vector<unsigned char> readBytes(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void writeBytes(const std::string& path, const std::vector<unsigned char>& bytes)
{
    std::ofstream out(path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

VolumeRequest request(const std::string& input, std::optional<float> isovalue = std::nullopt,
    KeepBlocks keep = KeepBlocks::Crossing)
{
    VolumeRequest r;
    r.input = input;
    r.isovalue = isovalue;
    r.keep = keep;
    return r;
}

/// The one-line message of the InputError that loading @a r throws.
std::string inputError(const VolumeRequest& r)
{
    try {
        isouq::loadVolume(r);
    } catch (const isouq::InputError& e) {
        const std::string message = e.what();
        CHECK(!message.empty());
        CHECK(message.find('\n') == std::string::npos);
        return message;
    }
    FAIL("no InputError for " << r.input);
    return "";
}

openvdb::Vec3i metaVec3i(const openvdb::FloatGrid& grid, const char* name)
{
    return grid.metaValue<openvdb::Vec3i>(name);
}

/// 5x4x3 int16 volume with v = x + 10y + 100z - 150, written little-endian by hand.
int testValue(int x, int y, int z) { return x + 10 * y + 100 * z - 150; }

std::vector<unsigned char> int16Bytes()
{
    std::vector<unsigned char> bytes;
    for (int z = 0; z < 3; ++z)
        for (int y = 0; y < 4; ++y)
            for (int x = 0; x < 5; ++x) {
                const auto v = std::uint16_t(std::int16_t(testValue(x, y, z)));
                bytes.push_back(static_cast<unsigned char>(v & 0xff));
                bytes.push_back(static_cast<unsigned char>(v >> 8));
            }
    return bytes;
}

} // namespace

TEST_CASE("VolumeSources: field samples include both domain ends", "[sources][field]")
{
    VolumeRequest r = request("field:tangle", std::nullopt, KeepBlocks::All);
    r.resolution = 32;
    const isouq::LoadedVolume v = isouq::loadVolume(r);
    REQUIRE(v.grid);
    CHECK(v.isovalue == 0.1f);
    CHECK(v.isovalueSource == "SPEC §5 default");
    REQUIRE(v.truth);
    const openvdb::Vec3d lo = v.grid->indexToWorld(Coord(0)), hi = v.grid->indexToWorld(Coord(31));
    for (int a = 0; a < 3; ++a) {
        CHECK(lo[a] == -1.0);
        CHECK_THAT(hi[a], WithinAbs(1.0, 1e-15));
    }
    CHECK(metaVec3i(*v.grid, isouq::kDataBoundsMinMeta) == openvdb::Vec3i(0, 0, 0));
    CHECK(metaVec3i(*v.grid, isouq::kDataBoundsMaxMeta) == openvdb::Vec3i(31, 31, 31));
    // every voxel is the field at the grid's own index -> world map (hand formula)
    auto acc = v.grid->getConstAccessor();
    int mismatches = 0;
    for (int i = 0; i < 32; ++i)
        for (int j = 0; j < 32; ++j)
            for (int k = 0; k < 32; ++k) {
                const openvdb::Vec3d p = v.grid->indexToWorld(Coord(i, j, k));
                const double x = p[0], y = p[1], z = p[2];
                const double f = x * x * x * x + y * y * y * y + z * z * z * z - (x * x + y * y + z * z - 0.4);
                mismatches += std::abs(acc.getValue(Coord(i, j, k)) - float(f)) > 2e-7f;
                mismatches += !acc.isValueOn(Coord(i, j, k));
            }
    CHECK(mismatches == 0);
    CHECK_FALSE(acc.isValueOn(Coord(32, 0, 0)));
}

TEST_CASE("VolumeSources: a formula is sampled like the hand formula, in parallel",
    "[sources][formula]")
{
    VolumeRequest r = request("formula:x^2+y^2+z^2-0.5", std::nullopt, KeepBlocks::All);
    r.resolution = 17;
    r.domain = std::make_pair(-2.0, 3.0);
    const isouq::LoadedVolume v = isouq::loadVolume(r);
    CHECK(v.isovalue == 0.0f);
    CHECK(v.isovalueSource == "formula default");
    CHECK(v.grid->indexToWorld(Coord(0)) == openvdb::Vec3d(-2.0));
    CHECK_THAT(v.grid->indexToWorld(Coord(16))[2], WithinAbs(3.0, 1e-15));
    auto acc = v.grid->getConstAccessor();
    for (int i = 0; i < 17; i += 4) {
        const openvdb::Vec3d p = v.grid->indexToWorld(Coord(i, 16 - i, i / 2));
        const double f = p.lengthSqr() - 0.5;
        CHECK_THAT(acc.getValue(Coord(i, 16 - i, i / 2)), WithinAbs(f, 1e-6 * (1 + std::abs(f))));
    }
    // the exact field from many threads at once
    REQUIRE(v.truth);
    std::vector<double> values(20000);
    tbb::parallel_for(std::size_t(0), values.size(), [&](std::size_t n) {
        values[n] = (*v.truth)(1e-4 * double(n), -0.5, 0.25);
    });
    int wrong = 0;
    for (std::size_t n = 0; n < values.size(); ++n) {
        const double x = 1e-4 * double(n);
        wrong += std::abs(values[n] - (x * x + 0.25 + 0.0625 - 0.5)) > 1e-12;
    }
    CHECK(wrong == 0);
}

TEST_CASE("VolumeSources: a small int16 raw round-trips with x fastest", "[sources][raw]")
{
    TempDir dir;
    const std::string path = dir / "vol_5x4x3_int16.raw";
    writeBytes(path, int16Bytes());
    const isouq::LoadedVolume v = isouq::loadVolume(request(path, 0.5f, KeepBlocks::All));
    CHECK(v.grid->getName() == "vol");
    CHECK(v.isovalueSource == "given");
    CHECK(metaVec3i(*v.grid, isouq::kDataBoundsMaxMeta) == openvdb::Vec3i(4, 3, 2));
    CHECK(v.grid->voxelSize() == openvdb::Vec3d(1.0));
    auto acc = v.grid->getConstAccessor();
    for (int z = 0; z < 3; ++z)
        for (int y = 0; y < 4; ++y)
            for (int x = 0; x < 5; ++x) {
                CHECK(acc.getValue(Coord(x, y, z)) == float(testValue(x, y, z)));
                CHECK(acc.isValueOn(Coord(x, y, z)));
            }
    CHECK_FALSE(acc.isValueOn(Coord(5, 0, 0))); // outside the data box
    CHECK_FALSE(acc.isValueOn(Coord(0, 4, 0)));
    CHECK_FALSE(acc.isValueOn(Coord(0, 0, 3)));
}

TEST_CASE("VolumeSources: raw overrides of dims, dtype and spacing", "[sources][raw]")
{
    TempDir dir;
    const std::vector<unsigned char> bytes = int16Bytes();
    SECTION("an unnamed file with --dims --dtype --spacing")
    {
        const std::string path = dir / "plain.raw";
        writeBytes(path, bytes);
        VolumeRequest r = request(path, 0.5f, KeepBlocks::All);
        r.dims = openvdb::Vec3i(5, 4, 3);
        r.dtype = "int16";
        r.spacing = openvdb::Vec3d(0.5, 1.0, 2.0);
        const isouq::LoadedVolume v = isouq::loadVolume(r);
        CHECK(v.grid->voxelSize() == openvdb::Vec3d(0.5, 1.0, 2.0));
        CHECK(v.grid->indexToWorld(Coord(2, 3, 1)) == openvdb::Vec3d(1.0, 3.0, 2.0));
        CHECK(v.grid->tree().getValue(Coord(4, 3, 2)) == float(testValue(4, 3, 2)));
        CHECK(v.grid->tree().getValue(Coord(1, 2, 0)) == float(testValue(1, 2, 0)));
    }
    SECTION("the name's dims and dtype overridden: the same bytes as 10x4x3 uint8")
    {
        const std::string path = dir / "vol_5x4x3_int16.raw";
        writeBytes(path, bytes);
        VolumeRequest r = request(path, 100.0f, KeepBlocks::All);
        r.dims = openvdb::Vec3i(10, 4, 3);
        r.dtype = "uint8";
        const isouq::LoadedVolume v = isouq::loadVolume(r);
        CHECK(metaVec3i(*v.grid, isouq::kDataBoundsMaxMeta) == openvdb::Vec3i(9, 3, 2));
        for (int z = 0; z < 3; ++z)
            for (int y = 0; y < 4; ++y)
                for (int x = 0; x < 10; ++x) {
                    CHECK(v.grid->tree().getValue(Coord(x, y, z)) == float(bytes[x + 10 * (y + 4 * z)]));
                }
    }
}

TEST_CASE("VolumeSources: every raw dtype decodes little-endian", "[sources][raw]")
{
    TempDir dir;
    const std::string dtype = GENERATE("uint8", "uint16", "int16", "float32", "float64");
    // values exact in every type: v = 3x + 7y + 11z (+ 0.5 for floats, - 40 for int16)
    auto value = [&](int x, int y, int z) {
        const double v = 3 * x + 7 * y + 11 * z;
        if (dtype == "int16") return v - 40.0;
        if (dtype == "uint16") return v + 60000.0;
        if (dtype[0] == 'f') return v + 0.5;
        return v;
    };
    std::vector<unsigned char> bytes;
    auto push = [&](std::uint64_t bits, int size) {
        for (int b = 0; b < size; ++b) bytes.push_back(static_cast<unsigned char>(bits >> (8 * b)));
    };
    for (int z = 0; z < 2; ++z)
        for (int y = 0; y < 2; ++y)
            for (int x = 0; x < 3; ++x) {
                const double v = value(x, y, z);
                if (dtype == "uint8") push(std::uint8_t(v), 1);
                if (dtype == "uint16") push(std::uint16_t(v), 2);
                if (dtype == "int16") push(std::uint16_t(std::int16_t(v)), 2);
                if (dtype == "float32") {
                    const float f = float(v);
                    std::uint32_t bits;
                    std::memcpy(&bits, &f, 4);
                    push(bits, 4);
                }
                if (dtype == "float64") {
                    std::uint64_t bits;
                    std::memcpy(&bits, &v, 8);
                    push(bits, 8);
                }
            }
    const std::string path = dir / ("t_3x2x2_" + dtype + ".raw");
    writeBytes(path, bytes);
    const isouq::LoadedVolume v =
        isouq::loadVolume(request(path, float(value(1, 1, 0)), KeepBlocks::All));
    for (int z = 0; z < 2; ++z)
        for (int y = 0; y < 2; ++y)
            for (int x = 0; x < 3; ++x) CHECK(v.grid->tree().getValue(Coord(x, y, z)) == float(value(x, y, z)));
}

TEST_CASE("VolumeSources: bucky voxels equal the file's bytes", "[sources][raw][data]")
{
    const std::string path = dataPath("bucky_32x32x32_uint8.raw");
    const std::vector<unsigned char> bytes = readBytes(path);
    REQUIRE(bytes.size() == 32 * 32 * 32);
    const isouq::LoadedVolume v = isouq::loadVolume(request(path, 51.0f));
    auto acc = v.grid->getConstAccessor();
    int mismatches = 0, active = 0;
    for (int z = 0; z < 32; ++z)
        for (int y = 0; y < 32; ++y)
            for (int x = 0; x < 32; ++x) {
                if (!acc.isValueOn(Coord(x, y, z))) continue;
                ++active;
                mismatches += acc.getValue(Coord(x, y, z)) != float(bytes[x + 32 * (y + 32 * z)]);
            }
    CHECK(active > 0);
    CHECK(mismatches == 0);
    CHECK(acc.getValue(Coord(16, 16, 16)) == float(bytes[16 + 32 * (16 + 32 * 16)]));
    CHECK(acc.getValue(Coord(31, 0, 5)) == float(bytes[31 + 32 * (0 + 32 * 5)]));
}

TEST_CASE("VolumeSources: sphere.vdb and smoke.vdb (stored as half) load as FloatGrid",
    "[sources][vdb][data]")
{
    const isouq::LoadedVolume sphere = isouq::loadVolume(request(dataPath("sphere.vdb")));
    CHECK(sphere.grid->getName() == "ls_sphere");
    CHECK(sphere.grid->getGridClass() == openvdb::GRID_LEVEL_SET);
    CHECK(sphere.grid->activeVoxelCount() == 270638);
    CHECK(sphere.isovalue == 0.0f);
    CHECK(sphere.isovalueSource == "level set");
    CHECK_THAT(sphere.grid->voxelSize()[0], WithinAbs(0.05, 1e-7));
    // the zero crossing is at radius 3.0 = 60 voxels (README): |phi| < half a voxel there
    CHECK(std::abs(sphere.grid->tree().getValue(Coord(60, 0, 0))) < 0.025f);
    CHECK_FALSE(sphere.truth);

    VolumeRequest r = request(dataPath("smoke.vdb"));
    r.gridName = "density";
    const isouq::LoadedVolume smoke = isouq::loadVolume(r);
    CHECK(smoke.grid->getName() == "density");
    CHECK(smoke.grid->activeVoxelCount() == 1049275);
    CHECK(smoke.isovalueSource == "Otsu (starting value)");
    CHECK(smoke.isovalue > 1e-5f);
    CHECK(smoke.isovalue < 5.71f);
}

TEST_CASE("VolumeSources: engine made sparse keeps every crossing edge and its stencil",
    "[sources][sparse][data]")
{
    const std::string path = dataPath("engine_256x256x128_uint8.raw");
    const std::vector<unsigned char> d = readBytes(path);
    const int X = 256, Y = 256, Z = 128;
    REQUIRE(d.size() == std::size_t(X) * Y * Z);
    const float k = 71.0f;
    const isouq::LoadedVolume v = isouq::loadVolume(request(path, k));
    const openvdb::FloatTree& tree = v.grid->tree();
    auto acc = v.grid->getConstAccessor();
    auto dense = [&](int x, int y, int z) { return float(d[x + std::size_t(X) * (y + std::size_t(Y) * z)]); };
    const int dims[3] = {X, Y, Z};

    std::size_t denseCrossings = 0, sparseCrossings = 0, edgeMismatches = 0, stencilMisses = 0;
    for (int z = 0; z < Z; ++z)
        for (int y = 0; y < Y; ++y)
            for (int x = 0; x < X; ++x) {
                const Coord p(x, y, z);
                for (int a = 0; a < 3; ++a) {
                    if (p[a] + 1 >= dims[a]) continue;
                    Coord q = p;
                    q[a] += 1;
                    const bool crossDense = (dense(p[0], p[1], p[2]) >= k) != (dense(q[0], q[1], q[2]) >= k);
                    const bool crossSparse = (acc.getValue(p) >= k) != (acc.getValue(q) >= k);
                    denseCrossings += crossDense;
                    sparseCrossings += crossSparse;
                    edgeMismatches += crossDense != crossSparse;
                    if (!crossDense) continue;
                    for (int s = -2; s <= 3; ++s) { // SPEC §2 stencil i-2..i+3
                        Coord c = p;
                        c[a] += s;
                        if (c[a] < 0 || c[a] >= dims[a]) continue;
                        stencilMisses += !acc.isValueOn(c) || acc.getValue(c) != dense(c[0], c[1], c[2]);
                    }
                }
            }
    CHECK(denseCrossings > 100000);
    CHECK(sparseCrossings == denseCrossings);
    CHECK(edgeMismatches == 0);
    CHECK(stencilMisses == 0);
    const std::size_t denseLeaves = 32 * 32 * 16;
    CHECK(v.denseBlocks == denseLeaves);
    CHECK(tree.leafCount() == v.keptBlocks);
    CHECK(tree.leafCount() < denseLeaves / 2);
    CHECK(metaVec3i(*v.grid, isouq::kDataBoundsMaxMeta) == openvdb::Vec3i(255, 255, 127));
}

TEST_CASE("VolumeSources: keep rules nest, and the hidden-feature margin covers every tricubic "
          "crossing", "[sources][sparse][hidden][data]")
{
    const std::string path = dataPath("bucky_32x32x32_uint8.raw");
    const std::vector<unsigned char> d = readBytes(path);
    const float k = GENERATE(25.5f, 51.0f, 128.0f, 229.5f);
    const auto crossing = isouq::loadVolume(request(path, k, KeepBlocks::Crossing));
    const auto hidden = isouq::loadVolume(request(path, k, KeepBlocks::CrossingOrHidden));
    const auto nonConstant = isouq::loadVolume(request(path, k, KeepBlocks::NonConstant));
    const auto all = isouq::loadVolume(request(path, k, KeepBlocks::All));
    CHECK(crossing.keptBlocks <= hidden.keptBlocks);
    CHECK(hidden.keptBlocks <= nonConstant.keptBlocks);
    CHECK(all.keptBlocks == 64);
    CHECK(all.grid->tree().leafCount() == 64);
    for (auto leaf = crossing.grid->tree().cbeginLeaf(); leaf; ++leaf) {
        CHECK(hidden.grid->tree().probeConstLeaf(leaf->origin()) != nullptr);
    }

    // Brute force: tricubic Lagrange (nodes -1..2, SPEC §4) at the 5^3 subcell corners of
    // every cell with a full 4x4x4 stencil; where they straddle k, the stencil must be leaves.
    auto weights = [](double t, double w[4]) {
        w[0] = -t * (t - 1) * (t - 2) / 6, w[1] = (t + 1) * (t - 1) * (t - 2) / 2;
        w[2] = -(t + 1) * t * (t - 2) / 2, w[3] = (t + 1) * t * (t - 1) / 6;
    };
    auto acc = hidden.grid->getConstAccessor();
    int refinedCells = 0, misses = 0;
    for (int z = 1; z + 2 < 32; ++z)
        for (int y = 1; y + 2 < 32; ++y)
            for (int x = 1; x + 2 < 32; ++x) {
                bool above = false, below = false;
                for (int s = 0; s <= 4; ++s)
                    for (int t = 0; t <= 4; ++t)
                        for (int u = 0; u <= 4; ++u) {
                            double wx[4], wy[4], wz[4], p = 0.0;
                            weights(0.25 * s, wx), weights(0.25 * t, wy), weights(0.25 * u, wz);
                            for (int c = 0; c < 4; ++c)
                                for (int b = 0; b < 4; ++b)
                                    for (int a = 0; a < 4; ++a)
                                        p += wx[a] * wy[b] * wz[c]
                                            * d[(x - 1 + a) + 32 * ((y - 1 + b) + 32 * (z - 1 + c))];
                            (p >= k ? above : below) = true;
                        }
                if (!(above && below)) continue;
                ++refinedCells;
                for (int c = 0; c < 4; ++c)
                    for (int b = 0; b < 4; ++b)
                        for (int a = 0; a < 4; ++a)
                            misses += !acc.isValueOn(Coord(x - 1 + a, y - 1 + b, z - 1 + c));
            }
    CHECK(refinedCells > 0);
    CHECK(misses == 0);
}

TEST_CASE("VolumeSources: Otsu on a two-spike histogram splits between the spikes", "[sources][otsu]")
{
    std::array<std::uint64_t, 256> h{};
    h[10] = 1000, h[200] = 3000;
    const double t = isouq::otsuThreshold(h, 0.0, 256.0); // bin b is [b, b+1)
    CHECK(t >= 10.5);
    CHECK(t < 200.5);
    // three spikes: the split falls in the widest between-class gap of the two heavy ones
    std::array<std::uint64_t, 256> g{};
    g[20] = 5000, g[30] = 10, g[220] = 5000;
    const double u = isouq::otsuThreshold(g, 0.0, 256.0);
    CHECK(u >= 30.5);
    CHECK(u < 220.5);
}

TEST_CASE("VolumeSources: default raw isovalue is Otsu, matching the data README", "[sources][otsu][data]")
{
    struct Case { const char* file; double otsu, lo, hi; };
    const Case cases[] = {{"engine_256x256x128_uint8.raw", 71, 0, 255},
        {"fuel_64x64x64_uint8.raw", 62, 0, 255}, {"stent_128x128x256_int16.raw", 184, 0, 2000},
        {"brainsmall_128x128x84_uint8.raw", 33, 0, 202}, {"t1_kmeans_128x128x62_int16.raw", 46, 0, 255}};
    for (const Case& c : cases) {
        const isouq::LoadedVolume v = isouq::loadVolume(request(dataPath(c.file)));
        INFO(c.file << " Otsu " << v.isovalue);
        CHECK(v.isovalueSource == "Otsu (starting value)");
        CHECK_THAT(v.isovalue, WithinAbs(c.otsu, (c.hi - c.lo) / 256.0)); // one bin
    }
}

TEST_CASE("VolumeSources: the skull's anisotropic spacing and documented isovalue", "[sources][raw][data]")
{
    VolumeRequest r = request(dataPath("skull_64x64x64_float32.raw"), 2.9f);
    r.spacing = openvdb::Vec3d(3.943050, 3.943050, 3.650790);
    const isouq::LoadedVolume v = isouq::loadVolume(r);
    CHECK(v.grid->voxelSize() == *r.spacing);
    CHECK(v.keptBlocks > 0);
    CHECK(v.keptBlocks < v.denseBlocks);
}

TEST_CASE("VolumeSources: a raw scan's tree is the same whatever the thread count", "[sources][raw][threads]")
{
    // 125 layers of 8 slices (the last one short), which 2, 3 and 8 threads make in runs that
    // idle threads split (Sparsify.cc LayerRuns); one thread makes them in one run. Every
    // voxel's value and state, the kept blocks and the range must be equal, and the active
    // values the file's bytes.
    const int X = 48, Y = 40, Z = 997;
    std::vector<unsigned char> bytes(std::size_t(X) * Y * Z);
    for (int z = 0; z < Z; ++z)
        for (int y = 0; y < Y; ++y)
            for (int x = 0; x < X; ++x)
                bytes[x + std::size_t(X) * (y + std::size_t(Y) * z)] = static_cast<unsigned char>(
                    128.0 + 120.0 * std::sin(x / 5.0) * std::cos(y / 7.0) * std::sin(z / 23.0));
    TempDir tmp;
    const std::string path = (tmp.path / "waves_48x40x997_uint8.raw").string();
    writeBytes(path, bytes);
    const auto loadWith = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        tbb::task_arena arena(threads);
        return arena.execute([&] { return isouq::loadVolume(request(path, 128.0f)); });
    };
    const isouq::LoadedVolume one = loadWith(1);
    auto oneAcc = one.grid->getConstAccessor();
    std::size_t wrong = 0;
    for (int z = 0; z < Z; ++z)
        for (int y = 0; y < Y; ++y)
            for (int x = 0; x < X; ++x)
                if (oneAcc.isValueOn(Coord(x, y, z)))
                    wrong += oneAcc.getValue(Coord(x, y, z)) != float(bytes[x + std::size_t(X) * (y + std::size_t(Y) * z)]);
    CHECK(wrong == 0);
    CHECK(one.keptBlocks > 1000);
    CHECK(one.keptBlocks < one.denseBlocks);
    for (int threads : {2, 3, 8}) {
        INFO(threads << " threads");
        const isouq::LoadedVolume many = loadWith(threads);
        CHECK(many.description == one.description);
        CHECK(many.keptBlocks == one.keptBlocks);
        CHECK(many.grid->tree().leafCount() == one.grid->tree().leafCount());
        CHECK(many.grid->tree().activeVoxelCount() == one.grid->tree().activeVoxelCount());
        auto acc = many.grid->getConstAccessor();
        std::size_t differ = 0;
        for (int z = -1; z <= Z; ++z)
            for (int y = -1; y <= Y; ++y)
                for (int x = -1; x <= X; ++x) {
                    const Coord c(x, y, z);
                    differ += acc.getValue(c) != oneAcc.getValue(c) || acc.isValueOn(c) != oneAcc.isValueOn(c);
                }
        CHECK(differ == 0);
    }
}

TEST_CASE("VolumeSources: an interrupter stops loading", "[sources][interrupt]")
{
    struct StopNow : openvdb::util::NullInterrupter {
        bool wasInterrupted(int) override { return true; }
    } stop;
    CHECK_THROWS_AS(isouq::loadVolume(request("field:tangle"), &stop), isouq::InterruptedError);
}

// ---- Errors: each a clear single line ------------------------------------------------------

TEST_CASE("VolumeSources: error for a missing file", "[sources][errors]")
{
    CHECK_THAT(inputError(request("/nonexistent/dir/a_4x4x4_uint8.raw")), Contains("no such file"));
    CHECK_THAT(inputError(request("/nonexistent/dir/a.vdb")), Contains("no such file"));
    CHECK_THAT(inputError(request("/nonexistent/volume.xyz")), Contains("no such file"));
}

TEST_CASE("VolumeSources: error for an empty file", "[sources][errors]")
{
    TempDir dir;
    writeBytes(dir / "e.vdb", {});
    writeBytes(dir / "e_2x2x2_uint8.raw", {});
    CHECK_THAT(inputError(request(dir / "e.vdb")), Contains("is empty"));
    CHECK_THAT(inputError(request(dir / "e_2x2x2_uint8.raw")), Contains("is empty"));
}

TEST_CASE("VolumeSources: error for a truncated .vdb", "[sources][errors][vdb][data]")
{
    TempDir dir;
    const std::vector<unsigned char> bytes = readBytes(dataPath("sphere.vdb"));
    const std::size_t cut = GENERATE(4, 10, 100, 200, 500, 1000, 50000, 500000, 829635);
    REQUIRE(cut < bytes.size());
    const std::string path = dir / "cut.vdb";
    writeBytes(path, std::vector<unsigned char>(bytes.begin(), bytes.begin() + long(cut)));
    INFO("truncated at " << cut);
    const std::string message = inputError(request(path));
    CHECK((message.find("truncated") != std::string::npos || message.find("not a VDB") != std::string::npos));
}

#ifdef __linux__
/// Resident kB of this process's mappings of @a path (/proc/self/smaps), found by device and inode.
long mappedResidentKb(const std::string& path)
{
    struct stat st {};
    REQUIRE(::stat(path.c_str(), &st) == 0);
    std::ifstream smaps("/proc/self/smaps");
    long kb = 0;
    bool ours = false;
    for (std::string line; std::getline(smaps, line);) {
        unsigned long long begin = 0, end = 0, inode = 0;
        unsigned devMajor = 0, devMinor = 0;
        if (std::sscanf(line.c_str(), "%llx-%llx %*s %*s %x:%x %llu", &begin, &end, &devMajor, &devMinor, &inode) == 5)
            ours = inode == st.st_ino && devMajor == major(st.st_dev) && devMinor == minor(st.st_dev);
        else if (ours && line.rfind("Rss:", 0) == 0)
            kb += std::stol(line.substr(4));
    }
    return kb;
}

TEST_CASE("VolumeSources: a delay-loaded .vdb gives back its mapped pages and still reads right",
    "[sources][vdb][mpi]")
{
    // An MPI rank maps the file (delayed loading) and, once its leaves are loaded, drops the
    // mapped pages (releaseMappedPages): its memory is then its leaves, not also the file.
    TempDir dir;
    openvdb::initialize();
    const auto truth =
        openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(60.0f, openvdb::Vec3f(0.5f), 1.0f, 3.0f);
    truth->setName("ls");
    const std::string path = dir / "sphere.vdb";
    {
        openvdb::io::File file(path);
        file.setCompression(openvdb::io::COMPRESS_NONE); // 2 KB of values a leaf in the file
        file.write({truth});
    }
    VolumeRequest r = request(path);
    r.delayLoad = true;
    const isouq::LoadedVolume volume = isouq::loadVolume(r);
    const auto& tree = volume.grid->tree();
    REQUIRE(tree.leafCount() == truth->tree().leafCount());
    REQUIRE(tree.leafCount() > 1000);
    // Load the first half of the leaves (an MPI rank's own), as a rank's scan does.
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    tree.getNodes(leaves);
    const std::size_t half = leaves.size() / 2;
    auto sameAsTruth = [&](std::size_t from, std::size_t to) {
        std::size_t differ = 0;
        const auto truthAccess = truth->getConstAccessor();
        for (std::size_t l = from; l < to; ++l)
            for (auto v = leaves[l]->cbeginValueAll(); v; ++v)
                differ += *v != truthAccess.getValue(v.getCoord());
        return differ;
    };
    CHECK(sameAsTruth(0, half) == 0);
    const long before = mappedResidentKb(path);
    CHECK(before >= long(half) * 2 * 4 / 5); // about 2 KB a loaded leaf, in whole pages

    isouq::releaseMappedPages(path);
    CHECK(mappedResidentKb(path) == 0);
    CHECK(sameAsTruth(0, half) == 0);              // the loaded leaves kept their copies
    // The others still load from the mapping (their pages fault in again); once every leaf is
    // loaded, OpenVDB unmaps the file.
    const std::size_t threeQuarters = leaves.size() * 3 / 4;
    CHECK(sameAsTruth(half, threeQuarters) == 0);
    CHECK(mappedResidentKb(path) > 0);
    CHECK(sameAsTruth(threeQuarters, leaves.size()) == 0);
    isouq::releaseMappedPages(dir / "not-there.vdb"); // nothing to release: no error
}
#endif

TEST_CASE("VolumeSources: error for a .vdb without a float grid names the grids", "[sources][errors][vdb]")
{
    TempDir dir;
    openvdb::initialize();
    auto vectors = openvdb::Vec3SGrid::create();
    vectors->setName("velocity");
    vectors->tree().setValue(Coord(1, 2, 3), openvdb::Vec3s(1, 0, 0));
    auto mask = openvdb::BoolGrid::create();
    mask->setName("mask");
    mask->tree().setValue(Coord(0), true);
    openvdb::io::File(dir / "nofloat.vdb").write({vectors, mask});
    const std::string message = inputError(request(dir / "nofloat.vdb"));
    CHECK_THAT(message, Contains("no float grid"));
    CHECK_THAT(message, Contains("velocity (vec3s)"));
    CHECK_THAT(message, Contains("mask (bool)"));

    VolumeRequest r = request(dir / "nofloat.vdb");
    r.gridName = "mask";
    CHECK_THAT(inputError(r), Contains("'mask'") && Contains("is bool"));
    r.gridName = "nope";
    CHECK_THAT(inputError(r), Contains("named 'nope'") && Contains("velocity (vec3s)"));
}

TEST_CASE("VolumeSources: error for a raw size that mismatches its name", "[sources][errors][raw]")
{
    TempDir dir;
    writeBytes(dir / "a_4x4x4_uint8.raw", std::vector<unsigned char>(63));
    CHECK_THAT(inputError(request(dir / "a_4x4x4_uint8.raw", 0.5f)),
        Contains("63 bytes") && Contains("4x4x4 uint8 needs 64"));
    writeBytes(dir / "b_4x4x4_float32.raw", std::vector<unsigned char>(64));
    CHECK_THAT(inputError(request(dir / "b_4x4x4_float32.raw", 0.5f)), Contains("needs 256"));
}

TEST_CASE("VolumeSources: error for X*Y*Z overflow", "[sources][errors][raw]")
{
    TempDir dir;
    const std::string path = dir / "name_4000000000x4000000000x4000000000_uint8.raw";
    writeBytes(path, {1});
    CHECK_THAT(inputError(request(path)), Contains("overflows"));
}

TEST_CASE("VolumeSources: error for a raw name without dims or dtype", "[sources][errors][raw]")
{
    TempDir dir;
    writeBytes(dir / "scan.raw", std::vector<unsigned char>(8));
    CHECK_THAT(inputError(request(dir / "scan.raw")), Contains("name_XxYxZ_dtype.raw"));
    writeBytes(dir / "s_2x2x2_int32.raw", std::vector<unsigned char>(32));
    CHECK_THAT(inputError(request(dir / "s_2x2x2_int32.raw")), Contains("unknown raw dtype 'int32'"));
}

TEST_CASE("VolumeSources: error for an isovalue outside the data range", "[sources][errors]")
{
    TempDir dir;
    writeBytes(dir / "vol_5x4x3_int16.raw", int16Bytes());
    const std::string message = inputError(request(dir / "vol_5x4x3_int16.raw", 300.0f));
    CHECK_THAT(message, Contains("isovalue 300") && Contains("[-150, 84]"));
    // k = min: every voxel is >= k, no surface
    CHECK_THAT(inputError(request(dir / "vol_5x4x3_int16.raw", -150.0f)), Contains("no surface"));
    CHECK_THAT(inputError(request("field:sphere", std::numeric_limits<float>::quiet_NaN())),
        Contains("not finite"));
}

TEST_CASE("VolumeSources: error for an unknown field name", "[sources][errors][field]")
{
    CHECK_THAT(inputError(request("field:donut")),
        Contains("unknown field 'donut'") && Contains("tangle") && Contains("marschner-lobb"));
}

TEST_CASE("VolumeSources: error for a bad formula says where", "[sources][errors][formula]")
{
    const std::string message = inputError(request("formula:x^2+"));
    CHECK_THAT(message, Contains("cannot parse formula 'x^2+' at character 5"));
    CHECK_THAT(inputError(request("formula:x+w")), Contains("at character 3 ('w')"));
}

TEST_CASE("VolumeSources: error for a formula that is NaN in the domain", "[sources][errors][formula]")
{
    VolumeRequest r = request("formula:sqrt(x)");
    r.resolution = 9;
    const std::string message = inputError(r);
    CHECK_THAT(message, Contains("not finite") && Contains("x=-1") && Contains("voxel 0,0,0"));
    r.input = "formula:1/(x*x+y*y+z*z)"; // inf at the centre voxel (4,4,4)
    CHECK_THAT(inputError(r), Contains("inf") && Contains("voxel 4,4,4"));
}

TEST_CASE("VolumeSources: error for a bad resolution or domain", "[sources][errors][field]")
{
    VolumeRequest r = request("field:tangle");
    r.resolution = 1;
    CHECK_THAT(inputError(r), Contains("--resolution"));
    r = request("formula:x");
    r.domain = std::make_pair(1.0, -1.0);
    CHECK_THAT(inputError(r), Contains("--domain"));
}

TEST_CASE("VolumeSources: a NaN in a float32 raw stays in a leaf for the input checks",
    "[sources][raw][diagnostics]")
{
    TempDir dir;
    std::vector<unsigned char> bytes;
    for (int n = 0; n < 27; ++n) {
        const float v = n == 13 ? std::numeric_limits<float>::quiet_NaN() : float(n % 3); // x
        std::uint32_t bits;
        std::memcpy(&bits, &v, 4);
        for (int b = 0; b < 4; ++b) bytes.push_back(static_cast<unsigned char>(bits >> (8 * b)));
    }
    const std::string path = dir / "nan_3x3x3_float32.raw";
    writeBytes(path, bytes);
    const KeepBlocks keep = GENERATE(KeepBlocks::Crossing, KeepBlocks::CrossingOrHidden,
        KeepBlocks::NonConstant);
    const isouq::LoadedVolume v = isouq::loadVolume(request(path, 1.5f, keep));
    CHECK(v.keptBlocks == 1);
    CHECK(std::isnan(v.grid->tree().getValue(Coord(1, 1, 1))));
    CHECK_THAT(isouq::checkScalarVolume(*v.grid, v.isovalue),
        Contains("1 active non-finite") && Contains("[1, 1, 1]"));
}

TEST_CASE("VolumeSources: meshes of the sparse grid equal meshes of the dense one",
    "[sources][sparse][mesh][data]")
{
    const std::string input = GENERATE(std::string("field:tangle"), std::string("field:marschner-lobb"),
        dataPath("engine_256x256x128_uint8.raw"));
    const bool uncertainty = GENERATE(false, true);
    std::vector<std::array<float, 3>> positions[2];
    std::size_t triangles[2];
    for (int dense = 0; dense < 2; ++dense) {
        VolumeRequest r = request(input, std::nullopt, dense ? KeepBlocks::All : KeepBlocks::Crossing);
        const isouq::LoadedVolume v = isouq::loadVolume(r);
        isouq::MeshSettings settings;
        settings.isovalue = v.isovalue;
        settings.uncertainty = uncertainty;
        const isouq::Mesh mesh = isouq::extractIsosurface(*v.grid, settings);
        for (const openvdb::Vec3s& p : mesh.positions) positions[dense].push_back({p[0], p[1], p[2]});
        std::sort(positions[dense].begin(), positions[dense].end());
        triangles[dense] = mesh.triangles.size();
    }
    INFO(input << (uncertainty ? " with uncertainty" : ""));
    CHECK(!positions[0].empty());
    CHECK(triangles[0] == triangles[1]);
    CHECK(positions[0] == positions[1]); // bit for bit, as multisets
}
