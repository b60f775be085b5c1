// isouq example: a node graph built in C++ and run through isouq::nodes — Teardrop 32^3, the
// vertices above the 90th percentile of err_est (C1) moved to their WENO crossing (C3), and the
// C7 summary printed. The same graph as JSON is examples/fig8_framework.json.
//
//   cmake -S examples/cpp -B build-example -DCMAKE_PREFIX_PATH=<isouq install prefix>
//   cmake --build build-example && ./build-example/graph_in_code teardrop.ply
#include <isouq/nodes/Graph.h>

#include <openvdb/openvdb.h>

#include <cstdio>
#include <iostream>

int main(int argc, char** argv)
{
    const std::string output = argc > 1 ? argv[1] : "teardrop_blend.ply";
    openvdb::initialize();
    const nlohmann::json doc = {
        {"nodes",
            {{{"id", "read"}, {"type", "read_volume"}, {"parms", {{"input", "field:teardrop"}, {"resolution", 32}}}},
                {{"id", "mesh"}, {"type", "mesh"}, {"inputs", {{"volume", "read"}}}, {"parms", {{"method", "linear"}}}},
                {{"id", "c1"}, {"type", "threshold"}, {"inputs", {{"mesh", "mesh"}}}, {"parms", {{"percentile", 90}}}},
                {{"id", "c3"}, {"type", "method_blend"}, {"inputs", {{"mesh", "c1"}}},
                    {"parms", {{"selection", "above"}, {"inside", "weno"}, {"outside", "linear"}}}},
                {{"id", "c7"}, {"type", "summary"}, {"inputs", {{"mesh", "c3"}}}},
                {{"id", "save"}, {"type", "write_ply"}, {"inputs", {{"mesh", "c3"}}}, {"parms", {{"path", output}}}}}}};
    try {
        const isouq::nodes::Graph graph = isouq::nodes::parseGraph(doc); // checks everything first
        const isouq::nodes::GraphResult result = isouq::nodes::runGraph(graph);
        const nlohmann::json& summary = result.outputs["c7"]["summary"];
        std::printf("%s: %d vertices, %d above the threshold %.3g, moved %d to WENO\n", output.c_str(),
            summary["vertices"].get<int>(), summary["threshold"]["above"].get<int>(),
            summary["threshold"]["threshold"].get<double>(), summary["blend"]["moved"].get<int>());
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 2;
    }
}
