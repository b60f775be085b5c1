// Hostile but fair input (issue 14; SPEC §8, §10 "Errors"): every case of the probe that broke
// the contract, and more. Each ends in one "isouq: error:" line and exit 2 (or 128 + signal),
// with no file at the output names and no temporary left, or in a correct success.
#include "CliHarness.h"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <thread>
#include <tuple>

using namespace isouq_test;

namespace {

/// One error line, exit 2, that mentions @a mustMention; none of @a outputs exists afterwards.
void requireRefused(const CliResult& r, const std::string& mustMention, const std::vector<fs::path>& outputs)
{
    INFO("stderr: " << (r.stderrLines.empty() ? std::string() : r.stderrLines[0]));
    CHECK(r.status == 2);
    REQUIRE(r.stderrLines.size() == 1);
    CHECK(r.stderrLines[0].rfind("isouq: error: ", 0) == 0);
    CHECK(r.stderrLines[0].find(mustMention) != std::string::npos);
    for (const fs::path& p : outputs) CHECK_FALSE(fs::exists(p));
}

void requireNoTemporaries(const fs::path& dir)
{
    for (const auto& entry : fs::recursive_directory_iterator(dir))
        CHECK(entry.path().filename().string().find(".tmp") == std::string::npos);
}

void writeGrid(const fs::path& path, openvdb::FloatGrid::Ptr grid)
{
    openvdb::io::File((path).string()).write({grid});
}

} // namespace

TEST_CASE("CLI hostile: two names of one output are one output", "[cli][hostile]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    fs::create_directories(dir / "sub");
    fs::create_directory_symlink(dir, dir / "link");
    const std::string mesh = "mesh field:sphere -n 16 -q -o out.ply ";
    for (const std::string& second : std::vector<std::string>{"--summary ./out.ply", "--summary sub/../out.ply",
             "--summary " + quote(dir / "out.ply"), "--summary link/out.ply", "--hidden-out ./out.ply",
             "--save-graph ./out.ply"}) {
        INFO(second);
        requireRefused(runCli(mesh + second, dir), "out.ply", {dir / "out.ply"});
    }
    requireNoTemporaries(dir);
}

TEST_CASE("CLI hostile: an output that is the input is refused, the input kept", "[cli][hostile]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const std::string original = readFile(std::string(ISOUQ_DATA_DIR) + "/bucky_32x32x32_uint8.raw");
    writeFile(dir / "bucky_32x32x32_uint8.raw", original);
    // A mesh output that names the input is refused by its extension first (.ply or .vtp only).
    for (const auto& [args, why] : std::vector<std::pair<std::string, std::string>>{
             {"-o bucky_32x32x32_uint8.raw", "not a mesh format"},
             {"-o x.ply --summary ./bucky_32x32x32_uint8.raw", "input"},
             {"-o x.ply --hidden-out bucky_32x32x32_uint8.raw", "not a mesh format"}}) {
        INFO(args);
        requireRefused(runCli("mesh bucky_32x32x32_uint8.raw -k 51 -q " + args, dir), why, {dir / "x.ply"});
        CHECK(readFile(dir / "bucky_32x32x32_uint8.raw") == original);
    }
}

TEST_CASE("CLI hostile: wrong successes are errors now", "[cli][hostile]")
{
    openvdb::initialize();
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const fs::path out = dir / "out.ply";
    SECTION("a level set whose background is NaN")
    {
        auto grid = openvdb::FloatGrid::create(std::numeric_limits<float>::quiet_NaN());
        grid->setGridClass(openvdb::GRID_LEVEL_SET);
        for (int i = 0; i < 8; ++i) grid->tree().setValueOn(openvdb::Coord(i, 0, 0), float(i) - 3.5f);
        writeGrid(dir / "nan.vdb", grid);
        requireRefused(runCli("mesh nan.vdb -q -o out.ply", dir), "background", {out});
    }
    SECTION("a spacing that puts vertices beyond float32")
    {
        requireRefused(runCli("mesh " + quote(std::string(ISOUQ_DATA_DIR) + "/bucky_32x32x32_uint8.raw") +
                                  " -k 51 --spacing 1,1,1e300 -q -o out.ply",
                           dir),
            "float32", {out});
    }
    SECTION("an empty number") { requireRefused(runCli("mesh field:sphere --isovalue '' -q -o out.ply", dir), "--isovalue", {out}); }
    SECTION("a NaN isovalue, or one beyond float32, is named as given")
    {
        requireRefused(runCli("mesh field:sphere --isovalue nan -q -o out.ply", dir), "finite number, got nan", {out});
        requireRefused(runCli("mesh field:sphere --isovalue 1e40 -q -o out.ply", dir), "1e+40 is beyond float32", {out});
    }
    SECTION("an integer beyond 64 bits is named as given, not as the largest long long")
    {
        requireRefused(runCli("mesh field:sphere --resolution 99999999999999999999 -q -o out.ply", dir),
            "--resolution: 99999999999999999999 is beyond the range of a 64-bit integer", {out});
        requireRefused(runCli("mesh " + quote(std::string(ISOUQ_DATA_DIR) + "/bucky_32x32x32_uint8.raw") +
                                  " --dims 18446744073709551616,1,1 -q -o out.ply",
                           dir),
            "--dims: 18446744073709551616 is beyond", {out});
    }
    SECTION("a raw scan with no cell")
    {
        writeFile(dir / "flat_2x2x1_uint8.raw", std::string("\1\2\3\4", 4));
        requireRefused(runCli("mesh flat_2x2x1_uint8.raw -q -o out.ply", dir), "nothing to mesh", {out});
    }
    SECTION("constant data with the default isovalue")
    {
        writeFile(dir / "const_8x8x8_uint8.raw", std::string(512, '\7'));
        requireRefused(runCli("mesh const_8x8x8_uint8.raw -q -o out.ply", dir), "no default isovalue", {out});
        auto grid = openvdb::FloatGrid::create(0.5f);
        grid->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(20)), 0.5f, true);
        grid->setName("flat");
        writeGrid(dir / "const.vdb", grid);
        requireRefused(runCli("mesh const.vdb -q -o out.ply", dir), "no default isovalue", {out});
    }
    SECTION("a progress delay that is not a number of seconds")
    {
        for (const char* delay : {"abc", "-1", "10s", "nan", "1e300"})
            requireRefused(runCli("mesh field:sphere -q -o out.ply", dir,
                               std::string("ISOUQ_PROGRESS_SECONDS=") + quote(delay) + " " + ISOUQ_CLI),
                "ISOUQ_PROGRESS_SECONDS", {out});
        // Set but empty is unset, as for most variables.
        CHECK(runCli("mesh field:sphere --resolution 16 -q -o out.ply", dir, "ISOUQ_PROGRESS_SECONDS= " ISOUQ_CLI).status == 0);
        CHECK(fs::exists(out));
    }
    SECTION("a graph path with an embedded NUL")
    {
        writeFile(dir / "g.json", R"({"nodes": [{"id": "r", "type": "read_volume", "parms": {"input": "field:sphere"}},
            {"id": "m", "type": "mesh", "inputs": {"volume": "r"}},
            {"id": "w", "type": "write_ply", "inputs": {"mesh": "m"}, "parms": {"path": "a\u0000b.ply"}}]})");
        requireRefused(runCli("run g.json -q", dir), "NUL", {dir / "a", dir / "a\\u0000b.ply"});
    }
}

