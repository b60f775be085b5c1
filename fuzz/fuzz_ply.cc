// libFuzzer target: the PLY reader (vdb_ops/src/MeshIO.cc, isouq::readPly): ascii and both
// binary layouts, header and isouq comments, size checks before allocation, lists and
// columns. A mesh that reads is written back with writePly and read again: same counts.
#include "FuzzCommon.h"

#include <isouq/MeshIO.h>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string path = isouq::fuzz::writeTemp("input.ply", data, size);
    isouq::fuzz::expectingErrors([&] {
        isouq::PlyInfo info;
        const isouq::Mesh mesh = isouq::readPly(path, &info);
        const std::string copy = (isouq::fuzz::tempDir() / "copy.ply").string();
        isouq::writePly(mesh, copy);
        const isouq::Mesh back = isouq::readPly(copy);
        if (back.positions.size() != mesh.positions.size() || back.triangles.size() != mesh.triangles.size())
            std::abort(); // writePly and readPly disagree
    });
    return 0;
}
