// isouq nodes: JSON node graphs (`isouq run GRAPH.json`; docs/nodes.md).
//
// {"description": "...",
//  "nodes": [{"id": "read", "type": "read_volume", "parms": {"input": "field:teardrop"}},
//            {"id": "mesh", "type": "mesh", "inputs": {"volume": "read"}},
//            {"id": "save", "type": "write_ply", "inputs": {"mesh": "mesh"},
//             "parms": {"path": "teardrop.ply"}}]}
//
// An input names a node ("read") or one of its outputs ("read.volume"). String parameters may
// use ${NAME} for an environment variable. Relative output paths are taken from the output
// folder (default: the current one).
#pragma once

#include "isouq/nodes/Node.h"

#include <isouq/VolumeSources.h>

#include <string>
#include <vector>

namespace isouq::nodes {

/// A graph that cannot run: what() is one line naming the node and, where there is one, the
/// parameter or input, e.g. "node 'thr' (threshold): parameter 'percentile': 150 is outside
/// the hard range [0, 100]".
struct GraphError : InputError {
    using InputError::InputError;
};

struct GraphNode {
    std::string id;
    const NodeType* type = nullptr;
    ParmValues parms;
    /// input port -> (source node index, source output port)
    std::map<std::string, std::pair<std::size_t, std::string>> inputs;
};

struct GraphOptions {
    std::string outputDir; ///< where relative output paths go ("" = current folder)
    std::string graphFile; ///< the file the graph was read from, which no output may replace
};

struct Graph {
    std::string description;
    std::vector<GraphNode> nodes; ///< in an order where every input precedes its reader
};

/// The parameters of node @a id of @a type from @a given over the declared defaults, checked as
/// parseGraph checks them (unknown tokens, types, hard ranges, menu tokens, NUL characters),
/// with ${NAME} expanded and relative paths taken from options.outputDir. For a node cooked
/// outside a graph (the Python module's load and write). @throw GraphError
ParmValues evaluateParms(const nlohmann::json& given, const std::string& id, const NodeType& type,
    const GraphOptions& options = {});

/// Parses and checks @a doc completely: unknown node types, parameters or inputs, wrong
/// types, values outside hard ranges, missing inputs, port type mismatches, cycles, and two
/// outputs to one path. Nothing runs and nothing is written.
/// @throw GraphError
Graph parseGraph(const nlohmann::json& doc, const GraphOptions& options = {});

/// Reads and parses a graph file. @throw GraphError (also for unreadable or invalid JSON).
Graph loadGraph(const std::string& path, const GraphOptions& options = {});

struct GraphResult {
    std::vector<std::string> written;  ///< committed files, in order
    std::vector<std::string> warnings; ///< one line each
    nlohmann::json outputs = nlohmann::json::object(); ///< per node id, its json outputs
    /// Per node id named in runGraph's @a keepMeshes, its mesh output (hosts that use the mesh
    /// in memory: the Python module, the Blender add-on).
    std::map<std::string, std::shared_ptr<const MeshData>> meshes;
};

/// Cooks every node in order, then commits the pending writes. In one process a write fills
/// its temporary file on another thread while later nodes cook (a mesh writer before the
/// summary: the PLY is written while the summary measures). Interruption or a failing node
/// leaves nothing written (and existing files untouched). With @a ranks (collective; MPI,
/// docs/mpi.md) every rank runs the graph on its piece, each cook and each write ends with an
/// agreement, and a failure anywhere throws on every rank the message of the lowest failing
/// one; a node type that does not cook on ranks (NodeType::onRanks) is refused.
/// @throw InputError naming the node, IoError, InterruptedError.
GraphResult runGraph(const Graph& graph, openvdb::util::NullInterrupter* interrupter = nullptr,
    const std::vector<std::string>& keepMeshes = {}, const Ranks* ranks = nullptr);

} // namespace isouq::nodes
