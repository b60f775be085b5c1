// isouq nodes: the graph that meshes one input (MeshGraph.h).
#include "isouq/nodes/MeshGraph.h"

#include "isouq/nodes/Parm.h"

#include <isouq/Errors.h>

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

/// The writer of @a path (meshWriterType), write_ply with the request's PLY parameters.
nlohmann::json writer(const char* id, const std::string& path, const nlohmann::json& plyParms, const std::string& mesh)
{
    if (std::string(meshWriterType(path)) == "write_ply") {
        nlohmann::json parms = plyParms;
        parms["path"] = path;
        return node(id, "write_ply", parms, {{"mesh", mesh}});
    }
    if (!plyParms.empty())
        throw InputError("--ply-format applies to .ply outputs, and " + path + " is a .vtp file");
    return node(id, "write_vtp", {{"path", path}}, {{"mesh", mesh}});
}

} // namespace

const char* meshWriterType(const std::string& path)
{
    const std::string ext = pathExtension(path);
    if (ext == ".ply") return "write_ply";
    if (ext == ".vtp") return "write_vtp";
    throw InputError("output '" + path + "' is not a mesh format isouq writes: name it .ply (PLY with every "
                     "attribute) or .vtp (VTK XML PolyData)");
}

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
    std::string hiddenMesh = "hidden";
    if (hidden)
        nodes.push_back(node("hidden", "hidden_features", request.hidden, {{"volume", "load"}, {"mesh", standard}}));
    // --color-by: red green blue quality on each mesh before it is summarised and written.
    if (request.color.contains("measure")) {
        nodes.push_back(node("color", "color_map", request.color, {{"mesh", standard}}));
        standard = "color";
        if (hidden) {
            nodes.push_back(node("color_hidden", "color_map", request.color, {{"mesh", hiddenMesh}}));
            hiddenMesh = "color_hidden";
        }
    }
    // The mesh writers before the summary: their files fill while it measures (Graph.h runGraph).
    if (!request.output.empty()) nodes.push_back(writer("write", request.output, request.write, standard));
    if (!request.hiddenOutput.empty())
        nodes.push_back(writer("write_hidden", request.hiddenOutput, request.write, hiddenMesh));
    nlohmann::json summaryInputs = {{"mesh", standard}};
    if (hidden) summaryInputs["hidden"] = hiddenMesh;
    nodes.push_back(node(kMeshGraphSummary, "summary", {}, summaryInputs));
    if (!request.summaryPath.empty())
        nodes.push_back(node("write_summary", "write_summary", {{"path", request.summaryPath}},
            {{"summary", kMeshGraphSummary}}));
    return {{"description", "isouq mesh " + read.value("input", std::string())}, {"nodes", nodes}};
}

} // namespace isouq::nodes
