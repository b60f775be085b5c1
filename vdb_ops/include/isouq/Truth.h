// isouq: measured errors where the truth is known: the truth columns a mesh of a field: or
// formula: input carries (paper sec. 4.1; SPEC §3 "Measured error", §5, §6).
//
// Truth columns (per vertex, world units, float; docs/validation.md):
//   err_true_<m>  |x_m - x*|: method m's crossing against the exact crossing x* of the analytic
//                 field on the vertex's own edge, for each t_<m> column present
//                 (m = linear, cubic, weno, weno_paper);
//   dist_true     distance from the vertex (x, y, z) to the true surface f = k;
//   dist_true_<m> (optional) the same for method m's crossing.
#pragma once

#include "isouq/AnalyticFields.h"
#include "isouq/MeshAttributes.h"

#include <openvdb/openvdb.h>

#include <string>
#include <string_view>
#include <vector>

namespace isouq {

// ---- Exact truths of an analytic field ----------------------------------------------------

/// The exact crossing of f = k on the segment a -> b as t in [0, 1], in double. Roots are
/// isolated on 32 sub-intervals and each refined by bisection-secant (Illinois) to ~1e-15;
/// with several roots the median one is taken (SPEC §2's rule for the methods). With no sign
/// change in double (the float samples straddled k by rounding) it is the end nearer to k.
struct EdgeRoot {
    double t = 0.0;
    int roots = 0; ///< roots found on the segment (0 means "no sign change in double")
};
EdgeRoot exactEdgeCrossing(const AnalyticField& field, double k, const openvdb::Vec3d& a,
    const openvdb::Vec3d& b);

/// Distance from @a p to the level set f = k, by a closest-point iteration: Newton steps along
/// the gradient with a backtracking line search put q on the surface, then q moves by the part
/// of p - q tangent to the surface and is projected again, until p - q is normal to it
/// (tangential residual < 1e-9 @a scale). Gradients are central differences (step 1e-6 @a scale).
/// If @a seed (a known surface point, e.g. the edge's exact crossing) is closer than the
/// result, the iteration is restarted from it and the smaller distance kept.
/// @a scale is a length of the problem (the grid spacing). Returns NaN if it does not converge.
double distanceToLevelSet(const AnalyticField& field, double k, const openvdb::Vec3d& p,
    double scale, const openvdb::Vec3d* seed = nullptr);

struct TruthSettings {
    bool perMethodDistance = false; ///< also write dist_true_<m> for each t_<m> column
    bool threaded = true;
};

/// What addTruthColumns met on the way.
struct TruthReport {
    std::size_t vertices = 0;
    std::size_t multiRootEdges = 0; ///< edges where f = k has several roots (median taken)
    std::size_t noRootEdges = 0;    ///< edges straddling k only by float rounding
    std::size_t failedProjections = 0; ///< dist_true is NaN there
};

/// Adds err_true_<m> for every t_<m> column of @a mesh, and dist_true (and dist_true_<m>).
/// @a isovalue must be the one the mesh was extracted at (the float the mesher compared with).
/// Parallel over vertices (TBB) and deterministic: each vertex is computed on its own.
/// @throw openvdb::ValueError if the mesh lacks the provenance columns edge_i/j/k, edge_axis.
TruthReport addTruthColumns(Mesh& mesh, const AnalyticField& field, double isovalue,
    const TruthSettings& settings = {});

/// World position of every vertex's crossing for column @a tColumn ("t_linear", ...):
/// M * (edge + t e_axis, 1) with M = mesh.indexToWorld.
/// @throw openvdb::ValueError if a column is missing.
std::vector<openvdb::Vec3d> crossingPositions(const Mesh& mesh, std::string_view tColumn);

} // namespace isouq
