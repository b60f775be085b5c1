// isouq: measured errors where the truth is known, and the statistics that compare them with
// the estimates (paper sec. 4.1, Figs. 3-4; SPEC §3 "Measured error", §5, §6; issue 3).
//
// Truth columns (per vertex, world units, float; docs/validation.md):
//   err_true_<m>  |x_m - x*|: method m's crossing against the exact crossing x* of the analytic
//                 field on the vertex's own edge, for each t_<m> column present
//                 (m = linear, cubic, weno, weno_paper);
//   dist_true     distance from the vertex (x, y, z) to the true surface f = k;
//   dist_true_<m> (optional) the same for method m's crossing.
// The METRO measure (the paper's, for data without a formula) is the distance to a reference
// surface meshed at a finer resolution, found through a uniform bucket grid of its triangles.
#pragma once

#include "isouq/AnalyticFields.h"
#include "isouq/MeshAttributes.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <string>
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
std::vector<openvdb::Vec3d> crossingPositions(const Mesh& mesh, const std::string& tColumn);

// ---- METRO: distance to a finer reference surface -----------------------------------------

/// A triangle mesh with a uniform grid of buckets (cell size @a cellSize; each triangle is in
/// every cell its bounding box touches) for exact point-to-surface distances: the cube of
/// cells around a point grows until the best distance found is within it.
class ReferenceSurface {
public:
    ReferenceSurface(const Mesh& mesh, double cellSize);
    /// Exact Euclidean distance from @a p to the nearest triangle; NaN for an empty mesh.
    double distance(const openvdb::Vec3d& p) const;
    std::size_t triangleCount() const { return mTriangles.size(); }

private:
    std::array<openvdb::Vec3d, 3> corners(std::uint32_t triangle) const;
    bool cellRange(const openvdb::Coord& c, std::size_t& begin, std::size_t& end) const;

    std::vector<openvdb::Vec3d> mPoints;
    std::vector<openvdb::Vec3I> mTriangles;
    double mCellSize;
    openvdb::Coord mMin, mMax;              ///< cells holding triangles
    std::vector<std::uint64_t> mCellKeys;   ///< sorted occupied cells
    std::vector<std::uint32_t> mCellStart;  ///< CSR offsets into mCellTriangles (size keys+1)
    std::vector<std::uint32_t> mCellTriangles;
};

/// Distances of @a points to @a reference (parallel, deterministic), as float.
std::vector<float> metroDistances(const ReferenceSurface& reference,
    const std::vector<openvdb::Vec3d>& points);

// ---- Statistics ---------------------------------------------------------------------------

/// max, mean, RMS over the finite values (NaN estimates mean "unknown", SPEC §3).
struct ErrorStats {
    double max = 0.0, mean = 0.0, rms = 0.0;
    std::size_t count = 0;
};
ErrorStats errorStats(const std::vector<float>& values);

/// An estimate against a measured error over the vertices where both are finite:
/// RMS(estimate) / RMS(measured) and Spearman's rank correlation (ties get mean ranks).
struct Agreement {
    double rmsRatio = 0.0, spearman = 0.0;
    std::size_t count = 0;
};
Agreement compareColumns(const std::vector<float>& estimate, const std::vector<float>& measured);

/// Spearman's rho of two equal-length samples (Pearson correlation of mid-ranks).
double spearmanCorrelation(const std::vector<double>& a, const std::vector<double>& b);

// ---- The paper's experiments --------------------------------------------------------------

/// Meshes @a grid at @a isovalue with every method (positions: WENO) and copies t_weno_paper
/// from a second pass with the weno-paper method, so one mesh carries all four crossings.
Mesh meshAllMethods(const openvdb::FloatGrid& grid, float isovalue);

/// One synthetic field at one resolution (SPEC §5; the paper's Figs. 3-4).
struct ValidationCase {
    std::string field;           ///< AnalyticFields.h name
    int resolution = 32;
    int referenceResolution = 0; ///< METRO reference (meshed with WENO); 0: none
};

/// The paper's five fields at its resolutions and isovalues (SPEC §5, Fig. 3 captions), with
/// torus-paper beside the standard torus.
std::vector<ValidationCase> paperCases();

/// A validated mesh: every method's crossing and estimate, err_true_<m>, dist_true_<m>
/// (m = linear cubic weno weno_paper), dist_true, and dist_metro_linear when a reference is
/// asked for.
struct ValidationResult {
    ValidationCase spec;
    float isovalue = 0.0f;
    Mesh mesh;
    TruthReport truth;
    std::size_t referenceTriangles = 0;
};

/// Loads the field, meshes it with every method and adds the truth (and METRO) columns.
/// @throw InputError for an unknown field.
ValidationResult runValidationCase(const ValidationCase& spec);

/// Method names in column order, and their crossing columns.
inline constexpr std::array<const char*, 4> kValidationMethods = {"linear", "cubic", "weno", "weno_paper"};

/// RMS edge-crossing error per method over the interior edges of one resolution: the edges
/// whose six-point stencil lies in the data (WENO's order is 6). "mesher" uses the mesh's
/// float t columns; "exact" re-evaluates the same interpolators (EdgeInterp.h) in double on
/// the analytic samples, free of the float32 storage floor.
struct ConvergenceRow {
    std::string field;
    int resolution = 0;
    double spacing = 0.0;
    std::size_t edges = 0;
    std::array<double, 4> mesher{}; ///< kValidationMethods order
    std::array<double, 4> exact{};
};
ConvergenceRow convergenceRow(const std::string& field, int resolution);

/// Observed order between two resolutions: log(e1 / e2) / log(h1 / h2).
double observedOrder(double coarseError, double coarseSpacing, double fineError, double fineSpacing);

/// Least-squares slope of log(error) against log(h) over all the points: the order fitted to
/// a whole sequence, less sensitive than one pair to how the edges' crossings are spread.
double fittedOrder(const std::vector<double>& errors, const std::vector<double>& spacings);

} // namespace isouq
