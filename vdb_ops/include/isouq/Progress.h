// isouq: interruption and progress conventions shared by the operators (STYLE "Interrupters").
#pragma once

#include <openvdb/util/NullInterrupter.h>

#include <stdexcept>

namespace isouq {

/// Thrown by an operator whose interrupter asked it to stop; no partial result is returned.
struct InterruptedError : std::runtime_error {
    InterruptedError() : std::runtime_error("interrupted") {}
};

/// Throws InterruptedError when @a interrupter says so (call between phases, not in hot loops).
inline void throwIfInterrupted(openvdb::util::NullInterrupter* interrupter, int percent = -1)
{
    if (openvdb::util::wasInterrupted(interrupter, percent)) throw InterruptedError();
}

} // namespace isouq
