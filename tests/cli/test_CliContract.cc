// The command-line contract of SPEC §8, tested through the real binary: bad input gives one line
// "isouq: error: ...", exit status 2, no output file, and an existing output left untouched;
// the output does not depend on the thread count.
#include <isouq/MarchingCubes.h>

#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <sys/wait.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>

namespace fs = std::filesystem;

namespace {

struct CliResult {
    int status = -1;
    std::vector<std::string> stderrLines;
};

std::string quote(const std::string& s) { return "'" + s + "'"; }

CliResult runCli(const std::string& args, const fs::path& dir)
{
    const fs::path errFile = dir / "stderr.txt";
    const std::string command = std::string(ISOUQ_CLI) + " " + args + " > /dev/null 2> " + quote(errFile);
    const int raw = std::system(command.c_str());
    CliResult r;
    r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
    std::ifstream in(errFile);
    for (std::string line; std::getline(in, line);) r.stderrLines.push_back(line);
    return r;
}

std::string readFile(const fs::path& p)
{
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
}

void writeFile(const fs::path& p, const std::string& bytes)
{
    std::ofstream(p, std::ios::binary) << bytes;
}

struct TempDir {
    fs::path path;
    TempDir()
    {
        path = fs::temp_directory_path() / ("isouq-cli-" + std::to_string(::getpid()) + "-" +
                                            std::to_string(std::rand()));
        fs::create_directories(path);
    }
    ~TempDir() { fs::remove_all(path); }
};

/// Runs `isouq mesh INPUT_ARGS -o OUT` twice: with no output present (none may appear) and with
/// an existing output (it must stay byte-identical). Each run: exit 2, one "isouq: error:" line.
void requireCleanFailure(const std::string& inputArgs, const fs::path& dir, const std::string& mustMention)
{
    const fs::path out = dir / "out.ply";
    fs::remove(out);
    CliResult r = runCli("mesh " + inputArgs + " -q -o " + quote(out) + " --summary " + quote(dir / "s.json"), dir);
    INFO("isouq mesh " << inputArgs);
    CHECK(r.status == 2);
    REQUIRE(r.stderrLines.size() == 1);
    CHECK(r.stderrLines[0].rfind("isouq: error: ", 0) == 0);
    CHECK(r.stderrLines[0].find(mustMention) != std::string::npos);
    CHECK_FALSE(fs::exists(out));
    CHECK_FALSE(fs::exists(dir / "s.json"));
    writeFile(out, "precious");
    r = runCli("mesh " + inputArgs + " -q -o " + quote(out), dir);
    CHECK(r.status == 2);
    CHECK(readFile(out) == "precious");
    fs::remove(out);
    for (const auto& entry : fs::directory_iterator(dir)) // no temporary left behind
        CHECK(entry.path().filename().string().find(".tmp") == std::string::npos);
}

} // namespace

