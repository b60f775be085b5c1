// isouq CLI: an OpenVDB interrupter that shows progress with stage names (a bar on a terminal,
// lines in an MPI job's log) and turns Ctrl-C, SIGTERM and SIGHUP into a cancellation
// (HoudiniInterrupter-style; STYLE "Interrupters"; SPEC §10 "Errors"): the run stops, writes
// nothing and exits 128 + signal.
#pragma once

#include <openvdb/util/NullInterrupter.h>

#include <chrono>
#include <string>

namespace isouq::cli {

/// How progress shows on stderr: not at all (--quiet, a pipe, the ranks but 0), as a bar redrawn
/// in place (a terminal), or as lines (rank 0 of an MPI job, whose stderr the launcher pipes into
/// a terminal or a batch log alike): "isouq: Meshing 40% (12.3 s)" at each tenth of a stage once
/// it has run ISOUQ_PROGRESS_SECONDS (10 unless set), then "isouq: Meshing done (31.0 s)".
enum class ProgressStyle { None, Bar, Lines };

class ProgressInterrupter final : public openvdb::util::NullInterrupter {
public:
    /// Installs the SIGINT, SIGTERM and SIGHUP handlers; a second signal removes the temporary
    /// files and ends the process. Throws InputError if ISOUQ_PROGRESS_SECONDS is set but is not
    /// a number of seconds (0 or more).
    explicit ProgressInterrupter(ProgressStyle style);
    ~ProgressInterrupter() override;

    void start(const char* name = nullptr) override;
    void end() override;
    bool wasInterrupted(int percent = -1) override;

    /// Text drawn before the stage, e.g. "frame 3/24, ETA 12 s | " (sequences).
    void setPrefix(std::string prefix);

    /// True once a signal arrived (also outside any stage).
    static bool interrupted();
    /// The exit status for it: 128 + the signal (130 for Ctrl-C).
    static int exitStatus();

private:
    void draw(int percent);
    void drawLine(int percent);
    void clearLine();

    ProgressStyle mStyle;
    double mLineDelay = 10; ///< seconds of a stage before its first line (ProgressStyle::Lines)
    std::string mStage, mPrefix;
    int mLastPercent = -2;
    int mLastTenth = 0; ///< the tenth of the stage that the last line reported; 0: none yet
    std::chrono::steady_clock::time_point mStageStart, mLastDraw;
};

} // namespace isouq::cli
