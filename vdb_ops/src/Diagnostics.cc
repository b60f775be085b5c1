// isouq: input checks (STYLE "Input checks"); docs/inputs.md.
#include "isouq/Diagnostics.h"

#include <openvdb/tree/LeafManager.h>

#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace isouq {
namespace diagnostics_internal {

/// Non-finite count, first non-finite location (leaf order, then tiles) and finite range of
/// the active values.
struct ValueScan {
    openvdb::Index64 nonFinite = 0;
    std::size_t firstLeaf = std::numeric_limits<std::size_t>::max();
    openvdb::Coord first;
    float firstValue = 0.0f;
    float min = std::numeric_limits<float>::infinity(), max = -min;

    void add(float v, std::size_t leafIndex, const openvdb::Coord& ijk, openvdb::Index64 count)
    {
        if (std::isfinite(v)) {
            min = std::min(min, v), max = std::max(max, v);
            return;
        }
        nonFinite += count;
        if (leafIndex < firstLeaf) firstLeaf = leafIndex, first = ijk, firstValue = v;
    }
    void join(const ValueScan& other)
    {
        nonFinite += other.nonFinite;
        min = std::min(min, other.min), max = std::max(max, other.max);
        if (other.firstLeaf < firstLeaf) firstLeaf = other.firstLeaf, first = other.first,
                                         firstValue = other.firstValue;
    }
};

ValueScan scanActiveValues(const openvdb::FloatGrid& grid)
{
    using LeafRange = openvdb::tree::LeafManager<const openvdb::FloatTree>::LeafRange;
    openvdb::tree::LeafManager<const openvdb::FloatTree> leaves(grid.tree());
    ValueScan scan = tbb::parallel_reduce(leaves.leafRange(), ValueScan(),
        [](const LeafRange& range, ValueScan partial) {
            for (auto leaf = range.begin(); leaf; ++leaf) {
                for (auto it = leaf->cbeginValueOn(); it; ++it) {
                    partial.add(*it, leaf.pos(), it.getCoord(), 1);
                }
            }
            return partial;
        },
        [](ValueScan a, const ValueScan& b) { a.join(b); return a; });
    // Active tiles come after every leaf in "first" order.
    auto tile = grid.tree().cbeginValueOn();
    tile.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile) {
        scan.add(*tile, leaves.leafCount(), tile.getCoord(), tile.getVoxelCount());
    }
    return scan;
}

template <typename T>
std::string str(const T& v)
{
    std::ostringstream os;
    os << v;
    return os.str();
}

} // namespace diagnostics_internal

std::string checkScalarVolume(const openvdb::FloatGrid& grid, std::optional<float> isovalue)
{
    namespace di = diagnostics_internal;
    const std::string name = grid.getName().empty() ? "the grid" : "grid '" + grid.getName() + "'";
    if (grid.tree().activeVoxelCount() == 0) {
        return name + " has no active voxels or tiles: nothing to mesh";
    }
    const openvdb::Vec3d voxel = grid.voxelSize();
    for (int a = 0; a < 3; ++a) {
        if (!(std::isfinite(voxel[a]) && voxel[a] > 0.0)) {
            return name + " has a bad transform: voxel size " + di::str(voxel[0]) + " "
                + di::str(voxel[1]) + " " + di::str(voxel[2]) + " (each must be positive and finite)";
        }
    }
    // Vertices are float32 world positions: every corner of the active box must map into range.
    const openvdb::CoordBBox box = grid.evalActiveVoxelBoundingBox();
    for (int corner = 0; corner < 8; ++corner) {
        const openvdb::Coord c((corner & 1 ? box.max() : box.min()).x(), (corner & 2 ? box.max() : box.min()).y(),
            (corner & 4 ? box.max() : box.min()).z());
        const openvdb::Vec3d w = grid.indexToWorld(c);
        for (int a = 0; a < 3; ++a)
            if (!(std::fabs(w[a]) <= double(std::numeric_limits<float>::max())))
                return name + " has a bad transform: voxel " + di::str(c) + " is at world " + di::str(w)
                    + ", beyond float32 coordinates (check the spacing and origin)";
    }
    const float background = grid.background();
    if (!std::isfinite(background)) {
        return name + " has a non-finite background value " + di::str(background)
            + " (inactive voxels read it); set a finite background";
    }
    const di::ValueScan scan = di::scanActiveValues(grid);
    if (scan.nonFinite > 0) {
        return name + " has " + std::to_string(scan.nonFinite) + " active non-finite value(s); the first, "
            + di::str(scan.firstValue) + ", at voxel " + di::str(scan.first);
    }
    if (isovalue && !std::isfinite(*isovalue)) return "isovalue " + di::str(*isovalue) + " is not finite";
    // A sparse grid's surface also lies where active voxels meet the background (SPEC §10).
    const float lo = std::min(scan.min, background), hi = std::max(scan.max, background);
    if (isovalue && !(lo <= *isovalue && *isovalue <= hi)) {
        return "isovalue " + di::str(*isovalue) + " is outside the range of " + name + ", [" + di::str(lo) + ", "
            + di::str(hi) + "] (active values [" + di::str(scan.min) + ", " + di::str(scan.max) + "], background "
            + di::str(background) + ")";
    }
    return "";
}

} // namespace isouq
