// isouq: the `isouq mesh` pipeline as one call — load, check, mesh, measure, write (SPEC §8).
// The command line and the node graph both run it; it never prints, it reports through the
// interrupter (stages and percentages) and returns the summary.
#pragma once

#include <isouq/MarchingCubes.h>
#include <isouq/VolumeSources.h>
#include <isouq/nodes/Summary.h>

#include <nlohmann/json.hpp>

#include <string>

namespace isouq::nodes {

struct MeshJob {
    VolumeRequest volume;      ///< INPUT and its options (--grid, --dims, --resolution, ...)
    std::string output;        ///< -o OUT.ply
    std::string summaryPath;   ///< --summary S.json ("" for none)
    EdgeMethod method = EdgeMethod::Weno; ///< --method: the primary method (positions)
    bool uncertainty = true;   ///< all methods and estimates; false = linear positions only
    int threads = 0;           ///< --threads (0: all cores)
    bool hiddenFeatures = false; ///< --hidden-features: the summary's `hidden` block (SPEC §4, §8)
    int subdivisions = 4;        ///< --subdivisions M
    bool hiddenFilter = true;    ///< --hidden-filter / --no-hidden-filter (HiddenFeatureSettings::filter)
    std::string hiddenOutput;    ///< --hidden-out HF.ply ("" for none)
    /// field: and formula: inputs: err_true_<method> and dist_true against the exact field (SPEC §3).
    bool truth = true;
};

/// Notes the job makes for the user (defaults it chose), one line each.
using JobNotes = std::vector<std::string>;

/// Runs @a job. Outputs are written atomically and only after everything succeeded: a failed
/// or interrupted run leaves no file behind and existing outputs untouched.
/// @throw InputError, IoError (bad input or output), InterruptedError (Ctrl-C).
nlohmann::json runMeshJob(const MeshJob& job, openvdb::util::NullInterrupter* interrupter,
    JobNotes* notes = nullptr);

} // namespace isouq::nodes
