// isouq CLI: an OpenVDB interrupter that draws a progress bar with stage names on a terminal
// and turns Ctrl-C into a cancellation (HoudiniInterrupter-style; STYLE "Interrupters").
#pragma once

#include <openvdb/util/NullInterrupter.h>

#include <chrono>
#include <string>

namespace isouq::cli {

class ProgressInterrupter final : public openvdb::util::NullInterrupter {
public:
    /// @a show: draw the bar (a terminal and not --quiet). Installs the SIGINT handler.
    explicit ProgressInterrupter(bool show);
    ~ProgressInterrupter() override;

    void start(const char* name = nullptr) override;
    void end() override;
    bool wasInterrupted(int percent = -1) override;

    /// True once Ctrl-C was pressed (also outside any stage).
    static bool interrupted();

private:
    void draw(int percent);
    void clearLine();

    bool mShow;
    std::string mStage;
    int mLastPercent = -2;
    std::chrono::steady_clock::time_point mStageStart, mLastDraw;
};

} // namespace isouq::cli
