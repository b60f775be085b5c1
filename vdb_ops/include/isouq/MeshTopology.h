// isouq: topology and size measures of a triangle mesh (SPEC §4 crack-free and component
// claims, §8 `boundary_edges` and `components` of the summary).
#pragma once

#include "isouq/MeshAttributes.h"

#include <array>
#include <cstddef>
#include <cstdint>
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

/// Area, signed volume and degenerate triangles, summed triangle by triangle in the order
/// measureTopology sums them, about @a centre (measureTopology's is the centre of the vertices'
/// bounding box): a mesh cut into consecutive runs of triangles (the pieces of SPEC §10 "MPI")
/// that hands the sums from one run to the next gets the same bits as the whole.
struct GeometrySums {
    double area = 0, signedVolume = 0;
    std::size_t degenerate = 0;
};
void addTriangleGeometry(const std::vector<openvdb::Vec3s>& positions, const openvdb::Vec3I* first,
    const openvdb::Vec3I* last, const std::array<double, 3>& centre, GeometrySums& sums);

/// Per triangle, its component in 0..C-1, numbered in the order of their first triangle.
/// Components are vertex connectivity: two triangles are connected when they share a vertex
/// index (vertices are shared by index, SPEC §1), so two sheets touching at one vertex count
/// as one component, and coincident but distinct vertices do not connect.
/// @throw std::invalid_argument if a triangle names a vertex that does not exist.
std::vector<std::uint32_t> componentLabels(const Mesh& mesh);

/// Triangles per component, indexed by the labels of componentLabels().
std::vector<std::size_t> componentTriangleCounts(const std::vector<std::uint32_t>& labels);

} // namespace isouq
