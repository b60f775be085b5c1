// isouq CLI: `isouq validate` (being written: the validation engineer owns this file).
#include "ValidateCommand.h"

namespace isouq::cli {

void addValidateCommand(CLI::App& app, int& exitStatus)
{
    CLI::App* validate = app.add_subcommand("validate", "Reproduce the paper's accuracy tables (Figs. 3, 4)");
    validate->callback([&exitStatus] { exitStatus = 2; throw CLI::RuntimeError("validate: not available yet", 2); });
}

} // namespace isouq::cli
