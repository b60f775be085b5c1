// libFuzzer target: the VTK XML PolyData reader (vdb_ops/src/VtpReader.cc, isouq::readVtp): the
// XML head (expat), the piece's counts, each array's format, type, offset and size word checked
// before allocation, ascii values, the field data. A mesh that reads is written back with
// writeVtp and read again: same counts.
#include "FuzzCommon.h"

#include <isouq/MeshIO.h>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string path = isouq::fuzz::writeTemp("input.vtp", data, size);
    isouq::fuzz::expectingErrors([&] {
        isouq::PlyInfo info;
        const isouq::Mesh mesh = isouq::readVtp(path, &info);
        const std::string copy = (isouq::fuzz::tempDir() / "copy.vtp").string();
        isouq::writeVtp(mesh, copy);
        const isouq::Mesh back = isouq::readVtp(copy);
        if (back.positions.size() != mesh.positions.size() || back.triangles.size() != mesh.triangles.size())
            std::abort(); // writeVtp and readVtp disagree
    });
    return 0;
}