TEST_CASE("CLI hostile: a fog volume above the threshold meshes where it meets the background", "[cli][hostile]")
{
    // Blender smoke: every active voxel is above k, the background (0) below (issue 11).
    openvdb::initialize();
    TempDir tmp;
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    grid->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(15)), 0.5f, true);
    writeGrid(tmp.path / "smoke.vdb", grid);
    const CliResult r = runCli("mesh smoke.vdb -k 0.05 -q -o out.ply --summary s.json", tmp.path);
    REQUIRE(r.status == 0);
    const std::string summary = readFile(tmp.path / "s.json");
    CHECK(summary.find("\"boundary_edges\": 0") != std::string::npos);
    CHECK(summary.find("\"components\": 1") != std::string::npos);
}

TEST_CASE("CLI hostile: user strings cannot split the error line", "[cli][hostile]")
{
    openvdb::initialize();
    TempDir tmp;
    const fs::path& dir = tmp.path;
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName("den\nsity");
    grid->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(9)), 1.0f, true);
    writeGrid(dir / "nl.vdb", grid);
    requireRefused(runCli("mesh nl.vdb --grid " + quote("x\ny") + " -q -o out.ply", dir), "x\\ny", {dir / "out.ply"});
    requireRefused(runCli("mesh " + quote("field:sp\nhere") + " -q -o out.ply", dir), "sp\\nhere", {dir / "out.ply"});
    requireRefused(runCli("mesh " + quote("bad\r\n.vdb") + " -q -o out.ply", dir), "bad\\r\\n.vdb", {dir / "out.ply"});
    // Bytes that are not UTF-8 (a Latin-1 name) and C1 controls are escaped; UTF-8 stays as it is.
    requireRefused(runCli("mesh " + quote("caf\xe9.vdb") + " -q -o out.ply", dir), "caf\\xe9.vdb", {dir / "out.ply"});
    requireRefused(runCli("mesh " + quote("csi\xc2\x9b.vdb") + " -q -o out.ply", dir), "csi\\xc2\\x9b.vdb", {dir / "out.ply"});
    requireRefused(runCli("mesh " + quote("caf\xc3\xa9.vdb") + " -q -o out.ply", dir), "caf\xc3\xa9.vdb", {dir / "out.ply"});
    writeFile(dir / "g.json", R"({"nodes": [{"id": "a\nb", "type": "nope"}]})");
    requireRefused(runCli("run g.json -q", dir), "a\\nb", {});
    writeFile(dir / "v.json", R"({"nodes": [{"id": "r", "type": "read_volume", "parms": {"input": "${ISOUQ_NL}"}},
        {"id": "m", "type": "mesh", "inputs": {"volume": "r"}}]})");
    const CliResult env = runCli("run v.json -q", dir); // ISOUQ_NL unset: an error naming it
    requireRefused(env, "ISOUQ_NL", {});
    ::setenv("ISOUQ_NL", "field:\nsphere", 1);
    requireRefused(runCli("run v.json -q", dir), "'\\nsphere'", {});
    ::unsetenv("ISOUQ_NL");
    // A long user string is echoed only in part.
    const CliResult longFormula = runCli("mesh 'formula:x+" + std::string(100000, 'q') + "' -q -o out.ply", dir);
    requireRefused(longFormula, "more characters", {dir / "out.ply"});
    CHECK(longFormula.stderrLines[0].size() < 1200);
}

TEST_CASE("CLI hostile: graphs that once crashed or hung", "[cli][hostile]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    writeFile(dir / "deep1.json", std::string(100000, '['));
    std::string objects;
    for (int i = 0; i < 100000; ++i) objects += "{\"a\":";
    writeFile(dir / "deep2.json", objects);
    requireRefused(runCli("run deep1.json -q", dir), "nested deeper", {});
    requireRefused(runCli("run deep2.json -q", dir), "nested deeper", {});
    REQUIRE(::mkfifo((dir / "fifo.json").c_str(), 0600) == 0);
    requireRefused(runCli("run fifo.json -q", dir), "not a regular file", {});

    // 60k chained nodes: linear in the node count (it was cubic: 4k nodes took 57 s).
    std::string chain = R"({"nodes": [{"id": "r", "type": "read_volume", "parms": {"input": "field:sphere", "resolution": 16}},
        {"id": "n0", "type": "mesh", "inputs": {"volume": "r"}})";
    const int n = 60000;
    for (int i = 1; i < n; ++i)
        chain += ",\n{\"id\": \"n" + std::to_string(i) + "\", \"type\": \"box_select\", \"inputs\": {\"mesh\": \"n" +
            std::to_string(i - 1) + "\"}}";
    chain += ",\n{\"id\": \"w\", \"type\": \"write_ply\", \"inputs\": {\"mesh\": \"n" + std::to_string(n - 1) +
        "\"}, \"parms\": {\"path\": \"chain.ply\"}}]}";
    writeFile(dir / "chain.json", chain);
    const auto start = std::chrono::steady_clock::now();
    CHECK(runCli("run chain.json -q", dir).status == 0);
    CHECK(std::chrono::steady_clock::now() - start < std::chrono::seconds(60));
    CHECK(fs::exists(dir / "chain.ply"));

    // run -d: relative outputs stay inside the folder.
    writeFile(dir / "up.json", R"({"nodes": [{"id": "r", "type": "read_volume", "parms": {"input": "field:sphere"}},
        {"id": "m", "type": "mesh", "inputs": {"volume": "r"}},
        {"id": "w", "type": "write_ply", "inputs": {"mesh": "m"}, "parms": {"path": "../escaped.ply"}}]})");
    fs::create_directories(dir / "outdir");
    requireRefused(runCli("run up.json -d outdir -q", dir), "leaves the output folder", {dir / "escaped.ply"});
}

