// Helpers of the command-line contract tests (test_CliContract.cc, test_CliHostile.cc): run the
// real binary in a temporary folder and read what it left there.
#pragma once

#include "../TempDir.h"

#include <catch2/catch.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace isouq_test {

namespace fs = std::filesystem;


struct CliResult {
    int status = -1;
    std::vector<std::string> stderrLines;
};

inline std::string quote(const std::string& s) { return "'" + s + "'"; }

/// Runs `PROGRAM ARGS` (by default the isouq binary) in @a dir through the shell.
inline CliResult runCli(const std::string& args, const fs::path& dir, const std::string& program = ISOUQ_CLI)
{
    const fs::path errFile = dir / "stderr.txt";
    const std::string command = "cd " + quote(dir.string()) + " && " + program + " " + args + " > /dev/null 2> " +
        quote(errFile.string());
    const int raw = std::system(command.c_str());
    CliResult r;
    r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
    std::ifstream in(errFile);
    for (std::string line; std::getline(in, line);) r.stderrLines.push_back(line);
    fs::remove(errFile);
    return r;
}

inline std::string readFile(const fs::path& p)
{
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
}

inline void writeFile(const fs::path& p, const std::string& bytes)
{
    std::ofstream(p, std::ios::binary) << bytes;
}

/// Runs `isouq mesh INPUT_ARGS -o OUT` twice: with no output present (none may appear) and with
/// an existing output (it must stay byte-identical). Each run: exit 2, one "isouq: error:" line.
inline void requireCleanFailure(const std::string& inputArgs, const fs::path& dir, const std::string& mustMention)
{
    const fs::path out = dir / "out.ply";
    fs::remove(out);
    CliResult r = runCli("mesh " + inputArgs + " -q -o " + quote(out) + " --summary " + quote(dir / "s.json"), dir);
    INFO("isouq mesh " << inputArgs);
    CHECK(r.status == 2);
    REQUIRE(r.stderrLines.size() == 1);
    CHECK(r.stderrLines[0].rfind("isouq: error: ", 0) == 0);
    CHECK(r.stderrLines[0].find(mustMention) != std::string::npos);
    CHECK_FALSE(fs::exists(out));
    CHECK_FALSE(fs::exists(dir / "s.json"));
    writeFile(out, "precious");
    r = runCli("mesh " + inputArgs + " -q -o " + quote(out), dir);
    CHECK(r.status == 2);
    CHECK(readFile(out) == "precious");
    fs::remove(out);
    for (const auto& entry : fs::directory_iterator(dir)) // no temporary left behind
        CHECK(entry.path().filename().string().find(".tmp") == std::string::npos);
}

} // namespace isouq_test
