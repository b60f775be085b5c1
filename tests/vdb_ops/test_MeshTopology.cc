// Tests of isouq/MeshTopology.h against hand-built meshes with known answers, closed-form
// areas and volumes, and brute-force edge and component counts.
#include <isouq/MeshTopology.h>

#include <catch2/catch.hpp>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <numeric>
#include <random>
#include <utility>

using isouq::Mesh;
using isouq::measureTopology;

namespace {

Mesh makeMesh(std::vector<openvdb::Vec3s> positions, std::vector<openvdb::Vec3I> triangles)
{
    Mesh m;
    m.positions = std::move(positions);
    m.triangles = std::move(triangles);
    return m;
}

/// Right-corner tetrahedron with legs a, b, c along x, y, z, faces outward.
Mesh tetrahedron(float a, float b, float c)
{
    return makeMesh({{0, 0, 0}, {a, 0, 0}, {0, b, 0}, {0, 0, c}},
        {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}});
}

/// Axis-aligned cube [o, o+1]^3, 12 outward triangles.
void appendCube(Mesh& m, openvdb::Vec3s o)
{
    const auto base = static_cast<std::uint32_t>(m.positions.size());
    for (int i = 0; i < 8; ++i)
        m.positions.push_back(o + openvdb::Vec3s(float(i & 1), float((i >> 1) & 1), float((i >> 2) & 1)));
    const std::uint32_t quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
        {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (const auto& q : quads) {
        m.triangles.emplace_back(base + q[0], base + q[1], base + q[2]);
        m.triangles.emplace_back(base + q[0], base + q[2], base + q[3]);
    }
}

/// Latitude-longitude sphere of radius r: n rings of 2n vertices between two poles, inscribed.
Mesh uvSphere(int n, double r)
{
    Mesh m;
    const double pi = std::acos(-1.0);
    m.positions.emplace_back(0.f, 0.f, float(r));
    for (int i = 1; i < n; ++i)
        for (int j = 0; j < 2 * n; ++j) {
            const double th = pi * i / n, ph = pi * j / n;
            m.positions.emplace_back(float(r * std::sin(th) * std::cos(ph)),
                float(r * std::sin(th) * std::sin(ph)), float(r * std::cos(th)));
        }
    m.positions.emplace_back(0.f, 0.f, float(-r));
    const auto south = static_cast<std::uint32_t>(m.positions.size() - 1);
    auto ring = [n](int i, int j) { return std::uint32_t(1 + (i - 1) * 2 * n + (j % (2 * n))); };
    for (int j = 0; j < 2 * n; ++j) {
        m.triangles.emplace_back(0, ring(1, j), ring(1, j + 1));
        m.triangles.emplace_back(south, ring(n - 1, j + 1), ring(n - 1, j));
        for (int i = 1; i + 1 < n; ++i) {
            m.triangles.emplace_back(ring(i, j), ring(i + 1, j), ring(i + 1, j + 1));
            m.triangles.emplace_back(ring(i, j), ring(i + 1, j + 1), ring(i, j + 1));
        }
    }
    return m;
}

} // namespace

TEST_CASE("MeshTopology: tetrahedron is closed with the corner-tetrahedron area and volume",
    "[topology]")
{
    // Legs 2, 3, 6: volume abc/6 = 6; right faces 3, 6, 9; slanted face
    // sqrt((ab)^2 + (bc)^2 + (ca)^2) / 2 = sqrt(36 + 324 + 144) / 2 = sqrt(504) / 2.
    const auto s = measureTopology(tetrahedron(2, 3, 6));
    CHECK(s.boundaryEdges == 0);
    CHECK(s.nonManifoldEdges == 0);
    CHECK(s.edges == 6);
    CHECK(s.components == 1);
    CHECK(s.degenerateTriangles == 0);
    CHECK_THAT(s.area, Catch::WithinRel(18 + std::sqrt(504.0) / 2, 1e-14));
    CHECK_THAT(s.enclosedVolume, Catch::WithinRel(6.0, 1e-14));
}

