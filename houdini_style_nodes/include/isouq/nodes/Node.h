// isouq nodes: node types and what flows between them (STYLE "Nodes": ParmFactory SOPs, the
// verb/cache split, vdb_tool actions). A NodeType is a declaration (parameters, ports, help)
// plus a pure cook: it reads its inputs and parameters and fills its outputs, nothing else.
// Files are never written during a cook: write nodes queue a PendingWrite that the graph
// commits only when every node has cooked, so a failed or interrupted run writes nothing.
#pragma once

#include "isouq/nodes/Parm.h"
#include "isouq/nodes/Ranks.h"

#include <isouq/MeshAttributes.h>
#include <isouq/MeshIO.h>

#include <openvdb/util/NullInterrupter.h>

#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace isouq {
struct LoadedVolume; // VolumeSources.h
}

namespace isouq::nodes {

/// A mesh on its way through a graph, with what later nodes need to know about it.
struct MeshData {
    Mesh mesh;
    float isovalue = 0.0f;
    std::string method;    ///< method of the positions ("linear", "weno", "blend", ...)
    bool uncertainty = false; ///< meshed with every method and estimate (MeshSettings)
    nlohmann::json info = nlohmann::json::object(); ///< e.g. "hidden", "threshold", "box" blocks
    /// On ranks (Ranks.h): the mesh holds this rank's piece, whose triangles name the whole
    /// mesh's vertices; null in one process.
    std::shared_ptr<const MeshPiece> piece;

    /// Everything but the mesh, for a node that makes a new mesh from this one.
    MeshData withoutMesh() const { return {Mesh(), isovalue, method, uncertainty, info, nullptr}; }
};

/// The value on one port: which member is set follows the port's type.
struct NodeValue {
    std::shared_ptr<const LoadedVolume> volume; ///< "volume"
    std::shared_ptr<const VolumePiece> piece;   ///< "volume" on ranks: what this rank read (Ranks.h)
    std::shared_ptr<const MeshData> mesh;       ///< "mesh"
    nlohmann::json json;                        ///< "json"
};

/// A file a write node will produce once the whole graph has cooked.
struct PendingWrite {
    std::string path;
    /// Writes the output to its temporary file in the batch (MeshIO.h OutputBatch); the graph
    /// commits the batch, so a run's outputs appear together or not at all. Throws IoError.
    std::function<void(OutputBatch&)> stage;
    /// stage only fills the batch's temporary files, so it may run on another thread while
    /// later nodes cook (Graph.h runGraph); otherwise it runs after the last cook.
    bool early = false;
};

/// What a cook sees. Inputs of optional ports that are not connected are absent.
struct CookContext {
    std::string nodeId;
    ParmValues parms;
    std::map<std::string, const NodeValue*> inputs;
    std::map<std::string, NodeValue> outputs;
    openvdb::util::NullInterrupter* interrupter = nullptr;
    std::vector<std::string>* warnings = nullptr; ///< one line each, naming the skipped item
    std::vector<PendingWrite>* writes = nullptr;
    /// The ranks the graph runs on (docs/mpi.md), null in one process; only node types marked
    /// NodeType::onRanks cook there.
    const Ranks* ranks = nullptr;
    /// Set by the runner (Graph.cc); a context without them (a cook called directly) gets
    /// no timings, no destinations and copies.
    std::function<nlohmann::json()> timingsOfUpstream;
    std::function<std::vector<std::string>(const std::string& port)> destinationsOf;
    std::function<std::shared_ptr<MeshData>(const std::string& port)> meshTaker;

    /// Cook times (ms) of the nodes upstream of this one, by node id, in running order.
    nlohmann::json upstreamTimings() const
    {
        return timingsOfUpstream ? timingsOfUpstream() : nlohmann::json::object();
    }
    /// The files that mesh writers (NodeType::meshWriter) make of what input @a port reads.
    std::vector<std::string> destinations(const std::string& port) const
    {
        return destinationsOf ? destinationsOf(port) : std::vector<std::string>();
    }
    /// The mesh on input @a port for this node to change and output: the upstream value itself
    /// when no later node and no pending write needs it (no copy), else a copy.
    std::shared_ptr<MeshData> takeMesh(const std::string& port) const
    {
        if (meshTaker) return meshTaker(port);
        const NodeValue* v = input(port);
        if (!v || !v->mesh) throw std::invalid_argument("input '" + port + "' holds no mesh");
        return std::make_shared<MeshData>(*v->mesh);
    }

    const NodeValue* input(const std::string& name) const
    {
        auto it = inputs.find(name);
        return it == inputs.end() ? nullptr : it->second;
    }
    void warn(const std::string& line) const
    {
        if (warnings) warnings->push_back(nodeId + ": " + line);
    }
};

struct NodeType {
    std::string type;        ///< lowercase token used in graphs, e.g. "threshold"
    std::string label;       ///< Title Case
    std::string description; ///< one or two sentences, citing paper section and SPEC §
    std::vector<ParmSpec> parms;
    std::vector<PortSpec> inputs;
    std::vector<PortSpec> outputs;
    std::function<void(CookContext&)> cook;
    bool meshWriter = false; ///< writes its input mesh to the file its first path parameter names
    bool onRanks = false;    ///< cooks on MPI ranks, each rank its piece (Ranks.h; docs/mpi.md)

    const ParmSpec* findParm(const std::string& token) const
    {
        for (const ParmSpec& p : parms)
            if (p.token == token) return &p;
        return nullptr;
    }
};

/// Every node type, in documentation order.
const std::vector<NodeType>& nodeTypes();

/// The node type called @a type, or nullptr.
const NodeType* findNodeType(const std::string& type);

/// The declarations as JSON (`isouq nodes --json`, read by the Blender add-on).
nlohmann::json nodeTypesJson();

/// The parameter tables as Markdown (docs/node-parameters.md is this text).
std::string nodeTypesMarkdown();

} // namespace isouq::nodes
