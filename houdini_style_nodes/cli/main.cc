// isouq: the command line (SPEC §8). A thin face over isouq::nodes: parse, run, report. It is
// the module libisouq_cli.so, which the `isouq` program runs (CliModule.h, Launcher.cc).
// The options of `mesh` come from the parameter declarations of the read_volume, mesh,
// write_ply, color_map and write_summary nodes (ParmOptions.h); `run` runs a JSON node graph.
// Exit status: 0 success, 2 bad input or usage (one line "isouq: error: ..."), 130 interrupted.
#include "CliModule.h"
#include "ParmOptions.h"
#include "ProgressInterrupter.h"
#include "ValidateCommand.h"

#include <isouq/MeshIO.h>
#include <isouq/Threads.h>
#include <isouq/VolumeSources.h>
#include <isouq/nodes/Graph.h>
#include <isouq/nodes/MeshGraph.h>
#include <isouq/nodes/Sequence.h>
#ifdef ISOUQ_HAVE_MPI
#include <isouq/nodes/Distributed.h>
#endif

#include <CLI/CLI.hpp>
#include <openvdb/Exceptions.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <memory>
#include <vector>
#include <unistd.h>

namespace {

using isouq::nodes::MeshGraphRequest;

constexpr int kExitBadInput = 2;

const char* const kMeshExamples = R"(
Examples:
  isouq mesh sphere.vdb -o sphere.ply                    level set: isovalue 0
  isouq mesh smoke.vdb --grid density --isovalue 0.1 -o smoke.ply --summary smoke.json
  isouq mesh engine_256x256x128_uint8.raw --isovalue 71 -o engine.ply
                                                          dims and dtype from the file name
  isouq mesh scan.raw --dims 512,512,300 --dtype int16 --spacing 0.5,0.5,1 -o scan.ply
  isouq mesh field:tangle --resolution 64 -o tangle.ply   SPEC §5 fields: tangle, torus,
                                                          torus-paper, marschner-lobb, teardrop,
                                                          tubey, sphere
  isouq mesh "formula:x^2+y^2+z^2-0.5" --domain -1,1 --resolution 128 -o ball.ply
  isouq mesh field:tangle -o tangle.vtp                  VTK XML PolyData (ParaView, VTK)
  isouq mesh field:tangle -o tangle.ply --color-by err_est
                                                          vertex colours any viewer shows

Every vertex carries the edge it lies on (edge_i edge_j edge_k edge_axis) and where each method
puts it (t_linear ...); see docs/ply-format.md. Outputs are written atomically: a failed or
interrupted run (Ctrl-C, exit 130) leaves no partial file and never clobbers an existing one.
The command runs a node graph (docs/nodes.md): --save-graph G.json writes it, and
'isouq run G.json' from the same folder writes the same files.
Under mpirun or srun (--mpi=pmix) the same command meshes on every rank into one file; rank 0
prints a progress line at each tenth of a stage that has run ISOUQ_PROGRESS_SECONDS (10)
(docs/mpi.md).
With an input of 16 MiB or more, isouq restarts itself once with glibc's malloc.hugetlb=1 and
malloc.arena_max=1 (2 MiB memory pages for every thread: fewer page faults); ISOUQ_HUGE_PAGES=0
turns that off (docs/mesher.md).
)";

const char* const kRunFooter = R"(
A graph is JSON: {"nodes": [{"id": "read", "type": "read_volume", "parms": {...}},
  {"id": "mesh", "type": "mesh", "inputs": {"volume": "read"}}, ...]}. 'isouq nodes' lists the
node types and their parameters; examples/ has one graph per paper figure; see docs/nodes.md.
${NAME} in a string parameter is the environment variable NAME. Files appear only once every
node has cooked: a failed or interrupted run writes nothing.
)";

bool stderrIsTerminal() { return ::isatty(STDERR_FILENO) == 1; }

