// isouq: edge-crossing interpolation methods (paper sec. 3.2-3.4, SPEC §2).
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace isouq {

/// Interpolation method for the crossing of an isosurface with a cell edge (SPEC §2).
enum class EdgeMethod { Linear, Cubic, Weno, WenoPaper };

inline std::string toString(EdgeMethod m)
{
    switch (m) {
    case EdgeMethod::Linear: return "linear";
    case EdgeMethod::Cubic: return "cubic";
    case EdgeMethod::Weno: return "weno";
    case EdgeMethod::WenoPaper: return "weno-paper";
    }
    return "linear";
}

inline std::string toMenuName(EdgeMethod m)
{
    switch (m) {
    case EdgeMethod::Linear: return "Linear";
    case EdgeMethod::Cubic: return "Cubic (4-point Lagrange)";
    case EdgeMethod::Weno: return "WENO (6th order)";
    case EdgeMethod::WenoPaper: return "WENO (paper's constant weights)";
    }
    return "Linear";
}

/// Parses "linear", "cubic", "weno" or "weno-paper"; nullopt for anything else.
inline std::optional<EdgeMethod> edgeMethodFromString(std::string_view s)
{
    if (s == "linear") return EdgeMethod::Linear;
    if (s == "cubic") return EdgeMethod::Cubic;
    if (s == "weno") return EdgeMethod::Weno;
    if (s == "weno-paper") return EdgeMethod::WenoPaper;
    return std::nullopt;
}

} // namespace isouq
