// isouq: primal marching cubes on sparse OpenVDB grids (SPEC §1, §8, §9; DESIGN.md).
//
// Every cell (the cube between voxels ijk and ijk+1) with at least one active corner is
// meshed, including cells on the borders of active tiles (tiles are never voxelised). A corner
// is inside when its value is >= the isovalue. Each vertex belongs to the edge it lies on,
// keyed by (lower voxel, axis), so neighbouring cells share it and closed surfaces are
// watertight. Vertex and triangle order depend only on the grid, never on the thread count.
#pragma once

#include "isouq/EdgeInterp.h"
#include "isouq/MeshAttributes.h"
#include "isouq/Progress.h"

#include <openvdb/openvdb.h>

#include <memory>
#include <optional>

namespace isouq {

/// Which way triangles face.
enum class Orientation {
    Auto,          ///< level sets: outward (towards larger values); other grids: towards smaller
    TowardsLower,  ///< normals point from values >= k towards values < k (CT "outward")
    TowardsHigher, ///< normals point towards values >= k
};

/// What a stencil voxel outside the active set means for high-order methods (SPEC §1).
enum class StencilPolicy {
    TreeValues, ///< inactive voxels read the tree's value (tile or background)
    ActiveOnly, ///< inactive voxels are missing: the method falls back to a lower order
};

struct MeshSettings {
    float isovalue = 0.0f;
    /// false: linear crossings only, positions and triangles (fastest); true: all methods,
    /// estimates and provenance as SPEC §6 lists.
    bool uncertainty = false;
    /// With uncertainty off, still record `edge_i edge_j edge_k edge_axis t_linear`.
    bool provenance = false;
    /// With uncertainty on: false computes only the linear crossing and the paper's estimates
    /// (`err_est`, `err_bound`; the paper's "extraction plus estimate"), no cubic or WENO.
    bool highOrder = true;
    /// The method whose crossing gives the positions when uncertainty is on.
    EdgeMethod method = EdgeMethod::Weno;
    StencilPolicy stencil = StencilPolicy::TreeValues;
    Orientation orientation = Orientation::Auto;
    /// The box of real data; when unset it is read from the grid metadata if present.
    std::optional<openvdb::CoordBBox> dataBounds;
    /// Mesh only the cells whose minimum corner lies in this box (SPEC §9 bricks). The result
    /// holds every vertex those cells use, wherever its edge is owned; meshes of the bricks of
    /// any partition, joined by source edge (edge_i/j/k/axis), equal the mesh of the whole.
    std::optional<openvdb::CoordBBox> brick;
    bool threaded = true;
};

namespace mc_internal {
struct MesherBuffers;
}

/// The mesher as an object that keeps its buffers between calls (interactive re-meshing,
/// benchmarks; DESIGN.md "Memory and allocation"): meshing again, into the same Mesh, reuses
/// the block tables and the output arrays instead of faulting in new pages.
class IsosurfaceMesher {
public:
    explicit IsosurfaceMesher(const MeshSettings& settings = MeshSettings());
    ~IsosurfaceMesher();
    IsosurfaceMesher(const IsosurfaceMesher&) = delete;
    IsosurfaceMesher& operator=(const IsosurfaceMesher&) = delete;

    MeshSettings& settings() { return mSettings; }
    const MeshSettings& settings() const { return mSettings; }

    /// Meshes @a grid into @a mesh, replacing its content (columns the settings do not produce
    /// are removed) and reusing its storage. On an exception the mesh's content is unspecified.
    /// @throw as extractIsosurface.
    template <typename GridT>
    void operator()(const GridT& grid, Mesh& mesh, openvdb::util::NullInterrupter* interrupter = nullptr);

    /// Wall milliseconds of the last call's stages (bench/README.md "Threads: where the second core
    /// went"): the block set, the side and count passes, the serial prefix sums, the output
    /// allocation, the fill.
    struct StageTimes {
        double blocks = 0, sides = 0, count = 0, offsets = 0, allocate = 0, fill = 0;
    };
    const StageTimes& stageTimes() const { return mStageTimes; }

private:
    MeshSettings mSettings;
    StageTimes mStageTimes;
    std::unique_ptr<mc_internal::MesherBuffers> mBuffers;
};

extern template void IsosurfaceMesher::operator()<openvdb::FloatGrid>(
    const openvdb::FloatGrid&, Mesh&, openvdb::util::NullInterrupter*);

/// Extracts the isosurface of @a grid at settings.isovalue.
/// @throw openvdb::ValueError if the isovalue is not finite.
/// @throw InterruptedError if @a interrupter asked to stop (nothing is returned then).
template <typename GridT>
Mesh extractIsosurface(const GridT& grid, const MeshSettings& settings,
    openvdb::util::NullInterrupter* interrupter = nullptr);

extern template Mesh extractIsosurface<openvdb::FloatGrid>(
    const openvdb::FloatGrid&, const MeshSettings&, openvdb::util::NullInterrupter*);

} // namespace isouq
