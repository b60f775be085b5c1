// isouq: marching cubes with hidden features (paper sec. 4.2, Figs. 5-7; SPEC §4, §6;
// docs/hidden-features.md).
//
// A thin feature whose cell corners all lie on one side of the isovalue is invisible to marching
// cubes. Cells where the data turns around along an edge are detected (slope rule), refined into
// m^3 subcells whose corner values come from the tricubic Lagrange interpolant (Tricubic.h), and
// meshed with the same inside rule as everywhere (value >= k is inside) and the same
// face-consistent case tables. Every unrefined cell that shares a face or an edge with a refined
// one is a transition cell: its surface is rebuilt from the loops its six faces' segments form
// (refined faces contribute their subdivided segments) and each loop is fanned to its centre, the
// paper's fan patch. The result has no cracks: a closed surface stays closed.
#pragma once

#include "isouq/MarchingCubes.h"

#include <openvdb/openvdb.h>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace isouq {

struct HiddenFeatureSettings {
    /// m: each refined cell becomes m^3 subcells; 1..64.
    int subdivisions = 4;
    /// Refine a flagged cell only where marching cubes cannot see what the tricubic shows: the
    /// tricubic reveals a sign that the corners of the cell, of one of its faces or of one of its
    /// edges hide, or the cell's case has several surface pieces whose connection the corners
    /// leave open. Without it, every flagged cell through which the tricubic surface passes is
    /// refined.
    bool filter = true;
};

struct HiddenFeatureStats {
    std::size_t cellsTotal = 0;      ///< cells examined (meshed cells: an active corner, in the data)
    std::size_t cellsFlagged = 0;    ///< of those, flagged by the slope rule
    std::size_t cellsRefined = 0;    ///< flagged, the tricubic crosses k (and the filter kept them)
    std::size_t cellsTransition = 0; ///< unrefined cells sharing a face or an edge with a refined one
    double fraction() const { return cellsTotal ? double(cellsFlagged) / double(cellsTotal) : 0.0; }
};

/// SPEC §4 slope rule on four consecutive values along an edge's line (f_{i-1}, f_i, f_{i+1},
/// f_{i+2}): true when two of the slopes f_i - f_{i-1}, f_{i+1} - f_i, f_{i+2} - f_{i+1} have
/// opposite signs. A zero slope has no sign: a plateau alone never flags, a plateau between a
/// rise and a fall does (the data turns around across it).
inline bool slopesTurn(float f0, float f1, float f2, float f3)
{
    const float s1 = f1 - f0, s2 = f2 - f1, s3 = f3 - f2;
    const bool rises = s1 > 0 || s2 > 0 || s3 > 0, falls = s1 < 0 || s2 < 0 || s3 < 0;
    return rises && falls;
}

/// The mesh with hidden features: standard marching cubes (extractIsosurface(grid, settings))
/// outside the refined and transition cells, subcell marching cubes inside refined cells, fan
/// patches in transition cells. Vertex columns are those of extractIsosurface with @a settings
/// plus `hidden` (uint8); faces get `hidden`. A refined vertex (hidden = 1) lies on a subcell
/// edge: `x y z` is its linear crossing of the subcell edge, `edge_i edge_j edge_k` a cell whose
/// closure holds it, `edge_axis` the subcell edge's axis (255 for a fan centre), and every other
/// float attribute (t_*, err_*, d_*) is NaN, `order` 0. With no refined cell the result equals
/// the standard mesh (plus zero `hidden` columns). Deterministic for any thread count.
/// @throw openvdb::ValueError if subdivisions is not in 1..64, or the isovalue is not finite.
/// @throw InterruptedError if @a interrupter asked to stop.
Mesh extractWithHiddenFeatures(const openvdb::FloatGrid& grid, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* stats = nullptr,
    openvdb::util::NullInterrupter* interrupter = nullptr);

/// As extractWithHiddenFeatures, from a standard mesh already extracted from @a grid with
/// @a settings and provenance (edge_i edge_j edge_k edge_axis), so a caller that wants both
/// meshes meshes once. The result keeps @a standard's columns.
/// @throw openvdb::ValueError also if @a standard has no provenance columns.
Mesh addHiddenFeatures(const openvdb::FloatGrid& grid, const Mesh& standard,
    const MeshSettings& settings, const HiddenFeatureSettings& hidden,
    HiddenFeatureStats* stats = nullptr, openvdb::util::NullInterrupter* interrupter = nullptr);

class BrickPlan; // Bricks.h
class PieceComm; // Bricks.h

/// A piece's share of addHiddenFeatures of the whole grid (SPEC §4, §9, §10 "MPI";
/// docs/mpi.md): the whole mesh is three sections of vertices (the kept standard vertices, the
/// refined vertices sorted by their subcell edge, the fan centres) and three of triangles (the
/// kept standard ones, the refined cells', the transition cells'), in the one-process order, and
/// the piece holds one run of each, its rows concatenated in section order.
struct HiddenPiece {
    Mesh mesh; ///< this piece's rows (columns as addHiddenFeatures'); indices are the whole mesh's
    /// Section s of piece p is rows [begin[s P + p], begin[s P + p + 1]) of the whole mesh.
    std::vector<std::uint64_t> vertexBegin, triangleBegin;
    HiddenFeatureStats stats; ///< the whole grid's
};

/// addHiddenFeatures by the pieces of @a plan (collective over @a comm): @a standard is this
/// piece's BrickMesher piece, whose vertices are rows [standardBegin[p], standardBegin[p + 1])
/// of the whole standard mesh, and @a grid holds the values of its blocks and the blocks around
/// them. Each piece detects the cells of its blocks, refines its refined cells and patches its
/// transition cells (a transition cell of a brick face knows the refined cells across it: the
/// refined cells of every piece are shared), and writes its share of the refined vertices (the
/// pieces that use one send its crossing); the standard vertices that stay are those a kept
/// triangle or a transition loop of any piece uses.
/// @throw as addHiddenFeatures, on every piece.
HiddenPiece addHiddenFeaturesByPieces(const openvdb::FloatGrid& grid, const Mesh& standard,
    const std::vector<std::uint64_t>& standardBegin, const BrickPlan& plan, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, const PieceComm& comm, openvdb::util::NullInterrupter* interrupter = nullptr);

} // namespace isouq
