// isouq: METRO references, the statistics that compare estimates with measured errors, and
// the paper's experiments (paper sec. 4.1, Figs. 3-4; SPEC §3, §5; docs/validation.md).
#include "isouq/Validation.h"

#include "ValidationInternal.h"

#include "isouq/Columns.h"
#include "isouq/EdgeInterp.h"
#include "isouq/MarchingCubes.h"
#include "isouq/VolumeSources.h"

#include <openvdb/math/Proximity.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <numeric>

namespace isouq {
namespace validation_internal {
namespace {


std::uint64_t cellKey(const openvdb::Coord& c)
{
    constexpr std::int64_t bias = 1 << 20;
    return (std::uint64_t(c[0] + bias) << 42) | (std::uint64_t(c[1] + bias) << 21) | std::uint64_t(c[2] + bias);
}

std::vector<double> midRanks(const std::vector<double>& v)
{
    std::vector<std::size_t> order(v.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return v[a] < v[b]; });
    std::vector<double> rank(v.size());
    for (std::size_t s = 0; s < order.size();) {
        std::size_t e = s;
        while (e < order.size() && v[order[e]] == v[order[s]]) ++e;
        const double mid = 0.5 * double(s + e - 1);
        for (std::size_t q = s; q < e; ++q) rank[order[q]] = mid;
        s = e;
    }
    return rank;
}


} // namespace
} // namespace validation_internal

using namespace validation_internal;

// ---- METRO ----------------------------------------------------------------------------------

ReferenceSurface::ReferenceSurface(const Mesh& mesh, double cellSize)
    : mTriangles(mesh.triangles), mCellSize(cellSize)
{
    mPoints.reserve(mesh.positions.size());
    for (const openvdb::Vec3s& p : mesh.positions) mPoints.emplace_back(p[0], p[1], p[2]);
    std::vector<std::pair<std::uint64_t, std::uint32_t>> entries;
    mMin = openvdb::Coord::max();
    mMax = openvdb::Coord::min();
    for (std::uint32_t t = 0; t < mTriangles.size(); ++t) {
        const auto c = corners(t);
        openvdb::Coord lo, hi;
        for (int a = 0; a < 3; ++a) {
            const double mn = std::min({c[0][a], c[1][a], c[2][a]}), mx = std::max({c[0][a], c[1][a], c[2][a]});
            lo[a] = int(std::floor(mn / mCellSize));
            hi[a] = int(std::floor(mx / mCellSize));
        }
        mMin.minComponent(lo);
        mMax.maxComponent(hi);
        for (int x = lo[0]; x <= hi[0]; ++x)
            for (int y = lo[1]; y <= hi[1]; ++y)
                for (int z = lo[2]; z <= hi[2]; ++z) entries.emplace_back(cellKey(openvdb::Coord(x, y, z)), t);
    }
    std::sort(entries.begin(), entries.end());
    mCellTriangles.reserve(entries.size());
    for (std::size_t e = 0; e < entries.size(); ++e) {
        if (e == 0 || entries[e].first != entries[e - 1].first) {
            mCellKeys.push_back(entries[e].first);
            mCellStart.push_back(std::uint32_t(e));
        }
        mCellTriangles.push_back(entries[e].second);
    }
    mCellStart.push_back(std::uint32_t(entries.size()));
}

std::array<Vec3d, 3> ReferenceSurface::corners(std::uint32_t t) const
{
    const openvdb::Vec3I& tri = mTriangles[t];
    return {mPoints[tri[0]], mPoints[tri[1]], mPoints[tri[2]]};
}

bool ReferenceSurface::cellRange(const openvdb::Coord& c, std::size_t& begin, std::size_t& end) const
{
    const auto it = std::lower_bound(mCellKeys.begin(), mCellKeys.end(), cellKey(c));
    if (it == mCellKeys.end() || *it != cellKey(c)) return false;
    const std::size_t slot = std::size_t(it - mCellKeys.begin());
    begin = mCellStart[slot];
    end = mCellStart[slot + 1];
    return true;
}

double ReferenceSurface::distance(const Vec3d& p) const
{
    if (mTriangles.empty()) return kNaN;
    const openvdb::Coord c(int(std::floor(p[0] / mCellSize)), int(std::floor(p[1] / mCellSize)),
        int(std::floor(p[2] / mCellSize)));
    // Any point within r * cellSize of p lies in the cells c +- r; grow r until the best
    // distance is within that radius (or the cube covers every occupied cell).
    double best = std::numeric_limits<double>::infinity();
    for (int r = 1;; ++r) {
        for (int x = c[0] - r; x <= c[0] + r; ++x)
            for (int y = c[1] - r; y <= c[1] + r; ++y)
                for (int z = c[2] - r; z <= c[2] + r; ++z) {
                    const bool shell = std::max({std::abs(x - c[0]), std::abs(y - c[1]), std::abs(z - c[2])}) == r;
                    if (r > 1 && !shell) continue;
                    std::size_t b, e;
                    if (!cellRange(openvdb::Coord(x, y, z), b, e)) continue;
                    for (std::size_t q = b; q < e; ++q) {
                        const auto tri = corners(mCellTriangles[q]);
                        Vec3d uvw;
                        const Vec3d cp = openvdb::math::closestPointOnTriangleToPoint(tri[0], tri[1], tri[2], p, uvw);
                        best = std::min(best, (cp - p).length());
                    }
                }
        const bool covers = c[0] - r <= mMin[0] && c[1] - r <= mMin[1] && c[2] - r <= mMin[2]
            && c[0] + r >= mMax[0] && c[1] + r >= mMax[1] && c[2] + r >= mMax[2];
        if (best <= r * mCellSize || covers) return best;
    }
}

