// Tests of the sparse marching-cubes mesher against independent truths: analytic surfaces,
// a brute-force dense pass over every grid edge, edge-use counts for watertightness, and exact
// counts for tiles and plateaus (SPEC §1, §8, §9).
#include <isouq/GridMetadata.h>
#include <isouq/MarchingCubes.h>
#include <isouq/McTables.h>
#include <isouq/VolumeSources.h>

#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <numeric>
#include <random>
#include <cstring>

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

TEST_CASE("MarchingCubes: partly active data and data bounds mesh exactly the edges of meshed cells", "[mc][bruteforce]")
{
    // The rule of SPEC §1 from its definition: a cell is meshed when one of its corners is active
    // and all of them lie inside the data bounds; an edge has a vertex when its ends straddle k
    // and one of the (up to four) cells around it is meshed; each meshed cell contributes its
    // case's triangles. Inactive voxels hold values too, on both sides of k, and the data bounds
    // cut the active region, so cells at every block face are meshed, unmeshed and cut.
    openvdb::initialize();
    const int seed = GENERATE(1, 2, 3);
    std::mt19937 rng(4321 + seed);
    const Coord lo(-5, 2, -11), hi(18, 25, 12); // voxels written; 24^3 across block faces
    auto grid = openvdb::FloatGrid::create(0.0f);
    auto acc = grid->getAccessor();
    std::uniform_int_distribution<int> level(0, 4);
    std::bernoulli_distribution active(seed == 1 ? 0.1 : seed == 2 ? 0.4 : 0.8);
    for (int i = lo[0]; i <= hi[0]; ++i)
        for (int j = lo[1]; j <= hi[1]; ++j)
            for (int k = lo[2]; k <= hi[2]; ++k) {
                acc.setValue(Coord(i, j, k), float(level(rng)));
                acc.setActiveState(Coord(i, j, k), active(rng));
            }
    const Coord boundsLo(-3, 3, -9), boundsHi(16, 23, 11);
    grid->insertMeta(kDataBoundsMinMeta, openvdb::Vec3IMetadata(openvdb::Vec3i(boundsLo.asPointer())));
    grid->insertMeta(kDataBoundsMaxMeta, openvdb::Vec3IMetadata(openvdb::Vec3i(boundsHi.asPointer())));
    const float isovalue = 2.0f;
    auto inside = [&](const Coord& c) { return acc.getValue(c) >= isovalue; };
    auto meshed = [&](const Coord& cell) {
        for (int a = 0; a < 3; ++a)
            if (cell[a] < boundsLo[a] || cell[a] + 1 > boundsHi[a]) return false;
        for (const auto& o : kMcCornerOffset)
            if (acc.isValueOn(cell.offsetBy(o.x, o.y, o.z))) return true;
        return false;
    };
    std::set<std::array<int, 4>> expected;
    std::size_t expectedTriangles = 0;
    for (int i = lo[0] - 1; i <= hi[0]; ++i)
        for (int j = lo[1] - 1; j <= hi[1]; ++j)
            for (int k = lo[2] - 1; k <= hi[2]; ++k) {
                const Coord c(i, j, k);
                if (!meshed(c)) continue;
                int cubeCase = 0;
                for (int corner = 0; corner < 8; ++corner) {
                    const auto& o = kMcCornerOffset[corner];
                    cubeCase |= int(inside(c.offsetBy(o.x, o.y, o.z))) << corner;
                }
                expectedTriangles += kMcCases.triangleCount[cubeCase];
                for (const McEdge& e : kMcEdges) {
                    const Coord a = c.offsetBy(e.dx, e.dy, e.dz);
                    const Coord b = a.offsetBy(e.axis == 0, e.axis == 1, e.axis == 2);
                    if (inside(a) != inside(b)) expected.insert({a[0], a[1], a[2], int(e.axis)});
                }
            }
    MeshSettings settings;
    settings.isovalue = isovalue;
    settings.provenance = true;
    const Mesh mesh = extractIsosurface(*grid, settings);
    const auto& ei = *mesh.vertexAttributes.find<std::int32_t>("edge_i");
    const auto& ej = *mesh.vertexAttributes.find<std::int32_t>("edge_j");
    const auto& ek = *mesh.vertexAttributes.find<std::int32_t>("edge_k");
    const auto& ea = *mesh.vertexAttributes.find<std::uint8_t>("edge_axis");
    std::set<std::array<int, 4>> got;
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) got.insert({ei[v], ej[v], ek[v], int(ea[v])});
    REQUIRE(expected.size() > 100);
    CHECK(got.size() == mesh.positions.size());
    CHECK(got == expected);
    CHECK(mesh.triangles.size() == expectedTriangles);
    // The estimate pass fills from a wider window; its vertices are the same edges.
    settings.uncertainty = true;
    const Mesh withEstimates = extractIsosurface(*grid, settings);
    CHECK(withEstimates.triangles == mesh.triangles);
    CHECK(*withEstimates.vertexAttributes.find<std::int32_t>("edge_i") == ei);
}

