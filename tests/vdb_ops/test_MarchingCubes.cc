// Tests of the sparse marching-cubes mesher against independent truths: analytic surfaces,
// a brute-force dense pass over every grid edge, edge-use counts for watertightness, and exact
// counts for tiles and plateaus (SPEC §1, §8, §9).
#include <isouq/MarchingCubes.h>

#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <random>

using namespace isouq;
using openvdb::Coord;

namespace {

struct EdgeUse {
    std::size_t boundary = 0, nonManifold = 0;
};

/// Counts how many triangles use each undirected mesh edge (brute force, sort-based).
EdgeUse countEdgeUse(const Mesh& mesh)
{
    std::vector<std::uint64_t> edges;
    edges.reserve(mesh.triangles.size() * 3);
    for (const auto& t : mesh.triangles)
        for (int i = 0; i < 3; ++i) {
            std::uint64_t a = t[i], b = t[(i + 1) % 3];
            if (a > b) std::swap(a, b);
            edges.push_back((a << 32) | b);
        }
    std::sort(edges.begin(), edges.end());
    EdgeUse use;
    for (std::size_t i = 0; i < edges.size();) {
        std::size_t j = i;
        while (j < edges.size() && edges[j] == edges[i]) ++j;
        if (j - i == 1) ++use.boundary;
        if (j - i > 2) ++use.nonManifold;
        i = j;
    }
    return use;
}

std::size_t countComponents(const Mesh& mesh)
{
    std::vector<std::uint32_t> parent(mesh.positions.size());
    std::iota(parent.begin(), parent.end(), 0u);
    auto find = [&](std::uint32_t v) {
        while (parent[v] != v) v = parent[v] = parent[parent[v]];
        return v;
    };
    for (const auto& t : mesh.triangles) {
        parent[find(t[1])] = find(t[0]);
        parent[find(t[2])] = find(t[0]);
    }
    std::size_t roots = 0;
    std::vector<bool> used(mesh.positions.size());
    for (const auto& t : mesh.triangles) used[t[0]] = true;
    for (std::uint32_t v = 0; v < parent.size(); ++v) roots += used[v] && find(v) == v;
    return roots;
}

double area(const Mesh& m)
{
    double a = 0;
    for (const auto& t : m.triangles) {
        const openvdb::Vec3d p0(m.positions[t[0]]), p1(m.positions[t[1]]), p2(m.positions[t[2]]);
        a += 0.5 * (p1 - p0).cross(p2 - p0).length();
    }
    return a;
}

double signedVolume(const Mesh& m)
{
    double v = 0;
    for (const auto& t : m.triangles) {
        const openvdb::Vec3d p0(m.positions[t[0]]), p1(m.positions[t[1]]), p2(m.positions[t[2]]);
        v += p0.dot(p1.cross(p2)) / 6.0;
    }
    return v;
}

/// A dense, fully active grid of the given size filled by f(i, j, k), with data bounds set.
template <typename F>
openvdb::FloatGrid::Ptr denseGrid(int nx, int ny, int nz, F&& f)
{
    auto grid = openvdb::FloatGrid::create(0.0f);
    auto acc = grid->getAccessor();
    for (int i = 0; i < nx; ++i)
        for (int j = 0; j < ny; ++j)
            for (int k = 0; k < nz; ++k) acc.setValueOn(Coord(i, j, k), float(f(i, j, k)));
    grid->insertMeta(kDataBoundsMinMeta, openvdb::Vec3IMetadata(openvdb::Vec3i(0, 0, 0)));
    grid->insertMeta(kDataBoundsMaxMeta, openvdb::Vec3IMetadata(openvdb::Vec3i(nx - 1, ny - 1, nz - 1)));
    return grid;
}

} // namespace

TEST_CASE("MarchingCubes: level-set sphere is closed and on the sphere", "[mc]")
{
    openvdb::initialize();
    const float radius = 1.0f, voxel = 0.02f;
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(radius, {0.1f, -0.2f, 0.3f}, voxel);
    MeshSettings settings;
    const Mesh mesh = extractIsosurface(*grid, settings);
    REQUIRE(mesh.triangles.size() > 10000);
    const EdgeUse use = countEdgeUse(mesh);
    CHECK(use.boundary == 0);
    CHECK(use.nonManifold == 0);
    CHECK(countComponents(mesh) == 1);
    // The narrow band stores exact distances to within float rounding; linear interpolation of a
    // distance function along an edge errs by O(h^2 / r): far below a tenth of a voxel here.
    double worst = 0;
    for (const auto& p : mesh.positions)
        worst = std::max(worst, std::abs((openvdb::Vec3d(p) - openvdb::Vec3d(0.1, -0.2, 0.3)).length() - radius));
    CHECK(worst < 0.1 * voxel);
    // Level sets: triangles face outward, so the enclosed signed volume is positive.
    CHECK(signedVolume(mesh) > 0);
}

