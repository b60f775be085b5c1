// isouq: the grid metadata keys isouq writes and reads (after OpenVDB's GridBase META_* keys).
// Dense sources (raw scans, fields, formulas) record the index box that holds real data:
// cells outside it are not meshed and stencil voxels outside it are missing (SPEC §1).
#pragma once

#include <openvdb/openvdb.h>

#include <optional>

namespace isouq {

inline constexpr const char* kDataBoundsMinMeta = "isouq_data_min";
inline constexpr const char* kDataBoundsMaxMeta = "isouq_data_max";

/// The data box recorded in @a grid's metadata, or nullopt for grids without one (a .vdb).
inline std::optional<openvdb::CoordBBox> dataBounds(const openvdb::GridBase& grid)
{
    const auto lo = grid.getMetadata<openvdb::Vec3IMetadata>(kDataBoundsMinMeta);
    const auto hi = grid.getMetadata<openvdb::Vec3IMetadata>(kDataBoundsMaxMeta);
    if (!lo || !hi) return std::nullopt;
    return openvdb::CoordBBox(openvdb::Coord(lo->value()), openvdb::Coord(hi->value()));
}

/// Records @a box as @a grid's data box.
inline void setDataBounds(openvdb::GridBase& grid, const openvdb::CoordBBox& box)
{
    grid.insertMeta(kDataBoundsMinMeta, openvdb::Vec3IMetadata(box.min().asVec3i()));
    grid.insertMeta(kDataBoundsMaxMeta, openvdb::Vec3IMetadata(box.max().asVec3i()));
}

} // namespace isouq
