// Tests of the validation truths (exact edge crossings, distances to the true surface, METRO)
// against closed forms and brute force, and of the paper's claims (paper sec. 4.1, Figs. 3-4;
// SPEC §2, §3; docs/validation.md).
#include <isouq/MarchingCubes.h>
#include <isouq/Validation.h>
#include <isouq/VolumeSources.h>

#include <openvdb/math/Proximity.h>

#include <catch2/catch.hpp>

#include <cmath>
#include <random>

using namespace isouq;
using openvdb::Vec3d;

namespace {

constexpr double kRadius = 0.75; // AnalyticFields.h sphere

AnalyticField makeField(std::string name, double lo, double hi, std::function<double(double, double, double)> f)
{
    AnalyticField field;
    field.name = std::move(name);
    field.lo = lo;
    field.hi = hi;
    field.f = std::move(f);
    return field;
}

/// Every voxel of the N^3 samples of @a field (world lo + ijk h), all active, with the data box
/// set, as VolumeSources builds dense fields.
openvdb::FloatGrid::Ptr sampleDense(const AnalyticField& field, int n)
{
    auto grid = openvdb::FloatGrid::create(0.0f);
    auto acc = grid->getAccessor();
    const double h = field.spacing(n);
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                acc.setValue(openvdb::Coord(i, j, k), float(field(field.lo + i * h, field.lo + j * h, field.lo + k * h)));
    auto xform = openvdb::math::Transform::createLinearTransform(h);
    xform->postTranslate(Vec3d(field.lo));
    grid->setTransform(xform);
    return grid;
}

Mesh meshDense(const AnalyticField& field, int n, float k)
{
    MeshSettings settings;
    settings.isovalue = k;
    settings.uncertainty = true;
    settings.dataBounds = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(n - 1));
    return extractIsosurface(*sampleDense(field, n), settings);
}

double rms(const std::vector<float>& v) { return errorStats(v).rms; }

} // namespace

TEST_CASE("Validation: exact edge crossings of a plane and a sphere are the closed forms", "[validation][truth]")
{
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-0.9, 0.9), t01(0.0, 1.0);
    SECTION("plane")
    {
        const AnalyticField plane = makeField("plane", -1, 1, [](double x, double y, double z) { return 0.3 * x - 0.7 * y + 0.2 * z; });
        for (int s = 0; s < 500; ++s) {
            const Vec3d a(u(rng), u(rng), u(rng));
            Vec3d b = a;
            b[s % 3] += 0.05;
            const double fa = plane(a[0], a[1], a[2]), fb = plane(b[0], b[1], b[2]);
            const double k = fa + t01(rng) * (fb - fa);
            const EdgeRoot r = exactEdgeCrossing(plane, k, a, b);
            CHECK(r.roots == 1);
            CHECK_THAT(r.t, Catch::WithinAbs((k - fa) / (fb - fa), 1e-12));
        }
    }
    SECTION("sphere along x")
    {
        const AnalyticField& sphere = *findAnalyticField("sphere");
        for (int s = 0; s < 500; ++s) {
            const double y = 0.5 * u(rng), z = 0.5 * u(rng);
            const double x = std::sqrt(kRadius * kRadius - y * y - z * z);
            const double x0 = x - 0.05 * t01(rng);
            const EdgeRoot r = exactEdgeCrossing(sphere, 0.0, Vec3d(x0, y, z), Vec3d(x0 + 0.05, y, z));
            CHECK_THAT(r.t, Catch::WithinAbs((x - x0) / 0.05, 1e-12));
        }
    }
    SECTION("three roots: the median")
    {
        // f = (x - 0.2)(x - 0.5)(x - 0.8) on [0, 1] along x: roots at t = 0.2, 0.5, 0.8.
        const AnalyticField cubic = makeField("cubic", -1, 1, [](double x, double, double) { return (x - 0.2) * (x - 0.5) * (x - 0.8); });
        const EdgeRoot r = exactEdgeCrossing(cubic, 0.0, Vec3d(0, 0, 0), Vec3d(1, 0, 0));
        CHECK(r.roots == 3);
        CHECK_THAT(r.t, Catch::WithinAbs(0.5, 1e-12));
    }
}