TEST_CASE("MeshTopology: a single triangle has three boundary edges", "[topology]")
{
    const auto s = measureTopology(makeMesh({{0, 0, 0}, {4, 0, 0}, {0, 3, 0}}, {{0, 1, 2}}));
    CHECK(s.boundaryEdges == 3);
    CHECK(s.edges == 3);
    CHECK(s.components == 1);
    CHECK(s.area == 6.0);
}

TEST_CASE("MeshTopology: two disjoint cubes are two components of volume 2", "[topology]")
{
    Mesh m;
    appendCube(m, {0, 0, 0});
    appendCube(m, {3.5f, -2, 10});
    const auto s = measureTopology(m);
    CHECK(s.boundaryEdges == 0);
    CHECK(s.nonManifoldEdges == 0);
    CHECK(s.edges == 36); // 18 per cube: Euler 8 - 18 + 12 = 2
    CHECK(s.components == 2);
    CHECK_THAT(s.area, Catch::WithinAbs(12.0, 1e-12));
    CHECK_THAT(s.enclosedVolume, Catch::WithinAbs(2.0, 1e-12));

    const auto labels = isouq::componentLabels(m);
    REQUIRE(labels.size() == 24);
    for (std::size_t f = 0; f < 24; ++f) CHECK(labels[f] == (f < 12 ? 0u : 1u));
    CHECK(isouq::componentTriangleCounts(labels) == std::vector<std::size_t>{12, 12});
}

TEST_CASE("MeshTopology: a book of three pages has one non-manifold edge", "[topology]")
{
    const Mesh book = makeMesh({{0, 0, 0}, {0, 0, 1}, {1, 0, 0}, {0, 1, 0}, {-1, -1, 0}},
        {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}});
    const auto s = measureTopology(book);
    CHECK(s.nonManifoldEdges == 1);
    CHECK(s.boundaryEdges == 6);
    CHECK(s.edges == 7);
    CHECK(s.components == 1);
}

TEST_CASE("MeshTopology: octahedron volume and area, anywhere and either way round",
    "[topology]")
{
    // Vertices at +-a on the axes: volume 4a^3/3, eight equilateral faces of side a*sqrt(2),
    // area 4*sqrt(3)*a^2. A closed mesh's volume does not depend on where it is, and the
    // absolute value does not depend on the orientation.
    const float a = 1.5f;
    const bool flip = GENERATE(false, true);
    const openvdb::Vec3s o = GENERATE(openvdb::Vec3s(0, 0, 0), openvdb::Vec3s(1000.5f, -7, 3.25f));
    Mesh m = makeMesh({o + openvdb::Vec3s(a, 0, 0), o + openvdb::Vec3s(-a, 0, 0), o + openvdb::Vec3s(0, a, 0),
                          o + openvdb::Vec3s(0, -a, 0), o + openvdb::Vec3s(0, 0, a), o + openvdb::Vec3s(0, 0, -a)},
        {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}});
    if (flip)
        for (auto& t : m.triangles) std::swap(t[1], t[2]);
    const auto s = measureTopology(m);
    CHECK(s.boundaryEdges == 0);
    CHECK(s.edges == 12);
    CHECK_THAT(s.enclosedVolume, Catch::WithinRel(4.0 * a * a * a / 3.0, 1e-12));
    CHECK_THAT(s.area, Catch::WithinRel(4.0 * std::sqrt(3.0) * a * a, 1e-12));
}

