// isouq: the mesh job (SPEC §8): load -> check -> mesh -> measure -> write.
#include "isouq/nodes/MeshJob.h"

#include <isouq/Diagnostics.h>
#include <isouq/HiddenFeatures.h>
#include <isouq/MeshIO.h>
#include <isouq/MeshTopology.h>
#include <isouq/Validation.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <memory>
#include <sstream>

namespace isouq::nodes {
namespace {

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

nlohmann::json runMeshJob(const MeshJob& job, openvdb::util::NullInterrupter* interrupter, JobNotes* notes)
{
    std::unique_ptr<tbb::global_control> threadLimit;
    if (job.threads > 0)
        threadLimit = std::make_unique<tbb::global_control>(
            tbb::global_control::max_allowed_parallelism, std::size_t(job.threads));

    // Fail on unwritable outputs before any heavy work.
    checkWritable(job.output);
    if (!job.summaryPath.empty()) checkWritable(job.summaryPath);
    if (!job.hiddenOutput.empty()) checkWritable(job.hiddenOutput);
    {
        std::vector<std::filesystem::path> paths;
        for (const std::string& p : {job.output, job.summaryPath, job.hiddenOutput}) {
            if (p.empty()) continue;
            const std::filesystem::path canonical = std::filesystem::weakly_canonical(p);
            if (std::find(paths.begin(), paths.end(), canonical) != paths.end())
                throw InputError("two outputs go to " + p + "; give each output its own path");
            paths.push_back(canonical);
        }
    }

    nlohmann::json timings;
    StageClock clock;
    if (interrupter) interrupter->start("Loading");
    VolumeRequest request = job.volume;
    if (job.hiddenFeatures && request.keep == KeepBlocks::Crossing) request.keep = KeepBlocks::CrossingOrHidden;
    const LoadedVolume volume = loadVolume(request, interrupter);
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

    if (job.truth && job.uncertainty && volume.truth) {
        addTruthColumns(mesh, *volume.truth, settings.isovalue);
        clock.lap(timings, "truth");
    }

    Mesh hiddenMesh;
    HiddenFeatureStats hiddenStats;
    if (job.hiddenFeatures) {
        HiddenFeatureSettings hidden;
        hidden.subdivisions = job.subdivisions;
        hidden.filter = job.hiddenFilter;
        hiddenMesh = addHiddenFeatures(*volume.grid, mesh, settings, hidden, &hiddenStats, interrupter);
        clock.lap(timings, "hidden");
    }

    nlohmann::json summary = summarizeMesh(mesh);
    if (job.hiddenFeatures) {
        const MeshTopologyStats after = measureTopology(hiddenMesh);
        summary["hidden"] = {{"cells_flagged", hiddenStats.cellsFlagged}, {"cells_total", hiddenStats.cellsTotal},
            {"fraction", hiddenStats.fraction()}, {"cells_refined", hiddenStats.cellsRefined},
            {"cells_transition", hiddenStats.cellsTransition}, {"components_before", summary["components"]},
            {"components_after", after.components}, {"boundary_edges", after.boundaryEdges},
            {"subdivisions", job.subdivisions}, {"filter", job.hiddenFilter}};
        if (!job.hiddenOutput.empty()) summary["hidden"]["output"] = job.hiddenOutput;
    }
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
    // All outputs appear together or not at all.
    OutputBatch outputs;
    outputs.addPly(mesh, job.output, ply);
    if (!job.hiddenOutput.empty()) outputs.addPly(hiddenMesh, job.hiddenOutput, ply);
    clock.lap(timings, "write");
    summary["timings_ms"] = timings;
    if (!job.summaryPath.empty()) outputs.addText(job.summaryPath, summary.dump(2) + "\n");
    throwIfInterrupted(interrupter);
    outputs.commit();
    return summary;
}

} // namespace isouq::nodes
