// Tests of isouq/MeshIO.h: header and body bytes against the layout of docs/ply-format.md
// assembled by hand, exact round trips, an independent numpy/meshio reader, atomic writes
// under real failures, and malformed input.
#include <isouq/MeshIO.h>

#include "../TempDir.h"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <cinttypes>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <thread>

namespace fs = std::filesystem;
using isouq_test::TempDir;
using isouq::IoError;
using isouq::Mesh;

namespace {

std::string readBytes(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

void writeBytes(const std::string& path, const std::string& bytes)
{
    std::ofstream(path, std::ios::binary) << bytes;
}

/// The message of the IoError that @a f throws.
template <typename F>
std::string ioErrorOf(F&& f)
{
    try {
        f();
    } catch (const IoError& e) {
        return e.what();
    }
    return "(no IoError)";
}

/// "io" for IoError, "ok" for success, anything else is a bug.
std::string readOutcome(const std::string& path)
{
    try {
        isouq::readPly(path);
        return "ok";
    } catch (const IoError&) {
        return "io";
    } catch (const std::exception& e) {
        return std::string("other: ") + e.what();
    }
}

template <typename T>
bool sameBits(const std::vector<T>& a, const std::vector<T>& b)
{
    // memcmp of empty vectors would pass null pointers (UB, caught by UBSan's nonnull-attribute)
    return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

bool sameColumns(const isouq::AttributeTable& a, const isouq::AttributeTable& b)
{
    if (a.columns().size() != b.columns().size()) return false;
    for (std::size_t c = 0; c < a.columns().size(); ++c) {
        const auto &x = a.columns()[c], &y = b.columns()[c];
        if (x.name != y.name || x.data.index() != y.data.index()) return false;
        const bool same = std::visit(
            [&](const auto& v) { return sameBits(v, std::get<std::decay_t<decltype(v)>>(y.data)); }, x.data);
        if (!same) return false;
    }
    return true;
}

/// @a r and @a info, read back from a file written from @a m with @a options, hold it exactly.
void checkReadBack(const Mesh& r, const Mesh& m, const isouq::PlyInfo& info, const isouq::MeshFileOptions& options)
{
    CHECK(sameBits(r.positions, m.positions));
    CHECK(sameBits(r.triangles, m.triangles));
    CHECK(sameColumns(r.vertexAttributes, m.vertexAttributes));
    CHECK(sameColumns(r.faceAttributes, m.faceAttributes));
    CHECK(std::memcmp(r.indexToWorld.data(), m.indexToWorld.data(), sizeof(m.indexToWorld)) == 0);
    CHECK(info.version == options.version);
    CHECK(info.isovalue == options.isovalue);
    CHECK(info.method == options.method);
    CHECK(info.hasIndexToWorld);
    CHECK(info.comments == options.comments);
}

/// A mesh with every SPEC §6 column, special floats included.
Mesh fullMesh(std::size_t nv, std::size_t nf, unsigned seed)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-100.f, 100.f);
    Mesh m;
    for (std::size_t v = 0; v < nv; ++v) m.positions.emplace_back(u(rng), u(rng), u(rng));
    for (std::size_t f = 0; f < nf; ++f)
        m.triangles.emplace_back(rng() % nv, rng() % nv, rng() % nv);
    const float specials[] = {0.f, -0.f, std::numeric_limits<float>::quiet_NaN(),
        std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
        std::numeric_limits<float>::denorm_min(), std::numeric_limits<float>::max(), 0.1f};
    for (const char* name : {"t_linear", "t_cubic", "t_weno"}) {
        auto& col = m.vertexAttributes.add<float>(name, nv);
        for (auto& x : col) x = u(rng);
    }
    for (const char* name : {"edge_i", "edge_j", "edge_k"}) {
        auto& col = m.vertexAttributes.add<std::int32_t>(name, nv);
        for (auto& x : col) x = static_cast<std::int32_t>(rng());
        if (nv > 1) col[0] = std::numeric_limits<std::int32_t>::min(), col[1] = -1;
    }
    for (const char* name : {"edge_axis", "order"}) {
        auto& col = m.vertexAttributes.add<std::uint8_t>(name, nv);
        for (auto& x : col) x = static_cast<std::uint8_t>(rng());
    }
    for (const char* name : {"err_est", "err_bound", "d_lc", "d_lw", "d_cw", "max_var",
             "err_true_linear", "err_true_cubic", "err_true_weno"}) {
        auto& col = m.vertexAttributes.add<float>(name, nv);
        for (std::size_t v = 0; v < nv; ++v) col[v] = v < 8 ? specials[v] : u(rng);
    }
    auto& hidden = m.vertexAttributes.add<std::uint8_t>("hidden", nv);
    for (auto& x : hidden) x = static_cast<std::uint8_t>(rng() % 2);
    if (nv > 0) hidden[0] = 255;
    auto& faceHidden = m.faceAttributes.add<std::uint8_t>("hidden", nf);
    for (auto& x : faceHidden) x = static_cast<std::uint8_t>(rng() % 2);
    m.indexToWorld = {0.1, 1.0 / 3.0, -2.5e-300, 7, 0, 0.7, 0, -1e300, 0, 0, 0.25, 3.5, 0, 0, 0, 1};
    return m;
}

/// Little-endian bytes of a value, assembled by shifting, not by memcpy.
std::string le32(std::uint32_t v)
{
    std::string s;
    for (int i = 0; i < 4; ++i) s += static_cast<char>((v >> (8 * i)) & 0xff);
    return s;
}
std::string be32(std::uint32_t v)
{
    std::string s;
    for (int i = 3; i >= 0; --i) s += static_cast<char>((v >> (8 * i)) & 0xff);
    return s;
}

} // namespace

