// isouq: measured errors against analytic truths (paper sec. 4.1; SPEC §3 "Measured error",
// §6; docs/validation.md).
#include "isouq/Truth.h"

#include "ValidationInternal.h"

#include "isouq/Columns.h"

#include <algorithm>
#include <cmath>

namespace isouq {
namespace validation_internal {
namespace {


/// Root of g on [lo, hi] with g(lo), g(hi) of opposite signs: Illinois regula falsi, which
/// keeps the bracket and converges superlinearly; stops at a relative width of ~1e-15.
template <typename FunT>
double refineRoot(const FunT& g, double lo, double hi, double gLo, double gHi)
{
    int side = 0;
    for (int it = 0; it < 200 && hi - lo > 1e-15; ++it) {
        double t = (lo * gHi - hi * gLo) / (gHi - gLo);
        if (!(t > lo && t < hi)) t = 0.5 * (lo + hi);
        const double gt = g(t);
        if (gt == 0.0) return t;
        if ((gt < 0.0) == (gLo < 0.0)) {
            lo = t;
            gLo = gt;
            if (side == -1) gHi *= 0.5;
            side = -1;
        } else {
            hi = t;
            gHi = gt;
            if (side == 1) gLo *= 0.5;
            side = 1;
        }
    }
    return 0.5 * (lo + hi);
}

Vec3d gradient(const AnalyticField& field, const Vec3d& p, double step)
{
    Vec3d g;
    for (int a = 0; a < 3; ++a) {
        Vec3d lo = p, hi = p;
        lo[a] -= step;
        hi[a] += step;
        g[a] = (field(hi[0], hi[1], hi[2]) - field(lo[0], lo[1], lo[2])) / (2.0 * step);
    }
    return g;
}

/// Newton steps q <- q - (f(q) - k) g / |g|^2 with backtracking on |f - k|; false if stuck.
bool projectToSurface(const AnalyticField& field, double k, Vec3d& q, double scale)
{
    const double step = 1e-6 * scale;
    double r = field(q[0], q[1], q[2]) - k;
    for (int it = 0; it < 100; ++it) {
        const Vec3d g = gradient(field, q, step);
        const double g2 = g.lengthSqr();
        if (!(g2 > 0.0) || !std::isfinite(r)) return false;
        const Vec3d delta = g * (-r / g2);
        if (delta.length() < 1e-13 * scale) return true;
        double lambda = 1.0;
        for (int ls = 0; ls < 40; ++ls, lambda *= 0.5) {
            const Vec3d trial = q + delta * lambda;
            const double rt = field(trial[0], trial[1], trial[2]) - k;
            if (std::abs(rt) < std::abs(r) * (1.0 - 1e-4 * lambda)) {
                q = trial;
                r = rt;
                break;
            }
        }
        if (lambda < 1e-12) return std::abs(r) / std::sqrt(g2) < 1e-12 * scale;
    }
    return std::abs(r) / gradient(field, q, step).length() < 1e-12 * scale;
}

/// From a surface point q, slide along the surface until p - q is normal to it.
double closestPointDistance(const AnalyticField& field, double k, const Vec3d& p, Vec3d q, double scale)
{
    if (!projectToSurface(field, k, q, scale)) return kNaN;
    for (int it = 0; it < 200; ++it) {
        Vec3d n = gradient(field, q, 1e-6 * scale);
        n.normalize();
        const Vec3d v = p - q;
        const Vec3d tangential = v - n * v.dot(n);
        if (tangential.length() < 1e-9 * scale) return v.length();
        // Damped: accept a move only if it brings q closer to p.
        double lambda = 1.0;
        bool moved = false;
        for (int ls = 0; ls < 30 && !moved; ++ls, lambda *= 0.5) {
            Vec3d trial = q + tangential * lambda;
            if (!projectToSurface(field, k, trial, scale)) continue;
            if ((p - trial).length() <= v.length()) {
                q = trial;
                moved = true;
            }
        }
        if (!moved) return v.length(); // a local minimum of the distance up to rounding
    }
    return (p - q).length();
}


} // namespace
} // namespace validation_internal

using namespace validation_internal;


EdgeRoot exactEdgeCrossing(const AnalyticField& field, double k, const Vec3d& a, const Vec3d& b)
{
    const Vec3d d = b - a;
    auto g = [&](double t) { return field(a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]) - k; };
    constexpr int kSub = 32;
    double roots[kSub];
    int count = 0;
    double tPrev = 0.0, gPrev = g(0.0);
    double nearest = 0.0, nearestAbs = std::abs(gPrev);
    for (int s = 1; s <= kSub; ++s) {
        const double t = double(s) / kSub, gt = g(t);
        if (std::abs(gt) < nearestAbs) {
            nearest = t;
            nearestAbs = std::abs(gt);
        }
        if (gPrev == 0.0) {
            roots[count++] = tPrev;
        } else if ((gPrev < 0.0) != (gt < 0.0) && gt != 0.0) {
            roots[count++] = refineRoot(g, tPrev, t, gPrev, gt);
        } else if (gt == 0.0 && s == kSub) {
            roots[count++] = t;
        }
        tPrev = t;
        gPrev = gt;
    }
    if (count == 0) return {nearest, 0};
    return {roots[(count - 1) / 2], count};
}

