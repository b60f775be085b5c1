// isouq nodes: the nodes that write files — write_ply, write_vtp, write_summary, report. Each
// cook only queues a PendingWrite; the graph commits them after every node has cooked (Node.h).
#include "NodeFamilies.h"
#include "Pieces.h"

#include "isouq/nodes/Resources.h"

#include <isouq/MeshIO.h>

#include <cstdlib>
#include <filesystem>
#include <stdexcept>
#include <sys/wait.h>

namespace isouq::nodes::nodes_internal {
namespace {

namespace fs = std::filesystem;

PlyOptions plyOptionsOf(const MeshData& m)
{
    PlyOptions ply;
    ply.version = ISOUQ_VERSION_STRING;
    ply.isovalue = m.isovalue;
    ply.method = m.method;
    // Where the index_to_world comment comes from for scans with a header (SPEC §10 "Formats").
    if (m.info.contains("geometry")) ply.comments.push_back("isouq geometry " + m.info["geometry"].get<std::string>());
    return ply;
}

void cookWritePly(CookContext& ctx)
{
    auto mesh = ctx.input("mesh")->mesh;
    const std::string path = ctx.parms.getString("path");
    PlyOptions options = plyOptionsOf(*mesh);
    if (ctx.parms.getString("format") == "ascii") options.encoding = PlyEncoding::Ascii;
    if (ctx.ranks) { // every rank writes its rows into the one file (docs/mpi.md)
        if (!mesh->piece) throw std::invalid_argument("input 'mesh' is not a mesh made by pieces");
        const Ranks* ranks = ctx.ranks;
        ctx.writes->push_back({path, [mesh, path, options, ranks](OutputBatch& batch) {
            stagePlyOnRanks(*ranks, mesh->mesh, *mesh->piece, path, options, batch);
        }});
        return;
    }
    ctx.writes->push_back({path, [mesh, path, options](OutputBatch& batch) { batch.addPly(mesh->mesh, path, options); }, true});
}

void cookWriteVtp(CookContext& ctx)
{
    auto mesh = ctx.input("mesh")->mesh;
    const std::string path = ctx.parms.getString("path");
    const MeshFileOptions options = plyOptionsOf(*mesh);
    if (ctx.ranks) { // as write_ply's
        if (!mesh->piece) throw std::invalid_argument("input 'mesh' is not a mesh made by pieces");
        const Ranks* ranks = ctx.ranks;
        ctx.writes->push_back({path, [mesh, path, options, ranks](OutputBatch& batch) {
            stageVtpOnRanks(*ranks, mesh->mesh, *mesh->piece, path, options, batch);
        }});
        return;
    }
    ctx.writes->push_back({path, [mesh, path, options](OutputBatch& batch) { batch.addVtp(mesh->mesh, path, options); }, true});
}

void cookWriteSummary(CookContext& ctx)
{
    const std::string text = ctx.input("summary")->json.dump(2) + "\n";
    const std::string path = ctx.parms.getString("path");
    const bool writes = !ctx.ranks || ctx.ranks->rank() == 0; // on ranks rank 0 holds the summary
    ctx.writes->push_back({path, [text, path, writes](OutputBatch& batch) {
        if (writes) batch.addText(path, text);
    }, true});
}

std::string envOr(const char* name, const std::string& fallback)
{
    const char* v = std::getenv(name);
    return v && *v ? v : fallback;
}

std::string quoted(const std::string& s)
{
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
}

/// Runs report.py (scripts/ in the source, share/isouq/ installed; matplotlib) on the mesh and summary, staged in a temporary folder.
void writeReport(const MeshData& m, const nlohmann::json& summary, const std::string& dir, bool html)
{
    const fs::path stage = fs::path(dir).parent_path() / (fs::path(dir).filename().string() + ".isouq-stage");
    fs::create_directories(stage);
    struct Cleanup {
        fs::path p;
        ~Cleanup() { std::error_code ec; fs::remove_all(p, ec); }
    } cleanup{stage};
    writePly(m.mesh, (stage / "mesh.ply").string(), plyOptionsOf(m));
    writeTextFileAtomic((stage / "summary.json").string(), summary.dump(2) + "\n");
    const std::string command = quoted(envOr("ISOUQ_PYTHON", "/usr/bin/python3")) + " " +
        quoted(envOr("ISOUQ_REPORT_SCRIPT", resourcePath("report.py").string())) + " --mesh " + quoted((stage / "mesh.ply").string()) +
        " --summary " + quoted((stage / "summary.json").string()) + " --out " + quoted(dir) + (html ? " --html" : "");
    const int status = std::system(command.c_str());
    if (status != 0)
        throw IoError("cannot write report " + dir + ": report.py failed (status " +
            std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : status) + ")");
}

void cookReport(CookContext& ctx)
{
    auto mesh = ctx.input("mesh")->mesh;
    const NodeValue* s = ctx.input("summary");
    nlohmann::json summary = s ? s->json : nlohmann::json::object();
    const std::string dir = ctx.parms.getString("dir");
    const bool html = ctx.parms.getBool("html");
    // The pictures are drawn once every node has cooked, before the batch commits.
    ctx.writes->push_back({dir, [mesh, summary, dir, html](OutputBatch&) { writeReport(*mesh, summary, dir, html); }});
}

} // namespace

