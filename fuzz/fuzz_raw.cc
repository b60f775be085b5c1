// libFuzzer target: raw scans (RawSource.cc through isouq::loadVolume). An input is a file
// name line, `name_XxYxZ_dtype.raw\n`, then the file's bytes: the name parser, the size check,
// the slab reader, Otsu's default isovalue and the sparsifier all see hostile values. A small volume
// that loads is also meshed (all methods and estimates), so NaN, inf and huge values reach the
// mesher as they would from the CLI.
#include "FuzzCommon.h"

#include <isouq/Diagnostics.h>
#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>

#include <algorithm>
#include <cstring>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const auto* end = static_cast<const std::uint8_t*>(std::memchr(data, '\n', std::min<std::size_t>(size, 128)));
    if (!end) return 0;
    std::string name(reinterpret_cast<const char*>(data), end - data);
    // A file name: no folders, no NUL, not "." or "..".
    if (name.empty() || name == "." || name == ".." || name.find_first_of(std::string("/\0", 2)) != std::string::npos)
        return 0;
    const std::size_t offset = std::size_t(end - data) + 1;
    const std::string path = isouq::fuzz::writeTemp(name, data + offset, size - offset);
    isouq::fuzz::expectingErrors([&] {
        isouq::VolumeRequest request;
        request.input = path;
        const isouq::LoadedVolume volume = isouq::loadVolume(request);
        if (!isouq::checkScalarVolume(*volume.grid, volume.isovalue).empty()) return;
        // Small volumes only: all methods under ASan take seconds on bucky's 32^3.
        if (size - offset > 16 * 16 * 16 * 8) return;
        isouq::MeshSettings settings;
        settings.isovalue = volume.isovalue;
        settings.uncertainty = true;
        isouq::extractIsosurface(*volume.grid, settings);
    });
    std::remove(path.c_str());
    return 0;
}