TEST_CASE("MeshIO: header and body bytes are exactly the documented layout", "[io][ply]")
{
    Mesh m;
    m.positions = {{1, 2, 3}, {-1.5f, 0, 0.5f}};
    m.triangles = {{0, 1, 0}};
    m.vertexAttributes.add<float>("t_linear", 2) = {0.5f, 2.0f};
    m.vertexAttributes.add<std::int32_t>("edge_i", 2) = {-2, 258};
    m.vertexAttributes.add<std::uint8_t>("edge_axis", 2) = {2, 255};
    m.faceAttributes.add<std::uint8_t>("hidden", 1) = {1};
    m.indexToWorld = {0.5, 0, 0, 10, 0, 0.5, 0, 20, 0, 0, 0.5, 30, 0, 0, 0, 1};
    isouq::PlyOptions options;
    options.version = "0.1.0";
    options.isovalue = 0.1f;
    options.method = "weno";
    options.comments = {"made by test"};

    TempDir dir;
    isouq::writePly(m, dir / "m.ply", options);
    const std::string header = "ply\n"
                               "format binary_little_endian 1.0\n"
                               "comment isouq version 0.1.0\n"
                               "comment isouq index_to_world 0.5 0 0 10 0 0.5 0 20 0 0 0.5 30 0 0 0 1\n"
                               "comment isouq isovalue 0.1\n"
                               "comment isouq method weno\n"
                               "comment made by test\n"
                               "element vertex 2\n"
                               "property float x\n"
                               "property float y\n"
                               "property float z\n"
                               "property float t_linear\n"
                               "property int edge_i\n"
                               "property uint8 edge_axis\n"
                               "element face 1\n"
                               "property list uchar int vertex_indices\n"
                               "property uint8 hidden\n"
                               "end_header\n";
    // IEEE-754 single: 1 = 3f800000, 2 = 40000000, 3 = 40400000, 0.5 = 3f000000,
    // -1.5 = bfc00000; int -2 = fffffffe, 258 = 00000102.
    const std::string body = le32(0x3f800000) + le32(0x40000000) + le32(0x40400000) +
        le32(0x3f000000) + le32(0xfffffffe) + std::string(1, '\x02') +
        le32(0xbfc00000) + le32(0) + le32(0x3f000000) + le32(0x40000000) + le32(258) +
        std::string(1, '\xff') + std::string(1, '\x03') + le32(0) + le32(1) + le32(0) +
        std::string(1, '\x01');
    CHECK(readBytes(dir / "m.ply") == header + body);
    CHECK(dir.list() == std::vector<std::string>{"m.ply"});
}

TEST_CASE("MeshIO: round trip of every SPEC §6 attribute type is exact, through PLY and VTP", "[io][ply][vtp]")
{
    const std::size_t nv = GENERATE(0, 1, 9, 100000);
    const Mesh m = fullMesh(nv, nv == 0 ? 0 : 2 * nv, 7);
    isouq::PlyOptions options;
    options.version = "0.1.0";
    options.isovalue = -0.001f;
    options.method = "weno-paper";
    options.comments = {"isouq source field:tangle", "free text  with  spaces", "a <comment> & \"quotes\""};
    TempDir dir;
    isouq::writePly(m, dir / "m.ply", options);
    isouq::writeVtp(m, dir / "m.vtp", options);

    isouq::PlyInfo info, vtpInfo;
    checkReadBack(isouq::readPly(dir / "m.ply", &info), m, info, options);
    CHECK(info.format == "binary_little_endian");
    checkReadBack(isouq::readVtp(dir / "m.vtp", &vtpInfo), m, vtpInfo, options);
    CHECK(vtpInfo.format == "vtp");
}