TEST_CASE("CLI hostile: a legal long output name works", "[cli][hostile]")
{
    TempDir tmp;
    const std::string name = std::string(246, 'n') + ".ply"; // 250 bytes, NAME_MAX is 255
    REQUIRE(runCli("mesh field:sphere -n 16 -q -o " + name, tmp.path).status == 0);
    CHECK(fs::exists(tmp.path / name));
    requireNoTemporaries(tmp.path);
}

TEST_CASE("CLI hostile: a small file that implies a mesh larger than memory is refused", "[cli][hostile]")
{
    // One active 2048^3 tile: 25M vertices, about 2.5 GB, under a 2 GB address-space limit
    // (AddressSanitizer reserves terabytes of shadow address space: no limit applies there).
#if defined(__SANITIZE_ADDRESS__)
    WARN("skipped under AddressSanitizer");
    return;
#endif
    openvdb::initialize();
    TempDir tmp;
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(2047)), 1.0f, true);
    writeGrid(tmp.path / "tile.vdb", grid);
    REQUIRE(fs::file_size(tmp.path / "tile.vdb") < 100000);
    const CliResult r = runCli("-c 'ulimit -v 2000000; exec " + std::string(ISOUQ_CLI) +
                                   " mesh tile.vdb -k 0.5 -q -o out.ply'",
        tmp.path, "bash");
    requireRefused(r, "memory available", {tmp.path / "out.ply"});
}

TEST_CASE("CLI hostile: a file size limit is a full disk, not a crash", "[cli][hostile]")
{
    // `ulimit -f` (bash: 1024-byte blocks) lets 100 kB of the 1.3 MB PLY through; SIGXFSZ used to
    // end the process with its temporary file left behind.
    TempDir tmp;
    const CliResult r = runCli("-c 'ulimit -f 100; exec " + std::string(ISOUQ_CLI) +
                                   " mesh field:sphere -n 64 -q -o out.ply --summary s.json'",
        tmp.path, "bash");
    requireRefused(r, "File too large", {tmp.path / "out.ply", tmp.path / "s.json"});
    requireNoTemporaries(tmp.path);
}

namespace {

/// Waits (at most 60 s) until process @a pid catches SIGINT, SIGTERM and SIGHUP (SigCgt in
/// /proc/PID/status): a signal sent before the CLI set its handlers would kill it outright, and
/// a sanitized CLI on a busy machine can take seconds to get there.
bool catchesSignals(pid_t pid)
{
    const std::uint64_t wanted = (1ull << (SIGINT - 1)) | (1ull << (SIGTERM - 1)) | (1ull << (SIGHUP - 1));
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < deadline) {
        std::ifstream status("/proc/" + std::to_string(pid) + "/status");
        for (std::string line; std::getline(status, line);)
            if (line.rfind("SigCgt:", 0) == 0 && (std::stoull(line.substr(7), nullptr, 16) & wanted) == wanted)
                return true;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
}

} // namespace

TEST_CASE("CLI hostile: SIGTERM, SIGHUP and a second SIGINT clean up", "[cli][hostile][signals]")
{
    TempDir tmp;
    for (const auto& [first, second] : {std::pair{SIGTERM, 0}, std::pair{SIGHUP, 0}, std::pair{SIGINT, SIGINT}}) {
        INFO("signal " << first << " then " << second);
        // Long enough to be caught mid-run on any machine: the full pass on tangle at 400^3.
        const pid_t pid = ::fork();
        REQUIRE(pid >= 0);
        if (pid == 0) {
            const std::string out = (tmp.path / "big.ply").string(), s = (tmp.path / "big.json").string();
            ::execl(ISOUQ_CLI, ISOUQ_CLI, "mesh", "field:tangle", "-n", "400", "-q", "-o", out.c_str(), "--summary",
                s.c_str(), static_cast<char*>(nullptr));
            std::_Exit(127);
        }
        REQUIRE(catchesSignals(pid));
        std::this_thread::sleep_for(std::chrono::milliseconds(1000)); // into the run
        ::kill(pid, first);
        if (second) {
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
            ::kill(pid, second);
        }
        int status = 0;
        ::waitpid(pid, &status, 0);
        REQUIRE(WIFEXITED(status));
        CHECK(WEXITSTATUS(status) == 128 + first);
        CHECK_FALSE(fs::exists(tmp.path / "big.ply"));
        CHECK_FALSE(fs::exists(tmp.path / "big.json"));
        requireNoTemporaries(tmp.path);
    }
}

// ---- Scans with headers, folders and sequences (SPEC §10 "Formats", "Sequences", "Errors") ----
// Files written here byte by byte from the formats' documents (NIfTI-1 header, TIFF 6.0, DICOM
// PS3.5/PS3.10, teem's NRRD format page), so each can lie in exactly one field.

