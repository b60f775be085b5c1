#include "ProgressInterrupter.h"

#include <isouq/Errors.h>
#include <isouq/MeshIO.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>

namespace isouq::cli {
namespace {

std::atomic<bool> sInterrupted{false};
std::atomic<int> sSignal{SIGINT};
std::mutex sDrawMutex;
constexpr int kSignals[] = {SIGINT, SIGTERM, SIGHUP};

extern "C" void onSignal(int signal)
{
    // The first signal cancels (the run unwinds and removes its temporaries); a second one while
    // the first is being honoured ends the process at once, without leaving a temporary.
    if (sInterrupted.exchange(true)) {
        removeTemporaryFiles();
        std::_Exit(128 + sSignal.load());
    }
    sSignal.store(signal);
}

} // namespace

ProgressInterrupter::ProgressInterrupter(ProgressStyle style) : mStyle(style)
{
    if (const char* delay = std::getenv("ISOUQ_PROGRESS_SECONDS"); delay && *delay) {
        char* end = nullptr;
        const double seconds = std::strtod(delay, &end);
        if (end == delay || *end != '\0' || !(seconds >= 0 && seconds < 1e9))
            throw InputError("ISOUQ_PROGRESS_SECONDS is '" + std::string(delay) +
                             "'; give the seconds a stage runs before its progress lines, such as 10 or 0.5");
        mLineDelay = seconds;
    }
    for (int signal : kSignals) std::signal(signal, onSignal);
}

// The handlers stay installed: a second signal while the run unwinds must still clean up and
// exit 128 + n rather than take the default action.
ProgressInterrupter::~ProgressInterrupter() { clearLine(); }

bool ProgressInterrupter::interrupted() { return sInterrupted.load(); }

void ProgressInterrupter::setPrefix(std::string prefix)
{
    std::lock_guard<std::mutex> lock(sDrawMutex);
    mPrefix = std::move(prefix);
}

int ProgressInterrupter::exitStatus() { return 128 + sSignal.load(); }

void ProgressInterrupter::start(const char* name)
{
    std::lock_guard<std::mutex> lock(sDrawMutex);
    mStage = name ? name : "";
    mStageStart = std::chrono::steady_clock::now();
    mLastPercent = -2;
    mLastTenth = 0;
    draw(0);
}

void ProgressInterrupter::end()
{
    std::lock_guard<std::mutex> lock(sDrawMutex);
    if (mStyle == ProgressStyle::Lines && mLastTenth > 0) {
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - mStageStart).count();
        std::fprintf(stderr, "isouq: %s%s done (%.1f s)\n", mPrefix.c_str(), mStage.c_str(), seconds);
        std::fflush(stderr);
        return;
    }
    draw(100);
    clearLine();
}

bool ProgressInterrupter::wasInterrupted(int percent)
{
    if (percent >= 0 && mStyle != ProgressStyle::None) {
        // Called from worker threads: draw at most every 100 ms, never block a worker.
        std::unique_lock<std::mutex> lock(sDrawMutex, std::try_to_lock);
        if (lock.owns_lock()) draw(percent);
    }
    return sInterrupted.load(std::memory_order_relaxed);
}

void ProgressInterrupter::draw(int percent)
{
    if (mStyle == ProgressStyle::Lines) return drawLine(percent);
    if (mStyle != ProgressStyle::Bar || percent == mLastPercent) return;
    const auto now = std::chrono::steady_clock::now();
    if (percent != 0 && percent != 100 && now - mLastDraw < std::chrono::milliseconds(100)) return;
    mLastDraw = now;
    mLastPercent = percent;
    constexpr int kWidth = 30;
    const int filled = kWidth * std::max(0, std::min(percent, 100)) / 100;
    const double seconds = std::chrono::duration<double>(now - mStageStart).count();
    std::fprintf(stderr, "\r%s%-10s [%.*s%*s] %3d%% %6.1fs", mPrefix.c_str(), mStage.c_str(), filled,
        "##############################", kWidth - filled, "", percent, seconds);
    std::fflush(stderr);
}

// A line at each tenth the stage reaches once it has run mLineDelay seconds: at most ten a stage,
// none for a short run.
void ProgressInterrupter::drawLine(int percent)
{
    const int tenth = std::max(0, std::min(percent, 100)) / 10;
    if (mStage.empty() || tenth <= mLastTenth || tenth == 10) return;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - mStageStart).count();
    if (seconds < mLineDelay) return;
    mLastTenth = tenth;
    std::fprintf(stderr, "isouq: %s%s %d%% (%.1f s)\n", mPrefix.c_str(), mStage.c_str(), 10 * tenth, seconds);
    std::fflush(stderr);
}

void ProgressInterrupter::clearLine()
{
    if (mStyle != ProgressStyle::Bar) return;
    std::fprintf(stderr, "\r%*s\r", 60 + int(mPrefix.size()), "");
    std::fflush(stderr);
}

} // namespace isouq::cli
