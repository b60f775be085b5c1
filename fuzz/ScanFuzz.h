// isouq fuzzing: what the targets of the scans with headers share (NIfTI, NRRD, TIFF, DICOM;
// docs/hardening.md): INPUT through isouq::loadVolume (the reader, the header checks, the
// affine, Otsu's default isovalue, the sparsifier), then the mesher with every estimate on a
// small volume that passes the input checks, so hostile values reach it as from the CLI.
#pragma once

#include "FuzzCommon.h"

#include <isouq/Diagnostics.h>
#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>

namespace isouq::fuzz {

inline void loadAndMesh(const std::string& input)
{
    expectingErrors([&] {
        VolumeRequest request;
        request.input = input;
        const LoadedVolume volume = loadVolume(request);
        const openvdb::FloatGrid& grid = *volume.grid;
        if (!checkScalarVolume(grid, volume.isovalue).empty()) return;
        // Small volumes only: every estimate under ASan takes seconds on 32^3.
        if (grid.tree().activeTileCount() > 0 || grid.activeVoxelCount() > 16 * 16 * 16 * 8) return;
        MeshSettings settings;
        settings.isovalue = volume.isovalue;
        settings.uncertainty = true;
        extractIsosurface(grid, settings);
    });
}

} // namespace isouq::fuzz