namespace {

template <typename T>
void put(std::string& bytes, std::size_t at, T value)
{
    if (bytes.size() < at + sizeof(T)) bytes.resize(at + sizeof(T), '\0');
    std::memcpy(&bytes[at], &value, sizeof(T));
}

/// A NIfTI-1 single file (.nii) header, little-endian, int16, voxel sizes only, with dims
/// @a nx @a ny @a nz, vox_offset 352 and no data.
std::string niftiHeader(std::int16_t nx, std::int16_t ny, std::int16_t nz, float voxOffset = 352.0f)
{
    std::string h(352, '\0');
    put<std::int32_t>(h, 0, 348);                  // sizeof_hdr
    const std::int16_t dim[8] = {3, nx, ny, nz, 1, 1, 1, 1};
    for (int i = 0; i < 8; ++i) put<std::int16_t>(h, 40 + 2 * i, dim[i]);
    put<std::int16_t>(h, 70, 4);                   // datatype DT_INT16
    put<std::int16_t>(h, 72, 16);                  // bitpix
    for (int i = 0; i < 8; ++i) put<float>(h, 76 + 4 * i, 1.0f); // pixdim
    put<float>(h, 108, voxOffset);
    h.replace(344, 4, std::string("n+1\0", 4));
    return h;
}

/// A little-endian TIFF of @a pages 8-bit grey pages sharing the given tags (tag, type, value;
/// one value each) and the pixels @a pixels after the directories; with @a loop the last
/// directory points back to the first.
std::string tiff(std::vector<std::tuple<std::uint16_t, std::uint16_t, std::uint32_t>> tags, const std::string& pixels,
    int pages = 2, bool loop = false)
{
    std::string t("II*\0\x08\0\0\0", 8);
    const std::uint32_t size = 2 + 12 * std::uint32_t(tags.size()) + 4, data = 8 + std::uint32_t(pages) * size;
    std::sort(tags.begin(), tags.end());
    for (int p = 0; p < pages; ++p) {
        const std::uint32_t ifd = 8 + std::uint32_t(p) * size;
        put<std::uint16_t>(t, ifd, std::uint16_t(tags.size()));
        for (std::size_t i = 0; i < tags.size(); ++i) {
            auto [tag, type, value] = tags[i];
            if (tag == 273 || tag == 324) value = data; // StripOffsets, TileOffsets: the pixels
            const std::size_t at = ifd + 2 + 12 * i;
            put<std::uint16_t>(t, at, tag);
            put<std::uint16_t>(t, at + 2, type);
            put<std::uint32_t>(t, at + 4, 1);
            if (type == 3) put<std::uint16_t>(t, at + 8, std::uint16_t(value));
            else put<std::uint32_t>(t, at + 8, value);
        }
        put<std::uint32_t>(t, ifd + size - 4, p + 1 < pages ? ifd + size : loop ? 8 : 0); // the next directory
    }
    return t + pixels;
}

/// One DICOM element, explicit VR little endian (PS3.5 7.1.2), the value padded to even length.
std::string element(std::uint16_t group, std::uint16_t elem, const char* vr, std::string value)
{
    if (value.size() % 2) value += (std::string(vr) == "UI" || std::string(vr) == "OB") ? '\0' : ' ';
    std::string e;
    put(e, 0, group);
    put(e, 2, elem);
    e += vr;
    const std::string longForm[] = {"OB", "OW", "SQ", "UN", "UT"};
    if (std::find(std::begin(longForm), std::end(longForm), vr) != std::end(longForm)) {
        e += std::string(2, '\0');
        put<std::uint32_t>(e, 8, std::uint32_t(value.size()));
    } else {
        put<std::uint16_t>(e, 6, std::uint16_t(value.size()));
    }
    return e + value;
}

std::string us(std::uint16_t v) { return std::string(reinterpret_cast<const char*>(&v), 2); }

/// A CT slice of @a rows x @a columns uint16 at z = @a z of series @a series (PS3.10 file:
/// preamble, DICM, file meta information, data set); @a pixels defaults to a ramp.
std::string dicomSlice(const std::string& series, double z, std::uint16_t rows = 4, std::uint16_t columns = 5,
    std::string pixels = "")
{
    if (pixels.empty())
        for (int i = 0; i < rows * columns; ++i) pixels += us(std::uint16_t(i * 10 + z * 3));
    const std::string ct = "1.2.840.10008.5.1.4.1.1.2", uid = "1.2.3.4." + std::to_string(int(z * 10));
    std::string meta = element(0x0002, 0x0001, "OB", std::string("\0\1", 2)) + element(0x0002, 0x0002, "UI", ct) +
        element(0x0002, 0x0003, "UI", uid) + element(0x0002, 0x0010, "UI", "1.2.840.10008.1.2.1");
    std::string length;
    put<std::uint32_t>(length, 0, std::uint32_t(meta.size()));
    const std::string zText = std::to_string(z);
    return std::string(128, '\0') + "DICM" + element(0x0002, 0x0000, "UL", length) + meta +
        element(0x0008, 0x0016, "UI", ct) + element(0x0008, 0x0018, "UI", uid) + element(0x0008, 0x0060, "CS", "CT") +
        element(0x0020, 0x000d, "UI", "1.2.3") + element(0x0020, 0x000e, "UI", series) +
        element(0x0020, 0x0032, "DS", "0\\0\\" + zText) + element(0x0020, 0x0037, "DS", "1\\0\\0\\0\\1\\0") +
        element(0x0028, 0x0002, "US", us(1)) + element(0x0028, 0x0004, "CS", "MONOCHROME2") +
        element(0x0028, 0x0010, "US", us(rows)) + element(0x0028, 0x0011, "US", us(columns)) +
        element(0x0028, 0x0030, "DS", "1\\1") + element(0x0028, 0x0100, "US", us(16)) +
        element(0x0028, 0x0101, "US", us(16)) + element(0x0028, 0x0102, "US", us(15)) +
        element(0x0028, 0x0103, "US", us(0)) + element(0x7fe0, 0x0010, "OW", pixels);
}

/// A detached NRRD header for a 6x5x4 uchar volume whose `data file:` is @a dataFile.
std::string nhdr(const std::string& dataFile, const std::string& encoding = "raw", const std::string& sizes = "6 5 4")
{
    return "NRRD0004\ntype: uchar\ndimension: 3\nsizes: " + sizes + "\nencoding: " + encoding + "\ndata file: " +
        dataFile + "\n";
}

/// 6x5x4 uchar ramp: a surface at 60.
std::string ramp()
{
    std::string v;
    for (int i = 0; i < 6 * 5 * 4; ++i) v += char(i);
    return v;
}

/// Runs the CLI under `timeout 60`, so a hang fails the test instead of the suite.
CliResult runTimed(const std::string& args, const fs::path& dir, const std::string& env = "")
{
    return runCli("-c " + quote(env + " exec timeout 60 " + std::string(ISOUQ_CLI) + " " + args), dir, "bash");
}

} // namespace

