// isouq: topology and size measures of a triangle mesh (SPEC §4 crack-free and component
// claims, §8 `boundary_edges` and `components` of the summary).
#pragma once

#include "isouq/MeshAttributes.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

namespace isouq {

struct MeshTopologyStats {
    std::size_t boundaryEdges = 0;       ///< undirected edges used by exactly one triangle
    std::size_t nonManifoldEdges = 0;    ///< undirected edges used by more than two triangles
    std::size_t components = 0;          ///< see componentLabels()
    std::size_t degenerateTriangles = 0; ///< a repeated vertex index, or zero area in double
    double area = 0;                     ///< sum of the triangle areas
    double enclosedVolume = 0;           ///< |signed divergence sum|; the volume if closed
    std::size_t edges = 0;               ///< distinct undirected edges (Euler: V - E + F)
};

/// Edge use counts, components, degenerate triangles, area and enclosed volume, in double.
/// An edge joining a vertex to itself (a triangle with a repeated index) is not an edge.
/// The volume is summed about the centre of the vertices' bounding box; for a closed mesh it
/// does not depend on that centre, for an open one it is only a number.
/// @throw std::invalid_argument if a triangle names a vertex that does not exist.
MeshTopologyStats measureTopology(const Mesh& mesh);

/// measureTopology that also gives componentLabels() from the same pass, and skips the area,
/// volume and degenerate triangles unless @a geometry.
MeshTopologyStats measureTopology(const Mesh& mesh, std::vector<std::uint32_t>* labels, bool geometry);

/// Rows per chunk of every sum over a mesh's rows (the area and volume here, the summary's
/// statistics in nodes/Summary.h): each chunk of kSumRows rows is summed alone, in row order,
/// and the chunks' sums are added in chunk order. The sums are then the same bits whatever
/// the thread count, and a mesh cut into pieces (SPEC §10 "MPI") needs to hand on only the
/// chunk its cut falls in.
constexpr std::size_t kSumRows = std::size_t(1) << 16;

/// The sums of rows [0, rows) by that rule, the chunks on the calling thread's TBB arena:
/// add(sums, first, count) folds rows [first, first + count) into sums (Sums() empty).
template <typename Sums, typename Add>
Sums sumByChunks(std::size_t rows, const Add& add)
{
    std::vector<Sums> parts((rows + kSumRows - 1) / kSumRows);
    tbb::parallel_for(std::size_t(0), parts.size(),
        [&](std::size_t c) { add(parts[c], c * kSumRows, std::min(kSumRows, rows - c * kSumRows)); });
    Sums sums;
    for (const Sums& part : parts) sums.join(part);
    return sums;
}

/// Area, signed volume and degenerate triangles about @a centre (measureTopology's is the
/// centre of the vertices' bounding box), summed triangle by triangle within a chunk
/// (addTriangleGeometry), chunks joined in order (join).
struct GeometrySums {
    double area = 0, signedVolume = 0;
    std::size_t degenerate = 0;
    void join(const GeometrySums& next)
    {
        area += next.area;
        signedVolume += next.signedVolume;
        degenerate += next.degenerate;
    }
};
/// @a position(v) is vertex v's position.
template <typename PositionOf>
void addTriangleGeometry(const PositionOf& position, const openvdb::Vec3I* first, const openvdb::Vec3I* last,
    const std::array<double, 3>& centre, GeometrySums& sums)
{
    double area = sums.area, volume = sums.signedVolume;
    for (; first != last; ++first) {
        const openvdb::Vec3I& t = *first;
        double q[3][3];
        for (int v = 0; v < 3; ++v) {
            const openvdb::Vec3s& p = position(std::uint32_t(t[v]));
            for (int c = 0; c < 3; ++c) q[v][c] = double(p[c]) - centre[c];
        }
        const double e1[3] = {q[1][0] - q[0][0], q[1][1] - q[0][1], q[1][2] - q[0][2]};
        const double e2[3] = {q[2][0] - q[0][0], q[2][1] - q[0][1], q[2][2] - q[0][2]};
        const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0]};
        const double twiceArea = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        area += 0.5 * twiceArea;
        // q0 . (q1 x q2) = q0 . (e1 x e2), so the normal is reused.
        volume += (q[0][0] * n[0] + q[0][1] * n[1] + q[0][2] * n[2]) / 6.0;
        if (twiceArea == 0 || t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) ++sums.degenerate;
    }
    sums.area = area;
    sums.signedVolume = volume;
}

/// Triangles that are not stored as one array of a Mesh (a rank's piece in its own vertex
/// numbering, SPEC §10 "MPI"): fetch(first, count, out) writes triangles first..first+count-1
/// with corners in 0..vertexCount-1, and is called from several threads at once.
struct TriangleChunks {
    std::size_t vertexCount = 0, triangleCount = 0;
    std::function<void(std::size_t first, std::size_t count, openvdb::Vec3I* out)> fetch;
};

/// measureTopology(mesh, labels, false) of such triangles: edges and components, no geometry.
MeshTopologyStats measureTopology(const TriangleChunks& triangles, std::vector<std::uint32_t>* labels);

/// Per triangle, its component in 0..C-1, numbered in the order of their first triangle.
/// Components are vertex connectivity: two triangles are connected when they share a vertex
/// index (vertices are shared by index, SPEC §1), so two sheets touching at one vertex count
/// as one component, and coincident but distinct vertices do not connect.
/// @throw std::invalid_argument if a triangle names a vertex that does not exist.
std::vector<std::uint32_t> componentLabels(const Mesh& mesh);

/// Triangles per component, indexed by the labels of componentLabels().
std::vector<std::size_t> componentTriangleCounts(const std::vector<std::uint32_t>& labels);

} // namespace isouq