TEST_CASE("MeshIO: an independent numpy and meshio reader parses writePly output",
    "[io][ply][python]")
{
    const std::string script = std::string(ISOUQ_SOURCE_DIR) + "/tests/python/test_ply_format.py";
    if (std::system("/usr/bin/python3 -c 'import numpy, pytest' 2>/dev/null") != 0) {
        WARN("skipped: /usr/bin/python3 with numpy and pytest is not available");
        return;
    }
    const bool withFaceColumn = GENERATE(true, false);
    Mesh m = fullMesh(50, 80, 11);
    if (!withFaceColumn) m.faceAttributes.clear();
    TempDir dir;
    isouq::writePly(m, dir / "m.ply");

    const std::string command = "/usr/bin/python3 " + script + " --dump " + (dir / "m.ply");
    std::FILE* pipe = ::popen(command.c_str(), "r");
    REQUIRE(pipe);
    std::string text;
    char buf[4096];
    for (std::size_t n; (n = std::fread(buf, 1, sizeof(buf), pipe)) > 0;) text.append(buf, n);
    REQUIRE(::pclose(pipe) == 0);
    const auto j = nlohmann::json::parse(text);

    auto bits = [](float f) { std::uint32_t u; std::memcpy(&u, &f, 4); return u; };
    auto expectColumn = [&](const nlohmann::json& col, const isouq::Attribute& a) {
        const char* types[] = {"<f4", "<i4", "|u1"};
        CHECK(col["type"] == types[a.data.index()]);
        std::vector<std::int64_t> expected;
        std::visit([&](const auto& v) {
            for (auto x : v) {
                if constexpr (std::is_same_v<decltype(x), float>) expected.push_back(bits(x));
                else expected.push_back(x);
            }
        }, a.data);
        CHECK(col["values"].get<std::vector<std::int64_t>>() == expected);
    };
    CHECK(j["comments"][0].get<std::string>().rfind("isouq index_to_world 0.10000000000000001 ", 0) == 0);
    std::vector<std::int64_t> xs;
    for (const auto& p : m.positions) xs.push_back(bits(p[0]));
    CHECK(j["vertex"]["x"]["values"].get<std::vector<std::int64_t>>() == xs);
    for (const auto& a : m.vertexAttributes.columns()) expectColumn(j["vertex"][a.name], a);
    for (const auto& a : m.faceAttributes.columns()) expectColumn(j["face"][a.name], a);
    std::vector<std::int64_t> faces;
    for (const auto& t : m.triangles) faces.insert(faces.end(), {t[0], t[1], t[2]});
    CHECK(j["faces"].get<std::vector<std::int64_t>>() == faces);

    if (withFaceColumn) return; // meshio 7 (Debian) reads binary face columns as one value
    if (!j.contains("meshio")) {
        WARN("meshio is not installed: only the numpy reader was checked");
        return;
    }
    std::vector<std::int64_t> points;
    for (const auto& p : m.positions) points.insert(points.end(), {bits(p[0]), bits(p[1]), bits(p[2])});
    CHECK(j["meshio"]["points"].get<std::vector<std::int64_t>>() == points);
    for (const auto& a : m.vertexAttributes.columns()) {
        nlohmann::json col = {{"type", j["vertex"][a.name]["type"]}, {"values", j["meshio"]["point_data"][a.name]}};
        expectColumn(col, a);
    }
    CHECK(j["meshio"]["triangles"].get<std::vector<std::int64_t>>() == faces);
}

TEST_CASE("MeshIO: reads ascii and big-endian PLY from other tools", "[io][ply]")
{
    TempDir dir;
    SECTION("ascii with doubles, other integer types, a face column and an extra element")
    {
        writeBytes(dir / "a.ply", "ply\r\nformat ascii 1.0\r\ncomment hello there\r\n"
                                  "element vertex 4\nproperty double x\nproperty double y\n"
                                  "property double z\nproperty uchar hidden\nproperty ushort label\n"
                                  "element face 2\nproperty list uchar uint vertex_indices\n"
                                  "property float quality\nelement edge 1\nproperty int vertex1\n"
                                  "property int vertex2\nend_header\n"
                                  "0 0 0 1 7\n1 0 0 0 65535\n0 1 0 1 3\n0 0 1.5 0 2\n"
                                  "3 0 1 2 0.5\n3 0 2 3 -1.25\n0 1\n");
        isouq::PlyInfo info;
        const Mesh m = isouq::readPly(dir / "a.ply", &info);
        CHECK(info.format == "ascii");
        CHECK(info.comments == std::vector<std::string>{"hello there"});
        CHECK_FALSE(info.hasIndexToWorld);
        CHECK(m.indexToWorld[0] == 1.0);
        CHECK(m.positions == std::vector<openvdb::Vec3s>{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1.5f}});
        CHECK(m.triangles == std::vector<openvdb::Vec3I>{{0, 1, 2}, {0, 2, 3}});
        CHECK(*m.vertexAttributes.find<std::uint8_t>("hidden") == std::vector<std::uint8_t>{1, 0, 1, 0});
        CHECK(*m.vertexAttributes.find<std::int32_t>("label") == std::vector<std::int32_t>{7, 65535, 3, 2});
        CHECK(*m.faceAttributes.find<float>("quality") == std::vector<float>{0.5f, -1.25f});
    }
    SECTION("binary big endian")
    {
        // 1 = 3f800000, -2 = c0000000; short 300 = 012c.
        std::string bytes = "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\n"
                            "property float y\nproperty float z\nproperty short s\nelement face 1\n"
                            "property list uchar int vertex_index\nend_header\n";
        for (int v = 0; v < 3; ++v)
            bytes += be32(v == 1 ? 0x3f800000 : 0) + be32(v == 2 ? 0xc0000000 : 0) + be32(0) +
                     std::string("\x01\x2c", 2);
        bytes += std::string(1, '\x03') + be32(2) + be32(1) + be32(0);
        writeBytes(dir / "b.ply", bytes);
        const Mesh m = isouq::readPly(dir / "b.ply");
        CHECK(m.positions == std::vector<openvdb::Vec3s>{{0, 0, 0}, {1, 0, 0}, {0, -2, 0}});
        CHECK(*m.vertexAttributes.find<std::int32_t>("s") == std::vector<std::int32_t>{300, 300, 300});
        CHECK(m.triangles == std::vector<openvdb::Vec3I>{{2, 1, 0}});
    }
}