TEST_CASE("CLI hostile: a raw scan's memory check counts the threads -j gives", "[cli][hostile]")
{
    // 1024^2 uint8 slices: each thread's sparsifier is counted as 34.6 MB (Sparsify.cc
    // sparsifierBytes: 32 bytes per sample of a slice, and the columns' summaries). Under a
    // 50 MB budget one fits and two do not: -j 1 meshes, -j 2 is refused before reading.
    if (std::thread::hardware_concurrency() < 2) {
        WARN("skipped: one core, so -j 2 runs one sparsifier");
        return;
    }
    TempDir tmp;
    const int n = 1024, nz = 8;
    std::string voxels(std::size_t(n) * n * nz, '\0');
    for (int z = 2; z < 6; ++z)
        for (int y = 0; y < 16; ++y)
            for (int x = 0; x < 16; ++x) voxels[(std::size_t(z) * n + y) * n + x] = char(200);
    writeFile(tmp.path / "slab_1024x1024x8_uint8.raw", voxels);
    const fs::path out = tmp.path / "out.ply";
    const CliResult one = runTimed("mesh slab_1024x1024x8_uint8.raw -k 100 -j 1 -q -o out.ply", tmp.path,
        "ISOUQ_MEMORY_LIMIT_MB=50");
    INFO("stderr: " << (one.stderrLines.empty() ? std::string() : one.stderrLines[0]));
    CHECK(one.status == 0);
    CHECK(fs::exists(out));
    fs::remove(out);
    requireRefused(runTimed("mesh slab_1024x1024x8_uint8.raw -k 100 -j 2 -q -o out.ply", tmp.path,
                       "ISOUQ_MEMORY_LIMIT_MB=50"),
        "memory available", {out});
}

TEST_CASE("CLI hostile: NIfTI headers that lie", "[cli][hostile][nifti]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const fs::path out = dir / "out.ply";
    SECTION("dimensions of 32000^2 in a 60-byte .nii.gz: refused before allocating")
    {
        writeFile(dir / "huge.nii", niftiHeader(32000, 32000, 3) + std::string(64, '\0'));
        REQUIRE(std::system(("gzip -n " + quote(dir / "huge.nii")).c_str()) == 0);
        requireRefused(runTimed("mesh huge.nii.gz -q -o out.ply", dir, "ISOUQ_MEMORY_LIMIT_MB=512"), "memory available", {out});
    }
    SECTION("a header announcing more data than the file holds")
    {
        writeFile(dir / "short.nii", niftiHeader(64, 64, 64) + std::string(100, '\1'));
        requireRefused(runTimed("mesh short.nii -q -o out.ply", dir), "truncated", {out});
    }
    SECTION("a vox_offset past the end of the file")
    {
        writeFile(dir / "offset.nii", niftiHeader(2, 2, 2, 1e9f) + std::string(16, '\1'));
        requireRefused(runTimed("mesh offset.nii -q -o out.ply", dir), "truncated", {out});
    }
    SECTION("one slice: no cell, nothing to mesh")
    {
        writeFile(dir / "slice.nii", niftiHeader(4, 4, 1) + std::string(32, '\1'));
        requireRefused(runTimed("mesh slice.nii -k 1 -q -o out.ply", dir), "nothing to mesh", {out});
    }
    SECTION("a negative dimension")
    {
        writeFile(dir / "negative.nii", niftiHeader(-5, 2, 2) + std::string(64, '\1'));
        requireRefused(runTimed("mesh negative.nii -q -o out.ply", dir), "negative.nii", {out});
    }
    requireNoTemporaries(dir);
}

