// isouq nodes (internal): the node families and small builders for their declarations.
#pragma once

#include "isouq/nodes/Node.h"

#include <limits>
#include <string>
#include <vector>

namespace isouq::nodes::nodes_internal {

inline constexpr double kInf = std::numeric_limits<double>::infinity();

inline ParmSpec parm(std::string token, std::string label, ParmType type, nlohmann::json defaultValue,
    std::string tooltip, std::string flag = "")
{
    ParmSpec p;
    p.token = std::move(token);
    p.label = std::move(label);
    p.type = type;
    p.defaultValue = std::move(defaultValue);
    p.tooltip = std::move(tooltip);
    p.flag = std::move(flag);
    return p;
}

inline ParmSpec menuParm(std::string token, std::string label, std::vector<std::string> menu,
    nlohmann::json defaultValue, std::string tooltip, std::string flag = "")
{
    ParmSpec p = parm(std::move(token), std::move(label), ParmType::Menu, std::move(defaultValue),
        std::move(tooltip), std::move(flag));
    p.menu = std::move(menu);
    return p;
}

/// @a p (a Path) accepting only paths with one of @a extensions (lowercase, ".ply").
inline ParmSpec ending(ParmSpec p, std::vector<std::string> extensions)
{
    p.extensions = std::move(extensions);
    return p;
}

inline ParmSpec ranged(ParmSpec p, ParmRange soft, ParmRange hard)
{
    p.softRange = soft;
    p.hardRange = hard;
    return p;
}

/// linear, cubic, weno, weno-paper (EdgeInterp.h).
std::vector<std::string> methodMenu();

void addVolumeNodes(std::vector<NodeType>& types);   // VolumeNodes.cc
void addAnalysisNodes(std::vector<NodeType>& types); // AnalysisNodes.cc
void addOutputNodes(std::vector<NodeType>& types);   // OutputNodes.cc

/// The mesh on input @a port, or an error naming it.
const MeshData& inputMesh(const CookContext& ctx, const std::string& port = "mesh");

} // namespace isouq::nodes::nodes_internal