TEST_CASE("MeshTopology: UV-sphere area and volume converge at second order", "[topology]")
{
    // An inscribed polyhedron with edges O(1/n) misses area and volume by O(1/n^2).
    const double r = 2.0, pi = std::acos(-1.0);
    double prevArea = 0, prevVolume = 0;
    for (int n : {32, 64, 128}) {
        const Mesh m = uvSphere(n, r);
        const auto s = measureTopology(m);
        CHECK(s.boundaryEdges == 0);
        CHECK(s.nonManifoldEdges == 0);
        CHECK(s.components == 1);
        CHECK(m.vertexCount() - s.edges + m.triangleCount() == 2); // Euler characteristic
        const double eArea = 4 * pi * r * r - s.area, eVolume = 4.0 / 3.0 * pi * r * r * r - s.enclosedVolume;
        CHECK(eArea > 0); // inscribed: always short
        CHECK(eVolume > 0);
        if (prevArea > 0) {
            CHECK(std::log2(prevArea / eArea) == Approx(2.0).margin(0.1));
            CHECK(std::log2(prevVolume / eVolume) == Approx(2.0).margin(0.1));
        }
        prevArea = eArea;
        prevVolume = eVolume;
    }
    CHECK(prevArea / (4 * pi * r * r) < 2e-4);
}

TEST_CASE("MeshTopology: degenerate triangles and vertex connectivity", "[topology]")
{
    SECTION("a repeated index and a zero-area triangle are degenerate")
    {
        const auto s = measureTopology(makeMesh({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 1, 0}},
            {{0, 0, 3}, {0, 1, 2}, {0, 1, 3}}));
        CHECK(s.degenerateTriangles == 2);
        CHECK(s.edges == 5); // 03 (used twice by the first), 01, 12, 02, 13
    }
    SECTION("triangles sharing only one vertex are one component; coincident copies are not")
    {
        const Mesh bowtie = makeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {-1, 0, 0}, {-1, -1, 0}},
            {{0, 1, 2}, {0, 3, 4}});
        CHECK(measureTopology(bowtie).components == 1);
        const Mesh apart = makeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 0, 0}, {-1, 0, 0}, {-1, -1, 0}},
            {{0, 1, 2}, {3, 4, 5}});
        CHECK(measureTopology(apart).components == 2);
    }
    SECTION("unused vertices are not components")
    {
        const auto s = measureTopology(makeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 5, 5}}, {{0, 1, 2}}));
        CHECK(s.components == 1);
    }
    SECTION("an index out of range throws")
    {
        const Mesh bad = makeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {{0, 1, 3}});
        CHECK_THROWS_AS(measureTopology(bad), std::invalid_argument);
        CHECK_THROWS_AS(isouq::componentLabels(bad), std::invalid_argument);
    }
    SECTION("an empty mesh has nothing")
    {
        const auto s = measureTopology(Mesh{});
        CHECK(s.edges == 0);
        CHECK(s.components == 0);
        CHECK(s.area == 0);
    }
}

TEST_CASE("MeshTopology: fans around a vertex of high valence", "[topology]")
{
    // The lower-index bucket of the centre holds every spoke: the sorted (long bucket) path.
    const int k = 100;
    Mesh open, closed;
    open.positions.emplace_back(0, 0, 0);
    for (int i = 0; i <= k; ++i)
        open.positions.emplace_back(std::cos(i * 0.05f), std::sin(i * 0.05f), 0.f);
    for (int i = 1; i <= k; ++i) open.triangles.emplace_back(0, i, i + 1);
    const auto so = measureTopology(open);
    CHECK(so.edges == std::size_t(2 * k + 1));
    CHECK(so.boundaryEdges == std::size_t(k + 2)); // the rim and the two end spokes

    closed.positions = open.positions;
    closed.positions.pop_back();
    for (int i = 1; i <= k; ++i) closed.triangles.emplace_back(0, i, i % k + 1);
    const auto sc = measureTopology(closed);
    CHECK(sc.edges == std::size_t(2 * k));
    CHECK(sc.boundaryEdges == std::size_t(k));
}