TEST_CASE("MarchingCubes: a grid whose only data is one active tile meshes the tile's shell", "[mc][tiles]")
{
    openvdb::initialize();
    // A 128^3 tile (level 2) of value 1 in a background of 0; at k = 0.5 every edge leaving the
    // tile crosses halfway: 6 * 128^2 vertices, half a voxel outside the tile's faces.
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->tree().addTile(2, Coord(128, 0, -128), 1.0f, true);
    REQUIRE(grid->tree().leafCount() == 0);
    MeshSettings settings;
    settings.isovalue = 0.5f;
    const Mesh mesh = extractIsosurface(*grid, settings);
    CHECK(mesh.positions.size() == 6u * 128 * 128);
    const EdgeUse use = countEdgeUse(mesh);
    CHECK(use.boundary == 0);
    CHECK(use.nonManifold == 0);
    CHECK(countComponents(mesh) == 1);
    for (const auto& p : mesh.positions) {
        const openvdb::Vec3d lo(127.5, -0.5, -128.5), hi(255.5, 127.5, -0.5);
        int onFace = 0;
        for (int a = 0; a < 3; ++a) {
            CHECK(p[a] >= lo[a] - 1e-6);
            CHECK(p[a] <= hi[a] + 1e-6);
            onFace += std::abs(p[a] - lo[a]) < 1e-6 || std::abs(p[a] - hi[a]) < 1e-6;
        }
        CHECK(onFace >= 1);
    }
    // The box [127.5, 255.5] x [-0.5, 127.5] x [-128.5, -0.5] (side 128) with its 12 edges
    // chamfered by marching cubes: each cut is a prism of right-triangle section with legs 1/2
    // (area 1/8) along the edge; the 8 corner cuts overlap them by less than one voxel in all.
    const double side = 128.0, chamfered = side * side * side - 12 * side / 8.0;
    CHECK(std::abs(signedVolume(mesh)) == Approx(chamfered).margin(1.0));
}

TEST_CASE("MarchingCubes: an empty grid gives an empty mesh", "[mc]")
{
    openvdb::initialize();
    const Mesh mesh = extractIsosurface(*openvdb::FloatGrid::create(1.0f), MeshSettings{});
    CHECK(mesh.positions.empty());
    CHECK(mesh.triangles.empty());
}

