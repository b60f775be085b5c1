// isouq fuzzing: what every libFuzzer target shares (docs/hardening.md). Each reader takes a
// path, so an input is written to a file in a per-process temporary folder and read back.
// Errors the contract expects (one line, exit 2) are caught; anything else (another exception,
// a crash, a leak, undefined behaviour, a timeout, running out of memory) is a finding.
#pragma once

#include <isouq/Errors.h>

#include <openvdb/Exceptions.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>

namespace isouq::fuzz {

/// The per-process temporary folder ($TMPDIR or /tmp), removed at exit.
inline const std::filesystem::path& tempDir()
{
    static const std::filesystem::path dir = [] {
        const char* base = std::getenv("TMPDIR");
        std::string pattern = std::string(base && *base ? base : "/tmp") + "/isouq-fuzz-XXXXXX";
        if (!::mkdtemp(pattern.data())) std::abort();
        std::atexit([] {
            std::error_code ec;
            std::filesystem::remove_all(tempDir(), ec);
        });
        return std::filesystem::path(pattern);
    }();
    return dir;
}

/// Writes @a size bytes to tempDir()/name and returns the path.
inline std::string writeTemp(const std::string& name, const std::uint8_t* data, std::size_t size)
{
    const std::string path = (tempDir() / name).string();
    std::FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) std::abort();
    if (size && std::fwrite(data, 1, size, f) != size) std::abort();
    std::fclose(f);
    return path;
}

/// Runs @a body; the errors the contract allows end the run quietly, anything else escapes.
template <typename Body>
void expectingErrors(Body&& body)
{
    try {
        body();
    } catch (const isouq::InputError&) { // GraphError too
    } catch (const isouq::IoError&) {
    } catch (const openvdb::Exception&) {
    }
}

} // namespace isouq::fuzz
