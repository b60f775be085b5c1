// isouq: the one vocabulary of mesh columns (SPEC §6, §10 "One runner"; STYLE "One
// vocabulary"). Every column name that crosses a boundary (PLY writer, summary, node menus,
// `validate`, the add-on, scripts) is declared here once, with its type and meaning, and
// exported by `isouq nodes --json` as `columns`. Code names columns through isouq::col.
#pragma once

#include "isouq/EdgeInterp.h"

#include <array>
#include <string>
#include <string_view>
#include <vector>

namespace isouq {

enum class ColumnType { Float32, Int32, UInt8, List };
enum class ColumnElement { Vertex, Face };

/// "float32", "int32", "uint8", "list"; "vertex", "face".
std::string_view toString(ColumnType type);
std::string_view toString(ColumnElement element);

struct ColumnInfo {
    std::string_view name;
    ColumnType type;
    ColumnElement element;
    bool measure; ///< a per-vertex float for a threshold or a heat map (C1, C4)
    bool summary; ///< the summary reports its {min, max, mean, rms, count} (SPEC §8)
    std::string_view description;
};

/// The names (SPEC §6 and the columns added since). Contracts: extend, never rename.
namespace col {
inline constexpr std::string_view kX = "x", kY = "y", kZ = "z";
inline constexpr std::string_view kTLinear = "t_linear", kTCubic = "t_cubic", kTWeno = "t_weno",
                                  kTWenoPaper = "t_weno_paper";
inline constexpr std::string_view kEdgeI = "edge_i", kEdgeJ = "edge_j", kEdgeK = "edge_k",
                                  kEdgeAxis = "edge_axis";
inline constexpr std::string_view kOrder = "order";
inline constexpr std::string_view kErrEst = "err_est", kErrBound = "err_bound";
inline constexpr std::string_view kErrBest = "err_best", kErrBestSurface = "err_best_surface",
                                  kErrEstCubic = "err_est_cubic", kErrEstWeno = "err_est_weno";
inline constexpr std::string_view kDLc = "d_lc", kDLw = "d_lw", kDCw = "d_cw", kMaxVar = "max_var";
inline constexpr std::string_view kErrTrueLinear = "err_true_linear", kErrTrueCubic = "err_true_cubic",
                                  kErrTrueWeno = "err_true_weno", kErrTrueWenoPaper = "err_true_weno_paper";
inline constexpr std::string_view kDistTrue = "dist_true";
inline constexpr std::string_view kDistTrueLinear = "dist_true_linear", kDistTrueCubic = "dist_true_cubic",
                                  kDistTrueWeno = "dist_true_weno", kDistTrueWenoPaper = "dist_true_weno_paper";
inline constexpr std::string_view kDistMetroLinear = "dist_metro_linear";
inline constexpr std::string_view kHidden = "hidden"; ///< per vertex and per face
inline constexpr std::string_view kAbove = "above", kInBox = "in_box", kCompareDist = "compare_dist";
inline constexpr std::string_view kRed = "red", kGreen = "green", kBlue = "blue", kQuality = "quality";
inline constexpr std::string_view kVertexIndices = "vertex_indices";
} // namespace col

/// Every column, vertex columns first, in PLY property order.
const std::vector<ColumnInfo>& columnTable();

/// The entry of @a name for @a element, or nullptr.
const ColumnInfo* findColumnInfo(std::string_view name, ColumnElement element = ColumnElement::Vertex);

/// Names of the columns with `measure` set, in table order (the threshold menu, the add-on).
std::vector<std::string> measureColumns();

/// Every method, in menu order.
inline constexpr std::array<EdgeMethod, 4> kAllMethods = {EdgeMethod::Linear, EdgeMethod::Cubic,
    EdgeMethod::Weno, EdgeMethod::WenoPaper};

/// The method token as it appears in column names: "linear", "cubic", "weno", "weno_paper".
std::string_view columnSuffix(EdgeMethod m);

/// Method @a m's crossing column t_<m>, measured error err_true_<m> and distance to the true
/// surface dist_true_<m> (the method token with '-' as '_': t_weno_paper).
std::string_view tColumn(EdgeMethod m);
std::string_view errTrueColumn(EdgeMethod m);
std::string_view distTrueColumn(EdgeMethod m);

} // namespace isouq
