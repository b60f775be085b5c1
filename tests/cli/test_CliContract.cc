// The command-line contract of SPEC §8, tested through the real binary: bad input gives one line
// "isouq: error: ...", exit status 2, no output file, and an existing output left untouched;
// the output does not depend on the thread count.
#include "CliHarness.h"

#include <isouq/MarchingCubes.h>

#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <sstream>

using namespace isouq_test;

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