TEST_CASE("CLI hostile: detached NRRD data files", "[cli][hostile][nrrd]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const fs::path out = dir / "out.ply";
    fs::create_directories(dir / "scan");
    writeFile(dir / "scan" / "ramp.raw", ramp());
    auto refused = [&](const std::string& name, const std::string& header, const std::string& expected) {
        writeFile(dir / "scan" / (name + ".nhdr"), header);
        requireRefused(runTimed("mesh scan/" + name + ".nhdr -k 60 -q -o out.ply", dir), expected, {out});
    };
    SECTION("a FIFO: refused at once, not waited on")
    {
        REQUIRE(::mkfifo((dir / "scan" / "fifo").c_str(), 0600) == 0);
        refused("fifo", nhdr("fifo"), "not a regular file");
    }
    SECTION("the header itself a FIFO or /dev/zero, behind a NRRD name")
    {
        REQUIRE(::mkfifo((dir / "scan" / "head.nhdr").c_str(), 0600) == 0);
        requireRefused(runTimed("mesh scan/head.nhdr -q -o out.ply", dir), "not a regular file", {out});
        fs::create_symlink("/dev/zero", dir / "scan" / "zero.nrrd");
        requireRefused(runTimed("mesh scan/zero.nrrd -q -o out.ply", dir), "not a regular file", {out});
    }
    SECTION("a header of one 17 MiB line")
    {
        writeFile(dir / "scan" / "long.nhdr", "NRRD0004\n# " + std::string(17u << 20, 'x') + "\n");
        requireRefused(runTimed("mesh scan/long.nhdr -q -o out.ply", dir), "longer than 16 MiB", {out});
    }
    SECTION("/dev/zero")
    {
        refused("zero", nhdr("/dev/zero"), "not a regular file");
    }
    SECTION("a folder")
    {
        refused("folder", nhdr("."), "not a regular file");
    }
    SECTION("a missing file")
    {
        refused("missing", nhdr("nowhere.raw"), "missing");
    }
    SECTION("a LIST with a FIFO among the files")
    {
        REQUIRE(::mkfifo((dir / "scan" / "fifo").c_str(), 0600) == 0);
        refused("list", nhdr("LIST 2") + "ramp.raw\nfifo\n", "not a regular file");
    }
    SECTION("a pattern with %s and %n (teem would hand it to sprintf)")
    {
        refused("format", nhdr("%s%n%d 1 4 1 2"), "must hold one %d");
    }
    SECTION("a pattern naming two billion files")
    {
        refused("many", nhdr("s%03d.raw -2000000000 2000000000 1 2"), "name 1 to 1000000 files");
    }
    SECTION("a data file outside the header's folder is read (the NRRD format allows any path)")
    {
        writeFile(dir / "outside.raw", ramp());
        writeFile(dir / "scan" / "up.nhdr", nhdr("../outside.raw"));
        REQUIRE(runTimed("mesh scan/up.nhdr -k 60 -q -o out.ply", dir).status == 0);
        CHECK(fs::file_size(out) > 0);
    }
    SECTION("sizes of 10^6 x 10^6 in gzip: refused before allocating")
    {
        writeFile(dir / "scan" / "big.gz", "");
        writeFile(dir / "scan" / "big.nhdr", nhdr("big.gz", "gzip", "1000000 1000000 2"));
        requireRefused(runTimed("mesh scan/big.nhdr -k 60 -q -o out.ply", dir), "memory available", {out});
    }
    SECTION("ascii data of 20000^3 that teem would decode whole: refused before allocating")
    {
        writeFile(dir / "scan" / "text.txt", "1 2 3\n");
        writeFile(dir / "scan" / "text.nhdr", nhdr("text.txt", "ascii", "20000 20000 20000"));
        requireRefused(runTimed("mesh scan/text.nhdr -k 60 -q -o out.ply", dir), "memory available", {out});
    }
    requireNoTemporaries(dir);
}

TEST_CASE("CLI hostile: no output may replace a file an input reads", "[cli][hostile]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    writeFile(dir / "mesh.vtp", ramp()); // a NRRD data file may have any name
    writeFile(dir / "scan.nhdr", nhdr("mesh.vtp"));
    for (const std::string& args : {std::string("-o mesh.vtp"), std::string("-o x.ply --summary mesh.vtp"),
             std::string("-o x.ply --save-graph ./mesh.vtp")}) {
        INFO(args);
        requireRefused(runTimed("mesh scan.nhdr -k 60 -q " + args, dir), "input", {dir / "x.ply"});
        CHECK(readFile(dir / "mesh.vtp") == ramp());
    }
    writeFile(dir / "ramp_6x5x4_uint8.raw", ramp());
    requireRefused(runTimed("mesh ramp_6x5x4_uint8.raw -k 60 -q -o x.ply --save-graph ramp_6x5x4_uint8.raw", dir),
        "input", {dir / "x.ply"});
    CHECK(readFile(dir / "ramp_6x5x4_uint8.raw") == ramp());
    fs::create_directories(dir / "series");
    writeFile(dir / "series" / "a.ply", dicomSlice("1.2.3.9", 0));
    writeFile(dir / "series" / "b.ply", dicomSlice("1.2.3.9", 2));
    const std::string slice = readFile(dir / "series" / "a.ply");
    requireRefused(runTimed("mesh series -k 30 -q -o series/a.ply", dir), "input", {});
    CHECK(readFile(dir / "series" / "a.ply") == slice);
}

TEST_CASE("CLI hostile: outputs a rename would get wrong", "[cli][hostile]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const std::string sphere = "mesh field:sphere --resolution 16 -q ";
    SECTION("a later output's name too long: the earlier output is kept")
    {
        writeFile(dir / "a.ply", "KEEP");
        const std::string longName(252, 'a');
        requireRefused(runCli(sphere + "-o a.ply --summary " + longName + ".json", dir), "too long", {});
        CHECK(readFile(dir / "a.ply") == "KEEP");
    }
    SECTION("a FIFO is refused, not replaced by a file")
    {
        REQUIRE(::mkfifo((dir / "f.ply").c_str(), 0600) == 0);
        requireRefused(runCli(sphere + "-o f.ply", dir), "not a regular file", {});
        struct stat st;
        REQUIRE(::lstat((dir / "f.ply").c_str(), &st) == 0);
        CHECK(S_ISFIFO(st.st_mode));
    }
    SECTION("a symbolic link is written through, with the file's permissions")
    {
        fs::create_directory(dir / "real");
        writeFile(dir / "real" / "mesh.ply", "old");
        fs::permissions(dir / "real" / "mesh.ply", fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read);
        fs::create_symlink("real/mesh.ply", dir / "link.ply");
        REQUIRE(runCli(sphere + "-o link.ply", dir).status == 0);
        CHECK(fs::is_symlink(dir / "link.ply"));
        CHECK(readFile(dir / "real" / "mesh.ply").rfind("ply\n", 0) == 0);
        CHECK(fs::status(dir / "real" / "mesh.ply").permissions() ==
              (fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read));
        requireNoTemporaries(dir);
    }
    SECTION("a link to a missing file is refused")
    {
        fs::create_symlink("nothere.ply", dir / "dangling.ply");
        requireRefused(runCli(sphere + "-o dangling.ply", dir), "missing file", {dir / "nothere.ply"});
    }
    SECTION("a graph that writes over its own file")
    {
        const std::string graph = R"({"nodes": [{"id": "r", "type": "read_volume", "parms": {"input": "field:sphere"}},
            {"id": "m", "type": "mesh", "inputs": {"volume": "r"}},
            {"id": "s", "type": "summary", "inputs": {"mesh": "m"}},
            {"id": "w", "type": "write_summary", "inputs": {"summary": "s"}, "parms": {"path": "./g.json"}}]})";
        writeFile(dir / "g.json", graph);
        requireRefused(runCli("run g.json -q", dir), "the graph file", {});
        CHECK(readFile(dir / "g.json") == graph);
    }
}

