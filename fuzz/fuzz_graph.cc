// libFuzzer target: JSON node graphs (houdini_style_nodes/src/Graph.cc through
// isouq::nodes::loadGraph): the file checks, the nesting bound, nlohmann's parser and
// parseGraph's validation (node types, parameters and their ranges, inputs and ports, cycles,
// path resolution and aliasing). Nothing is cooked or written.
#include "FuzzCommon.h"

#include <isouq/nodes/Graph.h>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
    const std::string path = isouq::fuzz::writeTemp("graph.json", data, size);
    isouq::fuzz::expectingErrors([&] {
        isouq::nodes::GraphOptions options;
        options.outputDir = (isouq::fuzz::tempDir() / "out").string();
        isouq::nodes::loadGraph(path, options);
    });
    return 0;
}
