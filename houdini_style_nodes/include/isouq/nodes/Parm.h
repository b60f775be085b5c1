// isouq nodes: typed parameter declarations (STYLE "Nodes", after OpenVDB's ParmFactory).
// A node declares each parameter once as a ParmSpec; the same list drives the CLI11 flags,
// --help, JSON graph validation, `isouq nodes --json` and docs/node-parameters.md.
#pragma once

#include <nlohmann/json.hpp>

#include <array>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace isouq::nodes {

enum class ParmType { Bool, Int, Float, String, Menu, Vec2, Vec3, Int3, Path };

/// "bool", "int", "float", "string", "menu", "vec2", "vec3", "int3", "path".
std::string toString(ParmType type);

using ParmRange = std::optional<std::pair<double, double>>;

struct ParmSpec {
    std::string token;   ///< lowercase, e.g. "isovalue"
    std::string label;   ///< Title Case, e.g. "Isovalue"
    ParmType type = ParmType::Float;
    nlohmann::json defaultValue; ///< null: unset (the node documents what unset means)
    ParmRange softRange;         ///< where a slider goes; values outside are allowed
    ParmRange hardRange;         ///< values outside are errors (each component for vectors)
    std::vector<std::string> menu; ///< the tokens a Menu accepts
    std::vector<std::string> extensions; ///< the endings a Path accepts (pathExtension); empty: any
    std::string tooltip;
    std::string flag;            ///< CLI11 name(s) on the subcommands that expose it, e.g. "--isovalue,-k"
};

/// What a node reads or produces on one port.
struct PortSpec {
    std::string name;        ///< e.g. "mesh"
    std::string type;        ///< "volume", "mesh" or "json"
    std::string description;
    bool optional = false;   ///< inputs only
};

/// The extension of @a path in lowercase (".ply", ".vtp"; "" without one): how outputs are told apart.
std::string pathExtension(const std::string& path);

/// "" if @a value is a valid value of @a spec (null is valid: unset), else the reason,
/// e.g. "expected a number, got \"abc\"" or "150 is outside the hard range [0, 100]".
std::string checkParmValue(const ParmSpec& spec, const nlohmann::json& value);

/// A node's evaluated parameters: every declared token, defaults filled in.
class ParmValues {
public:
    ParmValues() = default;
    explicit ParmValues(nlohmann::json values) : mValues(std::move(values)) {}

    bool isSet(const std::string& token) const { return !at(token).is_null(); }
    bool getBool(const std::string& token) const { return at(token).get<bool>(); }
    int getInt(const std::string& token) const { return at(token).get<int>(); }
    double getFloat(const std::string& token) const { return at(token).get<double>(); }
    std::string getString(const std::string& token) const { return at(token).get<std::string>(); }
    std::array<double, 3> getVec3(const std::string& token) const { return at(token).get<std::array<double, 3>>(); }
    const nlohmann::json& at(const std::string& token) const { return mValues.at(token); }
    const nlohmann::json& json() const { return mValues; }

private:
    nlohmann::json mValues = nlohmann::json::object();
};

} // namespace isouq::nodes