/// False on the MPI ranks other than 0 while every rank reports the same thing (usage errors).
bool sPrintsErrors = true;
/// What an interrupted run leaves: nothing, or a sequence's finished frames.
const char* sInterruptedNote = "no output written";

void printError(const std::string& message)
{
    if (sPrintsErrors) std::fprintf(stderr, "isouq: error: %s\n", isouq::oneLine(message).c_str());
}

void printNotes(const std::vector<std::string>& notes, bool quiet)
{
    if (quiet) return;
    for (const std::string& note : notes) std::fprintf(stderr, "isouq: %s\n", isouq::oneLine(note).c_str());
}

/// @a path as printed on stdout, one line whatever its bytes (escaped as error lines are).
std::string shown(const std::string& path) { return isouq::oneLine(path, std::string::npos); }

void printResult(const nlohmann::json& s, const std::string& summaryPath)
{
    std::printf("wrote %s: %zu vertices, %zu triangles, %zu components, %zu boundary edges, "
                "%zu non-manifold edges (isovalue %g, %s)\n",
        shown(s["output"].get<std::string>()).c_str(), s["vertices"].get<std::size_t>(),
        s["triangles"].get<std::size_t>(), s["components"].get<std::size_t>(),
        s["boundary_edges"].get<std::size_t>(), s["non_manifold_edges"].get<std::size_t>(),
        s["isovalue"].get<double>(), s["method"].get<std::string>().c_str());
    if (s.contains("hidden") && s["hidden"].contains("output"))
        std::printf("wrote %s: hidden features, %zu -> %zu components\n",
            shown(s["hidden"]["output"].get<std::string>()).c_str(), s["hidden"]["components_before"].get<std::size_t>(),
            s["hidden"]["components_after"].get<std::size_t>());
    if (!summaryPath.empty()) std::printf("wrote %s: summary (JSON)\n", shown(summaryPath).c_str());
}

/// How a run shows progress: a bar on a terminal; on MPI ranks (@a ranks) rank 0 alone, as
/// lines when its stderr is the launcher's pipe.
isouq::cli::ProgressStyle progressStyle(bool quiet, const isouq::nodes::Ranks* ranks)
{
    using isouq::cli::ProgressStyle;
    return quiet || (ranks && ranks->rank() != 0) ? ProgressStyle::None
        : stderrIsTerminal()                       ? ProgressStyle::Bar
        : ranks                                    ? ProgressStyle::Lines
                                                   : ProgressStyle::None;
}

/// Runs @a graph (the mesh command's or a file's) with a progress bar; prints its warnings. On
/// MPI ranks (@a ranks) rank 0 shows progress and prints.
isouq::nodes::GraphResult runWithProgress(const isouq::nodes::Graph& graph, bool quiet,
    const isouq::nodes::Ranks* ranks)
{
    const bool root = !ranks || ranks->rank() == 0;
    isouq::cli::ProgressInterrupter progress(progressStyle(quiet, ranks));
    isouq::nodes::GraphResult result = isouq::nodes::runGraph(graph, &progress, {}, ranks);
    if (root) printNotes(result.warnings, quiet);
    return result;
}

