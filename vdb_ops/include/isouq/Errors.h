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
/// paths, formulas) are escaped, and so is every byte that is not part of valid UTF-8 (a file
/// name's Latin-1, say), so the line is valid UTF-8 for a terminal and for Python's str; it stops
/// after @a maxChars characters, never inside a character, saying how many it left out (the CLI's
/// "wrote PATH" lines on stdout escape a path whole: std::string::npos).
inline std::string oneLine(const std::string& message, std::size_t maxChars = 1000)
{
    const auto escaped = [](unsigned char c) {
        char hex[8];
        std::snprintf(hex, sizeof(hex), "\\x%02x", c);
        return std::string(hex);
    };
    // The length of the valid UTF-8 sequence at @a i (RFC 3629: no overlong form, no surrogate,
    // at most U+10FFFF), 0 if there is none; C1 controls (U+0080-U+009F) count as invalid.
    const auto sequence = [&](std::size_t i) -> std::size_t {
        const auto at = [&](std::size_t k) { return static_cast<unsigned char>(message[k]); };
        const unsigned char c = at(i);
        const std::size_t n = c >= 0xc2 && c <= 0xdf ? 2 : c >= 0xe0 && c <= 0xef ? 3 : c >= 0xf0 && c <= 0xf4 ? 4 : 0;
        if (n == 0 || i + n > message.size()) return 0;
        for (std::size_t k = 1; k < n; ++k)
            if ((at(i + k) & 0xc0) != 0x80) return 0;
        const unsigned char d = at(i + 1);
        if ((c == 0xc2 && d < 0xa0) || (c == 0xe0 && d < 0xa0) || (c == 0xed && d > 0x9f) || (c == 0xf0 && d < 0x90) ||
            (c == 0xf4 && d > 0x8f))
            return 0;
        return n;
    };
    std::string out;
    for (std::size_t i = 0; i < message.size(); ++i) {
        if (out.size() >= maxChars) return out + "... (" + std::to_string(message.size() - i) + " more characters)";
        const unsigned char c = static_cast<unsigned char>(message[i]);
        if (c == '\n') out += "\\n";
        else if (c == '\r') out += "\\r";
        else if (c == '\t') out += "\\t";
        else if (c < 0x20 || c == 0x7f) out += escaped(c);
        else if (c < 0x80) out += char(c);
        else if (const std::size_t n = sequence(i); n > 0) {
            out.append(message, i, n);
            i += n - 1;
        } else out += escaped(c);
    }
    return out;
}

} // namespace isouq
