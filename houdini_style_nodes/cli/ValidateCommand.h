// isouq CLI: `isouq validate` — reproduces the paper's Figs. 3 and 4 (SPEC §3, §5).
#pragma once

#include <CLI/CLI.hpp>

namespace isouq::cli {

/// Adds the `validate` subcommand to @a app; it runs when parsed (its own callback) and
/// returns its exit status through @a exitStatus.
void addValidateCommand(CLI::App& app, int& exitStatus);

} // namespace isouq::cli