TEST_CASE("MeshTopology: random meshes match brute-force edge and component counts",
    "[topology]")
{
    std::mt19937 rng(12345);
    for (int trial = 0; trial < 50; ++trial) {
        const int nv = 3 + int(rng() % 40), nf = int(rng() % 60);
        Mesh m;
        for (int v = 0; v < nv; ++v) m.positions.emplace_back(float(rng() % 7), float(rng() % 7), float(rng() % 7));
        for (int f = 0; f < nf; ++f) m.triangles.emplace_back(rng() % nv, rng() % nv, rng() % nv);

        std::map<std::pair<std::uint32_t, std::uint32_t>, int> uses;
        for (const auto& t : m.triangles)
            for (int c = 0; c < 3; ++c) {
                const std::uint32_t a = t[c], b = t[(c + 1) % 3];
                if (a != b) ++uses[{std::min(a, b), std::max(a, b)}];
            }
        std::size_t boundary = 0, nonManifold = 0;
        for (const auto& [edge, n] : uses) {
            boundary += n == 1;
            nonManifold += n > 2;
        }
        // Components by repeated relaxation: a triangle takes the smallest label of any
        // triangle it shares a vertex with, until nothing changes.
        std::vector<int> label(nf);
        for (int f = 0; f < nf; ++f) label[f] = f;
        for (bool changed = true; changed;) {
            changed = false;
            for (int f = 0; f < nf; ++f)
                for (int g = 0; g < nf; ++g) {
                    bool share = false;
                    for (int c = 0; c < 3; ++c)
                        for (int d = 0; d < 3; ++d) share |= m.triangles[f][c] == m.triangles[g][d];
                    if (share && label[g] < label[f]) {
                        label[f] = label[g];
                        changed = true;
                    }
                }
        }
        std::size_t components = 0;
        for (int f = 0; f < nf; ++f) components += label[f] == f;

        const auto s = measureTopology(m);
        CHECK(s.edges == uses.size());
        CHECK(s.boundaryEdges == boundary);
        CHECK(s.nonManifoldEdges == nonManifold);
        CHECK(s.components == components);
        const auto labels = isouq::componentLabels(m);
        bool samePartition = true;
        for (int f = 0; f < nf; ++f)
            for (int g = 0; g < nf; ++g) samePartition &= (labels[f] == labels[g]) == (label[f] == label[g]);
        CHECK(samePartition);
    }
}