TEST_CASE("Validation: err_true and dist_true on the sphere field match closed forms", "[validation][truth]")
{
    VolumeRequest request;
    request.input = "field:sphere";
    request.resolution = 32;
    const LoadedVolume volume = loadVolume(request);
    Mesh mesh = meshAllMethods(*volume.grid, volume.isovalue);
    TruthSettings settings;
    settings.perMethodDistance = true;
    const TruthReport report = addTruthColumns(mesh, *volume.truth, volume.isovalue, settings);
    REQUIRE(report.vertices == mesh.positions.size());
    CHECK(report.failedProjections == 0);
    CHECK(report.multiRootEdges == 0);

    const double h = volume.truth->spacing(32);
    const auto& ei = *mesh.vertexAttributes.find<std::int32_t>("edge_i");
    const auto& ej = *mesh.vertexAttributes.find<std::int32_t>("edge_j");
    const auto& ek = *mesh.vertexAttributes.find<std::int32_t>("edge_k");
    const auto& axis = *mesh.vertexAttributes.find<std::uint8_t>("edge_axis");
    const auto& tLinear = *mesh.vertexAttributes.find<float>("t_linear");
    const auto& errLinear = *mesh.vertexAttributes.find<float>("err_true_linear");
    const auto& distTrue = *mesh.vertexAttributes.find<float>("dist_true");
    const auto& distLinear = *mesh.vertexAttributes.find<float>("dist_true_linear");
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
        // Closed form: on the axis-a line through the edge, x_a^2 = r^2 - (other two)^2.
        Vec3d lower(-1 + ei[v] * h, -1 + ej[v] * h, -1 + ek[v] * h);
        const int a = axis[v];
        double others = 0.0;
        for (int b = 0; b < 3; ++b)
            if (b != a) others += lower[b] * lower[b];
        double root = std::sqrt(kRadius * kRadius - others);
        if (std::abs(-root - (lower[a] + 0.5 * h)) < std::abs(root - (lower[a] + 0.5 * h))) root = -root;
        REQUIRE(root >= lower[a] - 1e-12);
        REQUIRE(root <= lower[a] + h + 1e-12);
        const double xLinear = lower[a] + double(tLinear[v]) * h;
        // float columns: relative 6e-8, and the float grid spacing of the index map.
        CHECK_THAT(errLinear[v], Catch::WithinAbs(std::abs(xLinear - root), 1e-7 * h + 1e-9));
        Vec3d pLinear = lower;
        pLinear[a] = xLinear;
        CHECK_THAT(distLinear[v], Catch::WithinAbs(std::abs(pLinear.length() - kRadius), 1e-7 * h + 1e-9));
        const Vec3d p(mesh.positions[v][0], mesh.positions[v][1], mesh.positions[v][2]);
        CHECK_THAT(distTrue[v], Catch::WithinAbs(std::abs(p.length() - kRadius), 1e-7 * h + 1e-9));
    }
}

TEST_CASE("Validation: distance to a level set matches closed forms", "[validation][truth]")
{
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-1.0, 1.0), off(-0.05, 0.05);
    SECTION("sphere as x^2 + y^2 + z^2 = r^2 (gradient length varies)")
    {
        const AnalyticField quadric = makeField("quadric", -1, 1, [](double x, double y, double z) { return x * x + y * y + z * z; });
        for (int s = 0; s < 300; ++s) {
            Vec3d dir(u(rng), u(rng), u(rng));
            if (dir.length() < 0.1) continue;
            dir.normalize();
            const Vec3d p = dir * (0.6 + off(rng)) + Vec3d(off(rng), off(rng), off(rng)) * 0.1;
            CHECK_THAT(distanceToLevelSet(quadric, 0.36, p, 0.05), Catch::WithinAbs(std::abs(p.length() - 0.6), 1e-11));
        }
    }
    SECTION("standard torus (closest point off the gradient line)")
    {
        const AnalyticField& torus = *findAnalyticField("torus");
        for (int s = 0; s < 300; ++s) {
            const double phi = 3.14159 * u(rng), theta = 3.14159 * u(rng), rho = 0.1 + 0.04 * u(rng);
            const Vec3d p((0.3 + rho * std::cos(theta)) * std::cos(phi), (0.3 + rho * std::cos(theta)) * std::sin(phi),
                rho * std::sin(theta));
            const double ring = std::sqrt(p[0] * p[0] + p[1] * p[1]) - 0.3;
            const double exact = std::abs(std::sqrt(ring * ring + p[2] * p[2]) - 0.1);
            CHECK_THAT(distanceToLevelSet(torus, 0.0, p, 0.03), Catch::WithinAbs(exact, 1e-11));
        }
    }
}

