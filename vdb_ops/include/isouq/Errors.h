// isouq: the errors every layer throws and the CLI turns into one line and an exit status
// (SPEC §8: 2 for bad input or output, 130 when interrupted). what() is one line without the
// "isouq: error:" prefix.
#pragma once

#include <cstdio>
#include <stdexcept>
#include <string>

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

/// An error message as one line of bounded length (SPEC §10 "Errors"), as the CLI prints it
/// and the Python module raises it: control characters in the user strings it echoes (names,
/// paths, formulas) are escaped, and it stops after 1000 characters, saying how many it left out.
inline std::string oneLine(const std::string& message)
{
    constexpr std::size_t kMax = 1000;
    std::string out;
    for (std::size_t i = 0; i < message.size(); ++i) {
        if (out.size() >= kMax) return out + "... (" + std::to_string(message.size() - i) + " more characters)";
        const unsigned char c = static_cast<unsigned char>(message[i]);
        if (c == '\n') out += "\\n";
        else if (c == '\r') out += "\\r";
        else if (c == '\t') out += "\\t";
        else if (c < 0x20 || c == 0x7f) {
            char hex[8];
            std::snprintf(hex, sizeof(hex), "\\x%02x", c);
            out += hex;
        } else out += char(c);
    }
    return out;
}

} // namespace isouq