TEST_CASE("MarchingCubes: sphere.vdb at k = 0 is one closed sphere of radius 3", "[mc][data]")
{
    openvdb::initialize();
    openvdb::io::File file(std::string(ISOUQ_DATA_DIR) + "/sphere.vdb");
    file.open();
    auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("ls_sphere"));
    REQUIRE(grid);
    const Mesh mesh = extractIsosurface(*grid, MeshSettings{});
    const EdgeUse use = countEdgeUse(mesh);
    CHECK(use.boundary == 0);
    CHECK(use.nonManifold == 0);
    CHECK(countComponents(mesh) == 1);
    double worst = 0;
    for (const auto& p : mesh.positions) worst = std::max(worst, std::abs(double(p.length()) - 3.0));
    CHECK(worst < 0.01);
    // Area and volume of an inscribed polyhedron with vertices within 0.01 of r = 3: the linear
    // mesh cuts corners by at most h^2/(8r) (h = 0.05) between vertices, so both stay within
    // a relative 2 * 0.01 / 3 of the sphere's (plus the flattening, far smaller).
    const double r = 3.0, pi = 3.14159265358979323846;
    CHECK(area(mesh) == Approx(4 * pi * r * r).epsilon(0.007));
    CHECK(std::abs(signedVolume(mesh)) == Approx(4.0 / 3.0 * pi * r * r * r).epsilon(0.01));
}

TEST_CASE("MarchingCubes: brute-force dense pass over every edge gives the same vertices", "[mc][bruteforce]")
{
    openvdb::initialize();
    const int n = GENERATE(5, 13, 20);
    std::mt19937 rng(1234 + n);
    std::uniform_int_distribution<int> level(0, 4); // small integers: many values equal k
    std::vector<float> data(std::size_t(n) * n * n);
    for (float& v : data) v = float(level(rng));
    auto at = [&](int i, int j, int k) { return data[(std::size_t(i) * n + j) * n + k]; };
    auto grid = denseGrid(n, n, n, at);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.5));
    const float k = 2.0f;
    MeshSettings settings;
    settings.isovalue = k;
    settings.provenance = true;
    const Mesh mesh = extractIsosurface(*grid, settings);

    // Every grid edge whose ends straddle k under ">= k is inside" has exactly one vertex.
    std::map<std::array<int, 4>, float> expected;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int kk = 0; kk < n; ++kk)
                for (int axis = 0; axis < 3; ++axis) {
                    int d[3] = {0, 0, 0};
                    d[axis] = 1;
                    if (i + d[0] >= n || j + d[1] >= n || kk + d[2] >= n) continue;
                    const float f0 = at(i, j, kk), f1 = at(i + d[0], j + d[1], kk + d[2]);
                    if ((f0 >= k) != (f1 >= k)) expected[{i, j, kk, axis}] = (k - f0) / (f1 - f0);
                }
    REQUIRE(mesh.positions.size() == expected.size());
    const auto& ei = *mesh.vertexAttributes.find<std::int32_t>("edge_i");
    const auto& ej = *mesh.vertexAttributes.find<std::int32_t>("edge_j");
    const auto& ek = *mesh.vertexAttributes.find<std::int32_t>("edge_k");
    const auto& ea = *mesh.vertexAttributes.find<std::uint8_t>("edge_axis");
    const auto& tl = *mesh.vertexAttributes.find<float>("t_linear");
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
        const auto it = expected.find({ei[v], ej[v], ek[v], int(ea[v])});
        REQUIRE(it != expected.end());
        CHECK(tl[v] == it->second);
        openvdb::Vec3d ijk(ei[v], ej[v], ek[v]);
        ijk[ea[v]] += it->second;
        CHECK((openvdb::Vec3d(mesh.positions[v]) - 0.5 * ijk).length() < 1e-6);
    }
    // Every triangle's vertices lie on edges of one cell.
    auto coord = [&](std::uint32_t v, int a) { return a == 0 ? ei[v] : a == 1 ? ej[v] : ek[v]; };
    for (const auto& t : mesh.triangles)
        for (int a = 0; a < 3; ++a) {
            const int lo = std::min({coord(t[0], a), coord(t[1], a), coord(t[2], a)});
            const int hi = std::max({coord(t[0], a), coord(t[1], a), coord(t[2], a)});
            CHECK(hi - lo <= 1);
        }
    // Inside the domain every mesh edge is used by exactly two triangles: an edge used once
    // joins two vertices on the domain's outer faces.
    auto onDomainFace = [&](std::uint32_t v) {
        for (int a = 0; a < 3; ++a)
            if (a != ea[v] && (coord(v, a) == 0 || coord(v, a) == n - 1)) return true;
        return false;
    };
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> uses;
    for (const auto& t : mesh.triangles)
        for (int i = 0; i < 3; ++i) ++uses[std::minmax(t[i], t[(i + 1) % 3])];
    for (const auto& [edge, count] : uses) {
        CHECK(count <= 2);
        if (count == 1) CHECK((onDomainFace(edge.first) && onDomainFace(edge.second)));
    }
}