/// `isouq mesh` and `isouq demo`: the mesh graph (MeshGraph.h), run like any other graph, in
/// one process or on the MPI ranks @a ranks (docs/mpi.md).
int runMesh(const MeshGraphRequest& request, const std::string& saveGraph, bool quiet,
    const isouq::nodes::Ranks* ranks = nullptr)
{
    const nlohmann::json doc = isouq::nodes::meshGraph(request);
    const isouq::nodes::Graph graph = isouq::nodes::parseGraph(doc);
    if (!saveGraph.empty()) {
        namespace fs = std::filesystem;
        const auto same = [&](const std::string& p) {
            return !p.empty() && fs::weakly_canonical(fs::absolute(p)) == fs::weakly_canonical(fs::absolute(saveGraph));
        };
        for (const std::string& out : {request.output, request.hiddenOutput, request.summaryPath})
            if (same(out)) throw isouq::InputError("--save-graph " + saveGraph + " is also an output; give it its own path");
        // Nor the input, or a file it reads (a NRRD data file, a slice of a folder).
        const std::string input = request.read.value("input", std::string());
        std::vector<std::string> inputs = isouq::volumeInputFiles(input);
        inputs.push_back(input);
        for (const std::string& in : inputs)
            if (same(in)) throw isouq::InputError("--save-graph " + saveGraph + " is the input '" + in + "'; refusing to overwrite an input");
        isouq::checkWritable(saveGraph);
    }
    const isouq::nodes::GraphResult result = runWithProgress(graph, quiet, ranks);
    if (ranks && ranks->rank() != 0) return 0;
    if (!saveGraph.empty()) isouq::writeTextFileAtomic(saveGraph, doc.dump(2) + "\n");
    printResult(result.outputs.at(isouq::nodes::kMeshGraphSummary).at("summary"), request.summaryPath);
    if (!saveGraph.empty()) std::printf("wrote %s: the graph (isouq run %s)\n", shown(saveGraph).c_str(), shown(saveGraph).c_str());
    return 0;
}

#ifdef ISOUQ_HAVE_MPI
/// MPI for the life of main, started only under a launcher (mpirun, srun): a plain start-up
/// never initialises it (SPEC §10 "MPI"; docs/mpi.md).
struct MpiSession {
    MpiSession(int& argc, char**& argv)
    {
        // Every rank on this machine (Open MPI's mpirun says so): Open MPI's ob1 messaging over
        // shared memory unless the user chose a layer. UCX, Open MPI's default where installed,
        // probes network devices for 0.2 s at start-up, which the ranks of one machine never use.
        const char* size = std::getenv("OMPI_COMM_WORLD_SIZE");
        const char* local = std::getenv("OMPI_COMM_WORLD_LOCAL_SIZE");
        if (size && local && std::strcmp(size, local) == 0) ::setenv("OMPI_MCA_pml", "ob1", 0);
        int provided = 0;
        MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided);
        ranks = isouq::nodes::mpiRanks(MPI_COMM_WORLD, [] { return isouq::cli::ProgressInterrupter::interrupted(); });
        MPI_Comm machine;
        MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, 0, MPI_INFO_NULL, &machine);
        MPI_Comm_size(machine, &ranksOnMachine);
        MPI_Comm_free(&machine);
    }
    ~MpiSession()
    {
        ranks.reset();
        MPI_Finalize();
    }
    std::unique_ptr<isouq::nodes::Ranks> ranks;
    int ranksOnMachine = 1; ///< this rank's and the others on its machine (shared memory)
};
#endif

/// `isouq mesh` on a frame sequence (Sequence.h): one progress line over the frames. On MPI
/// ranks (@a ranks) every rank meshes each frame; rank 0 shows progress and prints.
int runSequenceCommand(const isouq::nodes::SequenceRequest& request, bool quiet, const isouq::nodes::Ranks* ranks)
{
    sInterruptedNote = "the frames finished so far are written (--resume keeps them)";
    const bool root = !ranks || ranks->rank() == 0;
    isouq::cli::ProgressInterrupter progress(progressStyle(quiet, ranks));
    const auto start = std::chrono::steady_clock::now();
    std::vector<std::string> warnings;
    const auto onFrame = [&](std::size_t done, std::size_t total, int frame, const nlohmann::json& e) {
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        const double eta = seconds / double(done) * double(total - done);
        char prefix[96];
        std::snprintf(prefix, sizeof(prefix), "frame %zu/%zu, ETA %.0f s | ", done, total, eta);
        progress.setPrefix(prefix);
        std::printf("frame %d: %s %s: %zu vertices, %zu triangles, %zu components\n", frame,
            e.value("resumed", false) ? "kept" : "wrote", shown(e["output"].get<std::string>()).c_str(),
            e["vertices"].get<std::size_t>(), e["triangles"].get<std::size_t>(), e["components"].get<std::size_t>());
        std::fflush(stdout);
    };
    const nlohmann::json s = isouq::nodes::runSequence(request, &progress, onFrame, &warnings, ranks);
    if (!root) return 0;
    printNotes(warnings, quiet);
    const auto& t = s["totals"];
    std::printf("%zu frames (%d empty, %d kept from an earlier run): %zu vertices, %zu triangles (isovalue %s)\n",
        t["frames"].get<std::size_t>(), t["empty"].get<int>(), t["resumed"].get<int>(), t["vertices"].get<std::size_t>(),
        t["triangles"].get<std::size_t>(), s["isovalue"].dump().c_str());
    if (!request.frame.summaryPath.empty()) std::printf("wrote %s: sequence summary (JSON)\n", shown(request.frame.summaryPath).c_str());
    return 0;
}

