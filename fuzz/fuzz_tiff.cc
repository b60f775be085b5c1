// libFuzzer target: TIFF stacks (TiffSource.cc, ScanSource.cc through isouq::loadVolume):
// libtiff's directory chain, the page checks, strips and tiles, every compression libtiff
// decodes, ImageJ's description. An input without the separator (FuzzCommon.h) is one
// multi-page `input.tif`; with it, each part is a slice `slice0.tif`, `slice1.tif`, ... of a
// folder (at most 8).
#include "ScanFuzz.h"

#include <filesystem>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const auto parts = isouq::fuzz::splitFiles(data, size, 8);
    if (parts.size() == 1) {
        const std::string path = isouq::fuzz::writeTemp("input.tif", data, size);
        isouq::fuzz::loadAndMesh(path);
        std::remove(path.c_str());
        return 0;
    }
    const std::string dir = isouq::fuzz::writeFolder("slices", parts, "slice", ".tif");
    isouq::fuzz::loadAndMesh(dir);
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    return 0;
}