TEST_CASE("Validation: METRO distances equal brute force over all triangles", "[validation][metro]")
{
    VolumeRequest request;
    request.input = "field:tangle";
    request.resolution = 24;
    const LoadedVolume volume = loadVolume(request);
    MeshSettings settings;
    settings.isovalue = volume.isovalue;
    const Mesh mesh = extractIsosurface(*volume.grid, settings);
    const double h = volume.truth->spacing(24);
    const ReferenceSurface reference(mesh, h);
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1.2, 1.2);
    std::vector<Vec3d> points;
    for (int s = 0; s < 300; ++s) points.emplace_back(u(rng), u(rng), u(rng));
    for (std::size_t s = 0; s < 300; ++s) { // near the surface too
        const openvdb::Vec3s& p = mesh.positions[(s * 7919) % mesh.positions.size()];
        points.emplace_back(p[0] + 0.01 * u(rng), p[1] + 0.01 * u(rng), p[2] + 0.01 * u(rng));
    }
    const std::vector<float> fast = metroDistances(reference, points);
    for (std::size_t s = 0; s < points.size(); ++s) {
        double best = std::numeric_limits<double>::infinity();
        for (const openvdb::Vec3I& t : mesh.triangles) {
            Vec3d uvw;
            const auto corner = [&](int c) { return Vec3d(mesh.positions[t[c]]); };
            best = std::min(best,
                (openvdb::math::closestPointOnTriangleToPoint(corner(0), corner(1), corner(2), points[s], uvw) - points[s]).length());
        }
        CHECK(double(fast[s]) == Approx(best).epsilon(1e-6));
    }
}

TEST_CASE("Validation: statistics and Spearman's rho against hand values", "[validation][stats]")
{
    CHECK(spearmanCorrelation({1, 2, 3, 4, 5}, {2, 1, 4, 3, 5}) == Approx(0.8)); // 1 - 6*4/(5*24)
    CHECK(spearmanCorrelation({1, 2, 3}, {30, 20, 10}) == Approx(-1.0));
    // Ties get mid-ranks: (0, 1.5, 1.5, 3) against (0, 1, 2, 3) gives 4.5 / sqrt(4.5 * 5).
    CHECK(spearmanCorrelation({1, 2, 2, 3}, {1, 2, 3, 4}) == Approx(4.5 / std::sqrt(22.5)));
    const ErrorStats s = errorStats({3.0f, std::nanf(""), 4.0f});
    CHECK(s.count == 2);
    CHECK(s.max == 4.0);
    CHECK(s.mean == Approx(3.5));
    CHECK(s.rms == Approx(std::sqrt(12.5)));
    const Agreement g = compareColumns({2.0f, 4.0f, std::nanf("")}, {1.0f, 2.0f, 5.0f});
    CHECK(g.count == 2);
    CHECK(g.rmsRatio == Approx(2.0));
    CHECK(g.spearman == Approx(1.0));
    CHECK(observedOrder(4.0, 2.0, 1.0, 1.0) == Approx(2.0));
    CHECK(fittedOrder({16.0, 1.0, 1.0 / 16}, {4.0, 2.0, 1.0}) == Approx(4.0));
}

TEST_CASE("Validation: observed orders of the edge-crossing error on smooth fields", "[validation][convergence][slow]")
{
    // SPEC §2: linear ~2, cubic ~4, WENO ~6, weno-paper ~4, as h halves from 32^3 to 256^3.
    // Interior edges only (full six-point stencil). Orders are least-squares fits over the four
    // resolutions; "exact" evaluates the interpolators in double (no float32 floor).
    for (const char* name : {"sphere", "tangle"}) {
        std::vector<std::array<double, 4>> mesher, exact;
        std::vector<double> spacing;
        for (int n : {32, 64, 128, 256}) {
            const ConvergenceRow row = convergenceRow(name, n);
            mesher.push_back(row.mesher);
            exact.push_back(row.exact);
            spacing.push_back(row.spacing);
        }
        const auto order = [&](const std::vector<std::array<double, 4>>& rows, int m, std::size_t count) {
            std::vector<double> e, h;
            for (std::size_t q = 0; q < count; ++q) {
                e.push_back(rows[q][m]);
                h.push_back(spacing[q]);
            }
            return fittedOrder(e, h);
        };
        INFO(name);
        CHECK(order(exact, 0, 4) == Approx(2.0).margin(0.2));
        CHECK(order(exact, 1, 4) == Approx(4.0).margin(0.3));
        CHECK(order(exact, 2, 4) >= 5.5);
        CHECK(order(exact, 3, 4) == Approx(4.0).margin(0.3));
        // The mesher (float32 samples, float t) agrees until an error meets the float floor
        // (about ulp(k) / |grad f|: 5e-9 on tangle, k = 0.1): cubic from 256^3, WENO from 64^3.
        CHECK(order(mesher, 0, 4) == Approx(2.0).margin(0.2));
        CHECK(order(mesher, 1, 3) == Approx(4.0).margin(0.3));
        CHECK(order(mesher, 2, 2) >= 5.5);
        for (int m = 0; m < 4; ++m) CHECK(mesher[0][m] == Approx(exact[0][m]).epsilon(0.01));
    }
}

