// isouq: input checks (STYLE "Input checks"); docs/inputs.md.
#include "isouq/Diagnostics.h"

#include <openvdb/tree/LeafManager.h>

#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <sstream>

namespace isouq {
namespace diagnostics_internal {

template <typename T>
std::string str(const T& v)
{
    std::ostringstream os;
    os << v;
    return os.str();
}

} // namespace diagnostics_internal

void ActiveValueScan::add(float v, std::uint64_t leafIndex, const openvdb::Coord& ijk, std::uint64_t count)
{
    if (std::isfinite(v)) {
        min = std::min(min, v), max = std::max(max, v);
        return;
    }
    nonFinite += count;
    if (leafIndex < firstLeaf) firstLeaf = leafIndex, first = ijk, firstValue = v;
}

void ActiveValueScan::join(const ActiveValueScan& other)
{
    nonFinite += other.nonFinite;
    min = std::min(min, other.min), max = std::max(max, other.max);
    if (other.firstLeaf < firstLeaf) firstLeaf = other.firstLeaf, first = other.first, firstValue = other.firstValue;
}

namespace {

/// Adds one leaf's active values to @a scan. A leaf whose values are all finite (nearly every
/// leaf) takes one pass of min, max and x - x (NaN once x is not finite) over its values, in
/// lanes across a fully active leaf so that the compiler vectorises it; only a leaf with a
/// non-finite value is walked value by value, for the first one's voxel. (At N = 1024 the
/// value iterator took 150 ms: bench/journal/2026-12-04.md, 23:43.)
void scanLeaf(const openvdb::FloatTree::LeafNodeType& leaf, std::uint64_t leafIndex, ActiveValueScan& scan)
{
    using Leaf = openvdb::FloatTree::LeafNodeType;
    const float* v = leaf.buffer().data();
    const Leaf::NodeMaskType& mask = leaf.getValueMask();
    float lo = scan.min, hi = scan.max, check = 0.0f;
    if (mask.isOn()) {
        constexpr openvdb::Index kLanes = 16;
        std::array<float, kLanes> laneLo, laneHi, laneCheck{};
        laneLo.fill(lo), laneHi.fill(hi);
        for (openvdb::Index i = 0; i < Leaf::SIZE; i += kLanes)
            for (openvdb::Index l = 0; l < kLanes; ++l) {
                const float x = v[i + l];
                laneLo[l] = std::min(laneLo[l], x), laneHi[l] = std::max(laneHi[l], x), laneCheck[l] += x - x;
            }
        for (openvdb::Index l = 0; l < kLanes; ++l)
            lo = std::min(lo, laneLo[l]), hi = std::max(hi, laneHi[l]), check += laneCheck[l];
    } else {
        for (auto it = mask.beginOn(); it; ++it) {
            const float x = v[it.pos()];
            lo = std::min(lo, x), hi = std::max(hi, x), check += x - x;
        }
    }
    if (check == 0.0f) {
        scan.min = lo, scan.max = hi;
        return;
    }
    for (auto it = mask.beginOn(); it; ++it) scan.add(v[it.pos()], leafIndex, leaf.offsetToGlobalCoord(it.pos()), 1);
}

} // namespace

ActiveValueScan scanActiveValues(const openvdb::FloatGrid& grid,
    const std::function<bool(const openvdb::Coord&)>& leaves, bool tiles)
{
    using LeafRange = openvdb::tree::LeafManager<const openvdb::FloatTree>::LeafRange;
    openvdb::tree::LeafManager<const openvdb::FloatTree> manager(grid.tree());
    ActiveValueScan scan = tbb::parallel_reduce(manager.leafRange(), ActiveValueScan(),
        [&](const LeafRange& range, ActiveValueScan partial) {
            for (auto leaf = range.begin(); leaf; ++leaf)
                if (!leaves || leaves(leaf->origin())) scanLeaf(*leaf, leaf.pos(), partial);
            return partial;
        },
        [](ActiveValueScan a, const ActiveValueScan& b) { a.join(b); return a; });
    if (!tiles) return scan;
    // Active tiles come after every leaf in "first" order.
    auto tile = grid.tree().cbeginValueOn();
    tile.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile) scan.add(*tile, manager.leafCount(), tile.getCoord(), tile.getVoxelCount());
    return scan;
}

std::string checkScalarVolume(const openvdb::FloatGrid& grid, std::optional<float> isovalue)
{
    const openvdb::CoordBBox box = grid.evalActiveVoxelBoundingBox();
    if (box.empty()) return checkScalarVolume(grid, isovalue, ActiveValueScan(), box);
    return checkScalarVolume(grid, isovalue, scanActiveValues(grid), box);
}

std::string checkScalarVolume(const openvdb::FloatGrid& grid, std::optional<float> isovalue,
    const ActiveValueScan& scan, const openvdb::CoordBBox& box)
{
    namespace di = diagnostics_internal;
    const std::string name = grid.getName().empty() ? "the grid" : "grid '" + grid.getName() + "'";
    if (box.empty()) return name + " has no active voxels or tiles: nothing to mesh";
    const openvdb::Vec3d voxel = grid.voxelSize();
    for (int a = 0; a < 3; ++a) {
        if (!(std::isfinite(voxel[a]) && voxel[a] > 0.0)) {
            return name + " has a bad transform: voxel size " + di::str(voxel[0]) + " "
                + di::str(voxel[1]) + " " + di::str(voxel[2]) + " (each must be positive and finite)";
        }
    }
    // Vertices are float32 world positions: every corner of the active box must map into range.
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
