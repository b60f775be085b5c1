// isouq nodes: the graph that meshes one input (SPEC §8, §10 "One runner"; STYLE "One
// pipeline"). `isouq mesh` and `isouq demo` build it from their flags (each flag is a node
// parameter) and hand it to runGraph, as `isouq run` does with a file; the entry points that
// come later (sequences, Python, MPI, the add-on) build it too.
#pragma once

#include <nlohmann/json.hpp>

#include <string>

namespace isouq::nodes {

struct MeshGraphRequest {
    nlohmann::json read = nlohmann::json::object();   ///< read_volume parameters (input, grid, isovalue, ...)
    nlohmann::json mesh = nlohmann::json::object();   ///< mesh parameters (method, linear_only)
    nlohmann::json hidden = nlohmann::json::object(); ///< hidden_features parameters (subdivisions, filter)
    nlohmann::json write = nlohmann::json::object();  ///< write_ply parameters besides the path (format)
    nlohmann::json color = nlohmann::json::object();  ///< color_map parameters; with `measure` set, both
                                                      ///< meshes are coloured before they are written
    bool hiddenFeatures = false; ///< also recover hidden features (SPEC §4): the summary's `hidden` block
    std::string output;          ///< the mesh: write_vtp for a .vtp path, else write_ply ("" for none:
                                 ///< a host keeps the mesh in memory, runGraph keepMeshes)
    std::string hiddenOutput;    ///< the hidden-feature mesh ("" for none; implies hiddenFeatures)
    std::string summaryPath;     ///< the SPEC §8 summary ("" for none)
};

/// Node ids of the graph meshGraph() builds: `load` (read_volume), `mesh`, `truth` (field: and
/// formula: inputs, unless linear_only), `hidden`, `color` and `color_hidden` (color_map, with
/// request.color), `summary`, `write`, `write_hidden`, `write_summary`. The summary node's json
/// output is the summary the command prints.
inline constexpr const char* kMeshGraphSummary = "summary";

/// The node type that writes a mesh to @a path, by its ending (SPEC §10 "Formats"): "write_ply"
/// for .ply, "write_vtp" for .vtp (any case). @throw InputError for any other ending.
const char* meshWriterType(const std::string& path);

/// The graph document (the JSON `isouq run` reads; `--save-graph` writes it). Paths stay as
/// given, so the saved graph run from the same folder writes the same files.
/// @throw InputError for an output that is neither .ply nor .vtp, or write_ply parameters given
/// for a .vtp output.
nlohmann::json meshGraph(const MeshGraphRequest& request);

} // namespace isouq::nodes
