// isouq CLI: the command line is a module, libisouq_cli.so in PREFIX/lib/isouq, that the small
// `isouq` program (Launcher.cc) loads once it has settled its memory pages (HugePages.h). So a
// large run that restarts itself starts OpenVDB and the rest once, not twice (docs/mesher.md).
#pragma once

/// The command line's main(): parse, run, report (main.cc). Exit status as SPEC §8 says.
extern "C" __attribute__((visibility("default"))) int isouq_cli_main(int argc, char** argv);

namespace isouq::cli {
inline constexpr const char* kCliMainSymbol = "isouq_cli_main";
} // namespace isouq::cli
