// Reader inputs that the fuzzers (fuzz/, docs/hardening.md) found mishandled, each rebuilt here
// from a valid file: every one must now be an InputError with one line, quickly, without
// OpenVDB reading on past what the file holds. The fuzzers' own inputs are in
// fuzz/regressions/ and replayed by scripts/fuzz.sh.
#include <isouq/Diagnostics.h>
#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>

#include <catch2/catch.hpp>
#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

namespace fs = std::filesystem;
using Catch::Matchers::Contains;

namespace {

struct TempFile {
    std::string path;
    explicit TempFile(const std::string& name)
        : path((fs::temp_directory_path() / ("isouq_readers_fuzz_" + std::to_string(::getpid()) + "_" + name)).string()) {}
    ~TempFile() { fs::remove(path); }
};

/// A valid one-grid level-set .vdb (no compression) as bytes.
std::vector<char> sphereVdb()
{
    openvdb::initialize();
    TempFile file("sphere.vdb");
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(4.0f, openvdb::Vec3f(0.0f), 1.0f, 2.0f);
    grid->setName("surface");
    openvdb::io::File out(file.path);
    out.setCompression(openvdb::io::COMPRESS_NONE);
    out.write({grid});
    out.close();
    std::ifstream in(file.path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

template <typename T>
void poke(std::vector<char>& bytes, std::size_t at, T value)
{
    REQUIRE(at + sizeof(T) <= bytes.size());
    std::memcpy(bytes.data() + at, &value, sizeof(T));
}

template <typename T>
T peek(const std::vector<char>& bytes, std::size_t at)
{
    T value;
    std::memcpy(&value, bytes.data() + at, sizeof(T));
    return value;
}

/// loadVolume's InputError message for @a bytes as a .vdb file ("" if it loads).
std::string loadError(const std::vector<char>& bytes)
{
    TempFile file("input.vdb");
    std::ofstream(file.path, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
    isouq::VolumeRequest request;
    request.input = file.path;
    try {
        isouq::loadVolume(request);
    } catch (const isouq::InputError& e) {
        return e.what();
    }
    return "";
}

// Header layout of file version 224: magic (8), version (4), library version (8), has
// offsets (1), UUID (36 characters), file metadata count (4), grid count (4), descriptors.
constexpr std::size_t kUuid = 21, kFileMeta = 57, kGridCount = 61, kDescriptor = 65;

} // namespace

TEST_CASE("ReadersFuzz: a valid sphere loads", "[sources][vdb][fuzz]")
{
    CHECK(loadError(sphereVdb()) == "");
}

TEST_CASE("ReadersFuzz: an unsigned file metadata count is walked as unsigned", "[sources][vdb][fuzz]")
{
    // Was: the walk took 0xffffffff as -1 entries, OpenVDB as 4 billion (a timeout).
    std::vector<char> bytes = sphereVdb();
    REQUIRE(peek<std::uint32_t>(bytes, kFileMeta) == 0);
    poke<std::uint32_t>(bytes, kFileMeta, 0xffffffffu);
    CHECK_THAT(loadError(bytes), Contains("truncated or corrupt"));
}

TEST_CASE("ReadersFuzz: a UUID with blanks is refused", "[sources][vdb][fuzz]")
{
    // OpenVDB parses the UUID as text and skips blanks, so its reads and the walk's would part.
    std::vector<char> bytes = sphereVdb();
    bytes[kUuid + 1] = ' ';
    CHECK_THAT(loadError(bytes), Contains("bad UUID"));
}

TEST_CASE("ReadersFuzz: a fixed-size metadata value must have its size", "[sources][vdb][fuzz]")
{
    // File metadata {"k": int32 of 100 bytes}: OpenVDB reads 4 and goes on from byte 5 of it.
    std::vector<char> bytes = sphereVdb();
    std::vector<char> entry;
    auto put32 = [&entry](std::uint32_t v) { entry.insert(entry.end(), reinterpret_cast<char*>(&v), reinterpret_cast<char*>(&v) + 4); };
    auto putString = [&](const std::string& s) { put32(std::uint32_t(s.size())); entry.insert(entry.end(), s.begin(), s.end()); };
    putString("k");
    putString("int32");
    put32(100);
    entry.resize(entry.size() + 100, '\0');
    poke<std::uint32_t>(bytes, kFileMeta, 1);
    bytes.insert(bytes.begin() + kFileMeta + 4, entry.begin(), entry.end());
    CHECK_THAT(loadError(bytes), Contains("metadata of type int32 holds 100 bytes"));
}

TEST_CASE("ReadersFuzz: a grid's own metadata count is walked", "[sources][vdb][fuzz]")
{
    std::vector<char> bytes = sphereVdb();
    REQUIRE(peek<std::int32_t>(bytes, kGridCount) == 1);
    std::size_t at = kDescriptor;
    for (int s = 0; s < 3; ++s) at += 4 + peek<std::uint32_t>(bytes, at); // name, type, parent
    const auto gridPos = std::size_t(peek<std::int64_t>(bytes, at));
    // compression flags (4), then the grid's metadata count
    poke<std::uint32_t>(bytes, gridPos + 4, 0x7fffffffu);
    CHECK_THAT(loadError(bytes), Contains("truncated or corrupt"));
}

TEST_CASE("ReadersFuzz: a raw ball at the origin meshes without undefined behaviour", "[sources][raw][fuzz]")
{
    // Was (UBSan, fuzz_raw): block origins made with Coord << 3, a left shift of the negative
    // coordinates of the blocks left of the data. Run under scripts/sanitize.sh to see it.
    TempFile file("ball_6x6x6_float32.raw");
    std::vector<float> values;
    for (int z = 0; z < 6; ++z)
        for (int y = 0; y < 6; ++y)
            for (int x = 0; x < 6; ++x)
                values.push_back(float(std::sqrt((x - 2.5) * (x - 2.5) + (y - 2.5) * (y - 2.5) + (z - 2.5) * (z - 2.5)) - 2.0));
    std::ofstream(file.path, std::ios::binary)
        .write(reinterpret_cast<const char*>(values.data()), std::streamsize(values.size() * sizeof(float)));
    isouq::VolumeRequest request;
    request.input = file.path;
    request.isovalue = 0.0f;
    const isouq::LoadedVolume volume = isouq::loadVolume(request);
    isouq::MeshSettings settings;
    settings.isovalue = 0.0f;
    settings.uncertainty = true;
    CHECK(isouq::extractIsosurface(*volume.grid, settings).triangles.size() > 0);
}

TEST_CASE("ReadersFuzz: a file format version the walk does not know is refused", "[sources][vdb][fuzz]")
{
    // Was: the walk left unknown versions to OpenVDB, which only warns and reads on; a 1 KB file
    // then asked for 4 GB descriptor strings.
    for (std::uint32_t version : {217u, 218u, 225u, 2784u, 1073742048u}) {
        std::vector<char> bytes = sphereVdb();
        poke<std::uint32_t>(bytes, 8, version);
        CHECK_THAT(loadError(bytes), Contains("VDB file format version " + std::to_string(version)));
    }
}

TEST_CASE("ReadersFuzz: a file without grid offsets is refused", "[sources][vdb][fuzz]")
{
    // Was: the walk stopped at the file metadata of such files, and OpenVDB read every grid
    // unchecked (4 GB strings in descriptors, metadata and transforms; long loops at the end).
    std::vector<char> bytes = sphereVdb();
    REQUIRE(bytes[20] == 1);
    bytes[20] = 0;
    CHECK_THAT(loadError(bytes), Contains("no grid offsets"));
}

TEST_CASE("ReadersFuzz: a delayed-load table is walked before OpenVDB allocates it", "[sources][vdb][fuzz]")
{
    // OpenVDB 10 writes "__delayedload" into every grid: a leaf count, the masks (a byte count,
    // 0 for the raw bytes), then the compressed sizes the same way (0xffffffff: none). fuzz_vdb's
    // 600-s run found a 12 KB file whose second byte count, 0xfffffffc, made OpenVDB allocate 4 GiB
    // (fuzz/regressions/fuzz_vdb/delayed_load_count_oom-*); here the same lie in a valid file.
    const std::vector<char> valid = sphereVdb();
    const std::string key = "__delayedload";
    const auto at = std::search(valid.begin(), valid.end(), key.begin(), key.end()) - valid.begin();
    REQUIRE(std::size_t(at) < valid.size());
    const std::size_t value = std::size_t(at) + key.size() + 4; // after the type name and the value's size
    const auto bytes = peek<std::uint32_t>(valid, value - 4), leaves = peek<std::uint32_t>(valid, value);
    REQUIRE(peek<std::uint32_t>(valid, value + 4) == 0); // raw masks, one byte per leaf (no compression)
    const std::size_t sizes = value + 8 + leaves;
    REQUIRE(sizes + 4 == value + bytes); // the sizes' byte count ends the value
    REQUIRE(peek<std::uint32_t>(valid, sizes) == 0xffffffffu); // no compressed sizes
    std::vector<char> hostile = valid;
    poke<std::uint32_t>(hostile, sizes, 0xfffffffcu); // compressed sizes of 4 GiB
    CHECK_THAT(loadError(hostile), Contains("delayed-load table (20 bytes) runs past its end"));
    hostile = valid;
    poke<std::uint32_t>(hostile, sizes, 0); // raw compressed sizes, 8 bytes per leaf, not there
    CHECK_THAT(loadError(hostile), Contains("runs past its end"));
    hostile = valid;
    poke<std::uint32_t>(hostile, value, 0x7fffffffu);
    CHECK_THAT(loadError(hostile), Contains("has 2147483647 leaves"));
    hostile = valid;
    poke<std::uint32_t>(hostile, value + 4, 4); // a blosc part of 4 bytes: blosc reads a 16-byte header
    CHECK_THAT(loadError(hostile), Contains("without its header"));
}

TEST_CASE("ReadersFuzz: every kind of transform OpenVDB writes is walked", "[sources][vdb][fuzz]")
{
    // The walk steps over the transform by its map's type (math/Maps.h read()); a wrong length
    // would shift the root behind it. OpenVDB's own writer is the truth here.
    using namespace openvdb::math;
    const openvdb::Mat4d rotation = openvdb::math::rotation<openvdb::Mat4d>(openvdb::Vec3d(1, 2, 3), 0.4);
    const std::vector<MapBase::Ptr> maps = {std::make_shared<UniformScaleMap>(0.5),
        std::make_shared<ScaleMap>(openvdb::Vec3d(0.5, 1.0, 2.0)), std::make_shared<TranslationMap>(openvdb::Vec3d(1, 2, 3)),
        std::make_shared<ScaleTranslateMap>(openvdb::Vec3d(0.5, 1.0, 2.0), openvdb::Vec3d(1, 2, 3)),
        std::make_shared<UniformScaleTranslateMap>(0.5, openvdb::Vec3d(1, 2, 3)),
        std::make_shared<AffineMap>(rotation), std::make_shared<UnitaryMap>(rotation),
        std::make_shared<NonlinearFrustumMap>(openvdb::BBoxd(openvdb::Vec3d(-8), openvdb::Vec3d(8)), 0.5, 2.0)};
    for (const auto& map : maps) {
        INFO(map->type());
        openvdb::initialize();
        TempFile file("transform.vdb");
        auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(4.0f, openvdb::Vec3f(0.0f), 1.0f, 2.0f);
        grid->setTransform(std::make_shared<Transform>(map));
        auto plain = openvdb::FloatGrid::create(1.0f); // a second grid after the first, as the walk reads on
        plain->setName("second");
        openvdb::io::File(file.path).write({grid, plain});
        std::ifstream in(file.path, std::ios::binary);
        CHECK(loadError({std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()}) == "");
    }
}

TEST_CASE("ReadersFuzz: a root that holds more than its grid's bytes is refused", "[sources][vdb][fuzz]")
{
    // Was: OpenVDB allocates a 270 KB node per announced root child before reading it, and only
    // warns about a buffer count other than 1: fuzz_vdb's 13 KB files took 42 s and 4.5 GB
    // (fuzz/regressions/fuzz_vdb/multi_buffer_root_children-*). The tree starts after the
    // sphere's transform: "UniformScaleMap" and its 5 vectors of 3 doubles.
    const std::vector<char> valid = sphereVdb();
    const std::string map = "UniformScaleMap";
    const auto at = std::search(valid.begin(), valid.end(), map.begin(), map.end()) - valid.begin();
    REQUIRE(std::size_t(at) < valid.size());
    const std::size_t buffers = std::size_t(at) + map.size() + 5 * 24, tiles = buffers + 8, children = tiles + 4;
    REQUIRE(peek<std::int32_t>(valid, buffers) == 1);
    REQUIRE(peek<float>(valid, buffers + 4) == 2.0f); // the background: half width 2 voxels
    std::vector<char> hostile = valid;
    poke<std::int32_t>(hostile, buffers, 0);
    CHECK_THAT(loadError(hostile), Contains("grid 'surface' has 0 buffers (OpenVDB reads 1)"));
    hostile = valid;
    poke<std::uint32_t>(hostile, children, 65536);
    CHECK_THAT(loadError(hostile), Contains("65536 root children, more than its bytes hold"));
    hostile = valid;
    poke<std::uint32_t>(hostile, tiles, 0xffffffffu);
    CHECK_THAT(loadError(hostile), Contains("4294967295 root tiles"));
}

TEST_CASE("ReadersFuzz: every committed fuzz_vdb input is one InputError line", "[sources][vdb][fuzz]")
{
    // fuzz/regressions/fuzz_vdb/ as they are (scripts/fuzz.sh replays them in the fuzzer too).
    // root_child_topology_leak-*: an internal node's tile values announce a 1632-byte chunk that
    // is not there; OpenVDB's RootNode::readTopology throws past the child it allocated, which
    // leaks (scripts/sanitizers/lsan.supp says why that one is OpenVDB's and suppressed).
    const fs::path folder = fs::path(ISOUQ_SOURCE_DIR) / "fuzz" / "regressions" / "fuzz_vdb";
    std::size_t files = 0;
    for (const auto& entry : fs::directory_iterator(folder)) {
        std::ifstream in(entry.path(), std::ios::binary);
        const std::vector<char> bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
        INFO(entry.path().filename().string());
        const std::string error = loadError(bytes);
        CHECK(!error.empty());
        CHECK(error.find('\n') == std::string::npos);
        ++files;
    }
    CHECK(files >= 14);
}

TEST_CASE("ReadersFuzz: every committed fuzz_dicom input is one InputError line", "[sources][dicom][fuzz]")
{
    // fuzz/regressions/fuzz_dicom/: a fuzzer input is up to 8 files split at ISOUQ-NEXT-FILE
    // (fuzz/FuzzCommon.h), written as a series folder. gdcm_*_segv-* and gdcm_*_assert-* crash
    // or abort Debian's GDCM itself (not always on the first read); GDCM runs in a child
    // process (vdb_ops/src/Quarantine.h), so they end as "crashed GDCM" or another one line.
    const fs::path folder = fs::path(ISOUQ_SOURCE_DIR) / "fuzz" / "regressions" / "fuzz_dicom";
    const std::string separator = "ISOUQ-NEXT-FILE";
    std::size_t files = 0;
    for (const auto& entry : fs::directory_iterator(folder)) {
        std::ifstream in(entry.path(), std::ios::binary);
        std::string rest{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
        const TempFile series("series"); // a name only: the folder goes with remove_all below
        std::error_code ec;
        fs::remove_all(series.path, ec);
        fs::create_directory(series.path);
        for (int part = 0; part < 8; ++part) {
            const std::size_t at = part < 7 ? rest.find(separator) : std::string::npos;
            std::ofstream(series.path + "/slice" + std::to_string(part) + ".dcm", std::ios::binary) << rest.substr(0, at);
            if (at == std::string::npos) break;
            rest.erase(0, at + separator.size());
        }
        INFO(entry.path().filename().string());
        for (int run = 0; run < 3; ++run) {
            isouq::VolumeRequest request;
            request.input = series.path;
            std::string error;
            try {
                isouq::loadVolume(request);
            } catch (const isouq::InputError& e) {
                error = e.what();
            } catch (const std::exception& e) {
                FAIL_CHECK("not an InputError: " << e.what());
            }
            CHECK(!error.empty());
            CHECK(error.find('\n') == std::string::npos);
        }
        fs::remove_all(series.path, ec);
        ++files;
    }
    CHECK(files >= 11);
}
