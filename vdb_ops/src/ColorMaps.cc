// isouq: colour map tables and the red/green/blue/quality columns (ColorMaps.h).
#include "isouq/ColorMaps.h"

#include "isouq/Columns.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace isouq {
namespace {

using Anchors = std::array<std::uint32_t, 17>; // 0xRRGGBB at t = 0, 1/16, ..., 1

// Viridis (van der Walt and Smith, matplotlib 2.0, CC0) at 17 evenly spaced positions; linear
// between them it stays within 6/255 of the 256-entry map.
constexpr Anchors sViridis = {0x440154, 0x48186a, 0x472d7b, 0x424086, 0x3b528b, 0x33638d, 0x2c728e,
    0x26828e, 0x21918c, 0x1fa088, 0x28ae80, 0x3fbc73, 0x5ec962, 0x84d44b, 0xaddc30, 0xd8e219, 0xfde725};
// Moreland's diverging "cool to warm" (2009; ParaView's default, matplotlib's coolwarm) at 17
// positions, within 9/255 of the smooth map.
constexpr Anchors sCoolwarm = {0x3b4cc0, 0x4e68d8, 0x6282ea, 0x779af7, 0x8db0fe, 0xa3c2fe, 0xb9d0f9,
    0xccd9ed, 0xdddcdc, 0xecd3c5, 0xf5c4ac, 0xf7b093, 0xf4987a, 0xeb7d62, 0xdd5f4b, 0xca3b37, 0xb40426};

const Anchors* anchorsOf(ColorMap map)
{
    switch (map) {
    case ColorMap::Viridis: return &sViridis;
    case ColorMap::Coolwarm: return &sCoolwarm;
    case ColorMap::Gray: return nullptr;
    }
    return nullptr;
}

} // namespace

std::string toString(ColorMap map)
{
    switch (map) {
    case ColorMap::Viridis: return "viridis";
    case ColorMap::Coolwarm: return "coolwarm";
    case ColorMap::Gray: return "gray";
    }
    return "viridis";
}

std::string toMenuName(ColorMap map)
{
    switch (map) {
    case ColorMap::Viridis: return "Viridis";
    case ColorMap::Coolwarm: return "Cool to Warm";
    case ColorMap::Gray: return "Gray";
    }
    return "Viridis";
}

std::optional<ColorMap> colorMapFromString(std::string_view s)
{
    for (ColorMap m : kAllColorMaps)
        if (s == toString(m)) return m;
    return std::nullopt;
}

Rgb8 colorAt(ColorMap map, double t)
{
    t = std::clamp(std::isnan(t) ? 0.0 : t, 0.0, 1.0);
    const Anchors* anchors = anchorsOf(map);
    if (!anchors) {
        const auto g = std::uint8_t(std::lround(255.0 * t));
        return {g, g, g};
    }
    const double s = t * double(anchors->size() - 1);
    const std::size_t i = std::min(std::size_t(s), anchors->size() - 2);
    const double f = s - double(i);
    Rgb8 rgb;
    for (int c = 0; c < 3; ++c) {
        const int shift = 16 - 8 * c;
        const double a = double(((*anchors)[i] >> shift) & 0xff), b = double(((*anchors)[i + 1] >> shift) & 0xff);
        rgb[c] = std::uint8_t(std::lround(a + f * (b - a)));
    }
    return rgb;
}

void addColorColumns(Mesh& mesh, std::string_view measure, ColorMap map, double lo, double hi)
{
    const std::vector<float>* column = mesh.vertexAttributes.find<float>(measure);
    if (!column)
        throw std::invalid_argument("the mesh has no per-vertex float column '" + std::string(measure) + "'");
    if (!(std::isfinite(lo) && std::isfinite(hi) && lo <= hi))
        throw std::invalid_argument("colour range [" + std::to_string(lo) + ", " + std::to_string(hi) +
            "] is not finite with LO <= HI");
    const std::size_t n = mesh.vertexCount();
    const std::vector<float> values = *column; // a copy: the measure may be `quality` itself
    AttributeTable& a = mesh.vertexAttributes;
    // Add every column before taking references: adding may move the others.
    a.add<std::uint8_t>(col::kRed, n), a.add<std::uint8_t>(col::kGreen, n), a.add<std::uint8_t>(col::kBlue, n);
    a.add<float>(col::kQuality, n);
    std::vector<std::uint8_t>* rgb[3] = {a.find<std::uint8_t>(col::kRed), a.find<std::uint8_t>(col::kGreen),
        a.find<std::uint8_t>(col::kBlue)};
    std::vector<float>& quality = *a.find<float>(col::kQuality);
    for (std::size_t v = 0; v < n; ++v) {
        const float x = values[v];
        quality[v] = x;
        const Rgb8 c = !std::isfinite(x) ? kNoValueColor
            : colorAt(map, hi > lo ? (double(x) - lo) / (hi - lo) : 0.5);
        for (int k = 0; k < 3; ++k) (*rgb[k])[v] = c[k];
    }
}

} // namespace isouq