int runGraphFile(const std::string& path, const std::string& outDir, bool quiet, const isouq::nodes::Ranks* ranks)
{
    isouq::nodes::GraphOptions options;
    options.outputDir = outDir;
    const isouq::nodes::Graph graph = isouq::nodes::loadGraph(path, options);
    if (!outDir.empty()) std::filesystem::create_directories(outDir);
    const isouq::nodes::GraphResult result = runWithProgress(graph, quiet, ranks);
    if (ranks && ranks->rank() != 0) return 0;
    for (const std::string& file : result.written) std::printf("wrote %s\n", shown(file).c_str());
    return 0;
}

int listNodes(bool json, bool markdown)
{
    if (json) std::cout << isouq::nodes::nodeTypesJson().dump(2) << "\n";
    else if (markdown) std::cout << isouq::nodes::nodeTypesMarkdown();
    else
        for (const isouq::nodes::NodeType& t : isouq::nodes::nodeTypes()) {
            std::printf("%-15s %s\n", t.type.c_str(), t.label.c_str());
            for (const isouq::nodes::ParmSpec& p : t.parms)
                std::printf("    %-14s %-7s %s\n", p.token.c_str(), toString(p.type).c_str(), p.tooltip.c_str());
        }
    return 0;
}

constexpr const char* kThreadsHelp = "Worker threads (0: all cores; under MPI, the cores shared among a machine's ranks)";

} // namespace

