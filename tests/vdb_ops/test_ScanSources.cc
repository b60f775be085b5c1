// Tests of the scans with headers through isouq/VolumeSources.h (SPEC §10 "Formats";
// docs/inputs.md): a NRRD whose bytes the test writes from the format's documentation loads
// with every voxel's value and the header's affine as the grid transform, in either byte order;
// bad headers are one-line InputErrors. (tests/python/test_formats_in.py covers every format
// against files written by other libraries.)
#include <isouq/GridMetadata.h>
#include <isouq/VolumeSources.h>

#include "../TempDir.h"

#include <catch2/catch.hpp>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>

namespace fs = std::filesystem;
using isouq_test::TempDir;
using Catch::Matchers::Contains;

namespace {

constexpr int kNx = 19, kNy = 13, kNz = 11;

/// The test volume: a ball of radius 5 around (9, 6, 5), in whole numbers (int16 holds them).
std::int16_t value(int x, int y, int z)
{
    return std::int16_t(std::lround(100.0 - 4.0 * ((x - 9) * (x - 9) + (y - 6) * (y - 6) + (z - 5) * (z - 5))));
}

/// An attached NRRD, int16, with `space directions` (a shear included) and `space origin`.
void writeNrrd(const std::string& path, bool bigEndian, const std::string& headerExtra = "", std::size_t cut = 0)
{
    std::string bytes = "NRRD0004\ntype: short\ndimension: 3\nsizes: " + std::to_string(kNx) + " " + std::to_string(kNy)
        + " " + std::to_string(kNz) + "\nencoding: raw\nendian: " + (bigEndian ? "big" : "little")
        + "\nspace: right-anterior-superior\nspace directions: (0.5,0,0) (0.25,0.75,0) (0,0,2)\n"
          "space origin: (-10,20,30.5)\n" + headerExtra + "\n";
    for (int z = 0; z < kNz; ++z)
        for (int y = 0; y < kNy; ++y)
            for (int x = 0; x < kNx; ++x) {
                const auto v = std::uint16_t(value(x, y, z));
                const char lo = char(v & 0xff), hi = char(v >> 8);
                bytes += bigEndian ? std::string{hi, lo} : std::string{lo, hi};
            }
    std::ofstream(path, std::ios::binary) << bytes.substr(0, bytes.size() - cut);
}

std::string inputError(const isouq::VolumeRequest& request)
{
    try {
        isouq::loadVolume(request);
    } catch (const isouq::InputError& e) {
        return e.what();
    }
    return "(no InputError)";
}

} // namespace

TEST_CASE("ScanSources: a NRRD loads every voxel and its space as the grid transform", "[sources][nrrd]")
{
    const bool bigEndian = GENERATE(false, true);
    // A comment line of 5 bytes makes the data start at an odd byte once (SlabBuffer's other rule).
    const std::string comment = GENERATE(std::string(), std::string("#odd\n"));
    TempDir dir;
    writeNrrd(dir / "ball.nrrd", bigEndian, comment);
    isouq::VolumeRequest request;
    request.input = dir / "ball.nrrd";
    request.isovalue = 50.0f;
    request.keep = isouq::KeepBlocks::All;
    const isouq::LoadedVolume volume = isouq::loadVolume(request);
    CHECK(volume.grid->getName() == "ball");
    CHECK(volume.geometry == "NRRD space directions (right-anterior-superior)");
    CHECK_THAT(volume.description, Contains("ball.nrrd: NRRD int16 (raw)"));
    REQUIRE(isouq::dataBounds(*volume.grid) == openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(kNx - 1, kNy - 1, kNz - 1)));
    auto acc = volume.grid->getConstAccessor();
    bool allEqual = true;
    for (int z = 0; z < kNz; ++z)
        for (int y = 0; y < kNy; ++y)
            for (int x = 0; x < kNx; ++x) allEqual &= acc.getValue({x, y, z}) == float(value(x, y, z));
    CHECK(allEqual);
    // world = origin + i d0 + j d1 + k d2 with the header's directions.
    const openvdb::Vec3d w = volume.grid->transform().indexToWorld(openvdb::Vec3d(2, 3, 4));
    CHECK(w.x() == -10 + 2 * 0.5 + 3 * 0.25);
    CHECK(w.y() == 20 + 3 * 0.75);
    CHECK(w.z() == 30.5 + 4 * 2);
}