TEST_CASE("Validation: next to a jump WENO's crossing error is not larger than the cubic's", "[validation][step]")
{
    // A sphere of radius 0.5 as a distance, with a jump of +1 on the shell two cells outside
    // the surface: cubic stencils straddle the jump on many edges, WENO picks the smooth side.
    const int n = 48;
    const double h = 2.0 / (n - 1);
    for (double gap : {1.5, 2.0, 2.5}) {
        const AnalyticField step = makeField("step", -1, 1, [=](double x, double y, double z) {
            const double r = std::sqrt(x * x + y * y + z * z);
            return r - 0.5 + (r > 0.5 + gap * h ? 1.0 : 0.0);
        });
        Mesh mesh = meshDense(step, n, 0.0f);
        addTruthColumns(mesh, step, 0.0);
        const double cubic = rms(*mesh.vertexAttributes.find<float>("err_true_cubic"));
        const double weno = rms(*mesh.vertexAttributes.find<float>("err_true_weno"));
        INFO("gap " << gap << " cells: RMS cubic " << cubic << ", weno " << weno);
        CHECK(weno <= cubic);
    }
}

TEST_CASE("Validation: the paper's claims on its five fields", "[validation][paper][slow]")
{
    // Paper sec. 4.1, Fig. 4: e tracks the measured error, e_b overestimates it. Issue 3:
    // err_best = |x_cubic - x_linear| estimates the linear error almost exactly. The measured
    // errors are exact (edge: err_true_linear; surface: dist_true_linear), and METRO against a
    // 4x WENO reference checks dist_true_linear.
    for (ValidationCase spec : paperCases()) {
        spec.referenceResolution = 4 * spec.resolution;
        const ValidationResult r = runValidationCase(spec);
        const auto& a = r.mesh.vertexAttributes;
        const auto agree = [&](const char* est, const char* measured) {
            return compareColumns(*a.find<float>(est), *a.find<float>(measured));
        };
        INFO(spec.field << " " << spec.resolution << "^3");
        CHECK(r.truth.failedProjections == 0);
        const double eEdge = agree("err_est", "err_true_linear").rmsRatio;
        const double bEdge = agree("err_bound", "err_true_linear").rmsRatio;
        const double eSurface = agree("err_est", "dist_true_linear").rmsRatio;
        const double bSurface = agree("err_bound", "dist_true_linear").rmsRatio;
        INFO("RMS(e)/RMS(edge) " << eEdge << ", RMS(e_b)/RMS(edge) " << bEdge << ", RMS(e)/RMS(surface) "
                                 << eSurface << ", RMS(e_b)/RMS(surface) " << bSurface);
        CHECK(eEdge >= 0.5);
        CHECK(eEdge <= 2.0);
        CHECK(bEdge >= 3.0);
        CHECK(bSurface >= 3.0);
        // Against the surface distance e overestimates by up to 2.7x (Marschner-Lobb, Tubey,
        // torus-paper exceed 2; docs/validation.md): e measures along the edge, not the normal.
        CHECK(eSurface >= 1.0);
        CHECK(eSurface <= 3.0);
        const Agreement best = agree("err_best", "err_true_linear");
        CHECK(best.rmsRatio >= 0.75);
        CHECK(best.rmsRatio <= 1.33);
        CHECK(best.spearman >= 0.95);
        const Agreement bestSurface = agree("err_best_surface", "dist_true_linear");
        CHECK(bestSurface.rmsRatio >= 0.75);
        CHECK(bestSurface.rmsRatio <= 1.33);
        const Agreement metro = agree("dist_metro_linear", "dist_true_linear");
        CHECK(metro.rmsRatio == Approx(1.0).margin(0.1));
        CHECK(metro.spearman >= 0.95);
    }
}
