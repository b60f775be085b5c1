// libFuzzer target: NIfTI-1 and NIfTI-2 files (NiftiSource.cc, ScanSource.cc through
// isouq::loadVolume): nifticlib's header parse, the dimension, datatype, offset and size checks,
// scl_slope/inter, the sform/qform/pixdim affine, the slice reads through znzlib. An input that
// starts with gzip's magic is read as `input.nii.gz` (the streamed gzip path), else `input.nii`.
#include "ScanFuzz.h"

#include <cstdio>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const bool gzip = size >= 2 && data[0] == 0x1f && data[1] == 0x8b;
    const std::string path = isouq::fuzz::writeTemp(gzip ? "input.nii.gz" : "input.nii", data, size);
    isouq::fuzz::loadAndMesh(path);
    std::remove(path.c_str());
    return 0;
}
