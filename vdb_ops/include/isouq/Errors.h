// isouq: the errors every layer throws and the CLI turns into one line and an exit status
// (SPEC §8: 2 for bad input or output, 130 when interrupted). what() is one line without the
// "isouq: error:" prefix.
#pragma once

#include <stdexcept>

namespace isouq {

/// Bad input (missing or malformed file, unknown field, bad formula, bad parameter, ...).
struct InputError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// A file could not be written or read, e.g. "cannot write /nonexistent/x.ply: No such file
/// or directory".
class IoError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Thrown by an operator whose interrupter asked it to stop; no partial result is returned.
struct InterruptedError : std::runtime_error {
    InterruptedError() : std::runtime_error("interrupted") {}
};

} // namespace isouq