TEST_CASE("CLI hostile: TIFF directories that lie", "[cli][hostile][tiff]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const fs::path out = dir / "out.ply";
    using Tags = std::vector<std::tuple<std::uint16_t, std::uint16_t, std::uint32_t>>;
    const Tags grey = {{258, 3, 8}, {259, 3, 1}, {262, 3, 1}, {277, 3, 1}};
    auto with = [&](Tags extra) {
        extra.insert(extra.end(), grey.begin(), grey.end());
        return extra;
    };
    SECTION("a page of 2^30 x 2^30 pixels in 200 bytes: refused before allocating")
    {
        writeFile(dir / "huge.tif", tiff(with({{256, 4, 1u << 30}, {257, 4, 1u << 30}, {273, 4, 0}, {278, 4, 1u << 30},
                                          {279, 4, 1u << 30}}), std::string(64, '\1')));
        requireRefused(runTimed("mesh huge.tif -q -o out.ply", dir), "memory available", {out});
    }
    SECTION("tiles of 65536^2 on a 16x16 page: refused before allocating")
    {
        writeFile(dir / "tiles.tif", tiff(with({{256, 4, 16}, {257, 4, 16}, {322, 4, 65536}, {323, 4, 65536},
                                           {324, 4, 0}, {325, 4, 256}}), std::string(256, '\1')));
        requireRefused(runTimed("mesh tiles.tif -q -o out.ply", dir, "ISOUQ_MEMORY_LIMIT_MB=256"), "memory available", {out});
    }
    SECTION("one page: a 2-D image has no cell")
    {
        writeFile(dir / "flat.tif", tiff(with({{256, 4, 8}, {257, 4, 8}, {273, 4, 0}, {278, 4, 8}, {279, 4, 64}}),
                                        std::string(64, '\1'), 1));
        requireRefused(runTimed("mesh flat.tif -k 1 -q -o out.ply", dir), "nothing to mesh", {out});
    }
    SECTION("a directory chain that loops back on itself")
    {
        std::string pixels;
        for (int i = 0; i < 64; ++i) pixels += char(i * 4);
        writeFile(dir / "loop.tif", tiff(with({{256, 4, 8}, {257, 4, 8}, {273, 4, 0}, {278, 4, 8}, {279, 4, 64}}),
                                        pixels, 2, /*loop=*/true));
        requireRefused(runTimed("mesh loop.tif -k 100 -q -o out.ply", dir), "loop.tif", {out});
    }
    requireNoTemporaries(dir);
}

TEST_CASE("CLI hostile: DICOM folders", "[cli][hostile][dicom]")
{
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const fs::path out = dir / "out.ply";
    fs::create_directories(dir / "series");
    for (int k = 0; k < 3; ++k) writeFile(dir / "series" / ("s" + std::to_string(k)), dicomSlice("1.2.3.9", 2.0 * k));
    SECTION("two series mixed in one folder")
    {
        writeFile(dir / "series" / "x0", dicomSlice("1.2.3.8", 0.5));
        writeFile(dir / "series" / "x1", dicomSlice("1.2.3.8", 1.5));
        requireRefused(runTimed("mesh series -k 30 -q -o out.ply", dir), "2 DICOM series", {out});
    }
    SECTION("a FIFO and a device among the slices: ignored, every slice read, nothing waited on")
    {
        REQUIRE(::mkfifo((dir / "series" / "a_fifo").c_str(), 0600) == 0);
        fs::create_symlink("/dev/zero", dir / "series" / "b_zero");
        const CliResult r = runTimed("mesh series -k 30 -q -o out.ply --summary s.json", dir);
        REQUIRE(r.status == 0);
        CHECK(readFile(dir / "s.json").find("DICOM series of 3 slices") != std::string::npos);
    }
    SECTION("rows and columns of 65535 with 40 bytes of pixels")
    {
        fs::remove_all(dir / "series");
        fs::create_directories(dir / "series");
        for (int k = 0; k < 2; ++k)
            writeFile(dir / "series" / ("s" + std::to_string(k)), dicomSlice("1.2.3.9", k, 65535, 65535, std::string(40, '\1')));
        requireRefused(runTimed("mesh series -k 30 -q -o out.ply", dir), "series", {out});
    }
    SECTION("an element announcing 4 GB in a slice of 1 KB: refused before GDCM allocates it")
    {
        // fuzz_dicom's finding (fuzz/regressions/fuzz_dicom/gdcm_element_length_oom-*), rebuilt.
        std::string huge = element(0x7fe1, 0x0010, "OB", "");
        put<std::uint32_t>(huge, 8, 0xf1f2f3f4u);
        writeFile(dir / "series" / "s1", dicomSlice("1.2.3.9", 2.0) + huge + std::string(64, '\7'));
        requireRefused(runTimed("mesh series -k 30 -q -o out.ply", dir), "announces 4059231220 bytes", {out});
    }
    SECTION("2 samples per pixel: refused before GDCM asserts")
    {
        // fuzz_dicom's finding of 3 December (docs/hardening.md, Findings), rebuilt.
        std::string slice = dicomSlice("1.2.3.9", 2.0);
        const std::string samples("\x28\x00\x02\x00US\x02\x00\x01\x00", 10);
        const std::size_t at = slice.find(samples);
        REQUIRE(at != std::string::npos);
        slice[at + 8] = '\2';
        writeFile(dir / "series" / "s1", slice);
        requireRefused(runTimed("mesh series -k 30 -q -o out.ply", dir), "Samples per Pixel (0028,0002) is 2", {out});
    }
    SECTION("sequences nested 100 deep")
    {
        std::string nested;
        for (int k = 0; k < 100; ++k) {
            std::string sq = element(0x0008, 0x1115, "SQ", ""), item;
            put<std::uint32_t>(sq, 8, 0xffffffffu);
            put<std::uint16_t>(item, 0, 0xfffe);
            put<std::uint16_t>(item, 2, 0xe000);
            put<std::uint32_t>(item, 4, 0xffffffffu);
            nested += sq + item;
        }
        writeFile(dir / "series" / "s1", dicomSlice("1.2.3.9", 2.0) + nested);
        requireRefused(runTimed("mesh series -k 30 -q -o out.ply", dir), "nest deeper than 64", {out});
    }
    SECTION("a slice cut inside its pixels")
    {
        const std::string slice = dicomSlice("1.2.3.9", 2.0);
        writeFile(dir / "series" / "s1", slice.substr(0, slice.size() - 7));
        requireRefused(runTimed("mesh series -k 30 -q -o out.ply", dir), "are left", {out});
    }
    SECTION("an isouq without its GDCM module (GdcmServer.h) says so")
    {
        if (fs::exists(fs::path(ISOUQ_MODULE_INSTALLED) / "libisouq_gdcm.so")) return; // installed: found there
        // The program and its command line, in the installed layout, without the GDCM module.
        const fs::path modules = (dir / "bin" / ISOUQ_MODULE_FROM_BIN).lexically_normal();
        fs::create_directories(dir / "bin");
        fs::create_directories(modules);
        fs::copy_file(ISOUQ_CLI, dir / "bin" / "isouq");
        fs::copy_file(ISOUQ_CLI_MODULE_PATH, modules / fs::path(ISOUQ_CLI_MODULE_PATH).filename());
        const CliResult r = runCli("-c " + quote("exec timeout 60 bin/isouq mesh series -k 30 -q -o out.ply"), dir, "bash");
        requireRefused(r, "isouq's GDCM module libisouq_gdcm.so is in none of " + modules.string(), {out});
    }
    requireNoTemporaries(dir);
}

