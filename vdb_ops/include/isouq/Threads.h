// isouq: how many threads a parallel loop started here will get (the CLI's -j, the summary's
// ranks block).
#pragma once

#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstddef>

namespace isouq {

/// The most worker threads a caller may ask for (the CLI's -j, the Python module's threads):
/// more would only cost each arena's memory (TBB crashed setting up 10^7).
constexpr int kMaxThreads = 4096;

/// The threads of the current arena, as limited by a tbb::global_control (the CLI's -j), which
/// this_task_arena::max_concurrency() alone does not see.
inline int threadsInUse()
{
    return int(std::min<std::size_t>(tbb::this_task_arena::max_concurrency(),
        tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
}

} // namespace isouq