TEST_CASE("MarchingCubes: plateaus and values equal to k follow one inside rule", "[mc][ties]")
{
    openvdb::initialize();
    // A plateau of value exactly k inside a box of lower values: the plateau is inside (>= k), so
    // the surface wraps it and is closed; the vertices sit on the plateau's boundary voxels
    // (t = 1 from the outside end), so the mesh has zero-area triangles but no crack.
    const int n = 12;
    auto grid = denseGrid(n, n, n, [](int i, int j, int k) {
        const bool plateau = i >= 3 && i <= 8 && j >= 4 && j <= 7 && k >= 2 && k <= 9;
        return plateau ? 5.0 : 1.0 + 0.01 * ((i + 2 * j + 3 * k) % 7);
    });
    MeshSettings settings;
    settings.isovalue = 5.0f;
    const Mesh mesh = extractIsosurface(*grid, settings);
    const EdgeUse use = countEdgeUse(mesh);
    CHECK(use.boundary == 0);
    CHECK(use.nonManifold == 0);
    CHECK(countComponents(mesh) == 1);
    // 2 * (6*4 + 6*8 + 4*8) edges leave the 6 x 4 x 8 plateau.
    CHECK(mesh.positions.size() == 2u * (6 * 4 + 6 * 8 + 4 * 8));
}

TEST_CASE("MarchingCubes: thread count does not change the mesh", "[mc][determinism]")
{
    openvdb::initialize();
    // Radius 100 voxels (2 900 leaves) and 200 (11 600: the block set is built in parallel
    // from 8 192 leaves, vdb_ops/src/BlockScratch.h).
    const float voxel = GENERATE(0.01f, 0.005f);
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(1.0f, {0.1f, 0.2f, 0.3f}, voxel);
    if (voxel < 0.01f) REQUIRE(grid->tree().leafCount() >= 8192);
    MeshSettings serial;
    serial.threaded = false;
    serial.uncertainty = true;
    MeshSettings parallel = serial;
    parallel.threaded = true;
    const Mesh a = extractIsosurface(*grid, serial), b = extractIsosurface(*grid, parallel);
    REQUIRE(a.positions.size() == b.positions.size());
    CHECK(std::equal(a.positions.begin(), a.positions.end(), b.positions.begin()));
    CHECK(std::equal(a.triangles.begin(), a.triangles.end(), b.triangles.begin()));
    const auto& ea = *a.vertexAttributes.find<float>("err_est");
    const auto& eb = *b.vertexAttributes.find<float>("err_est");
    CHECK(std::memcmp(ea.data(), eb.data(), ea.size() * sizeof(float)) == 0);
}

TEST_CASE("MarchingCubes: bucky at k = 51, a value the scan holds, has no crack inside", "[mc][data][ties]")
{
    openvdb::initialize();
    // Integer CT data at an isovalue it holds: many corners equal k. Every mesh edge used once
    // must join two vertices on the faces of the 32^3 domain (scikit-image#8116 leaves holes).
    VolumeRequest request;
    request.input = std::string(ISOUQ_DATA_DIR) + "/bucky_32x32x32_uint8.raw";
    request.isovalue = 51.0f;
    const LoadedVolume volume = loadVolume(request);
    MeshSettings settings;
    settings.isovalue = volume.isovalue;
    settings.provenance = true;
    const Mesh mesh = extractIsosurface(*volume.grid, settings);
    REQUIRE(mesh.triangles.size() > 1000);
    const auto& ea = *mesh.vertexAttributes.find<std::uint8_t>("edge_axis");
    const std::vector<std::int32_t>* e[3] = {mesh.vertexAttributes.find<std::int32_t>("edge_i"),
        mesh.vertexAttributes.find<std::int32_t>("edge_j"), mesh.vertexAttributes.find<std::int32_t>("edge_k")};
    auto onDomainFace = [&](std::uint32_t v) {
        for (int a = 0; a < 3; ++a)
            if (a != ea[v] && ((*e[a])[v] == 0 || (*e[a])[v] == 31)) return true;
        return false;
    };
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> uses;
    for (const auto& t : mesh.triangles)
        for (int i = 0; i < 3; ++i) ++uses[std::minmax(t[i], t[(i + 1) % 3])];
    std::size_t inner = 0, nonManifold = 0;
    for (const auto& [edge, count] : uses) {
        nonManifold += count > 2;
        inner += count == 1 && !(onDomainFace(edge.first) && onDomainFace(edge.second));
    }
    CHECK(inner == 0);
    CHECK(nonManifold == 0);
}

