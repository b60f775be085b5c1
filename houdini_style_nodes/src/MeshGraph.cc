// isouq nodes: the graph that meshes one input (MeshGraph.h).
#include "isouq/nodes/MeshGraph.h"

namespace isouq::nodes {
namespace {

nlohmann::json node(const char* id, const char* type, nlohmann::json parms, nlohmann::json inputs)
{
    nlohmann::json n = {{"id", id}, {"type", type}};
    if (!parms.empty()) n["parms"] = std::move(parms);
    if (!inputs.empty()) n["inputs"] = std::move(inputs);
    return n;
}

bool hasExactField(const nlohmann::json& read)
{
    const std::string input = read.value("input", std::string());
    return input.rfind("field:", 0) == 0 || input.rfind("formula:", 0) == 0;
}

} // namespace

nlohmann::json meshGraph(const MeshGraphRequest& request)
{
    const bool hidden = request.hiddenFeatures || !request.hiddenOutput.empty();
    nlohmann::json read = request.read;
    // A dense source keeps the blocks refinement needs (VolumeSources.h KeepBlocks).
    if (hidden && !read.contains("keep")) read["keep"] = "crossing_or_hidden";

    nlohmann::json nodes = nlohmann::json::array();
    nodes.push_back(node("load", "read_volume", read, {}));
    nodes.push_back(node("mesh", "mesh", request.mesh, {{"volume", "load"}}));
    // SPEC §3 measured errors where the field is known.
    std::string standard = "mesh";
    if (hasExactField(read) && !request.mesh.value("linear_only", false)) {
        nodes.push_back(node("truth", "truth", {}, {{"volume", "load"}, {"mesh", "mesh"}}));
        standard = "truth";
    }
    nlohmann::json summaryInputs = {{"mesh", standard}};
    if (hidden) {
        nodes.push_back(node("hidden", "hidden_features", request.hidden, {{"volume", "load"}, {"mesh", standard}}));
        summaryInputs["hidden"] = "hidden";
    }
    nodes.push_back(node(kMeshGraphSummary, "summary", {}, summaryInputs));
    nodes.push_back(node("write", "write_ply", {{"path", request.output}}, {{"mesh", standard}}));
    if (!request.hiddenOutput.empty())
        nodes.push_back(node("write_hidden", "write_ply", {{"path", request.hiddenOutput}}, {{"mesh", "hidden"}}));
    if (!request.summaryPath.empty())
        nodes.push_back(node("write_summary", "write_summary", {{"path", request.summaryPath}},
            {{"summary", kMeshGraphSummary}}));
    return {{"description", "isouq mesh " + read.value("input", std::string())}, {"nodes", nodes}};
}

} // namespace isouq::nodes