double distanceToLevelSet(const AnalyticField& field, double k, const Vec3d& p, double scale, const Vec3d* seed)
{
    double d = closestPointDistance(field, k, p, p, scale);
    if (seed && !(d <= (p - *seed).length())) {
        const double fromSeed = closestPointDistance(field, k, p, *seed, scale);
        if (std::isnan(d) || fromSeed < d) d = fromSeed;
    }
    return d;
}

std::vector<Vec3d> crossingPositions(const Mesh& mesh, std::string_view tColumn)
{
    const Provenance prov(mesh);
    const std::vector<float>* t = mesh.vertexAttributes.find<float>(tColumn);
    if (!t) OPENVDB_THROW(openvdb::ValueError, "the mesh has no column " + std::string(tColumn));
    std::vector<Vec3d> out(t->size());
    for (std::size_t n = 0; n < out.size(); ++n) out[n] = toWorld(mesh.indexToWorld, prov.along(n, (*t)[n]));
    return out;
}

TruthReport addTruthColumns(Mesh& mesh, const AnalyticField& field, double isovalue, const TruthSettings& settings)
{
    Provenance prov(mesh);
    const std::size_t n = mesh.positions.size();
    const std::array<double, 16>& m = mesh.indexToWorld;
    // Smallest grid spacing: the length scale for gradients and tolerances.
    double scale = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) scale = std::min(scale, Vec3d(m[a], m[4 + a], m[8 + a]).length());

    // Exact crossing of every vertex's edge (SPEC §3 edge error).
    std::vector<double> tExact(n);
    std::vector<std::uint8_t> rootCount(n);
    forEachIndex(n, settings.threaded, [&](std::size_t b, std::size_t e) {
        for (std::size_t v = b; v < e; ++v) {
            const EdgeRoot r = exactEdgeCrossing(field, isovalue, toWorld(m, prov.lower(v)),
                toWorld(m, prov.along(v, 1.0)));
            tExact[v] = r.t;
            rootCount[v] = std::uint8_t(std::min(r.roots, 255));
        }
    });

    // Add every column first, then take pointers: adding a column may move the others.
    std::vector<EdgeMethod> present;
    for (EdgeMethod method : kAllMethods)
        if (mesh.vertexAttributes.find<float>(tColumn(method))) present.push_back(method);
    for (EdgeMethod method : present) {
        mesh.vertexAttributes.add<float>(errTrueColumn(method), n);
        if (settings.perMethodDistance) mesh.vertexAttributes.add<float>(distTrueColumn(method), n);
    }
    mesh.vertexAttributes.add<float>(col::kDistTrue, n);
    struct MethodColumns {
        const std::vector<float>* t;
        std::vector<float>* errTrue;
        std::vector<float>* distTrue;
    };
    std::vector<MethodColumns> methods;
    AttributeTable& table = mesh.vertexAttributes;
    for (EdgeMethod method : present)
        methods.push_back({table.find<float>(tColumn(method)), table.find<float>(errTrueColumn(method)),
            settings.perMethodDistance ? table.find<float>(distTrueColumn(method)) : nullptr});
    std::vector<float>& dist = *table.find<float>(col::kDistTrue);
    prov = Provenance(mesh); // the table's columns may have moved

    std::atomic<std::size_t> failed{0};
    forEachIndex(n, settings.threaded, [&](std::size_t b, std::size_t e) {
        std::size_t localFailed = 0;
        for (std::size_t v = b; v < e; ++v) {
            const Vec3d exact = toWorld(m, prov.along(v, tExact[v]));
            for (const MethodColumns& c : methods) {
                const Vec3d x = toWorld(m, prov.along(v, (*c.t)[v]));
                (*c.errTrue)[v] = float((x - exact).length());
                if (c.distTrue) (*c.distTrue)[v] = float(distanceToLevelSet(field, isovalue, x, scale, &exact));
            }
            const openvdb::Vec3s& p = mesh.positions[v];
            const double d = distanceToLevelSet(field, isovalue, Vec3d(p[0], p[1], p[2]), scale, &exact);
            dist[v] = float(d);
            if (std::isnan(d)) ++localFailed;
        }
        failed += localFailed;
    });

    TruthReport report;
    report.vertices = n;
    report.failedProjections = failed;
    for (std::uint8_t c : rootCount) {
        if (c == 0) ++report.noRootEdges;
        if (c > 1) ++report.multiRootEdges;
    }
    return report;
}

} // namespace isouq