TEST_CASE("CLI hostile: an isouq without its command-line module says so", "[cli][hostile]")
{
    // CliModule.h: `isouq` loads libisouq_cli.so from bin/../lib/isouq, then from the install.
    if (fs::exists(fs::path(ISOUQ_MODULE_INSTALLED) / fs::path(ISOUQ_CLI_MODULE_PATH).filename())) return;
    TempDir tmp;
    const fs::path& dir = tmp.path;
    const fs::path prefix = dir / "pre\nfix"; // the message echoes the path: still one line
    fs::create_directories(prefix / "bin");
    fs::copy_file(ISOUQ_CLI, prefix / "bin" / "isouq");
    for (const std::string& args : {"--version", "mesh field:sphere -q -o out.ply"}) {
        INFO(args);
        const CliResult r = runCli("-c " + quote("exec timeout 60 \"$(printf \"pre\\nfix\")/bin/isouq\" " + args), dir, "bash");
        requireRefused(r, "libisouq_cli.so is in none of " + (dir / "pre\\nfix" / "bin" / ISOUQ_MODULE_FROM_BIN).string(),
            {dir / "out.ply"});
    }
    // A module that is not one: the loader's own words, still one line and exit 2.
    fs::create_directories(dir / "bin");
    fs::copy_file(ISOUQ_CLI, dir / "bin" / "isouq");
    const fs::path modules = (dir / "bin" / ISOUQ_MODULE_FROM_BIN).lexically_normal();
    fs::create_directories(modules);
    writeFile(modules / fs::path(ISOUQ_CLI_MODULE_PATH).filename(), "not a shared object\n");
    requireRefused(runCli("-c " + quote("exec timeout 60 bin/isouq --version"), dir, "bash"),
        "cannot start isouq's command line", {});
}

TEST_CASE("CLI hostile: sequence patterns and --frames", "[cli][hostile][sequence]")
{
    openvdb::initialize();
    TempDir tmp;
    const fs::path& dir = tmp.path;
    auto frame = [&](const std::string& name) {
        auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(3.0f, openvdb::Vec3f(0), 0.5f);
        writeGrid(dir / name, grid);
    };
    frame("s_0001.vdb");
    frame("s_0002.vdb");
    frame("s_1001.vdb");
    const std::string kept = readFile(dir / "s_1001.vdb");
    SECTION("--frames that are not A, A-B or A-B:STEP, or name no frame")
    {
        for (const std::string& frames : {"' 1-2'", "1--2", "2-1", "1-2:0", "99999999999", "1-2:", "-1-2"}) {
            INFO("--frames " << frames);
            requireRefused(runTimed("mesh s_####.vdb --frames " + frames + " -q -o o_####.ply", dir), "--frames", {});
        }
    }
    SECTION("an output pattern that is the input pattern")
    {
        requireRefused(runTimed("mesh s_####.vdb --frames 1-2 -q -o s_%04d.vdb", dir), "input", {});
    }
    SECTION("an output of frame 1 that is the input of frame 1001")
    {
        requireRefused(runTimed("mesh s_####.vdb --frames 1-1001:1000 -q -o s_1###.vdb", dir), "input", {});
        CHECK(readFile(dir / "s_1001.vdb") == kept);
    }
    SECTION("a summary that is an input frame")
    {
        requireRefused(runTimed("mesh s_####.vdb --frames 1-2 -q -o o_####.ply --summary s_0002.vdb", dir), "input",
            {dir / "o_0001.ply"});
    }
    SECTION("a padding width of 11 digits")
    {
        requireRefused(runTimed("mesh s_%099999999999d.vdb -q -o o_####.ply", dir), "1-9 digits", {});
    }
    SECTION("frames on disk spanning a billion numbers")
    {
        frame("s_999999999.vdb");
        requireRefused(runTimed("mesh s_####.vdb -q -o o_####.ply", dir), "give --frames", {});
    }
    CHECK(readFile(dir / "s_1001.vdb") == kept);
    CHECK_FALSE(fs::exists(dir / "o_0001.ply"));
    requireNoTemporaries(dir);
}