TEST_CASE("MeshTopology: a mesh of many parts and vertex ranges matches sorting and a breadth-first search "
          "at any thread count", "[topology]")
{
    // 400 000 triangles and 300 000 vertices: more than one part of triangles and one range of
    // vertices in every pass. Strips of nearby vertices (most edges used twice), a long fan
    // across parts, repeated triangles (non-manifold edges), degenerate ones, and small islands
    // numbered late but used early, so components are not in vertex order.
    std::mt19937 rng(2026);
    const std::uint32_t nv = 300000;
    Mesh m;
    m.positions.resize(nv);
    for (std::uint32_t v = 0; v < nv; ++v) m.positions[v] = openvdb::Vec3s(float(v % 97), float(v % 89), float(v % 83));
    auto near = [&](std::uint32_t a) { return std::min<std::uint32_t>(nv - 1, a + 1 + rng() % 40); };
    for (int f = 0; f < 400000; ++f) {
        const int kind = int(rng() % 100);
        if (kind < 80) {
            const std::uint32_t a = rng() % 250000;
            m.triangles.emplace_back(a, near(a), near(a));
        } else if (kind < 85) {
            m.triangles.emplace_back(7, 1 + rng() % 249000, 1 + rng() % 249000); // the fan of vertex 7
        } else if (kind < 90 && !m.triangles.empty()) {
            m.triangles.push_back(m.triangles[rng() % m.triangles.size()]);
        } else if (kind < 92) {
            const std::uint32_t a = rng() % nv;
            m.triangles.emplace_back(a, a, near(a));
        } else {
            const std::uint32_t island = 250000 + 5 * (rng() % 10000); // vertices island .. island + 4
            m.triangles.emplace_back(island + rng() % 5, island + rng() % 5, island + rng() % 5);
        }
    }

    // Edges by sorting every (lower, upper) pair.
    std::vector<std::pair<std::uint32_t, std::uint32_t>> pairs;
    for (const auto& t : m.triangles)
        for (int c = 0; c < 3; ++c) {
            const std::uint32_t a = t[c], b = t[(c + 1) % 3];
            if (a != b) pairs.emplace_back(std::min(a, b), std::max(a, b));
        }
    std::sort(pairs.begin(), pairs.end());
    std::size_t edges = 0, boundary = 0, nonManifold = 0;
    for (std::size_t i = 0, j; i < pairs.size(); i = j) {
        for (j = i + 1; j < pairs.size() && pairs[j] == pairs[i];) ++j;
        ++edges;
        boundary += j - i == 1;
        nonManifold += j - i > 2;
    }
    // Components by a breadth-first search over triangles sharing a vertex, started from each
    // unlabelled triangle in order: labels in the order of the components' first triangles.
    std::vector<std::vector<std::uint32_t>> trianglesOf(nv);
    for (std::uint32_t f = 0; f < m.triangles.size(); ++f)
        for (int c = 0; c < 3; ++c) trianglesOf[m.triangles[f][c]].push_back(f);
    std::vector<std::uint32_t> expected(m.triangles.size(), ~0u);
    std::uint32_t components = 0;
    for (std::uint32_t f = 0; f < m.triangles.size(); ++f) {
        if (expected[f] != ~0u) continue;
        std::vector<std::uint32_t> queue{f};
        expected[f] = components;
        while (!queue.empty()) {
            const std::uint32_t g = queue.back();
            queue.pop_back();
            for (int c = 0; c < 3; ++c)
                for (std::uint32_t h : trianglesOf[m.triangles[g][c]])
                    if (expected[h] == ~0u) expected[h] = components, queue.push_back(h);
        }
        ++components;
    }
    REQUIRE(nonManifold > 0);
    REQUIRE(components > 1000);

    const isouq::TriangleChunks chunks{m.vertexCount(), m.triangleCount(),
        [&](std::size_t first, std::size_t count, openvdb::Vec3I* out) {
            std::copy_n(m.triangles.begin() + std::ptrdiff_t(first), count, out);
        }};
    for (int threads : {1, 2, 5}) {
        INFO(threads << " threads");
        const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        std::vector<std::uint32_t> labels, chunkLabels;
        const auto s = measureTopology(m, &labels, true);
        const auto c = measureTopology(chunks, &chunkLabels);
        const auto counted = measureTopology(m); // no labels: components counted, not numbered
        for (const auto& r : {s, c, counted}) {
            CHECK(r.edges == edges);
            CHECK(r.boundaryEdges == boundary);
            CHECK(r.nonManifoldEdges == nonManifold);
            CHECK(r.components == components);
        }
        // Counts of differing labels (a failed vector comparison would print 400 000 numbers).
        auto differing = [&](const std::vector<std::uint32_t>& got) {
            if (got.size() != expected.size()) return got.size() + expected.size();
            return std::size_t(std::inner_product(got.begin(), got.end(), expected.begin(), std::size_t(0),
                std::plus<>(), std::not_equal_to<>()));
        };
        CHECK(differing(labels) == 0);
        CHECK(differing(chunkLabels) == 0);
        CHECK(differing(isouq::componentLabels(m)) == 0);
    }

    // An index out of range names the first such triangle, in the last part as in the first.
    m.triangles[399990] = openvdb::Vec3I(1, 2, nv);
    m.triangles[399995] = openvdb::Vec3I(nv + 5, 2, 3);
    CHECK_THROWS_WITH(measureTopology(m), "triangle 399990 names vertex 300000 of 300000");
    m.triangles[3] = openvdb::Vec3I(0, nv + 1, 2);
    CHECK_THROWS_WITH(isouq::componentLabels(m), "triangle 3 names vertex 300001 of 300000");
}
