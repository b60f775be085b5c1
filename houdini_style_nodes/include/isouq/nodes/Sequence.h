// isouq nodes: frame sequences (SPEC §10 "Sequences"; docs/sequences.md). A path with a run of
// `#` (Houdini's $F4, Blender's ####) or a printf `%04d` names one file per frame. Each frame is
// the mesh graph (MeshGraph.h) with the frame's paths, run by the one runner; the loop adds
// one isovalue for all frames, the frame range, resume, and the sequence summary.
#pragma once

#include "isouq/nodes/MeshGraph.h"

#include <openvdb/util/NullInterrupter.h>

#include <nlohmann/json.hpp>

#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace isouq::nodes {

class Ranks;

/// A path with a frame-number placeholder in its file name.
struct FramePattern {
    std::string prefix, suffix; ///< the path around the placeholder
    int width = 1;              ///< zero padding: the number of '#', or N of %0Nd

    /// The path of @a frame: prefix, the number padded to width, suffix.
    std::string path(int frame) const;
};

/// The pattern of @a path, or nullopt if it has no placeholder. The last run of '#' or the
/// last %d / %0Nd in the file name counts. @throw InputError for a placeholder in a folder name.
std::optional<FramePattern> parseFramePattern(const std::string& path);

/// Frames from A to B (inclusive) every STEP frames: "A-B", "A-B:STEP" or "A".
/// @throw InputError naming what is wrong.
std::vector<int> parseFrameRange(const std::string& text);

struct SequenceRequest {
    MeshGraphRequest frame;   ///< paths with placeholders: read "input", output, hiddenOutput
    std::string frames;       ///< --frames ("" for every frame on disk, first to last)
    bool resume = false;      ///< skip frames whose outputs exist (outputs appear atomically)
    bool skipMissing = false; ///< go on without missing frames instead of refusing the run
    int frameJobs = 1;        ///< frames meshed at once (each with every thread; on ranks, a group of ranks)
};

/// What the loop reports after each frame: its index in the run, the run's length, the frame.
using FrameCallback = std::function<void(std::size_t done, std::size_t total, int frame, const nlohmann::json& entry)>;

/// Meshes every frame; returns the sequence summary (`frames`, `totals`, `isovalue`, ...).
/// Frames are committed one by one: an interruption leaves the finished ones. On @a ranks
/// (docs/mpi.md "Sequences") every rank meshes each frame in turn, as `isouq mesh` does one
/// input, or with frameJobs > 1 (at most one a rank) each group of ranks every frameJobs-th
/// frame; rank 0 checks the run, lists the frames, calls @a onFrame in frame order, gets the
/// warnings and the summary (the other ranks an empty object).
/// @throw InputError (missing frames listed, bad patterns), IoError, InterruptedError.
nlohmann::json runSequence(const SequenceRequest& request, openvdb::util::NullInterrupter* interrupter,
    const FrameCallback& onFrame = {}, std::vector<std::string>* warnings = nullptr, const Ranks* ranks = nullptr);

} // namespace isouq::nodes