int isouq_cli_main(int argc, char** argv)
{
    // Past a file size limit (`ulimit -f`) a write fails with EFBIG and is reported and cleaned
    // up as a full disk is, instead of SIGXFSZ ending the process with its temporary file left.
    std::signal(SIGXFSZ, SIG_IGN);
#ifdef ISOUQ_HAVE_MPI
    std::unique_ptr<MpiSession> mpi;
    if (const std::string why = isouq::nodes::srunWithoutPmix(); !why.empty()) {
        if (std::atoi(std::getenv("SLURM_PROCID")) == 0) printError(why); // one line, from the first task
        return kExitBadInput;
    }
    if (isouq::nodes::launchedByMpiLauncher()) {
        mpi = std::make_unique<MpiSession>(argc, argv);
        sPrintsErrors = mpi->ranks->rank() == 0;
    }
    const isouq::nodes::Ranks* ranks = mpi ? mpi->ranks.get() : nullptr;
#else
    const isouq::nodes::Ranks* ranks = nullptr;
#endif
    using isouq::cli::addParmOptions;
    using isouq::cli::nodeType;

    CLI::App app{"isouq: isosurfaces of sparse OpenVDB volumes with per-vertex uncertainty\n"
                 "(linear, cubic and WENO edge crossings, closed-form error estimates).", "isouq"};
    app.set_version_flag("--version", std::string("isouq ") + ISOUQ_VERSION);
    app.require_subcommand(1);
    app.footer("Run 'isouq COMMAND --help' for a command's options and examples.");

    bool quiet = false;
    int threads = 0;
    MeshGraphRequest meshRequest;
    nlohmann::json plyParms = nlohmann::json::object(), summaryParms = plyParms;
    std::string saveGraph;
    CLI::App* mesh = app.add_subcommand("mesh",
        "Extract an isosurface and write it as PLY or VTP (by the extension) with per-vertex attributes");
    addParmOptions(*mesh, nodeType("read_volume"), meshRequest.read);
    mesh->get_option("INPUT")->required()->default_str("");
    addParmOptions(*mesh, nodeType("write_ply"), plyParms);
    mesh->get_option("--output")->required()->default_str("");
    addParmOptions(*mesh, nodeType("mesh"), meshRequest.mesh);
    addParmOptions(*mesh, nodeType("write_summary"), summaryParms);
    mesh->get_option("--summary")->default_str("");
    addParmOptions(*mesh, nodeType("color_map"), meshRequest.color);
    mesh->add_flag("--hidden-features", meshRequest.hiddenFeatures,
        "Also recover hidden features (paper sec. 4.2): the summary's 'hidden' block");
    addParmOptions(*mesh, nodeType("hidden_features"), meshRequest.hidden);
    mesh->add_option("--hidden-out", meshRequest.hiddenOutput, "With --hidden-features: write that mesh too (.ply or .vtp)");
    mesh->add_option("--save-graph", saveGraph,
        "Also write the node graph this command runs (JSON; 'isouq run' reproduces the outputs)");
    mesh->add_option("--threads,-j", threads, kThreadsHelp)->check(CLI::Range(0, isouq::kMaxThreads));
    mesh->add_flag("--quiet,-q", quiet, "No progress bar or notes on stderr");
    isouq::nodes::SequenceRequest sequence;
    auto* frames = mesh->add_option("--frames", sequence.frames,
        "Sequences (INPUT with #### or %04d): frames A-B or A-B:STEP (default: every frame on disk)")
        ->check([](const std::string& v) { return v.empty() ? std::string("expected A, A-B or A-B:STEP, got ''") : ""; });
    auto* resume = mesh->add_flag("--resume", sequence.resume, "Sequences: keep the frames whose outputs exist");
    auto* skipMissing = mesh->add_flag("--skip-missing", sequence.skipMissing,
        "Sequences: mesh the frames that exist instead of refusing a range with missing ones");
    auto* frameJobs = mesh->add_option("--frame-jobs", sequence.frameJobs,
        "Sequences: frames meshed at once, each with every thread; under mpirun, groups of ranks that "
        "each mesh every N-th frame (N at most the ranks)")->check(CLI::Range(1, 64))->capture_default_str();
    mesh->footer(kMeshExamples);

    std::string demoDir = "isouq-demo";
    CLI::App* demo = app.add_subcommand("demo", "Run the built-in example end to end (Teardrop, SPEC §5)");
    demo->add_option("-d,--dir", demoDir, "Folder for the outputs")->capture_default_str();
    demo->add_flag("--quiet,-q", quiet, "No progress bar or notes on stderr");
    demo->footer("\nMeshes the Teardrop field (64^3, k = -0.001) with every method and estimate and\n"
                 "writes DIR/teardrop.ply and DIR/teardrop.summary.json.\n");

    bool asJson = false, asMarkdown = false;
    CLI::App* nodesCmd = app.add_subcommand("nodes", "List the node types and their parameters");
    nodesCmd->add_flag("--json", asJson, "As JSON (read by the Blender add-on)");
    nodesCmd->add_flag("--markdown", asMarkdown, "As the Markdown of docs/node-parameters.md");

    std::string graphPath, outDir;
    CLI::App* run = app.add_subcommand("run", "Run a JSON node graph");
    run->add_option("GRAPH", graphPath, "Graph file (.json)")->required();
    run->add_option("--out-dir,-d", outDir, "Folder for relative output paths (default: the current one)");
    run->add_option("--threads,-j", threads, kThreadsHelp)->check(CLI::Range(0, isouq::kMaxThreads));
    run->add_flag("--quiet,-q", quiet, "No progress bar or notes on stderr");
    run->footer(kRunFooter);

    int validateStatus = 0;
    isouq::cli::addValidateCommand(app, validateStatus);

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::RuntimeError& e) {
        printError(e.what());
        return e.get_exit_code();
    } catch (const CLI::ParseError& e) {
        printError(std::string(e.what()) + " (see 'isouq --help')");
        return kExitBadInput;
    }

    // -j 0 under MPI: the cores this rank may use (its affinity mask) shared with the other ranks
    // on its machine, so that `mpirun -np N` on one machine does not run N times its cores.
