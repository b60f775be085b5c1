// isouq: the command line (SPEC §8). A thin face over isouq::nodes: parse, run, report.
// Exit status: 0 success, 2 bad input or usage (one line "isouq: error: ..."), 130 interrupted.
#include "ProgressInterrupter.h"
#include "ValidateCommand.h"

#include <isouq/MeshIO.h>
#include <isouq/nodes/MeshJob.h>

#include <CLI/CLI.hpp>
#include <openvdb/Exceptions.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <unistd.h>

namespace {

using isouq::nodes::MeshJob;

constexpr int kExitBadInput = 2;
constexpr int kExitInterrupted = 130;

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

Every vertex carries the edge it lies on (edge_i edge_j edge_k edge_axis) and where each method
puts it (t_linear ...); see docs/ply-format.md. Outputs are written atomically: a failed or
interrupted run (Ctrl-C, exit 130) leaves no partial file and never clobbers an existing one.
)";

bool stderrIsTerminal() { return ::isatty(STDERR_FILENO) == 1; }

void printNotes(const isouq::nodes::JobNotes& notes, bool quiet)
{
    if (quiet) return;
    for (const std::string& note : notes) std::fprintf(stderr, "isouq: %s\n", note.c_str());
}

void printResult(const nlohmann::json& s, const std::string& summaryPath)
{
    std::printf("wrote %s: %zu vertices, %zu triangles, %zu components, %zu boundary edges, "
                "%zu non-manifold edges (isovalue %g, %s)\n",
        s["output"].get<std::string>().c_str(), s["vertices"].get<std::size_t>(),
        s["triangles"].get<std::size_t>(), s["components"].get<std::size_t>(),
        s["boundary_edges"].get<std::size_t>(), s["non_manifold_edges"].get<std::size_t>(),
        s["isovalue"].get<double>(), s["method"].get<std::string>().c_str());
    if (!summaryPath.empty()) std::printf("wrote %s: summary (JSON)\n", summaryPath.c_str());
}

/// Options shared by `mesh` and anything else that reads a volume.
void addVolumeOptions(CLI::App& cmd, MeshJob& job, std::vector<int>& dims, std::vector<double>& spacing,
    std::vector<double>& domain, float& isovalue)
{
    cmd.add_option("INPUT", job.volume.input,
           "Volume: FILE.vdb, NAME_XxYxZ_DTYPE.raw, field:NAME or formula:EXPR")
        ->required();
    cmd.add_option("--isovalue,-k", isovalue,
        "Isovalue k (default: 0 for level sets, SPEC §5's value for fields, else Otsu's "
        "threshold as a starting value; the value used is printed)");
    cmd.add_option("--grid", job.volume.gridName, ".vdb: the float grid to mesh (default: the first)");
    cmd.add_option("--dims", dims, ".raw: X,Y,Z (default: from the file name)")->delimiter(',')->expected(3);
    cmd.add_option("--dtype", job.volume.dtype, ".raw: uint8|uint16|int16|float32|float64 (default: from the name)")
        ->check(CLI::IsMember({"uint8", "uint16", "int16", "float32", "float64"}));
    cmd.add_option("--spacing", spacing, ".raw: voxel spacing X,Y,Z (default 1,1,1)")->delimiter(',')->expected(3);
    cmd.add_option("--resolution,-n", job.volume.resolution,
           "field:/formula:: samples per axis, both domain ends included (default: the paper's; 64)")
        ->check(CLI::Range(2, 4096));
    cmd.add_option("--domain", domain, "formula:: the cube [LO,HI]^3 (default -1,1)")->delimiter(',')->expected(2);
}

void finishVolumeOptions(MeshJob& job, const std::vector<int>& dims, const std::vector<double>& spacing,
    const std::vector<double>& domain, const CLI::App& cmd, float isovalue)
{
    if (!dims.empty()) job.volume.dims = openvdb::Vec3i(dims[0], dims[1], dims[2]);
    if (!spacing.empty()) job.volume.spacing = openvdb::Vec3d(spacing[0], spacing[1], spacing[2]);
    if (!domain.empty()) job.volume.domain = std::make_pair(domain[0], domain[1]);
    if (cmd.count("--isovalue")) job.volume.isovalue = isovalue;
}