TEST_CASE("CLI: bad input gives one line, exit 2, and writes nothing", "[cli][errors]")
{
    openvdb::initialize();
    TempDir tmp;
    const fs::path dir = tmp.path;
    const std::string data = ISOUQ_DATA_DIR;

    SECTION("missing file") { requireCleanFailure(quote((dir / "nope.vdb").string()), dir, "nope.vdb"); }
    SECTION("empty file")
    {
        writeFile(dir / "empty.vdb", "");
        requireCleanFailure(quote((dir / "empty.vdb").string()), dir, "empty.vdb");
    }
    SECTION("truncated vdb")
    {
        const std::string whole = readFile(data + "/sphere.vdb");
        writeFile(dir / "cut.vdb", whole.substr(0, whole.size() / 2));
        requireCleanFailure(quote((dir / "cut.vdb").string()), dir, "cut.vdb");
    }
    SECTION("non-float grid")
    {
        auto vectors = openvdb::Vec3SGrid::create(openvdb::Vec3s(0));
        vectors->setName("velocity");
        vectors->tree().setValueOn(openvdb::Coord(1, 2, 3), openvdb::Vec3s(1, 0, 0));
        openvdb::io::File((dir / "vec.vdb").string()).write({vectors});
        requireCleanFailure(quote((dir / "vec.vdb").string()), dir, "velocity");
    }
    SECTION("raw size not matching its name")
    {
        writeFile(dir / "scan_4x4x4_uint8.raw", std::string(63, '\1'));
        requireCleanFailure(quote((dir / "scan_4x4x4_uint8.raw").string()), dir, "scan_4x4x4_uint8.raw");
    }
    SECTION("X*Y*Z overflows")
    {
        writeFile(dir / "huge_4000000000x4000000000x4000000000_uint8.raw", std::string(8, '\1'));
        requireCleanFailure(quote((dir / "huge_4000000000x4000000000x4000000000_uint8.raw").string()), dir, "huge");
    }
    SECTION("NaN and inf values")
    {
        std::vector<float> values(4 * 4 * 4, 1.0f);
        values[5] = std::nanf("");
        values[9] = INFINITY;
        writeFile(dir / "bad_4x4x4_float32.raw",
            std::string(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float)));
        requireCleanFailure(quote((dir / "bad_4x4x4_float32.raw").string()) + " --isovalue 0.5", dir, "");
    }
    SECTION("isovalue outside the data range")
    {
        requireCleanFailure(quote(data + "/bucky_32x32x32_uint8.raw") + " --isovalue 300", dir, "300");
    }
    SECTION("unwritable output path")
    {
        const CliResult r = runCli("mesh field:sphere -n 16 -q -o /nonexistent-dir/x.ply", dir);
        CHECK(r.status == 2);
        REQUIRE(r.stderrLines.size() == 1);
        CHECK(r.stderrLines[0].rfind("isouq: error: ", 0) == 0);
        CHECK(r.stderrLines[0].find("/nonexistent-dir/x.ply") != std::string::npos);
    }
    SECTION("unknown field") { requireCleanFailure("field:klein-bottle", dir, "klein-bottle"); }
    SECTION("bad formula") { requireCleanFailure("'formula:x^2+*y'", dir, "formula"); }
    SECTION("formula that is NaN in the domain") { requireCleanFailure("'formula:sqrt(x)' --domain -1,1", dir, ""); }
    SECTION("unknown method") { requireCleanFailure("field:sphere --method quartic", dir, "quartic"); }
    SECTION("subdivisions 0, negative or absurd (issue 4)")
    {
        for (const char* m : {"0", "-3", "100000"})
            requireCleanFailure(std::string("field:teardrop -n 16 --hidden-features --subdivisions ") + m, dir,
                "--subdivisions");
    }
}

TEST_CASE("CLI: the PLY is byte-identical whatever the thread count", "[cli][determinism]")
{
    TempDir tmp;
    for (const std::string input : {std::string("field:tangle -n 64"), quote(std::string(ISOUQ_DATA_DIR) + "/sphere.vdb")}) {
        INFO(input);
        REQUIRE(runCli("mesh " + input + " -q --threads 1 -o " + quote(tmp.path / "one.ply"), tmp.path).status == 0);
        REQUIRE(runCli("mesh " + input + " -q --threads 2 -o " + quote(tmp.path / "two.ply"), tmp.path).status == 0);
        const std::string one = readFile(tmp.path / "one.ply"), two = readFile(tmp.path / "two.ply");
        CHECK(one.size() > 10000);
        CHECK(one == two);
    }
}

TEST_CASE("CLI: sphere.vdb meshes to one closed sphere of radius 3", "[cli][data]")
{
    TempDir tmp;
    const fs::path summary = tmp.path / "s.json";
    const CliResult r = runCli("mesh " + quote(std::string(ISOUQ_DATA_DIR) + "/sphere.vdb") + " -q -o " +
                                   quote(tmp.path / "s.ply") + " --summary " + quote(summary),
        tmp.path);
    REQUIRE(r.status == 0);
    const std::string json = readFile(summary);
    CHECK(json.find("\"boundary_edges\": 0") != std::string::npos);
    CHECK(json.find("\"non_manifold_edges\": 0") != std::string::npos);
    CHECK(json.find("\"components\": 1") != std::string::npos);
}