#ifdef ISOUQ_HAVE_MPI
    if (threads == 0 && mpi && mpi->ranksOnMachine > 1)
        threads = std::max(1, tbb::this_task_arena::max_concurrency() / mpi->ranksOnMachine);
#endif
    std::unique_ptr<tbb::global_control> threadLimit;
    if (threads > 0)
        threadLimit = std::make_unique<tbb::global_control>(
            tbb::global_control::max_allowed_parallelism, std::size_t(threads));

    try {
        if (*mesh) {
            meshRequest.output = plyParms.at("path");
            plyParms.erase("path");
            meshRequest.write = plyParms;
            meshRequest.summaryPath = summaryParms.value("path", std::string());
            if (isouq::nodes::parseFramePattern(meshRequest.read.value("input", std::string()))) {
                if (!saveGraph.empty()) throw isouq::InputError("--save-graph is for one input, not a sequence");
                sequence.frame = meshRequest;
                return runSequenceCommand(sequence, quiet, ranks);
            }
            for (const CLI::Option* o : {frames, resume, skipMissing, frameJobs})
                if (o->count() > 0)
                    throw isouq::InputError(o->get_name() + " is for sequences: INPUT needs #### or %04d in its name");
            return runMesh(meshRequest, saveGraph, quiet, ranks);
        }
        if (ranks && ranks->size() > 1 && !*run) throw isouq::InputError("only 'isouq mesh' and 'isouq run' run on several MPI ranks");
        if (*demo) {
            std::filesystem::create_directories(demoDir);
            MeshGraphRequest demoRequest;
            demoRequest.read = {{"input", "field:teardrop"}, {"resolution", 64}};
            demoRequest.output = (std::filesystem::path(demoDir) / "teardrop.ply").string();
            demoRequest.summaryPath = (std::filesystem::path(demoDir) / "teardrop.summary.json").string();
            return runMesh(demoRequest, "", quiet);
        }
        if (*nodesCmd) return listNodes(asJson, asMarkdown);
        if (*run) return runGraphFile(graphPath, outDir, quiet, ranks);
        return validateStatus;
    } catch (const isouq::InterruptedError&) {
        // On MPI ranks a rank that got no signal stops with the others, as Ctrl-C.
        if (sPrintsErrors) std::fprintf(stderr, "isouq: interrupted; %s\n", sInterruptedNote);
        return isouq::cli::ProgressInterrupter::interrupted() ? isouq::cli::ProgressInterrupter::exitStatus() : 130;
    } catch (const std::filesystem::filesystem_error& e) {
        printError(e.what());
        return kExitBadInput;
    } catch (const openvdb::Exception& e) {
        printError(e.what());
        return kExitBadInput;
    } catch (const std::exception& e) {
        if (isouq::cli::ProgressInterrupter::interrupted()) {
            std::fprintf(stderr, "isouq: interrupted; %s\n", sInterruptedNote);
            return isouq::cli::ProgressInterrupter::exitStatus();
        }
        printError(e.what());
        return kExitBadInput;
    }
    return 0;
}