void addOutputNodes(std::vector<NodeType>& types)
{
    types.push_back({"write_ply", "Write PLY",
        "Writes the mesh as PLY with every attribute (SPEC §6; docs/ply-format.md), binary little-endian or "
        "ascii, atomically.",
        {ending(parm("path", "Path", ParmType::Path, "out.ply",
             "Output mesh (.ply, binary little-endian; with isouq mesh a .vtp path writes VTK XML PolyData)",
             "-o,--output"), {".ply"}),
            menuParm("format", "Format", {"binary", "ascii"}, "binary",
                "PLY encoding: binary little-endian, or ascii (what meshio 7 reads face columns from)",
                "--ply-format")},
        {{"mesh", "mesh", "The mesh to write"}}, {}, cookWritePly, /*meshWriter=*/true, /*onRanks=*/true});

    types.push_back({"write_vtp", "Write VTP",
        "Writes the mesh as VTK XML PolyData for ParaView and VTK (SPEC §10; docs/vtp-format.md): every vertex "
        "column as point data and every face column as cell data under its own name, the PLY header "
        "comments as field data; raw binary appended, atomically.",
        {ending(parm("path", "Path", ParmType::Path, "out.vtp", "Output mesh (.vtp)"), {".vtp"})},
        {{"mesh", "mesh", "The mesh to write"}}, {}, cookWriteVtp, /*meshWriter=*/true, /*onRanks=*/true});

    types.push_back({"write_summary", "Write Summary",
        "Writes a JSON value (a summary, a CDF, compare statistics) to a file, atomically.",
        {parm("path", "Path", ParmType::Path, "summary.json", "Output JSON file (with isouq mesh: the SPEC §8 summary)",
            "--summary")},
        {{"summary", "json", "The JSON to write"}}, {}, cookWriteSummary, /*meshWriter=*/false, /*onRanks=*/true});

    types.push_back({"report", "Report",
        "Draws the C1 CDF with its threshold, the C5 vertex-by-vertex bars of err_est, d_lc and d_lw in the box, "
        "and the C7 summary as PNG (and an HTML page) with matplotlib (report.py; paper sec. 4.3).",
        {
            parm("dir", "Folder", ParmType::Path, "report", "Output folder for the PNG files", "-o,--output"),
            parm("html", "HTML Page", ParmType::Bool, false, "Also write index.html showing the pictures", "--html"),
        },
        {{"mesh", "mesh", "A mesh, with `above` (threshold) and `in_box` (box_select) for C1 and C5"},
            {"summary", "json", "The C7 summary", true}},
        {}, cookReport});
}

} // namespace isouq::nodes::nodes_internal
