// isouq nodes: parsing, checking and running JSON node graphs (Graph.h; docs/nodes.md).
#include "isouq/nodes/Graph.h"

#include <isouq/MeshIO.h>
#include <isouq/Progress.h>
#include <isouq/VolumeSources.h>

#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <regex>
#include <set>

namespace isouq::nodes {
namespace {

namespace fs = std::filesystem;

std::string where(const std::string& id, const NodeType* type)
{
    return "node '" + id + "'" + (type ? " (" + type->type + ")" : "");
}

[[noreturn]] void fail(const std::string& id, const NodeType* type, const std::string& what)
{
    throw GraphError(where(id, type) + ": " + what);
}

/// ${NAME} -> the environment variable NAME; unset ones are errors.
std::string expand(const std::string& s, const std::string& id, const NodeType* type, const std::string& token)
{
    static const std::regex var(R"(\$\{([A-Za-z_][A-Za-z0-9_]*)\})");
    std::string out;
    auto begin = std::sregex_iterator(s.begin(), s.end(), var);
    std::size_t last = 0;
    for (auto it = begin; it != std::sregex_iterator(); ++it) {
        const char* value = std::getenv((*it)[1].str().c_str());
        if (!value)
            fail(id, type, "parameter '" + token + "': environment variable " + (*it)[1].str() + " is not set");
        out += s.substr(last, it->position() - last) + value;
        last = it->position() + it->length();
    }
    return out + s.substr(last);
}

} // namespace

ParmValues evaluateParms(const nlohmann::json& given, const std::string& id, const NodeType& type,
    const GraphOptions& options)
{
    if (!given.is_object()) fail(id, &type, "\"parms\" must be an object");
    for (const auto& [token, value] : given.items()) {
        const ParmSpec* spec = type.findParm(token);
        if (!spec) fail(id, &type, "unknown parameter '" + token + "' (see 'isouq nodes')");
        if (std::string why = checkParmValue(*spec, value); !why.empty())
            fail(id, &type, "parameter '" + token + "': " + why);
    }
    nlohmann::json values = nlohmann::json::object();
    for (const ParmSpec& spec : type.parms) {
        nlohmann::json v = given.contains(spec.token) ? given[spec.token] : spec.defaultValue;
        if (v.is_string() && (spec.type == ParmType::String || spec.type == ParmType::Path))
            v = expand(v.get<std::string>(), id, &type, spec.token);
        if (v.is_string() && v.get<std::string>().find('\0') != std::string::npos)
            fail(id, &type, "parameter '" + spec.token + "': contains a NUL character");
        if (spec.type == ParmType::Path && v.is_string()) {
            fs::path p(v.get<std::string>());
            // With an output folder, relative outputs stay inside it (absolute ones are explicit).
            if (p.is_relative() && !options.outputDir.empty()) {
                if (const fs::path inside = p.lexically_normal(); !inside.empty() && *inside.begin() == "..")
                    fail(id, &type, "parameter '" + spec.token + "': " + p.string() +
                        " leaves the output folder " + options.outputDir + " (give an absolute path to write elsewhere)");
                p = fs::path(options.outputDir) / p;
            }
            v = p.lexically_normal().string();
        }
        values[spec.token] = v;
    }
    return ParmValues(values);
}

namespace {

struct RawNode {
    std::string id;
    const NodeType* type;
    ParmValues parms;
    nlohmann::json inputs;
};

const PortSpec* findPort(const std::vector<PortSpec>& ports, const std::string& name)
{
    for (const PortSpec& p : ports)
        if (p.name == name) return &p;
    return nullptr;
}

} // namespace

Graph parseGraph(const nlohmann::json& doc, const GraphOptions& options)
{
    if (!doc.is_object() || !doc.contains("nodes") || !doc["nodes"].is_array())
        throw GraphError("a graph is an object with a \"nodes\" array");
    for (const auto& [key, value] : doc.items())
        if (key != "nodes" && key != "description" && key != "figure")
            throw GraphError("unknown key '" + key + "' (a graph has description, figure and nodes)");
    if (doc.contains("description") && !doc["description"].is_string())
        throw GraphError("\"description\" must be a string, got " + doc["description"].dump());

    std::vector<RawNode> raw;
    std::map<std::string, std::size_t> byId;
    for (const nlohmann::json& n : doc["nodes"]) {
        if (!n.is_object() || !n.contains("id") || !n["id"].is_string() || n["id"].get<std::string>().empty())
            throw GraphError("each node is an object with a non-empty string \"id\": " + n.dump());
        const std::string id = n["id"];
        if (byId.count(id)) fail(id, nullptr, "the id is used twice");
        for (const auto& [key, value] : n.items())
            if (key != "id" && key != "type" && key != "parms" && key != "inputs" && key != "comment")
                fail(id, nullptr, "unknown key '" + key + "' (a node has id, type, parms, inputs, comment)");
        if (!n.contains("type") || !n["type"].is_string()) fail(id, nullptr, "no \"type\"");
        const NodeType* type = findNodeType(n["type"]);
        if (!type) fail(id, nullptr, "unknown node type '" + n["type"].get<std::string>() + "' (see 'isouq nodes')");
        const nlohmann::json inputs = n.value("inputs", nlohmann::json::object());
        if (!inputs.is_object()) fail(id, type, "\"inputs\" must be an object");
        byId[id] = raw.size();
        raw.push_back({id, type, evaluateParms(n.value("parms", nlohmann::json::object()), id, *type, options), inputs});
    }

    // Connections: "node" (its first output of the input's type) or "node.port".
    std::vector<GraphNode> nodes(raw.size());
    std::vector<std::vector<std::size_t>> readers(raw.size());
    std::vector<std::size_t> pending(raw.size(), 0);
    for (std::size_t n = 0; n < raw.size(); ++n) {
        const RawNode& r = raw[n];
        nodes[n] = {r.id, r.type, r.parms, {}};
        for (const auto& [port, source] : r.inputs.items()) {
            const PortSpec* in = findPort(r.type->inputs, port);
            if (!in) fail(r.id, r.type, "unknown input '" + port + "'");
            if (!source.is_string()) fail(r.id, r.type, "input '" + port + "': expected \"node\" or \"node.output\"");
            std::string from = source, outName;
            if (auto dot = from.find('.'); dot != std::string::npos) {
                outName = from.substr(dot + 1);
                from = from.substr(0, dot);
            }
            auto it = byId.find(from);
            if (it == byId.end()) fail(r.id, r.type, "input '" + port + "': no node '" + from + "'");
            const NodeType* srcType = raw[it->second].type;
            const PortSpec* out = nullptr;
            for (const PortSpec& o : srcType->outputs)
                if (outName.empty() ? o.type == in->type : o.name == outName) {
                    out = &o;
                    break;
                }
            if (!out)
                fail(r.id, r.type, "input '" + port + "': node '" + from + "' has no " +
                    (outName.empty() ? in->type + " output" : "output '" + outName + "'"));
            if (out->type != in->type)
                fail(r.id, r.type, "input '" + port + "': expects a " + in->type + ", '" + source.get<std::string>() +
                    "' is a " + out->type);
            nodes[n].inputs[port] = {it->second, out->name};
            readers[it->second].push_back(n);
            ++pending[n];
        }
        for (const PortSpec& in : r.type->inputs)
            if (!in.optional && !r.inputs.contains(in.name))
                fail(r.id, r.type, "input '" + in.name + "' is not connected");
    }

    // Kahn's order; what is left is on or behind a cycle.
    std::vector<std::size_t> ready;
    for (std::size_t n = 0; n < raw.size(); ++n)
        if (pending[n] == 0) ready.push_back(n);
    std::vector<bool> done(raw.size(), false);
    for (std::size_t next = 0; next < ready.size(); ++next) {
        const std::size_t n = ready[next];
        done[n] = true;
        for (std::size_t r : readers[n])
            if (--pending[r] == 0) ready.push_back(r);
    }
    if (ready.size() != raw.size()) {
        // Walk inputs backwards from an unfinished node until a node repeats: that is the cycle.
        std::size_t n = 0;
        while (done[n]) ++n;
        std::vector<std::size_t> path;
        std::vector<int> seenAt(raw.size(), -1);
        while (seenAt[n] < 0) {
            seenAt[n] = int(path.size());
            path.push_back(n);
            for (const auto& [port, src] : nodes[n].inputs)
                if (!done[src.first]) {
                    n = src.first;
                    break;
                }
        }
        // "a <- b": a reads b's output.
        std::string cycle;
        for (std::size_t i = std::size_t(seenAt[n]); i < path.size(); ++i) cycle += raw[path[i]].id + " <- ";
        fail(raw[n].id, raw[n].type, "input cycle: " + cycle + raw[n].id);
    }

    // Renumber in running order.
    Graph graph;
    graph.description = doc.value("description", "");
    std::vector<std::size_t> position(raw.size());
    for (std::size_t i = 0; i < ready.size(); ++i) position[ready[i]] = i;
    for (std::size_t n : ready) {
        graph.nodes.push_back(nodes[n]);
        for (auto& [port, src] : graph.nodes.back().inputs) src.first = position[src.first];
    }

    // Two writers of one file, or a writer of a file that a node reads. Paths are resolved
    // (symlinks, "..", "./"), so two spellings of one file are one file.
    auto resolved = [](const std::string& p) {
        std::error_code ec;
        const fs::path r = fs::weakly_canonical(fs::absolute(p), ec);
        return ec ? fs::absolute(p).lexically_normal().string() : r.string();
    };
    // An input is also what it reads besides itself: a NRRD header's data files, the slices
    // of a folder (volumeInputFiles).
    std::map<std::string, std::string> inputFiles;
    if (!options.graphFile.empty()) inputFiles.emplace(resolved(options.graphFile), "");
    for (const GraphNode& n : graph.nodes)
        for (const ParmSpec& spec : n.type->parms) {
            if (spec.type != ParmType::String || !n.parms.isSet(spec.token)) continue;
            const std::string value = n.parms.getString(spec.token);
            std::error_code ec;
            if (fs::is_regular_file(value, ec)) inputFiles.emplace(resolved(value), n.id);
            if (fs::exists(value, ec))
                for (const std::string& file : volumeInputFiles(value)) inputFiles.emplace(resolved(file), n.id);
        }
    std::map<std::string, std::string> writers;
    for (const GraphNode& n : graph.nodes)
        for (const ParmSpec& spec : n.type->parms)
            if (spec.type == ParmType::Path && n.parms.isSet(spec.token)) {
                const std::string given = n.parms.getString(spec.token), path = resolved(given);
                if (auto in = inputFiles.find(path); in != inputFiles.end())
                    fail(n.id, n.type, "parameter '" + spec.token + "': " + given +
                        (in->second.empty() ? std::string(" is the graph file") : " is the input of node '" + in->second + "'") +
                        "; refusing to overwrite an input");
                auto [it, fresh] = writers.emplace(path, n.id);
                if (!fresh)
                    fail(n.id, n.type, "parameter '" + spec.token + "': " + given + " is also written by node '" +
                        it->second + "'");
            }
    return graph;
}

Graph loadGraph(const std::string& path, const GraphOptions& options)
{
    // A regular file of bounded size (never block on a FIFO or a device), nested at most
    // kMaxDepth deep (the JSON library recurses on nesting).
    constexpr std::uintmax_t kMaxBytes = 64u << 20;
    constexpr int kMaxDepth = 256;
    std::error_code ec;
    if (!fs::exists(path, ec)) throw GraphError("cannot read " + path + ": no such file");
    if (!fs::is_regular_file(path, ec)) throw GraphError("cannot read " + path + ": not a regular file");
    if (fs::file_size(path, ec) > kMaxBytes) throw GraphError(path + ": larger than 64 MiB, not a graph");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw GraphError("cannot read " + path);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    int depth = 0;
    bool inString = false;
    for (std::size_t i = 0; i < text.size(); ++i) {
        const char c = text[i];
        if (inString) {
            if (c == '\\') ++i;
            else if (c == '"') inString = false;
        } else if (c == '"') inString = true;
        else if ((c == '[' || c == '{') && ++depth > kMaxDepth)
            throw GraphError(path + ": nested deeper than " + std::to_string(kMaxDepth) + " levels, not a graph");
        else if (c == ']' || c == '}') --depth;
    }
    nlohmann::json doc;
    try {
        doc = nlohmann::json::parse(text);
    } catch (const nlohmann::json::exception& e) { // parse_error, or out_of_range for 1e999
        throw GraphError(path + ": not valid JSON: " + e.what());
    }
    try {
        GraphOptions withFile = options;
        withFile.graphFile = path;
        return parseGraph(doc, withFile);
    } catch (const GraphError& e) {
        throw GraphError(path + ": " + e.what());
    }
}

namespace {

/// Whether clearing @a value frees a large volume or mesh (one nothing else holds, such as a
/// Python caller's grid): at least 32 MiB of leaf values, or of positions and triangles.
bool freesLargeData(const NodeValue& value)
{
    constexpr std::uint64_t kLarge = std::uint64_t(32) << 20;
    std::uint64_t bytes = 0;
    if (value.volume && value.volume.use_count() == 1 && value.volume->grid && value.volume->grid.use_count() == 1)
        bytes += value.volume->grid->tree().leafCount() * std::uint64_t(openvdb::FloatTree::LeafNodeType::SIZE * sizeof(float));
    if (value.mesh && value.mesh.use_count() == 1)
        bytes += 12 * std::uint64_t(value.mesh->mesh.vertexCount() + value.mesh->mesh.triangleCount());
    return bytes >= kLarge;
}

/// Gives the heap's free pages back to the kernel once a large volume or mesh is freed (glibc's
/// malloc_trim, about 1 ms after the 1 GiB scan's volume; not for small ones, as in Blender's
/// live mode, whose heap is Blender's): the PLY's page cache and the next nodes then take pages
/// the machine has already backed rather than fresh ones, which a VM's host backs on first
/// touch at 0.3-1 GB/s (bench/journal/2026-12-07.md: the 1 GiB scan's PLY write after
/// the last cook, -j 1, 0.40-0.53 -> 0.15-0.20 s).
void returnFreedMemory()
{
#if defined(__GLIBC__)
    malloc_trim(0);
#endif
}

/// Cook times of every node upstream of @a n, by id, in running order (a walk of its inputs).
nlohmann::json upstreamTimings(const Graph& graph, const std::vector<double>& cookMs, std::size_t n)
{
    std::vector<bool> seen(graph.nodes.size(), false);
    std::vector<std::size_t> stack{n};
    while (!stack.empty()) {
        const std::size_t m = stack.back();
        stack.pop_back();
        for (const auto& [port, src] : graph.nodes[m].inputs)
            if (!seen[src.first]) seen[src.first] = true, stack.push_back(src.first);
    }
    nlohmann::json timings = nlohmann::json::object();
    for (std::size_t m = 0; m < n; ++m)
        if (seen[m]) timings[graph.nodes[m].id] = cookMs[m];
    return timings;
}

/// The paths that mesh writers give to the value node @a n reads on @a port.
std::vector<std::string> destinations(const Graph& graph, std::size_t n, const std::string& port)
{
    std::vector<std::string> paths;
    const auto it = graph.nodes[n].inputs.find(port);
    if (it == graph.nodes[n].inputs.end()) return paths;
    for (const GraphNode& reader : graph.nodes) {
        if (!reader.type->meshWriter) continue;
        for (const auto& [readerPort, src] : reader.inputs)
            if (src == it->second)
                for (const ParmSpec& spec : reader.type->parms)
                    if (spec.type == ParmType::Path) {
                        paths.push_back(reader.parms.getString(spec.token));
                        break;
                    }
    }
    return paths;
}

} // namespace

GraphResult runGraph(const Graph& graph, openvdb::util::NullInterrupter* interrupter,
    const std::vector<std::string>& keepMeshes, const Ranks* ranks)
{
    if (ranks)
        for (const GraphNode& n : graph.nodes)
            if (!n.type->onRanks) fail(n.id, n.type, "not supported under MPI yet (docs/mpi.md); run it in one process");
    // On ranks, every stage ends with an agreement (Ranks::step).
    const auto collective = [ranks](const std::function<void()>& body, const std::string& at = std::string()) {
        if (ranks) ranks->step(body, at);
        else body();
    };
    // Fail on unwritable outputs before any heavy work.
    collective([&] {
        for (const GraphNode& n : graph.nodes)
            for (const ParmSpec& spec : n.type->parms)
                if (spec.type == ParmType::Path && n.parms.isSet(spec.token)) try {
                        checkWritable(n.parms.getString(spec.token));
                    } catch (const std::exception& e) {
                        throw IoError(where(n.id, n.type) + ": parameter '" + spec.token + "': " + e.what());
                    }
    });

    // A node's outputs are freed once its last reader has cooked (the volume after meshing).
    const std::size_t count = graph.nodes.size();
    std::vector<std::size_t> lastReader(count);
    for (std::size_t n = 0; n < count; ++n) {
        lastReader[n] = n;
        for (const auto& [port, src] : graph.nodes[n].inputs) lastReader[src.first] = std::max(lastReader[src.first], n);
    }
    std::vector<std::vector<std::size_t>> freeAfter(count);
    for (std::size_t n = 0; n < count; ++n) freeAfter[lastReader[n]].push_back(n);

    GraphResult result;
    std::vector<PendingWrite> writes;
    std::vector<std::map<std::string, NodeValue>> values(count);
    std::vector<double> cookMs(count, 0.0);
    // In one process an early write (PendingWrite::early) stages, filling its temporary file,
    // as soon as its node has cooked, on a thread that later cooks leave free: a PLY's bytes go
    // to the kernel while the summary measures. The others (a report's pictures) stage after
    // the last cook. Each stages into a batch of its own; the batches join the run's batch in
    // the graph's order. Cooks run isolated, so their parallel loops never take up a write; with
    // one thread (-j 1) every write stages after the last cook, as on ranks (collective writes).
    std::vector<std::unique_ptr<OutputBatch>> staged;
    tbb::task_group stagers;

    for (std::size_t n = 0; n < count; ++n) {
        const GraphNode& node = graph.nodes[n];
        CookContext ctx;
        ctx.nodeId = node.id;
        ctx.parms = node.parms;
        ctx.interrupter = interrupter;
        ctx.warnings = &result.warnings;
        ctx.writes = &writes;
        ctx.ranks = ranks;
        ctx.timingsOfUpstream = [&graph, &cookMs, n] { return upstreamTimings(graph, cookMs, n); };
        ctx.destinationsOf = [&graph, n](const std::string& port) { return destinations(graph, n, port); };
        ctx.meshTaker = [&](const std::string& port) {
            const auto& src = node.inputs.at(port);
            NodeValue& value = values[src.first].at(src.second);
            if (!value.mesh) throw std::invalid_argument("input '" + port + "' holds no mesh");
            std::size_t ports = 0; // this node's inputs that read the same value
            for (const auto& [other, from] : node.inputs) ports += from == src;
            if (lastReader[src.first] == n && ports == 1 && value.mesh.use_count() == 1)
                return std::const_pointer_cast<MeshData>(std::move(value.mesh));
            return std::make_shared<MeshData>(*value.mesh);
        };
        for (const auto& [port, src] : node.inputs)
            ctx.inputs[port] = &values[src.first].at(src.second);
        const auto start = std::chrono::steady_clock::now();
        if (ranks) {
            ranks->step([&] { node.type->cook(ctx); }, where(node.id, node.type) + ": ");
        } else {
            throwIfInterrupted(interrupter);
            try {
                tbb::this_task_arena::isolate([&] { node.type->cook(ctx); });
            } catch (const InterruptedError&) {
                throw;
            } catch (const std::exception& e) {
                if (openvdb::util::wasInterrupted(interrupter)) throw InterruptedError();
                throw InputError(where(node.id, node.type) + ": " + e.what());
            }
        }
        cookMs[n] = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        for (const PortSpec& out : node.type->outputs)
            if (out.type == "json" && ctx.outputs.count(out.name))
                result.outputs[node.id][out.name] = ctx.outputs[out.name].json;
        values[n] = std::move(ctx.outputs);
        // A kept mesh is shared, so a later takeMesh() copies it instead of changing it.
        if (std::find(keepMeshes.begin(), keepMeshes.end(), node.id) != keepMeshes.end() && values[n].count("mesh"))
            result.meshes[node.id] = values[n]["mesh"].mesh;
        bool freedData = false;
        for (std::size_t m : freeAfter[n]) {
            for (const auto& [port, value] : values[m]) freedData |= freesLargeData(value);
            values[m].clear();
        }
        if (freedData) returnFreedMemory();
        for (std::size_t w = staged.size(); !ranks && w < writes.size(); ++w) {
            OutputBatch* into = staged.emplace_back(std::make_unique<OutputBatch>()).get();
            if (writes[w].early) stagers.run([into, stage = writes[w].stage] { stage(*into); });
        }
    }
    OutputBatch batch;
    collective([&] { throwIfInterrupted(interrupter); });
    if (ranks) {
        for (const PendingWrite& w : writes) collective([&] { w.stage(batch); });
    } else {
        stagers.wait(); // rethrows a write's IoError
        for (std::size_t w = 0; w < writes.size(); ++w) {
            if (!writes[w].early) writes[w].stage(*staged[w]);
            batch.add(std::move(*staged[w]));
        }
    }
    collective([&] {
        throwIfInterrupted(interrupter);
        batch.commit(); // on ranks, rank 0 holds the files
    });
    for (const PendingWrite& w : writes) result.written.push_back(w.path);
    return result;
}

} // namespace isouq::nodes
