// libFuzzer target: formula:EXPR (FieldSource.cc): muParser's parse through
// isouq::makeFormulaField, evaluation at points inside, on and outside the domain, then the
// whole formula input at a small resolution (threaded sampling, non-finite checks, sparsify).
#include "FuzzCommon.h"

#include <isouq/VolumeSources.h>

#include <cstring>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    if (size > 4096 || std::memchr(data, '\0', size)) return 0; // the CLI cannot pass a NUL
    const std::string expression(reinterpret_cast<const char*>(data), size);
    isouq::fuzz::expectingErrors([&] {
        const auto field = isouq::makeFormulaField(expression, -1.0, 1.0);
        const double points[] = {-2.0, -1.0, 0.0, 0.5, 1.0};
        for (double x : points)
            for (double y : points) (void)(*field)(x, y, -x);
        isouq::VolumeRequest request;
        request.input = "formula:" + expression;
        request.resolution = 8;
        isouq::loadVolume(request);
    });
    return 0;
}
