// libFuzzer target: .vdb files (VdbSource.cc through isouq::loadVolume): the bounded walk of
// the header and grid descriptors, OpenVDB's grid read (metadata, transform, topology,
// compressed buffers), double-to-float conversion and Otsu's default isovalue. A small grid
// that passes the input checks is also meshed (linear only: the walk of an arbitrary tree).
#include "FuzzCommon.h"

#include <isouq/Diagnostics.h>
#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string path = isouq::fuzz::writeTemp("input.vdb", data, size);
    isouq::fuzz::expectingErrors([&] {
        isouq::VolumeRequest request;
        request.input = path;
        const isouq::LoadedVolume volume = isouq::loadVolume(request);
        const openvdb::FloatGrid& grid = *volume.grid;
        if (!isouq::checkScalarVolume(grid, volume.isovalue).empty()) return;
        // Huge active tiles are the resource-limit check's business, not a reader's.
        if (grid.tree().activeTileCount() > 0 || grid.activeVoxelCount() > (1u << 16)) return;
        isouq::MeshSettings settings;
        settings.isovalue = volume.isovalue;
        isouq::extractIsosurface(grid, settings);
    });
    return 0;
}
