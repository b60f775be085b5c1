// isouq: the synthetic scalar fields of the paper's appendix (SPEC §5), in double precision.
//
// Each field is f(x, y, z) on the cube [lo, hi]^3 with a default isovalue k; "inside" is
// f >= k as everywhere in isouq. Sampled at N^3 points that include both ends of the domain:
// spacing h = (hi - lo) / (N - 1), voxel (i, j, k) at world lo + (i, j, k) * h (VolumeSources
// sets the grid transform so index -> world is exactly that). The exact crossing of an edge is
// the bracketed root of f - k on it; f is exposed so callers can solve for it.
#pragma once

#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace isouq {

struct AnalyticField {
    std::string name;       ///< "tangle", ..., or "formula" for muParser fields
    std::string expression; ///< the formula, as text for summaries
    double lo = -1.0, hi = 1.0; ///< domain [lo, hi]^3 (world units)
    double isovalue = 0.0;  ///< default isovalue (SPEC §5)
    int resolution = 64;    ///< default N (the paper's, where it gives one)
    /// f(x, y, z); safe to call from several threads at once.
    std::function<double(double, double, double)> f;

    double operator()(double x, double y, double z) const { return f(x, y, z); }
    /// Grid spacing for N samples per axis, both domain ends included.
    double spacing(int n) const { return (hi - lo) / double(n - 1); }
};

namespace fields_internal {

inline double sq(double v) { return v * v; }
inline double pow4(double v) { return sq(sq(v)); }

// Tangle cube, SPEC §5: x^4 + y^4 + z^4 - (x^2 + y^2 + z^2 - 0.4).
inline double tangle(double x, double y, double z)
{
    return pow4(x) + pow4(y) + pow4(z) - (sq(x) + sq(y) + sq(z) - 0.4);
}

// Standard torus (SPEC §5): (sqrt(x^2 + y^2) - r1)^2 + z^2 - r0^2, r0 = 0.1, r1 = 0.3.
// Negative inside the tube, so with k = 0 the ">= k" side is the outside.
inline double torus(double x, double y, double z)
{
    return sq(std::sqrt(sq(x) + sq(y)) - 0.3) + sq(z) - sq(0.1);
}

// The paper's torus exactly as printed (not a torus, SPEC §5): r1 - (sqrt(x^2+y^2))^2 + z^2 - r0^2.
inline double torusPaper(double x, double y, double z)
{
    return 0.3 - sq(std::sqrt(sq(x) + sq(y))) + sq(z) - sq(0.1);
}

// Marschner-Lobb, SPEC §5: (1 - sin(pi z / 2) + a (1 + rho(r))) / (2 (1 + a)),
// rho(r) = cos(2 pi fM cos(pi r / 2)), r = sqrt(x^2 + y^2), fM = 6, a = 0.25.
inline double marschnerLobb(double x, double y, double z)
{
    constexpr double pi = 3.14159265358979323846, fM = 6.0, a = 0.25;
    const double rho = std::cos(2.0 * pi * fM * std::cos(pi * std::sqrt(sq(x) + sq(y)) / 2.0));
    return (1.0 - std::sin(pi * z / 2.0) + a * (1.0 + rho)) / (2.0 * (1.0 + a));
}

// Teardrop, SPEC §5: 0.5 x^5 + 0.5 x^4 - y^2 - z^2.
inline double teardrop(double x, double y, double z)
{
    return 0.5 * pow4(x) * x + 0.5 * pow4(x) - sq(y) - sq(z);
}

// Tubey, SPEC §5: -3x^8 - 3y^8 - 2z^8 + 5x^4y^2z^2 + 3x^2y^4z^2 - 4(x^3+y^3+z^3+1) + (x+y+z+1)^4 + 1.
inline double tubey(double x, double y, double z)
{
    const double x2 = sq(x), y2 = sq(y), z2 = sq(z);
    return -3.0 * sq(pow4(x)) - 3.0 * sq(pow4(y)) - 2.0 * sq(pow4(z)) + 5.0 * sq(x2) * y2 * z2
        + 3.0 * x2 * sq(y2) * z2 - 4.0 * (x2 * x + y2 * y + z2 * z + 1.0) + pow4(x + y + z + 1.0)
        + 1.0;
}

// Sphere of radius 0.75 as a signed distance (negative inside, like a VDB level set): the
// surface at k = 0 and the distance to it are both exact, which makes it the easiest truth.
inline double sphere(double x, double y, double z)
{
    return std::sqrt(sq(x) + sq(y) + sq(z)) - 0.75;
}

} // namespace fields_internal

/// The built-in fields (SPEC §5 names), in a fixed order.
inline const std::vector<AnalyticField>& analyticFields()
{
    namespace fi = fields_internal;
    static const std::vector<AnalyticField> sFields = {
        {"tangle", "x^4+y^4+z^4-(x^2+y^2+z^2-0.4)", -1, 1, 0.1, 32, fi::tangle},
        {"torus", "(sqrt(x^2+y^2)-0.3)^2+z^2-0.1^2", -1, 1, 0.0, 64, fi::torus},
        {"torus-paper", "0.3-(sqrt(x^2+y^2))^2+z^2-0.1^2", -1, 1, 0.0, 64, fi::torusPaper},
        {"marschner-lobb", "(1-sin(pi z/2)+0.25(1+cos(12 pi cos(pi r/2))))/2.5, r=sqrt(x^2+y^2)",
            -1, 1, 0.5, 64, fi::marschnerLobb},
        {"teardrop", "0.5x^5+0.5x^4-y^2-z^2", -1, 1, -0.001, 32, fi::teardrop},
        {"tubey",
            "-3x^8-3y^8-2z^8+5x^4y^2z^2+3x^2y^4z^2-4(x^3+y^3+z^3+1)+(x+y+z+1)^4+1", -3, 3, 0.0,
            32, fi::tubey},
        {"sphere", "sqrt(x^2+y^2+z^2)-0.75", -1, 1, 0.0, 64, fi::sphere},
    };
    return sFields;
}

/// The built-in field called @a name, or nullptr.
inline const AnalyticField* findAnalyticField(const std::string& name)
{
    for (const AnalyticField& field : analyticFields()) {
        if (field.name == name) return &field;
    }
    return nullptr;
}

} // namespace isouq
