// isouq: the mesh job (SPEC §8): load -> check -> mesh -> measure -> write.
#include "isouq/nodes/MeshJob.h"

#include <isouq/Diagnostics.h>
#include <isouq/MeshIO.h>

#include <tbb/global_control.h>

#include <chrono>
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