std::vector<float> metroDistances(const ReferenceSurface& reference, const std::vector<Vec3d>& points)
{
    std::vector<float> out(points.size());
    forEachIndex(points.size(), true, [&](std::size_t b, std::size_t e) {
        for (std::size_t v = b; v < e; ++v) out[v] = float(reference.distance(points[v]));
    });
    return out;
}

// ---- Statistics -----------------------------------------------------------------------------

ErrorStats errorStats(const std::vector<float>& values)
{
    ErrorStats s;
    double sum = 0.0, sumSq = 0.0;
    for (float v : values) {
        if (!std::isfinite(v)) continue;
        s.max = s.count ? std::max(s.max, double(v)) : double(v);
        sum += v;
        sumSq += double(v) * v;
        ++s.count;
    }
    if (s.count) {
        s.mean = sum / double(s.count);
        s.rms = std::sqrt(sumSq / double(s.count));
    }
    return s;
}

double spearmanCorrelation(const std::vector<double>& a, const std::vector<double>& b)
{
    const std::size_t n = a.size();
    if (n < 2 || b.size() != n) return kNaN;
    const std::vector<double> ra = midRanks(a), rb = midRanks(b);
    const double mean = 0.5 * double(n - 1);
    double sab = 0.0, saa = 0.0, sbb = 0.0;
    for (std::size_t q = 0; q < n; ++q) {
        sab += (ra[q] - mean) * (rb[q] - mean);
        saa += (ra[q] - mean) * (ra[q] - mean);
        sbb += (rb[q] - mean) * (rb[q] - mean);
    }
    return sab / std::sqrt(saa * sbb);
}

Agreement compareColumns(const std::vector<float>& estimate, const std::vector<float>& measured)
{
    std::vector<double> a, b;
    double sa = 0.0, sb = 0.0;
    for (std::size_t q = 0; q < std::min(estimate.size(), measured.size()); ++q) {
        if (!std::isfinite(estimate[q]) || !std::isfinite(measured[q])) continue;
        a.push_back(estimate[q]);
        b.push_back(measured[q]);
        sa += double(estimate[q]) * estimate[q];
        sb += double(measured[q]) * measured[q];
    }
    Agreement g;
    g.count = a.size();
    if (g.count == 0) return g;
    g.rmsRatio = std::sqrt(sa / sb);
    g.spearman = spearmanCorrelation(a, b);
    return g;
}

double observedOrder(double coarseError, double coarseSpacing, double fineError, double fineSpacing)
{
    return std::log(coarseError / fineError) / std::log(coarseSpacing / fineSpacing);
}

double fittedOrder(const std::vector<double>& errors, const std::vector<double>& spacings)
{
    const std::size_t n = std::min(errors.size(), spacings.size());
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (std::size_t q = 0; q < n; ++q) {
        const double x = std::log(spacings[q]), y = std::log(errors[q]);
        sx += x;
        sy += y;
        sxx += x * x;
        sxy += x * y;
    }
    return (double(n) * sxy - sx * sy) / (double(n) * sxx - sx * sx);
}

// ---- Experiments ----------------------------------------------------------------------------

Mesh meshAllMethods(const openvdb::FloatGrid& grid, float isovalue)
{
    MeshSettings settings;
    settings.isovalue = isovalue;
    settings.uncertainty = true;
    settings.method = EdgeMethod::Weno;
    Mesh mesh = extractIsosurface(grid, settings);
    settings.method = EdgeMethod::WenoPaper;
    const Mesh paper = extractIsosurface(grid, settings);
    const auto* paperT = paper.vertexAttributes.find<float>(col::kTWenoPaper);
    const auto *edgeI = mesh.vertexAttributes.find<std::int32_t>(col::kEdgeI),
               *paperI = paper.vertexAttributes.find<std::int32_t>(col::kEdgeI);
    const auto *axis = mesh.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis),
               *paperAxis = paper.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis);
    if (!paperT || *edgeI != *paperI || *axis != *paperAxis)
        OPENVDB_THROW(openvdb::RuntimeError, "weno-paper pass produced different vertices");
    mesh.vertexAttributes.add<float>(col::kTWenoPaper, paperT->size()) = *paperT;
    return mesh;
}

