// isouq: the mesh job (SPEC §8): load -> check -> mesh -> measure -> write.
#include "isouq/nodes/MeshJob.h"

#include <isouq/Diagnostics.h>
#include <isouq/MeshIO.h>
#include <isouq/MeshTopology.h>

#include <tbb/global_control.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>

namespace isouq::nodes {
namespace {

/// Per-vertex measures whose statistics the summary reports (SPEC §6, §8).
const char* const kSummaryMeasures[] = {"err_est", "err_bound", "err_best", "d_lc", "d_lw", "d_cw",
    "max_var", "err_true_linear", "err_true_cubic", "err_true_weno", "err_true_weno-paper",
    "dist_true"};

nlohmann::json statistics(const std::vector<float>& values)
{
    double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0, sumSq = 0;
    std::size_t n = 0;
    for (float v : values) {
        if (!std::isfinite(v)) continue;
        lo = std::min(lo, double(v));
        hi = std::max(hi, double(v));
        sum += v;
        sumSq += double(v) * v;
        ++n;
    }
    if (n == 0) return {{"min", nullptr}, {"max", nullptr}, {"mean", nullptr}, {"rms", nullptr}, {"count", 0}};
    return {{"min", lo}, {"max", hi}, {"mean", sum / double(n)}, {"rms", std::sqrt(sumSq / double(n))},
        {"count", n}};
}

class StageClock {
public:
    void lap(nlohmann::json& timings, const char* stage)
    {
        const auto now = std::chrono::steady_clock::now();
        timings[stage] = std::chrono::duration<double, std::milli>(now - mLast).count();
        mLast = now;
    }

private:
    std::chrono::steady_clock::time_point mLast = std::chrono::steady_clock::now();
};

} // namespace

nlohmann::json summarizeMesh(const Mesh& mesh)
{
    const MeshTopologyStats topo = measureTopology(mesh);
    nlohmann::json s;
    s["vertices"] = mesh.positions.size();
    s["triangles"] = mesh.triangles.size();
    s["boundary_edges"] = topo.boundaryEdges;
    s["non_manifold_edges"] = topo.nonManifoldEdges;
    s["components"] = topo.components;
    s["degenerate_triangles"] = topo.degenerateTriangles;
    s["area"] = topo.area;
    s["enclosed_volume"] = topo.enclosedVolume;
    for (const char* name : kSummaryMeasures)
        if (const auto* column = mesh.vertexAttributes.find<float>(name)) s[name] = statistics(*column);
    return s;
}

nlohmann::json runMeshJob(const MeshJob& job, openvdb::util::NullInterrupter* interrupter, JobNotes* notes)
{
    std::unique_ptr<tbb::global_control> threadLimit;
    if (job.threads > 0)
        threadLimit = std::make_unique<tbb::global_control>(
            tbb::global_control::max_allowed_parallelism, std::size_t(job.threads));

    // Fail on unwritable outputs before any heavy work.
    checkWritable(job.output);
    if (!job.summaryPath.empty()) checkWritable(job.summaryPath);

    nlohmann::json timings;
    StageClock clock;
    if (interrupter) interrupter->start("Loading");
    const LoadedVolume volume = loadVolume(job.volume, interrupter);
    if (interrupter) interrupter->end();
    clock.lap(timings, "load");
    if (notes && volume.isovalueSource != "given")
    {
        std::ostringstream line;
        line << "isovalue " << volume.isovalue << " (" << volume.isovalueSource << "; set it with --isovalue)";
        notes->push_back(line.str());
    }

    const std::string problem = checkScalarVolume(*volume.grid, volume.isovalue);
    if (!problem.empty()) throw InputError(problem);
    clock.lap(timings, "check");

    MeshSettings settings;
    settings.isovalue = volume.isovalue;
    settings.uncertainty = job.uncertainty;
    settings.provenance = true;
    settings.method = job.method;
    Mesh mesh = extractIsosurface(*volume.grid, settings, interrupter);
    clock.lap(timings, "mesh");

    nlohmann::json summary = summarizeMesh(mesh);
    clock.lap(timings, "measure");
    summary["input"] = job.volume.input;
    summary["description"] = volume.description;
    summary["isovalue"] = volume.isovalue;
    summary["isovalue_source"] = volume.isovalueSource;
    summary["method"] = job.uncertainty ? toString(job.method) : "linear";
    summary["output"] = job.output;
    if (volume.denseBlocks > 0)
        summary["sparse_blocks"] = {{"dense", volume.denseBlocks}, {"kept", volume.keptBlocks}};
    throwIfInterrupted(interrupter);

    PlyOptions ply;
    ply.version = ISOUQ_VERSION_STRING;
    ply.isovalue = volume.isovalue;
    ply.method = summary["method"].get<std::string>();
    writePly(mesh, job.output, ply);
    clock.lap(timings, "write");
    summary["timings_ms"] = timings;
    if (!job.summaryPath.empty()) writeTextFileAtomic(job.summaryPath, summary.dump(2) + "\n");
    return summary;
}

} // namespace isouq::nodes
