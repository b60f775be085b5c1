// isouq: a named stage of an OpenVDB interrupter, started on construction and ended on
// destruction, also when the stage throws (STYLE "Interrupters"): the CLI's progress names it.
#pragma once

#include <openvdb/util/NullInterrupter.h>

namespace isouq {

class InterrupterStage {
public:
    InterrupterStage(openvdb::util::NullInterrupter* interrupter, const char* name) : mInterrupter(interrupter)
    {
        if (mInterrupter) mInterrupter->start(name);
    }
    ~InterrupterStage()
    {
        if (mInterrupter) mInterrupter->end();
    }
    InterrupterStage(const InterrupterStage&) = delete;
    InterrupterStage& operator=(const InterrupterStage&) = delete;

private:
    openvdb::util::NullInterrupter* mInterrupter;
};

} // namespace isouq
