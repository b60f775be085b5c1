// isouq: the paper's validation experiments: METRO distances to finer reference surfaces, the
// statistics that compare estimates with measured errors, and the cases of Figs. 3-4 (paper
// sec. 4.1; SPEC §3, §5; docs/validation.md). The truth columns themselves are in Truth.h.
#pragma once

#include "isouq/Truth.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace isouq {

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

/// RMS edge-crossing error per method over the interior edges of one resolution: the edges
/// whose six-point stencil lies in the data (WENO's order is 6). "mesher" uses the mesh's
/// float t columns; "exact" re-evaluates the same interpolators (EdgeInterp.h) in double on
/// the analytic samples, free of the float32 storage floor.
struct ConvergenceRow {
    std::string field;
    int resolution = 0;
    double spacing = 0.0;
    std::size_t edges = 0;
    std::array<double, 4> mesher{}; ///< kAllMethods order (Columns.h)
    std::array<double, 4> exact{};
};
ConvergenceRow convergenceRow(const std::string& field, int resolution);

/// Observed order between two resolutions: log(e1 / e2) / log(h1 / h2).
double observedOrder(double coarseError, double coarseSpacing, double fineError, double fineSpacing);

/// Least-squares slope of log(error) against log(h) over all the points: the order fitted to
/// a whole sequence, less sensitive than one pair to how the edges' crossings are spread.
double fittedOrder(const std::vector<double>& errors, const std::vector<double>& spacings);

} // namespace isouq
