// isouq nodes: parameter types and value checks (Parm.h).
#include "isouq/nodes/Parm.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <sstream>

namespace isouq::nodes {
namespace {

std::string number(double v)
{
    std::ostringstream s;
    s << v;
    return s.str();
}

std::string outside(double v, const std::pair<double, double>& r)
{
    return number(v) + " is outside the hard range [" + number(r.first) + ", " + number(r.second) + "]";
}

std::string checkNumber(const nlohmann::json& v, bool integer, const ParmRange& hard)
{
    if (integer ? !v.is_number_integer() : !v.is_number())
        return std::string("expected ") + (integer ? "an integer" : "a number") + ", got " + v.dump();
    const double x = v.get<double>();
    if (!std::isfinite(x)) return "expected a finite number, got " + number(x);
    if (hard && (x < hard->first || x > hard->second)) return outside(x, *hard);
    return "";
}

std::string checkVector(const nlohmann::json& v, std::size_t n, bool integer, const ParmRange& hard)
{
    const std::string what = std::to_string(n) + (integer ? " integers" : " numbers");
    if (!v.is_array() || v.size() != n) return "expected an array of " + what + ", got " + v.dump();
    for (const nlohmann::json& x : v)
        if (std::string why = checkNumber(x, integer, hard); !why.empty()) return why;
    return "";
}

} // namespace

std::string toString(ParmType type)
{
    switch (type) {
    case ParmType::Bool: return "bool";
    case ParmType::Int: return "int";
    case ParmType::Float: return "float";
    case ParmType::String: return "string";
    case ParmType::Menu: return "menu";
    case ParmType::Vec2: return "vec2";
    case ParmType::Vec3: return "vec3";
    case ParmType::Int3: return "int3";
    case ParmType::Path: return "path";
    }
    return "string";
}

std::string pathExtension(const std::string& path)
{
    std::string ext = std::filesystem::path(path).extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    return ext;
}

std::string checkParmValue(const ParmSpec& spec, const nlohmann::json& value)
{
    if (value.is_null()) return "";
    switch (spec.type) {
    case ParmType::Bool:
        return value.is_boolean() ? "" : "expected true or false, got " + value.dump();
    case ParmType::Int: return checkNumber(value, true, spec.hardRange);
    case ParmType::Float: return checkNumber(value, false, spec.hardRange);
    case ParmType::Vec2: return checkVector(value, 2, false, spec.hardRange);
    case ParmType::Vec3: return checkVector(value, 3, false, spec.hardRange);
    case ParmType::Int3: return checkVector(value, 3, true, spec.hardRange);
    case ParmType::String:
    case ParmType::Path:
        if (!value.is_string()) return "expected a string, got " + value.dump();
        if (spec.type != ParmType::Path) return "";
        if (value.get<std::string>().empty()) return "expected a path, got \"\"";
        if (!spec.extensions.empty()
            && std::find(spec.extensions.begin(), spec.extensions.end(), pathExtension(value.get<std::string>()))
                == spec.extensions.end()) {
            std::string list;
            for (const std::string& e : spec.extensions) list += (list.empty() ? "" : " or ") + e;
            return "expected a path ending in " + list + ", got " + value.dump();
        }
        return "";
    case ParmType::Menu: {
        if (!value.is_string()) return "expected a string, got " + value.dump();
        const std::string s = value.get<std::string>();
        if (std::find(spec.menu.begin(), spec.menu.end(), s) != spec.menu.end()) return "";
        std::string list;
        for (const std::string& m : spec.menu) list += (list.empty() ? "" : "|") + m;
        return "\"" + s + "\" is not one of " + list;
    }
    }
    return "";
}

} // namespace isouq::nodes