int runJob(const MeshJob& job, bool quiet)
{
    isouq::cli::ProgressInterrupter progress(!quiet && stderrIsTerminal());
    isouq::nodes::JobNotes notes;
    const nlohmann::json summary = isouq::nodes::runMeshJob(job, &progress, &notes);
    printNotes(notes, quiet);
    printResult(summary, job.summaryPath);
    return 0;
}

} // namespace

int main(int argc, char** argv)
{
    CLI::App app{"isouq: isosurfaces of sparse OpenVDB volumes with per-vertex uncertainty\n"
                 "(linear, cubic and WENO edge crossings, closed-form error estimates).", "isouq"};
    app.set_version_flag("--version", std::string("isouq ") + ISOUQ_VERSION);
    app.require_subcommand(1);
    app.footer("Run 'isouq COMMAND --help' for a command's options and examples.");

    MeshJob job;
    std::vector<int> dims;
    std::vector<double> spacing, domain;
    float isovalue = 0.0f;
    std::string method = "weno";
    bool linearOnly = false, quiet = false;

    CLI::App* mesh = app.add_subcommand("mesh", "Extract an isosurface and write it as PLY with per-vertex attributes");
    addVolumeOptions(*mesh, job, dims, spacing, domain, isovalue);
    mesh->add_option("-o,--output", job.output, "Output mesh (.ply, binary little-endian)")->required();
    mesh->add_option("--method,-m", method, "Method that places the vertices (all are recorded)")
        ->check(CLI::IsMember({"linear", "cubic", "weno", "weno-paper"}))
        ->capture_default_str();
    mesh->add_flag("--linear-only", linearOnly, "Linear crossings only, no estimates: fastest");
    mesh->add_option("--summary", job.summaryPath, "Also write the summary as JSON (SPEC §8)");
    mesh->add_option("--threads,-j", job.threads, "Worker threads (0: all cores)")->check(CLI::Range(0, 4096));
    mesh->add_flag("--quiet,-q", quiet, "No progress bar or notes on stderr");
    mesh->footer(kMeshExamples);

    std::string demoDir = "isouq-demo";
    CLI::App* demo = app.add_subcommand("demo", "Run the built-in example end to end (Teardrop, SPEC §5)");
    demo->add_option("-d,--dir", demoDir, "Folder for the outputs")->capture_default_str();
    demo->add_flag("--quiet,-q", quiet, "No progress bar or notes on stderr");
    demo->footer("\nMeshes the Teardrop field (64^3, k = -0.001) with every method and estimate and\n"
                 "writes DIR/teardrop.ply and DIR/teardrop.summary.json.\n");

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
        std::fprintf(stderr, "isouq: error: %s\n", e.what());
        return e.get_exit_code();
    } catch (const CLI::ParseError& e) {
        std::fprintf(stderr, "isouq: error: %s (see 'isouq --help')\n", e.what());
        return kExitBadInput;
    }

    try {
        if (*mesh) {
            finishVolumeOptions(job, dims, spacing, domain, *mesh, isovalue);
            job.method = *isouq::edgeMethodFromString(method);
            job.uncertainty = !linearOnly;
            return runJob(job, quiet);
        }
        if (*demo) {
            std::filesystem::create_directories(demoDir);
            job.volume.input = "field:teardrop";
            job.volume.resolution = 64;
            job.output = (std::filesystem::path(demoDir) / "teardrop.ply").string();
            job.summaryPath = (std::filesystem::path(demoDir) / "teardrop.summary.json").string();
            return runJob(job, quiet);
        }
        return validateStatus;
    } catch (const isouq::InterruptedError&) {
        std::fprintf(stderr, "\nisouq: interrupted; no output written\n");
        return kExitInterrupted;
    } catch (const std::filesystem::filesystem_error& e) {
        std::fprintf(stderr, "isouq: error: %s\n", e.what());
        return kExitBadInput;
    } catch (const openvdb::Exception& e) {
        std::fprintf(stderr, "isouq: error: %s\n", e.what());
        return kExitBadInput;
    } catch (const std::exception& e) {
        if (isouq::cli::ProgressInterrupter::interrupted()) {
            std::fprintf(stderr, "\nisouq: interrupted; no output written\n");
            return kExitInterrupted;
        }
        std::fprintf(stderr, "isouq: error: %s\n", e.what());
        return kExitBadInput;
    }
    return 0;
}
