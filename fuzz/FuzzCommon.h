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
#include <string_view>
#include <system_error>
#include <vector>

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

/// What separates the files of a folder (a DICOM series, TIFF slices, a NRRD header and its
/// data file) inside one fuzz input; the targets' dictionaries hold it.
inline constexpr std::string_view kNextFile = "ISOUQ-NEXT-FILE";

/// @a data split at every kNextFile, at most @a maxParts parts (the last keeps the rest).
inline std::vector<std::string_view> splitFiles(const std::uint8_t* data, std::size_t size, std::size_t maxParts)
{
    std::vector<std::string_view> parts;
    std::string_view rest(reinterpret_cast<const char*>(data), size);
    for (std::size_t at; parts.size() + 1 < maxParts && (at = rest.find(kNextFile)) != std::string_view::npos;) {
        parts.push_back(rest.substr(0, at));
        rest.remove_prefix(at + kNextFile.size());
    }
    parts.push_back(rest);
    return parts;
}

/// Writes @a parts as files @a stem0@a ext, @a stem1@a ext, ... in a fresh folder tempDir()/@a
/// folder and returns the folder.
inline std::string writeFolder(const std::string& folder, const std::vector<std::string_view>& parts,
    const std::string& stem, const std::string& ext)
{
    const std::filesystem::path dir = tempDir() / folder;
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    std::filesystem::create_directory(dir);
    for (std::size_t i = 0; i < parts.size(); ++i) {
        writeTemp(folder + "/" + stem + std::to_string(i) + ext, reinterpret_cast<const std::uint8_t*>(parts[i].data()),
            parts[i].size());
    }
    return dir.string();
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

// libFuzzer calls this once. ASan's -rss_limit_mb=2048 also caps one malloc at 2 GiB, so the
// memory checks of the readers and the mesher must see a budget below that
// (ISOUQ_MEMORY_LIMIT_MB, docs/hardening.md); a caller's own value is kept.
extern "C" int LLVMFuzzerInitialize(int*, char***)
{
    ::setenv("ISOUQ_MEMORY_LIMIT_MB", "1024", /*overwrite=*/0);
    return 0;
}