TEST_CASE("MeshIO: a failed write throws, leaves no temporary file and keeps the target",
    "[io][atomic]")
{
    TempDir dir;
    const Mesh m = fullMesh(100000, 200000, 3);
    SECTION("missing directory")
    {
        const std::string path = dir / "missing/x.ply";
        CHECK(ioErrorOf([&] { isouq::writePly(m, path); }) ==
              "cannot write " + path + ": No such file or directory");
        CHECK(ioErrorOf([&] { isouq::checkWritable(path); }) ==
              "cannot write " + path + ": No such file or directory");
        CHECK(ioErrorOf([&] { isouq::writeTextFileAtomic(path, "{}"); }) ==
              "cannot write " + path + ": No such file or directory");
        CHECK(dir.list().empty());
    }
    SECTION("a file where a directory should be")
    {
        writeBytes(dir / "file", "x");
        CHECK(ioErrorOf([&] { isouq::writePly(m, dir / "file/x.ply"); }) ==
              "cannot write " + (dir / "file/x.ply") + ": Not a directory");
    }
    SECTION("the target is a directory")
    {
        fs::create_directory(dir / "sub");
        CHECK(ioErrorOf([&] { isouq::checkWritable(dir / "sub"); }) ==
              "cannot write " + (dir / "sub") + ": Is a directory");
        CHECK(dir.list() == std::vector<std::string>{"sub"});
    }
    SECTION("an inconsistent mesh does not replace an existing target")
    {
        writeBytes(dir / "t.ply", "old contents");
        Mesh bad = m;
        bad.vertexAttributes.add<float>("err_est", 3);
        CHECK(ioErrorOf([&] { isouq::writePly(bad, dir / "t.ply"); }) ==
              "cannot write " + (dir / "t.ply") + ": vertex column 'err_est' has 3 values for 100000 vertices");
        bad = m;
        bad.triangles.back()[2] = 100000; // in the body's last 4 MB chunk: found while another is written
        CHECK(ioErrorOf([&] { isouq::writePly(bad, dir / "t.ply"); }) ==
              "cannot write " + (dir / "t.ply") + ": triangle 199999 has a vertex index out of range");
        bad = m;
        bad.vertexAttributes.add<float>("err est", 100000);
        CHECK(ioErrorOf([&] { isouq::writePly(bad, dir / "t.ply"); }).find("not a PLY property name") != std::string::npos);
        CHECK(readBytes(dir / "t.ply") == "old contents");
        CHECK(dir.list() == std::vector<std::string>{"t.ply"});
    }
    SECTION("the disk refuses data in the middle of the body (RLIMIT_FSIZE)")
    {
        writeBytes(dir / "t.ply", "old contents");
        rlimit saved;
        REQUIRE(::getrlimit(RLIMIT_FSIZE, &saved) == 0);
        auto* savedHandler = std::signal(SIGXFSZ, SIG_IGN);
        rlimit small = saved;
        small.rlim_cur = 1 << 20; // the body is about 10 MB
        REQUIRE(::setrlimit(RLIMIT_FSIZE, &small) == 0);
        const std::string message = ioErrorOf([&] { isouq::writePly(m, dir / "t.ply"); });
        ::setrlimit(RLIMIT_FSIZE, &saved);
        std::signal(SIGXFSZ, savedHandler);
        CHECK(message == "cannot write " + (dir / "t.ply") + ": File too large");
        CHECK(readBytes(dir / "t.ply") == "old contents");
        CHECK(dir.list() == std::vector<std::string>{"t.ply"});
    }
    SECTION("a read-only directory")
    {
        if (::geteuid() == 0) {
            WARN("skipped: root may write into read-only directories");
            return;
        }
        fs::create_directory(dir / "ro");
        fs::permissions(dir / "ro", fs::perms::owner_read | fs::perms::owner_exec);
        CHECK(ioErrorOf([&] { isouq::checkWritable(dir / "ro/x.ply"); }) ==
              "cannot write " + (dir / "ro/x.ply") + ": Permission denied");
        fs::permissions(dir / "ro", fs::perms::owner_all);
    }
}

TEST_CASE("MeshIO: a sink that throws while the next chunk is being interleaved", "[io][ply]")
{
    // 300 000 vertices are several 4 MB chunks of rows: while the sink takes the first, a task
    // interleaves the second. The sink throws there; the task must finish before the writer's
    // frame is gone (AddressSanitizer saw it write a loop variable after the loop had unwound).
    const Mesh m = fullMesh(300000, 600000, 5);
    for (int ms : {0, 1, 2, 4, 8}) { // the write fails after a while: the task is under way by then
        int calls = 0;
        CHECK_THROWS_WITH(isouq::plyPieceRows(m, m.vertexCount(), [&](bool, const char*, std::size_t) {
            ++calls;
            std::this_thread::sleep_for(std::chrono::milliseconds(ms));
            throw std::runtime_error("disk full");
        }), "disk full");
        CHECK(calls == 1);
    }
    // Then every row arrives in order: the body built here a row and a value at a time.
    std::string rows;
    isouq::plyPieceRows(m, m.vertexCount(), [&](bool, const char* data, std::size_t n) { rows.append(data, n); });
    std::string expected;
    auto append = [&](const isouq::AttributeTable& table, std::size_t r) {
        for (const isouq::Attribute& a : table.columns())
            std::visit([&](const auto& v) { expected.append(reinterpret_cast<const char*>(&v[r]), sizeof v[r]); }, a.data);
    };
    for (std::size_t v = 0; v < m.vertexCount(); ++v) {
        expected.append(reinterpret_cast<const char*>(m.positions[v].asPointer()), 12);
        append(m.vertexAttributes, v);
    }
    for (std::size_t f = 0; f < m.triangleCount(); ++f) {
        expected += '\x03';
        for (int c = 0; c < 3; ++c) expected += le32(m.triangles[f][c]);
        append(m.faceAttributes, f);
    }
    CHECK(rows.size() == expected.size());
    CHECK((rows == expected)); // not decomposed: Catch would print 30 MB
}

