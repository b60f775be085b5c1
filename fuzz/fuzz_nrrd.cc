// libFuzzer target: NRRD files (NrrdSource.cc, ScanSource.cc through isouq::loadVolume): teem's
// header parse, the type, dimension, size and space checks, the raw and gzip slice streams and
// teem's whole decoding of the other encodings. An input without the separator (FuzzCommon.h)
// is an attached `input.nrrd`; with it, the first part is a detached header `input.nhdr` and
// the next ones its data files `data0`, `data1`, ... beside it (the seeds say `data file: data0`).
#include "ScanFuzz.h"

#include <filesystem>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const auto parts = isouq::fuzz::splitFiles(data, size, 5);
    if (parts.size() == 1) {
        const std::string path = isouq::fuzz::writeTemp("input.nrrd", data, size);
        isouq::fuzz::loadAndMesh(path);
        std::remove(path.c_str());
        return 0;
    }
    const std::string dir = isouq::fuzz::writeFolder("nhdr", {parts.begin() + 1, parts.end()}, "data", "");
    const std::string header = dir + "/input.nhdr";
    isouq::fuzz::writeTemp("nhdr/input.nhdr", reinterpret_cast<const std::uint8_t*>(parts[0].data()), parts[0].size());
    isouq::fuzz::loadAndMesh(header);
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    return 0;
}
