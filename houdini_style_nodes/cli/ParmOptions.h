// isouq CLI: CLI11 options made from node parameter declarations (STYLE "Nodes"): one ParmSpec
// gives the flag names, the help text, the default shown, the menu and the range checks.
#pragma once

#include <isouq/nodes/Node.h>

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

namespace isouq::cli {

/// Adds an option to @a cmd for each parameter of @a type that has a flag (all, or only
/// @a tokens when given). A value given on the command line lands in @a values[token] as the
/// JSON a graph would hold; parameters not given stay absent.
void addParmOptions(CLI::App& cmd, const nodes::NodeType& type, nlohmann::json& values,
    const std::vector<std::string>& tokens = {});

/// The node type called @a name (a programming error if it does not exist).
const nodes::NodeType& nodeType(const std::string& name);

} // namespace isouq::cli
