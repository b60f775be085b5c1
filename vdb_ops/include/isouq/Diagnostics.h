// isouq: input checks run before meshing (STYLE "Input checks", SPEC §8).
#pragma once

#include <openvdb/openvdb.h>

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>

namespace isouq {

/// Checks @a grid, fast to slow, and returns "" or one line naming the first problem:
/// no active voxels or tiles; a non-positive or non-finite voxel size; non-finite active values
/// (how many, and where the first is); @a isovalue not finite or outside [min, max] of the
/// active values. The line has no "isouq: error:" prefix (the CLI adds it, then exits with 2).
std::string checkScalarVolume(const openvdb::FloatGrid& grid, std::optional<float> isovalue);

/// What checkScalarVolume reads from the active values: the non-finite count, the first
/// non-finite value in leaf order (then tiles) and the finite range. Scans of disjoint parts of
/// a grid (the pieces of SPEC §10 "MPI") joined in any order equal the scan of the whole.
struct ActiveValueScan {
    std::uint64_t nonFinite = 0;
    std::uint64_t firstLeaf = std::numeric_limits<std::uint64_t>::max(); ///< leaf order; leaves + 1: a tile
    openvdb::Coord first;
    float firstValue = 0.0f;
    float min = std::numeric_limits<float>::infinity(), max = -std::numeric_limits<float>::infinity();

    void add(float v, std::uint64_t leafIndex, const openvdb::Coord& ijk, std::uint64_t count);
    void join(const ActiveValueScan& other);
};

/// Scans the active values of the leaves whose origin @a leaves accepts (all when empty), and
/// of the active tiles when @a tiles is true.
ActiveValueScan scanActiveValues(const openvdb::FloatGrid& grid,
    const std::function<bool(const openvdb::Coord&)>& leaves = {}, bool tiles = true);

/// checkScalarVolume with the value scan and the active voxels' bounding box (empty: nothing is
/// active) already made, both of the whole grid when @a grid is a piece of it (joined over the
/// pieces of SPEC §10 "MPI"; a piece may hold no active voxel).
std::string checkScalarVolume(const openvdb::FloatGrid& grid, std::optional<float> isovalue,
    const ActiveValueScan& scan, const openvdb::CoordBBox& activeBox);

} // namespace isouq