std::vector<ValidationCase> paperCases()
{
    // SPEC §5 and the captions of the paper's Fig. 3 (Marschner-Lobb at 64^3); the METRO
    // reference at 8x the resolution (the paper's 512^3 for the 64^3 fields).
    return {{"tangle", 32, 256}, {"torus", 64, 512}, {"torus-paper", 64, 512},
        {"marschner-lobb", 64, 512}, {"teardrop", 32, 256}, {"tubey", 32, 256}};
}

ValidationResult runValidationCase(const ValidationCase& spec)
{
    VolumeRequest request;
    request.input = "field:" + spec.field;
    request.resolution = spec.resolution;
    const LoadedVolume volume = loadVolume(request);
    ValidationResult result;
    result.spec = spec;
    result.isovalue = volume.isovalue;
    result.mesh = meshAllMethods(*volume.grid, volume.isovalue);
    TruthSettings truth;
    truth.perMethodDistance = true;
    result.truth = addTruthColumns(result.mesh, *volume.truth, volume.isovalue, truth);
    if (spec.referenceResolution > 0) {
        request.resolution = spec.referenceResolution;
        const LoadedVolume fine = loadVolume(request);
        MeshSettings settings;
        settings.isovalue = fine.isovalue;
        settings.uncertainty = true;
        settings.method = EdgeMethod::Weno;
        const Mesh reference = extractIsosurface(*fine.grid, settings);
        result.referenceTriangles = reference.triangles.size();
        const ReferenceSurface surface(reference, volume.truth->spacing(spec.resolution));
        result.mesh.vertexAttributes.add<float>(col::kDistMetroLinear, result.mesh.positions.size()) =
            metroDistances(surface, crossingPositions(result.mesh, col::kTLinear));
    }
    return result;
}

ConvergenceRow convergenceRow(const std::string& fieldName, int resolution)
{
    VolumeRequest request;
    request.input = "field:" + fieldName;
    request.resolution = resolution;
    const LoadedVolume volume = loadVolume(request);
    Mesh mesh = meshAllMethods(*volume.grid, volume.isovalue);
    addTruthColumns(mesh, *volume.truth, volume.isovalue);
    const AnalyticField& field = *volume.truth;
    const Provenance prov(mesh);
    const auto& order = *mesh.vertexAttributes.find<std::uint8_t>(col::kOrder);
    const double k = double(volume.isovalue);

    ConvergenceRow row;
    row.field = fieldName;
    row.resolution = resolution;
    row.spacing = field.spacing(resolution);
    const std::size_t n = mesh.positions.size();
    // Per vertex squared errors [mesher m, exact m]; summed serially for determinism.
    std::array<const std::vector<float>*, 4> errTrue;
    for (int q = 0; q < 4; ++q)
        errTrue[q] = mesh.vertexAttributes.find<float>(errTrueColumn(kAllMethods[q]));
    std::vector<std::array<double, 8>> sq(n);
    std::vector<std::uint8_t> interior(n);
    forEachIndex(n, true, [&](std::size_t b, std::size_t e) {
        for (std::size_t v = b; v < e; ++v) {
            interior[v] = order[v] == 6;
            if (!interior[v]) continue;
            const Vec3d lower = prov.lower(v);
            const int axis = (*prov.axis)[v];
            std::array<double, 6> f;
            for (int j = 0; j < 6; ++j) {
                Vec3d ijk = lower;
                ijk[axis] += j - 2;
                const Vec3d w = toWorld(mesh.indexToWorld, ijk);
                f[j] = field(w[0], w[1], w[2]);
            }
            const EdgeRoot root = exactEdgeCrossing(field, k, toWorld(mesh.indexToWorld, lower),
                toWorld(mesh.indexToWorld, prov.along(v, 1.0)));
            const double h = row.spacing;
            const double tExact[4] = {LinearEdge::crossing(f, kStencilAll, k).t,
                CubicEdge::crossing(f, kStencilAll, k).t, WenoEdge::crossing(f, kStencilAll, k).t,
                WenoPaperEdge::crossing(f, kStencilAll, k).t};
            for (int q = 0; q < 4; ++q) {
                const float err = (*errTrue[q])[v];
                sq[v][q] = double(err) * err;
                const double de = h * (tExact[q] - root.t);
                sq[v][4 + q] = de * de;
            }
        }
    });
    std::array<double, 8> sum{};
    for (std::size_t v = 0; v < n; ++v) {
        if (!interior[v]) continue;
        ++row.edges;
        for (int q = 0; q < 8; ++q) sum[q] += sq[v][q];
    }
    for (int q = 0; q < 4 && row.edges; ++q) {
        row.mesher[q] = std::sqrt(sum[q] / double(row.edges));
        row.exact[q] = std::sqrt(sum[4 + q] / double(row.edges));
    }
    return row;
}

} // namespace isouq
