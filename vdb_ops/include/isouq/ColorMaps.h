// isouq: colour maps that put a measure into a mesh file's own colours, for viewers without
// isouq (SPEC §10 "Formats": `--color-by`; paper sec. 4.3 C4). Each map is a piecewise-linear
// table of 17 published anchor colours (docs/ply-format.md "Colours").
#pragma once

#include "isouq/MeshAttributes.h"

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace isouq {

enum class ColorMap { Viridis, Coolwarm, Gray };

inline constexpr std::array<ColorMap, 3> kAllColorMaps = {ColorMap::Viridis, ColorMap::Coolwarm, ColorMap::Gray};

/// "viridis", "coolwarm", "gray".
std::string toString(ColorMap map);
/// "Viridis", "Cool to Warm", "Gray".
std::string toMenuName(ColorMap map);
/// Parses the toString() tokens; nullopt for anything else.
std::optional<ColorMap> colorMapFromString(std::string_view s);

using Rgb8 = std::array<std::uint8_t, 3>;

/// The colour of vertices whose measure is not finite (a hidden vertex's err_est).
inline constexpr Rgb8 kNoValueColor = {128, 128, 128};

/// sRGB colour at @a t in [0, 1] (clamped), linear between the map's anchors.
Rgb8 colorAt(ColorMap map, double t);

/// Adds `red green blue` (uint8) and `quality` (float32, equal to the measure) vertex columns
/// to @a mesh: vertex value v gets colorAt((v - lo) / (hi - lo)); with hi == lo every finite
/// value gets the middle colour; non-finite values get kNoValueColor.
/// @throw std::invalid_argument if @a mesh has no float vertex column @a measure, or the range
///        is not finite with lo <= hi.
void addColorColumns(Mesh& mesh, std::string_view measure, ColorMap map, double lo, double hi);

} // namespace isouq
