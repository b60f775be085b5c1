// isouq CLI: an OpenVDB interrupter that draws a progress bar with stage names on a terminal
// and turns Ctrl-C, SIGTERM and SIGHUP into a cancellation (HoudiniInterrupter-style; STYLE
// "Interrupters"; SPEC §10 "Errors"): the run stops, writes nothing and exits 128 + signal.
#pragma once

#include <openvdb/util/NullInterrupter.h>

#include <chrono>
#include <string>

namespace isouq::cli {

class ProgressInterrupter final : public openvdb::util::NullInterrupter {
public:
    /// @a show: draw the bar (a terminal and not --quiet). Installs the SIGINT, SIGTERM and
    /// SIGHUP handlers; a second signal removes the temporary files and ends the process.
    explicit ProgressInterrupter(bool show);
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
    void clearLine();

    bool mShow;
    std::string mStage, mPrefix;
    int mLastPercent = -2;
    std::chrono::steady_clock::time_point mStageStart, mLastDraw;
};

} // namespace isouq::cli
