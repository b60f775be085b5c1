// isouq: the column table (Columns.h; SPEC §6; docs/ply-format.md).
#include "isouq/Columns.h"

namespace isouq {

std::string_view toString(ColumnType type)
{
    switch (type) {
    case ColumnType::Float32: return "float32";
    case ColumnType::Int32: return "int32";
    case ColumnType::UInt8: return "uint8";
    case ColumnType::List: return "list";
    }
    return "float32";
}

std::string_view toString(ColumnElement element)
{
    return element == ColumnElement::Face ? "face" : "vertex";
}

const std::vector<ColumnInfo>& columnTable()
{
    using T = ColumnType;
    constexpr ColumnElement V = ColumnElement::Vertex, F = ColumnElement::Face;
    static const std::vector<ColumnInfo> table = {
        {col::kX, T::Float32, V, false, false, "position of the primary method's crossing (world)"},
        {col::kY, T::Float32, V, false, false, "position of the primary method's crossing (world)"},
        {col::kZ, T::Float32, V, false, false, "position of the primary method's crossing (world)"},
        {col::kTLinear, T::Float32, V, false, false, "linear crossing as the parameter along the vertex's edge, in [0, 1]"},
        {col::kTCubic, T::Float32, V, false, false, "cubic (4-point Lagrange) crossing along the edge, in [0, 1]"},
        {col::kTWeno, T::Float32, V, false, false, "WENO crossing along the edge, in [0, 1]"},
        {col::kTWenoPaper, T::Float32, V, false, false, "weno-paper crossing along the edge (with --method weno-paper)"},
        {col::kEdgeI, T::Int32, V, false, false, "voxel at the lower end of the vertex's edge, i"},
        {col::kEdgeJ, T::Int32, V, false, false, "voxel at the lower end of the vertex's edge, j"},
        {col::kEdgeK, T::Int32, V, false, false, "voxel at the lower end of the vertex's edge, k"},
        {col::kEdgeAxis, T::UInt8, V, false, false, "axis of the edge: 0 x, 1 y, 2 z (255: refined vertex, no grid edge)"},
        {col::kOrder, T::UInt8, V, false, false, "order of the primary method actually used (SPEC §1 fallback)"},
        {col::kErrEst, T::Float32, V, true, true, "the paper's error estimate e of the linear crossing (SPEC §3)"},
        {col::kErrBound, T::Float32, V, true, true, "the standard bound e_b of the linear crossing (SPEC §3)"},
        {col::kErrBest, T::Float32, V, true, true, "linear error estimated by the next higher order's crossing"},
        {col::kErrBestSurface, T::Float32, V, true, true, "err_best projected on the surface normal"},
        {col::kErrEstCubic, T::Float32, V, true, true, "estimated error of the cubic crossing"},
        {col::kErrEstWeno, T::Float32, V, true, true, "estimated error of the WENO crossing"},
        {col::kDLc, T::Float32, V, true, true, "distance between the linear and cubic crossings"},
        {col::kDLw, T::Float32, V, true, true, "distance between the linear and WENO crossings"},
        {col::kDCw, T::Float32, V, true, true, "distance between the cubic and WENO crossings"},
        {col::kMaxVar, T::Float32, V, true, true, "largest of d_lc, d_lw, d_cw"},
        {col::kErrTrueLinear, T::Float32, V, true, true, "measured error of the linear crossing on its edge (known truth)"},
        {col::kErrTrueCubic, T::Float32, V, true, true, "measured error of the cubic crossing on its edge (known truth)"},
        {col::kErrTrueWeno, T::Float32, V, true, true, "measured error of the WENO crossing on its edge (known truth)"},
        {col::kErrTrueWenoPaper, T::Float32, V, true, true, "measured error of the weno-paper crossing (known truth)"},
        {col::kDistTrue, T::Float32, V, true, true, "distance from the vertex to the true surface (known truth)"},
        {col::kDistTrueLinear, T::Float32, V, true, true, "distance from the linear crossing to the true surface"},
        {col::kDistTrueCubic, T::Float32, V, true, true, "distance from the cubic crossing to the true surface"},
        {col::kDistTrueWeno, T::Float32, V, true, true, "distance from the WENO crossing to the true surface"},
        {col::kDistTrueWenoPaper, T::Float32, V, true, true, "distance from the weno-paper crossing to the true surface"},
        {col::kDistMetroLinear, T::Float32, V, true, true, "METRO: distance from the linear crossing to a finer reference"},
        {col::kHidden, T::UInt8, V, false, false, "1 for a vertex from hidden-feature refinement (SPEC §4)"},
        {col::kAbove, T::UInt8, V, false, false, "1 where the threshold node's measure is above its threshold (C1)"},
        {col::kInBox, T::UInt8, V, false, false, "1 inside the box_select node's box (C2)"},
        {col::kCompareDist, T::Float32, V, true, true, "compare node: distance between two methods or meshes (C5/C6)"},
        {col::kRed, T::UInt8, V, false, false, "color_map node (--color-by): the measure's colour, red (PLY vertex colour)"},
        {col::kGreen, T::UInt8, V, false, false, "color_map node (--color-by): the measure's colour, green"},
        {col::kBlue, T::UInt8, V, false, false, "color_map node (--color-by): the measure's colour, blue"},
        {col::kQuality, T::Float32, V, false, false, "color_map node (--color-by): the coloured measure itself (MeshLab's vertex quality)"},
        {col::kVertexIndices, T::List, F, false, false, "the triangle's three vertex indices (PLY list uchar int)"},
        {col::kHidden, T::UInt8, F, false, false, "1 for a triangle from hidden-feature refinement or patching"},
    };
    return table;
}

const ColumnInfo* findColumnInfo(std::string_view name, ColumnElement element)
{
    for (const ColumnInfo& c : columnTable())
        if (c.name == name && c.element == element) return &c;
    return nullptr;
}

std::vector<std::string> measureColumns()
{
    std::vector<std::string> names;
    for (const ColumnInfo& c : columnTable())
        if (c.measure) names.emplace_back(c.name);
    return names;
}

namespace {

/// Per method (EdgeMethod order): t_<m>, err_true_<m>, dist_true_<m>.
struct MethodColumns {
    std::string_view t, errTrue, distTrue;
};
constexpr MethodColumns kMethodColumns[] = {
    {col::kTLinear, col::kErrTrueLinear, col::kDistTrueLinear},
    {col::kTCubic, col::kErrTrueCubic, col::kDistTrueCubic},
    {col::kTWeno, col::kErrTrueWeno, col::kDistTrueWeno},
    {col::kTWenoPaper, col::kErrTrueWenoPaper, col::kDistTrueWenoPaper},
};

const MethodColumns& methodColumns(EdgeMethod m) { return kMethodColumns[static_cast<int>(m)]; }

} // namespace

std::string_view columnSuffix(EdgeMethod m) { return methodColumns(m).t.substr(2); } // t_<suffix>
std::string_view tColumn(EdgeMethod m) { return methodColumns(m).t; }
std::string_view errTrueColumn(EdgeMethod m) { return methodColumns(m).errTrue; }
std::string_view distTrueColumn(EdgeMethod m) { return methodColumns(m).distTrue; }

} // namespace isouq