TEST_CASE("ScanSources: bad NRRD headers and data are one-line InputErrors", "[sources][nrrd]")
{
    TempDir dir;
    isouq::VolumeRequest request;
    request.isovalue = 50.0f;
    auto errorOf = [&](const std::string& name) {
        request.input = dir / name;
        const std::string message = inputError(request);
        CHECK(message.find('\n') == std::string::npos);
        return message;
    };
    writeNrrd(dir / "cut.nrrd", false, "", 100);
    CHECK_THAT(errorOf("cut.nrrd"), Contains("cannot read the data of"));
    writeNrrd(dir / "flat.nrrd", false, "space origin: (nan,0,0)\n");
    CHECK_THAT(errorOf("flat.nrrd"), Contains("not a readable NRRD file"));
    std::ofstream(dir / "singular.nrrd") << "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n"
                                            "endian: little\nspace: 3D-right-handed\nspace directions: (1,0,0) (2,0,0) (0,0,1)\n\n"
                                         << std::string(32, '\0');
    CHECK_THAT(errorOf("singular.nrrd"), Contains("unusable NRRD space directions"));
    writeNrrd(dir / "ok.nrrd", false);
    request.input = dir / "ok.nrrd";
    request.dtype = "uint8";
    CHECK_THAT(inputError(request), Contains("--dtype applies to .raw files; "));
    request.dtype.clear();
    request.spacing = openvdb::Vec3d(1.0);
    CHECK_THAT(inputError(request), Contains("--spacing applies to .raw files and TIFF stacks"));
    request.spacing.reset();
    request.input = (dir / "nothing.nrrd");
    CHECK_THAT(inputError(request), Contains("no such file"));
}

TEST_CASE("ScanSources: volumeInputFiles names what an input reads besides itself", "[sources][nrrd]")
{
    TempDir dir;
    auto names = [](std::vector<std::string> files) {
        std::vector<std::string> out;
        for (const std::string& f : files) out.push_back(fs::path(f).lexically_normal().string());
        std::sort(out.begin(), out.end());
        return out;
    };
    const std::string head = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n";
    std::ofstream(dir / "one.nhdr") << head << "data file: sub/../d.raw\n";
    CHECK(names(isouq::volumeInputFiles(dir / "one.nhdr")) == std::vector<std::string>{dir / "d.raw"});
    std::ofstream(dir / "abs.nhdr") << head << "datafile: /tmp/x.raw\n";
    CHECK(names(isouq::volumeInputFiles(dir / "abs.nhdr")) == std::vector<std::string>{"/tmp/x.raw"});
    // teem's pattern form: FORMAT MIN MAX STEP [SUBDIM]; and LIST, one name per line to the end.
    std::ofstream(dir / "pattern.nhdr") << head << "data file: s%02d.raw 3 -1 -2 2\n";
    CHECK(names(isouq::volumeInputFiles(dir / "pattern.nhdr")) ==
          std::vector<std::string>{dir / "s-1.raw", dir / "s01.raw", dir / "s03.raw"});
    std::ofstream(dir / "list.nhdr") << head << "data file: LIST 2\na.raw\nb.raw\n";
    CHECK(names(isouq::volumeInputFiles(dir / "list.nhdr")) == std::vector<std::string>{dir / "a.raw", dir / "b.raw"});
    std::ofstream(dir / "attached.nrrd") << head << "\n" << std::string(8, '\0');
    CHECK(isouq::volumeInputFiles(dir / "attached.nrrd").empty());
    // A bad pattern is the reader's error; here it only names nothing.
    std::ofstream(dir / "bad.nhdr") << head << "data file: %s%d 1 2 1\n";
    CHECK(isouq::volumeInputFiles(dir / "bad.nhdr").empty());
    isouq::VolumeRequest request;
    request.input = dir / "bad.nhdr";
    CHECK_THAT(inputError(request), Contains("must hold one %d"));
    // A folder: its regular files (slices), not its subfolders.
    fs::create_directories(dir.path / "series" / "sub");
    std::ofstream(dir / "series/IM1") << "x";
    std::ofstream(dir / "series/IM2") << "x";
    CHECK(names(isouq::volumeInputFiles(dir / "series")) == std::vector<std::string>{dir / "series/IM1", dir / "series/IM2"});
    CHECK(isouq::volumeInputFiles(dir / "nothing.vdb").empty());
}