TEST_CASE("MeshIO: successful atomic writes replace the target and leave nothing else",
    "[io][atomic]")
{
    TempDir dir;
    isouq::checkWritable(dir / "x.ply");
    CHECK(dir.list().empty());
    writeBytes(dir / "x.ply", "old");
    isouq::checkWritable(dir / "x.ply");
    CHECK(readBytes(dir / "x.ply") == "old");

    isouq::writeTextFileAtomic(dir / "s.json", "{\"a\": 1}\n");
    isouq::writeTextFileAtomic(dir / "s.json", "{}");
    CHECK(readBytes(dir / "s.json") == "{}");
    isouq::writePly(fullMesh(10, 10, 1), dir / "x.ply");
    CHECK(isouq::readPly(dir / "x.ply").vertexCount() == 10);
    CHECK(dir.list() == std::vector<std::string>{"s.json", "x.ply"});
}

TEST_CASE("MeshIO: truncated and malformed files give IoError, never a crash", "[io][ply]")
{
    TempDir dir;
    isouq::writePly(fullMesh(6, 5, 2), dir / "good.ply");
    const std::string good = readBytes(dir / "good.ply");
    REQUIRE(readOutcome(dir / "good.ply") == "ok");

    SECTION("every truncation")
    {
        bool allIo = true;
        for (std::size_t n = 0; n < good.size(); ++n) {
            writeBytes(dir / "t.ply", good.substr(0, n));
            allIo &= readOutcome(dir / "t.ply") == "io";
        }
        CHECK(allIo);
    }
    SECTION("random bytes, and random byte changes of a good file")
    {
        std::mt19937 rng(99);
        for (int trial = 0; trial < 300; ++trial) {
            std::string bytes(rng() % 400, '\0');
            for (char& c : bytes) c = static_cast<char>(rng());
            if (trial % 2) {
                bytes = good;
                for (int k = 0; k < 1 + trial % 4; ++k) bytes[rng() % bytes.size()] = static_cast<char>(rng());
            }
            writeBytes(dir / "g.ply", bytes);
            const std::string outcome = readOutcome(dir / "g.ply");
            CHECK((outcome == "io" || (trial % 2 && outcome == "ok")));
        }
    }
    SECTION("specific defects name the problem")
    {
        const std::string head = "ply\nformat binary_little_endian 1.0\n";
        const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
        auto error = [&](const std::string& bytes) {
            writeBytes(dir / "d.ply", bytes);
            return ioErrorOf([&] { isouq::readPly(dir / "d.ply"); });
        };
        CHECK(error("") == "cannot read " + (dir / "d.ply") + ": empty file");
        CHECK(ioErrorOf([&] { isouq::readPly(dir / "none.ply"); }) ==
              "cannot read " + (dir / "none.ply") + ": No such file or directory");
        CHECK(error("solid stl\n").find("not a PLY file") != std::string::npos);
        CHECK(error(head + "element vertex 1\n" + xyz).find("no end_header") != std::string::npos);
        CHECK(error(head + "element vertex 18446744073709551615\n" + xyz + "end_header\n")
                  .find("too short") != std::string::npos);
        CHECK(error(head + "element vertex 99999999999999999999\n").find("bad element line") != std::string::npos);
        CHECK(error(head + "element vertex -1\n").find("bad element line") != std::string::npos);
        CHECK(error(head + "property float x\n").find("property before any element") != std::string::npos);
        CHECK(error(head + "element vertex 0\nproperty float128 x\n").find("bad property line") != std::string::npos);
        CHECK(error("ply\nformat binary_middle_endian 1.0\n").find("unsupported format") != std::string::npos);
        CHECK(error(head + "element vertex 1\nproperty float x\nend_header\n" + le32(0))
                  .find("no float x, y and z") != std::string::npos);
        CHECK(error("ply\nformat ascii 1.0\nelement vertex 3\n" + xyz +
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n4 0 1 2 0\n")
                  .find("face 0 has 4 vertices; only triangles are supported") != std::string::npos);
        CHECK(error("ply\nformat ascii 1.0\nelement vertex 3\n" + xyz +
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n")
                  .find("face 0 refers to vertex 3 of 3") != std::string::npos);
        CHECK(error("ply\nformat ascii 1.0\nelement vertex 1\n" + xyz + "property uchar hidden\n"
                    "end_header\n0 0 0 256\n")
                  .find("out of range") != std::string::npos);
        CHECK(error("ply\nformat ascii 1.0\nelement vertex 1\n" + xyz + "end_header\n0 0 zero\n")
                  .find("'zero' is not a number") != std::string::npos);
        CHECK(error(head + "comment isouq index_to_world 1 2 3\nelement vertex 0\n" + xyz + "end_header\n")
                  .find("expected 16 numbers") != std::string::npos);
    }
}

TEST_CASE("MeshIO: writing and reading ten million triangles", "[io][ply][slow]")
{
    const Mesh m = fullMesh(5000000, 10000000, 5);
    TempDir dir;
    isouq::writePly(m, dir / "big.ply");
    const Mesh r = isouq::readPly(dir / "big.ply");
    CHECK(sameBits(r.positions, m.positions));
    CHECK(sameBits(r.triangles, m.triangles));
    CHECK(sameColumns(r.vertexAttributes, m.vertexAttributes));
    CHECK(sameColumns(r.faceAttributes, m.faceAttributes));
}

TEST_CASE("MeshIO: an output batch appears whole or not at all", "[io][atomic]")
{
    TempDir dir;
    isouq::Mesh mesh;
    mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    mesh.triangles = {{0, 1, 2}};
    writeBytes(dir / "a.ply", "old a");
    SECTION("a failing second output leaves the first untouched and no temporary")
    {
        {
            isouq::OutputBatch batch;
            batch.addPly(mesh, dir / "a.ply");
            CHECK_THROWS_AS(batch.addText(dir / "missing/s.json", "{}"), isouq::IoError);
        }
        CHECK(readBytes(dir / "a.ply") == "old a");
        CHECK(dir.list() == std::vector<std::string>{"a.ply"});
    }
    SECTION("commit renames every output")
    {
        isouq::OutputBatch batch;
        batch.addPly(mesh, dir / "a.ply");
        batch.addText(dir / "s.json", "{}\n");
        CHECK(readBytes(dir / "a.ply") == "old a"); // nothing visible before commit
        batch.commit();
        CHECK(readBytes(dir / "s.json") == "{}\n");
        CHECK(isouq::readPly(dir / "a.ply").triangles.size() == 1);
        CHECK(dir.list() == std::vector<std::string>{"a.ply", "s.json"});
    }
}

TEST_CASE("MeshIO: ascii PLY reads back to the same mesh", "[io][ply][ascii]")
{
    const std::size_t nv = GENERATE(0, 1, 9, 20000);
    const Mesh m = fullMesh(nv, nv == 0 ? 0 : 2 * nv, 13);
    isouq::PlyOptions options;
    options.encoding = isouq::PlyEncoding::Ascii;
    options.isovalue = 0.1f;
    options.comments = {"ascii test"};
    TempDir dir;
    isouq::writePly(m, dir / "a.ply", options);
    const std::string bytes = readBytes(dir / "a.ply");
    CHECK(bytes.rfind("ply\nformat ascii 1.0\ncomment isouq index_to_world ", 0) == 0);
    // 31 header lines (3 comments, 21 vertex and 2 face properties), then one line per row.
    CHECK(std::count(bytes.begin(), bytes.end(), '\n') == std::ptrdiff_t(31 + nv + m.triangleCount()));

    isouq::PlyInfo info;
    const Mesh r = isouq::readPly(dir / "a.ply", &info);
    CHECK(info.format == "ascii");
    CHECK(info.comments == options.comments);
    // Shortest round-trip text: every float, the special values of fullMesh included, reads back
    // with the same bits (quiet NaN, -0, infinities, the smallest denormal).
    CHECK(sameBits(r.positions, m.positions));
    CHECK(sameBits(r.triangles, m.triangles));
    CHECK(sameColumns(r.vertexAttributes, m.vertexAttributes));
    CHECK(sameColumns(r.faceAttributes, m.faceAttributes));
    CHECK(std::memcmp(r.indexToWorld.data(), m.indexToWorld.data(), sizeof(m.indexToWorld)) == 0);
}

namespace {

/// The `offset="N"` attributes of a .vtp header, in order.
std::vector<std::uint64_t> appendedOffsets(const std::string& header)
{
    std::vector<std::uint64_t> offsets;
    for (std::size_t at = 0; (at = header.find("offset=\"", at)) != std::string::npos;) {
        at += 8;
        offsets.push_back(std::stoull(header.substr(at, header.find('"', at) - at)));
    }
    return offsets;
}

std::uint64_t le64At(const std::string& bytes, std::size_t at)
{
    std::uint64_t v = 0;
    for (int i = 7; i >= 0; --i) v = v << 8 | static_cast<unsigned char>(bytes[at + i]);
    return v;
}

} // namespace

TEST_CASE("MeshIO: a .vtp has every column as an appended array at its declared offset", "[io][vtp]")
{
    const std::size_t nv = GENERATE(0, 7, 3000);
    const Mesh m = fullMesh(nv, nv == 0 ? 0 : 2 * nv, 17);
    isouq::MeshFileOptions options;
    options.version = "0.1.0";
    options.method = "weno";
    options.comments = {"a <comment> & \"quotes\""};
    TempDir dir;
    isouq::writeVtp(m, dir / "m.vtp", options);
    const std::string bytes = readBytes(dir / "m.vtp");
    REQUIRE(bytes.rfind("<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" "
                        "byte_order=\"LittleEndian\" header_type=\"UInt64\">\n", 0) == 0);
    const std::size_t data = bytes.find("<AppendedData encoding=\"raw\">\n   _");
    REQUIRE(data != std::string::npos);
    const std::size_t start = data + std::strlen("<AppendedData encoding=\"raw\">\n   _");
    const std::string header = bytes.substr(0, data);
    for (const auto& a : m.vertexAttributes.columns())
        CHECK(header.find("Name=\"" + a.name + "\"") != std::string::npos);
    CHECK(header.find("<PointData Scalars=\"err_est\">") != std::string::npos);
    CHECK(header.find("<CellData>\n        <DataArray type=\"UInt8\" Name=\"hidden\"") != std::string::npos);
    CHECK(header.find("NumberOfPoints=\"" + std::to_string(nv) + "\"") != std::string::npos);
    CHECK(header.find("NumberOfPolys=\"" + std::to_string(m.triangleCount()) + "\"") != std::string::npos);

    // Blocks: vertex columns, face columns, points, connectivity, offsets; each a UInt64 size
    // then the values, back to back, ending where the closing tags begin.
    const std::vector<std::uint64_t> offsets = appendedOffsets(header);
    REQUIRE(offsets.size() == m.vertexAttributes.columns().size() + m.faceAttributes.columns().size() + 3);
    std::vector<std::uint64_t> sizes;
    for (const auto& a : m.vertexAttributes.columns()) sizes.push_back(nv * (a.data.index() == 2 ? 1 : 4));
    sizes.push_back(m.triangleCount());
    sizes.insert(sizes.end(), {12 * nv, 24 * m.triangleCount(), 8 * m.triangleCount()});
    std::uint64_t expected = 0;
    for (std::size_t b = 0; b < offsets.size(); ++b) {
        CHECK(offsets[b] == expected);
        CHECK(le64At(bytes, start + offsets[b]) == sizes[b]);
        expected += 8 + sizes[b];
    }
    CHECK(bytes.substr(start + expected) == "\n  </AppendedData>\n</VTKFile>\n");
    // Points and the first triangle's connectivity and offset are the mesh's.
    const std::size_t points = start + offsets[offsets.size() - 3] + 8;
    if (nv > 0) { // (an empty mesh's positions are null: memcmp must not see them, UBSan)
        CHECK(std::memcmp(bytes.data() + points, m.positions.data(), 12 * nv) == 0);
        const std::size_t conn = start + offsets[offsets.size() - 2] + 8, offs = start + offsets.back() + 8;
        for (int c = 0; c < 3; ++c) CHECK(le64At(bytes, conn + 8 * c) == m.triangles[0][c]);
        CHECK(le64At(bytes, offs) == 3);
        CHECK(le64At(bytes, offs + 8 * (m.triangleCount() - 1)) == 3 * m.triangleCount());
    }
    // The comments are XML-safe: bytes as numbers in a String array.
    CHECK(header.find("<comment>") == std::string::npos);
    CHECK(header.find("NumberOfComponents=\"16\" NumberOfTuples=\"1\" format=\"ascii\">\n        "
                      "0.10000000000000001 0.33333333333333331 ") != std::string::npos);
}

TEST_CASE("MeshIO: a failed .vtp write keeps the target and leaves no temporary", "[io][vtp][atomic]")
{
    TempDir dir;
    writeBytes(dir / "t.vtp", "old contents");
    Mesh bad = fullMesh(100, 200, 4);
    bad.triangles.back()[1] = 100;
    CHECK(ioErrorOf([&] { isouq::writeVtp(bad, dir / "t.vtp"); }) ==
          "cannot write " + (dir / "t.vtp") + ": triangle 199 has a vertex index out of range");
    bad = fullMesh(100, 200, 4);
    bad.faceAttributes.add<float>("quality", 3);
    CHECK(ioErrorOf([&] { isouq::writeVtp(bad, dir / "t.vtp"); }).find("has 3 values for 200 faces") !=
          std::string::npos);
    CHECK(ioErrorOf([&] { isouq::writeVtp(bad, dir / "missing/t.vtp"); }) ==
          "cannot write " + (dir / "missing/t.vtp") + ": No such file or directory");
    CHECK(readBytes(dir / "t.vtp") == "old contents");
    CHECK(dir.list() == std::vector<std::string>{"t.vtp"});
    {
        isouq::OutputBatch batch;
        batch.addVtp(fullMesh(10, 10, 1), dir / "t.vtp");
        CHECK(readBytes(dir / "t.vtp") == "old contents");
        batch.commit();
    }
    CHECK(readBytes(dir / "t.vtp").rfind("<?xml", 0) == 0);
    CHECK(dir.list() == std::vector<std::string>{"t.vtp"});
}

TEST_CASE("MeshIO: readVtp refuses what it cannot read with one IoError, never a crash", "[io][vtp]")
{
    TempDir dir;
    const Mesh m = fullMesh(50, 100, 3);
    isouq::writeVtp(m, dir / "m.vtp");
    const std::string good = readBytes(dir / "m.vtp");
    const std::size_t underscore = good.find("   _") + 3;
    const auto outcome = [&](const std::string& bytes) {
        writeBytes(dir / "x.vtp", bytes);
        try {
            isouq::readVtp(dir / "x.vtp");
            return std::string("ok");
        } catch (const IoError& e) {
            return std::string(e.what()).substr(std::strlen("cannot read ") + (dir / "x.vtp").size() + 2);
        } catch (const std::exception& e) {
            return std::string("other: ") + e.what();
        }
    };
    const auto replaced = [&](const std::string& from, const std::string& to) {
        std::string s = good;
        const std::size_t at = s.find(from);
        REQUIRE(at != std::string::npos);
        return s.replace(at, from.size(), to);
    };
    CHECK(outcome(good) == "ok");
    CHECK(outcome(good.substr(0, underscore + 100)) == "truncated data (an array ends past the end of the file)");
    CHECK(outcome(good.substr(0, 200)).rfind("not VTK XML (", 0) == 0);
    CHECK(outcome("ply\nformat ascii 1.0\nend_header\n").rfind("not VTK XML (", 0) == 0);
    CHECK(outcome("") .rfind("not VTK XML (", 0) == 0);
    CHECK(outcome(replaced("NumberOfPoints=\"50\"", "NumberOfPoints=\"99999999999999\"")).rfind("array '", 0) == 0);
    CHECK(outcome(replaced("NumberOfPoints=\"50\"", "NumberOfPoints=\"-5\"")) == "Piece has a malformed count '-5'");
    CHECK(outcome(replaced("NumberOfVerts=\"0\"", "NumberOfVerts=\"2\"")) ==
          "vertices, lines or strips; only triangles (Polys) are read");
    CHECK(outcome(replaced("encoding=\"raw\"", "encoding=\"base64\"")) == "appended data in base64; only raw is read");
    CHECK(outcome(replaced("header_type=\"UInt64\"", "header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\"")) ==
          "compressed data (vtkZLibDataCompressor); write it uncompressed");
    CHECK(outcome(replaced("byte_order=\"LittleEndian\"", "byte_order=\"BigEndian\"")) ==
          "byte order 'BigEndian'; only LittleEndian is read");
    CHECK(outcome(replaced("type=\"PolyData\"", "type=\"UnstructuredGrid\"")) ==
          "not VTK XML PolyData (VTKFile type 'UnstructuredGrid')");
    // A block whose size word disagrees with its count; an offset past the end.
    std::string lying = good;
    lying[underscore + 1] = char(lying[underscore + 1] + 1);
    CHECK(outcome(lying).find("holds") != std::string::npos);
    CHECK(outcome(replaced("offset=\"0\"", "offset=\"18446744073709551615\"")) ==
          "truncated data (an array ends past the end of the file)");
    // A size word that agrees with a huge declared count: refused before anything is allocated.
    std::string huge = replaced("NumberOfPoints=\"50\"", "NumberOfPoints=\"10000000000\"");
    std::uint64_t pointsOffset = 0;
    std::sscanf(huge.c_str() + huge.find("offset=\"", huge.find("Name=\"Points\"")) + 8, "%" SCNu64, &pointsOffset);
    const std::uint64_t hugeBytes = std::uint64_t(10000000000) * 12;
    std::memcpy(huge.data() + huge.find("   _") + 4 + pointsOffset, &hugeBytes, 8); // the header grew
    CHECK(outcome(huge) == "truncated data (an array ends past the end of the file)");
    // A String block's size is not tied to a count: its type is refused before the count is allocated.
    std::string text = replaced("NumberOfPoints=\"50\"", "NumberOfPoints=\"10000000000\"");
    const std::string points = "type=\"Float32\" Name=\"Points\"";
    CHECK(outcome(text.replace(text.find(points), points.size(), "type=\"String\" Name=\"Points\"")) ==
          "array 'Points' has type 'String'");
    // A triangle's index past the points, and a polygon that is not a triangle.
    std::string far = good;
    const std::size_t conn = far.rfind("connectivity");
    std::uint64_t connOffset = 0;
    std::sscanf(far.c_str() + far.find("offset=\"", conn) + 8, "%" SCNu64, &connOffset);
    const std::int64_t big = 50;
    std::memcpy(far.data() + underscore + 1 + connOffset + 8, &big, 8);
    CHECK(outcome(far) == "triangle 0 has a vertex index out of range");
    std::string quad = good;
    std::uint64_t endsOffset = 0;
    std::sscanf(quad.c_str() + quad.find("offset=\"", quad.rfind("Name=\"offsets\"")) + 8, "%" SCNu64, &endsOffset);
    const std::int64_t four = 4;
    std::memcpy(quad.data() + underscore + 1 + endsOffset + 8, &four, 8);
    CHECK(outcome(quad) == "polygon 0 is not a triangle");
    // Not a regular file.
    CHECK(ioErrorOf([&] { isouq::readVtp(dir.path.string()); }).find("not a regular file") != std::string::npos);
    CHECK(ioErrorOf([&] { isouq::readVtp(dir / "missing.vtp"); }).find("No such file or directory") != std::string::npos);
}
