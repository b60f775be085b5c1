// isouq: interruption and progress conventions shared by the operators (STYLE "Interrupters").
#pragma once

#include "isouq/Errors.h"

#include <openvdb/util/NullInterrupter.h>

namespace isouq {

/// Throws InterruptedError when @a interrupter says so (call between phases, not in hot loops).
inline void throwIfInterrupted(openvdb::util::NullInterrupter* interrupter, int percent = -1)
{
    if (openvdb::util::wasInterrupted(interrupter, percent)) throw InterruptedError();
}

} // namespace isouq
