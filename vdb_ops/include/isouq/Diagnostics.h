// isouq: input checks run before meshing (STYLE "Input checks", SPEC §8).
#pragma once

#include <openvdb/openvdb.h>

#include <optional>
#include <string>

namespace isouq {

/// Checks @a grid, fast to slow, and returns "" or one line naming the first problem:
/// no active voxels or tiles; a non-positive or non-finite voxel size; non-finite active values
/// (how many, and where the first is); @a isovalue not finite or outside [min, max] of the
/// active values. The line has no "isouq: error:" prefix (the CLI adds it, then exits with 2).
std::string checkScalarVolume(const openvdb::FloatGrid& grid, std::optional<float> isovalue);

} // namespace isouq