TEST_CASE("MarchingCubes: bricks joined by source edge equal the whole mesh (SPEC §9)", "[mc][bricks]")
{
    openvdb::initialize();
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(1.0f, {0.05f, -0.1f, 0.02f}, 0.03f);
    MeshSettings settings;
    settings.uncertainty = true;
    using Key = std::array<std::int32_t, 4>;
    auto keysOf = [](const Mesh& m) {
        const auto& i = *m.vertexAttributes.find<std::int32_t>("edge_i");
        const auto& j = *m.vertexAttributes.find<std::int32_t>("edge_j");
        const auto& k = *m.vertexAttributes.find<std::int32_t>("edge_k");
        const auto& a = *m.vertexAttributes.find<std::uint8_t>("edge_axis");
        std::vector<Key> keys(m.positions.size());
        for (std::size_t v = 0; v < keys.size(); ++v) keys[v] = {i[v], j[v], k[v], a[v]};
        return keys;
    };
    // Triangles as edge-key triples, rotated to start at the smallest key (orientation kept).
    using Tri = std::array<Key, 3>;
    auto trianglesOf = [&](const Mesh& m, std::map<Key, openvdb::Vec3s>& positions, std::map<Key, float>& errors) {
        const std::vector<Key> keys = keysOf(m);
        const auto& err = *m.vertexAttributes.find<float>("err_est");
        std::vector<Tri> tris;
        for (const auto& t : m.triangles) {
            Tri tri{keys[t[0]], keys[t[1]], keys[t[2]]};
            std::rotate(tri.begin(), std::min_element(tri.begin(), tri.end()), tri.end());
            tris.push_back(tri);
            for (int c = 0; c < 3; ++c) {
                const auto [it, fresh] = positions.emplace(keys[t[c]], m.positions[t[c]]);
                CHECK(it->second == m.positions[t[c]]); // a shared edge has one position
                errors[keys[t[c]]] = err[t[c]];
                (void)fresh;
            }
        }
        return tris;
    };
    std::map<Key, openvdb::Vec3s> wholePositions, brickPositions;
    std::map<Key, float> wholeErrors, brickErrors;
    std::vector<Tri> whole = trianglesOf(extractIsosurface(*grid, settings), wholePositions, wholeErrors);
    std::vector<Tri> joined;
    const openvdb::CoordBBox box = grid->evalActiveVoxelBoundingBox();
    const Coord cut(3, -5, 11); // not aligned with leaves
    for (int octant = 0; octant < 8; ++octant) {
        Coord lo = box.min().offsetBy(-2), hi = box.max().offsetBy(2);
        for (int a = 0; a < 3; ++a) {
            if (octant >> a & 1) lo[a] = cut[a];
            else hi[a] = cut[a] - 1;
        }
        MeshSettings brick = settings;
        brick.brick = openvdb::CoordBBox(lo, hi);
        const std::vector<Tri> part = trianglesOf(extractIsosurface(*grid, brick), brickPositions, brickErrors);
        joined.insert(joined.end(), part.begin(), part.end());
    }
    std::sort(whole.begin(), whole.end());
    std::sort(joined.begin(), joined.end());
    CHECK(whole.size() > 10000);
    CHECK(whole == joined);
    CHECK(wholePositions == brickPositions);
    CHECK(wholeErrors == brickErrors);
}

