// libFuzzer target: DICOM series (DicomSource.cc, ScanSource.cc through isouq::loadVolume): a
// series is a folder, so the input is split at the separator (FuzzCommon.h) into the files
// `slice0.dcm`, `slice1.dcm`, ... (at most 8): GDCM's directory scan and parse, the series,
// size, type, orientation and spacing checks, the sort by position, per-slice rescale and
// GDCM's decoders.
#include "ScanFuzz.h"

#include <filesystem>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string dir = isouq::fuzz::writeFolder("series", isouq::fuzz::splitFiles(data, size, 8), "slice", ".dcm");
    isouq::fuzz::loadAndMesh(dir);
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    return 0;
}
