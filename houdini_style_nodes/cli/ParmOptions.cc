// isouq CLI: options from ParmSpecs (ParmOptions.h).
#include "ParmOptions.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <stdexcept>

namespace isouq::cli {
namespace {

using nodes::ParmSpec;
using nodes::ParmType;

/// CLI11 reads an integer too large for a long long as the largest one: such a number is
/// refused as the user wrote it (each of a list's).
const CLI::Validator kLongLong(
    [](std::string& text) {
        long long v = 0;
        for (const std::string& item : CLI::detail::split(text, ',')) {
            const char* end = item.data() + item.size();
            const auto [at, error] = std::from_chars(item.data() + (!item.empty() && item[0] == '+'), end, v);
            if (error == std::errc::result_out_of_range) return item + " is beyond the range of a 64-bit integer";
        }
        return std::string();
    },
    "");

/// Re-checks the value with the graph's rules, so a flag and a graph reject the same values, but
/// for a path's ending: `-o` names a .ply or a .vtp, and the graph builder picks the writer by it
/// (MeshGraph.cc writer()).
void store(nlohmann::json& values, const ParmSpec& spec, const nlohmann::json& value)
{
    ParmSpec rules = spec;
    rules.extensions.clear();
    if (std::string why = nodes::checkParmValue(rules, value); !why.empty()) throw CLI::ValidationError(spec.flag, why);
    values[spec.token] = value;
}

CLI::Option* addOne(CLI::App& cmd, const ParmSpec& spec, nlohmann::json& values)
{
    const std::string& names = spec.flag;
    switch (spec.type) {
    case ParmType::Bool: {
        // A parameter that is on by default gets a --no-NAME twin that turns it off.
        std::string withNegation = names;
        if (spec.defaultValue.is_boolean() && spec.defaultValue.get<bool>())
            for (const std::string& name : CLI::detail::split(names, ','))
                if (name.rfind("--", 0) == 0) withNegation += ",!--no-" + name.substr(2);
        return cmd.add_flag_function(withNegation,
            [&values, spec](std::int64_t count) { store(values, spec, count > 0); }, spec.tooltip);
    }
    // CLI11 reads "" as 0: a number option needs a number.
    case ParmType::Int:
        return cmd.add_option_function<long long>(names, [&values, spec](const long long& v) { store(values, spec, v); },
            spec.tooltip)->check(CLI::Number)->check(kLongLong);
    case ParmType::Float:
        return cmd.add_option_function<double>(names, [&values, spec](const double& v) { store(values, spec, v); },
            spec.tooltip)->check(CLI::Number);
    case ParmType::String:
    case ParmType::Path:
    case ParmType::Menu: {
        CLI::Option* o = cmd.add_option_function<std::string>(
            names, [&values, spec](const std::string& v) { store(values, spec, v); }, spec.tooltip);
        if (spec.type == ParmType::Menu) o->check(CLI::IsMember(spec.menu));
        return o;
    }
    case ParmType::Vec2:
    case ParmType::Vec3:
        return cmd.add_option_function<std::vector<double>>(
                      names, [&values, spec](const std::vector<double>& v) { store(values, spec, v); }, spec.tooltip)
            ->delimiter(',')
            ->expected(spec.type == ParmType::Vec2 ? 2 : 3)
            ->check(CLI::Number);
    case ParmType::Int3:
        return cmd.add_option_function<std::vector<long long>>(
                      names, [&values, spec](const std::vector<long long>& v) { store(values, spec, v); }, spec.tooltip)
            ->delimiter(',')
            ->expected(3)
            ->check(CLI::Number)
            ->check(kLongLong);
    }
    throw std::logic_error("unknown parameter type");
}

} // namespace

void addParmOptions(CLI::App& cmd, const nodes::NodeType& type, nlohmann::json& values,
    const std::vector<std::string>& tokens)
{
    for (const ParmSpec& spec : type.parms) {
        if (spec.flag.empty()) continue;
        if (!tokens.empty() && std::find(tokens.begin(), tokens.end(), spec.token) == tokens.end()) continue;
        CLI::Option* o = addOne(cmd, spec, values);
        if (spec.type != ParmType::Bool && !spec.defaultValue.is_null())
            o->default_str(spec.defaultValue.is_string() ? spec.defaultValue.get<std::string>() : spec.defaultValue.dump());
        if (spec.hardRange && (spec.type == ParmType::Int || spec.type == ParmType::Float) &&
            std::isfinite(spec.hardRange->first) && std::isfinite(spec.hardRange->second))
            o->check(spec.type == ParmType::Int
                    ? CLI::Range(static_cast<long long>(spec.hardRange->first), static_cast<long long>(spec.hardRange->second))
                    : CLI::Range(spec.hardRange->first, spec.hardRange->second));
    }
}

const nodes::NodeType& nodeType(const std::string& name)
{
    const nodes::NodeType* t = nodes::findNodeType(name);
    if (!t) throw std::logic_error("no node type " + name);
    return *t;
}

} // namespace isouq::cli