TEST_CASE("MarchingCubes: the estimate-only pass gives the full pass's e and e_b", "[mc][estimate]")
{
    openvdb::initialize();
    auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(1.0f, {0.0f, 0.0f, 0.0f}, 0.04f);
    MeshSettings full;
    full.uncertainty = true;
    full.method = EdgeMethod::Linear;
    MeshSettings estimate = full;
    estimate.highOrder = false;
    const Mesh a = extractIsosurface(*grid, full), b = extractIsosurface(*grid, estimate);
    REQUIRE(a.positions == b.positions);
    CHECK(b.vertexAttributes.find<float>("t_cubic") == nullptr);
    CHECK(*a.vertexAttributes.find<float>("err_est") == *b.vertexAttributes.find<float>("err_est"));
    CHECK(*a.vertexAttributes.find<float>("err_bound") == *b.vertexAttributes.find<float>("err_bound"));
}

TEST_CASE("MarchingCubes: a NaN stencil voxel outside the active set makes the methods fall back", "[mc][nan]")
{
    openvdb::initialize();
    // A linear ramp along x (crossing between x = 5 and 6) whose voxel x = 3 is an inactive NaN:
    // the WENO stencil i-2..i+3 of the crossing edge reads it, so WENO falls back to a lower
    // order but stays exact on the ramp; nothing becomes NaN.
    const int n = 12;
    auto grid = denseGrid(n, n, n, [](int i, int, int) { return double(i) - 5.5; });
    auto acc = grid->getAccessor();
    for (int j = 0; j < n; ++j)
        for (int k = 0; k < n; ++k) acc.setValueOff(Coord(3, j, k), std::nanf(""));
    MeshSettings settings;
    settings.uncertainty = true;
    const Mesh mesh = extractIsosurface(*grid, settings);
    const auto& order = *mesh.vertexAttributes.find<std::uint8_t>("order");
    const auto& tWeno = *mesh.vertexAttributes.find<float>("t_weno");
    const auto& axis = *mesh.vertexAttributes.find<std::uint8_t>("edge_axis");
    REQUIRE(!mesh.positions.empty());
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
        CHECK(std::isfinite(mesh.positions[v][0]));
        CHECK(axis[v] == 0);
        CHECK(order[v] < 6);
        CHECK(tWeno[v] == Approx(0.5f).margin(1e-6));
    }
}

TEST_CASE("MarchingCubes: a reused mesher and mesh give what a fresh call gives", "[mc][reuse]")
{
    openvdb::initialize();
    auto big = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(1.0f, {0.0f, 0.0f, 0.0f}, 0.02f);
    auto small = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(0.5f, {0.1f, 0.0f, 0.0f}, 0.05f);
    MeshSettings full;
    full.uncertainty = true;
    IsosurfaceMesher mesher(full);
    Mesh reused;
    mesher(*big, reused);
    reused.vertexAttributes.add<float>("stale_user_column", reused.vertexCount());
    // Smaller grid, fewer columns: the content equals a fresh extraction, leftovers are gone.
    mesher.settings().uncertainty = false;
    mesher(*small, reused);
    MeshSettings linear;
    const Mesh fresh = extractIsosurface(*small, linear);
    CHECK(reused.positions == fresh.positions);
    CHECK(reused.triangles == fresh.triangles);
    CHECK(reused.vertexAttributes.columns().size() == fresh.vertexAttributes.columns().size());
    // Back to the big grid with every column: equal to a fresh extraction.
    mesher.settings().uncertainty = true;
    mesher(*big, reused);
    const Mesh freshBig = extractIsosurface(*big, full);
    CHECK(reused.positions == freshBig.positions);
    CHECK(*reused.vertexAttributes.find<float>("d_lw") == *freshBig.vertexAttributes.find<float>("d_lw"));
    CHECK(reused.vertexAttributes.has("stale_user_column") == false);
    // Meshing the same grid again keeps every column's storage.
    const float* storage = reused.vertexAttributes.find<float>("d_lw")->data();
    const openvdb::Vec3s* positions = reused.positions.data();
    mesher(*big, reused);
    CHECK(reused.vertexAttributes.find<float>("d_lw")->data() == storage);
    CHECK(reused.positions.data() == positions);
}
