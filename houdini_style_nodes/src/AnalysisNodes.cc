// isouq nodes: the analysis views as nodes (paper sec. 4.3, SPEC §7): threshold (C1), box
// select (C2), method blend (C3), compare (C5/C6 data), color map (C4 for other viewers) and
// summary (C7). Mesh in, mesh out: each adds named per-vertex columns and an info block; none
// reads the volume.
#include "NodeFamilies.h"
#include "Pieces.h"
#include <isouq/ColorMaps.h>
#include <isouq/Columns.h>

#include "isouq/nodes/Summary.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <stdexcept>
#include <unordered_map>

namespace isouq::nodes::nodes_internal {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

const std::vector<float>& floatColumn(const MeshData& m, std::string_view name, const std::string& hint)
{
    const auto* c = m.mesh.vertexAttributes.find<float>(name);
    if (!c) throw std::invalid_argument("input 'mesh' has no per-vertex '" + std::string(name) + "'" + hint);
    return *c;
}

const std::vector<std::uint8_t>* hiddenColumn(const MeshData& m)
{
    return m.mesh.vertexAttributes.find<std::uint8_t>(col::kHidden);
}

/// numpy.percentile's default ("linear") of n ascending values, the i-th @a at(i): position
/// p/100 (n-1), linear between the values on either side.
template <typename At>
double percentileAt(std::uint64_t n, double p, At&& at)
{
    if (n == 0) return std::numeric_limits<double>::quiet_NaN();
    const double pos = p / 100.0 * double(n - 1);
    const std::uint64_t lo = std::uint64_t(std::floor(pos));
    if (lo + 1 >= n) return at(n - 1);
    return at(lo) + (pos - double(lo)) * (at(lo + 1) - at(lo));
}

double percentileOf(const std::vector<double>& sorted, double p)
{
    return percentileAt(sorted.size(), p, [&](std::uint64_t i) { return sorted[std::size_t(i)]; });
}

/// percentileOf each of @a ps over every rank's @a values together, @a n of them finite: the
/// same values on either side as one process's, so the same bits (orderStatisticsOnRanks).
std::vector<double> percentilesOnRanks(const Ranks& ranks, const std::vector<float>& values, std::uint64_t n,
    const std::vector<double>& ps)
{
    std::vector<std::uint64_t> ks; // the positions percentileAt reads, collected by a dry run
    for (double p : ps) percentileAt(n, p, [&](std::uint64_t i) { return ks.push_back(i), 0.0; });
    const std::vector<double> kth = orderStatisticsOnRanks(ranks, values, ks).kth;
    const auto at = [&](std::uint64_t i) { return kth[std::size_t(std::find(ks.begin(), ks.end(), i) - ks.begin())]; };
    std::vector<double> out;
    for (double p : ps) out.push_back(percentileAt(n, p, at));
    return out;
}

/// The finite values of a measure, ascending (the percentiles of C1 and C4).
std::vector<double> sortedFinite(const std::vector<float>& values)
{
    std::vector<double> sorted;
    sorted.reserve(values.size());
    for (float v : values)
        if (std::isfinite(v)) sorted.push_back(v);
    std::sort(sorted.begin(), sorted.end());
    return sorted;
}

/// C1: `above` = measure > threshold (strictly; NaN is never above), threshold given or the
/// percentile of the finite values.
void cookThreshold(CookContext& ctx)
{
    const ParmValues& p = ctx.parms;
    const std::string measure = p.getString("measure");
    auto out = ctx.takeMesh("mesh");
    // Add the column before taking references: adding may move the others.
    std::vector<std::uint8_t>& above = out->mesh.vertexAttributes.add<std::uint8_t>(col::kAbove, out->mesh.vertexCount());
    const std::vector<float>& values = floatColumn(*out, measure, " (mesh without linear_only?)");

    const std::vector<double> sorted = sortedFinite(values);
    const bool byPercentile = p.getString("mode") == "percentile";
    const double threshold = byPercentile ? percentileOf(sorted, p.getFloat("percentile")) : p.getFloat("value");

    std::size_t count = 0;
    for (std::size_t v = 0; v < values.size(); ++v) count += above[v] = double(values[v]) > threshold;
    if (sorted.size() < values.size())
        ctx.warn(std::to_string(values.size() - sorted.size()) + " vertices have no finite " + measure +
            " and are never above");

    // The CDF sampled at up to 1001 ranks, for the C1 plot.
    nlohmann::json x = nlohmann::json::array(), percent = nlohmann::json::array();
    const std::size_t samples = std::min<std::size_t>(sorted.size(), 1001);
    for (std::size_t s = 0; s < samples; ++s) {
        const std::size_t rank = samples == 1 ? 0 : s * (sorted.size() - 1) / (samples - 1);
        x.push_back(sorted[rank]);
        percent.push_back(100.0 * double(rank + 1) / double(sorted.size()));
    }
    nlohmann::json block = {{"measure", measure}, {"mode", p.getString("mode")},
        {"threshold", std::isfinite(threshold) ? nlohmann::json(threshold) : nlohmann::json(nullptr)},
        {"above", count}, {"finite", sorted.size()}, {"vertices", values.size()}};
    if (byPercentile) block["percentile"] = p.getFloat("percentile");
    out->info["threshold"] = block;
    block["cdf"] = {{"x", x}, {"percent", percent}};
    ctx.outputs["cdf"].json = block;
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// C4 in the file (SPEC §10 "Formats"): `red green blue` from a colour map over a range, the
/// 2nd to 98th percentile of the finite values unless given, and `quality` = the measure.
void cookColorMap(CookContext& ctx)
{
    const ParmValues& p = ctx.parms;
    const std::string measure = p.getString("measure");
    auto out = ctx.takeMesh("mesh");
    const std::vector<float>& values = floatColumn(*out, measure, " (mesh without linear_only?)");
    const bool given = p.isSet("range");
    double lo = 0.0, hi = 0.0;
    std::uint64_t all = values.size(), finite = 0; // of the whole mesh (every rank's piece)
    if (given) {
        const auto r = p.at("range").get<std::array<double, 2>>();
        lo = r[0], hi = r[1];
        if (!(lo < hi)) throw std::invalid_argument("parameter 'range': LO must be below HI");
    }
    if (ctx.ranks) { // every rank's values together (docs/mpi.md)
        const ValuesOnRanks whole = orderStatisticsOnRanks(*ctx.ranks, values, {});
        all = whole.count, finite = whole.finite;
        if (!given && finite > 0) {
            const std::vector<double> range = percentilesOnRanks(*ctx.ranks, values, finite, {2.0, 98.0});
            lo = range[0], hi = range[1];
        }
    } else if (given) { // the count alone
        finite = std::uint64_t(std::count_if(values.begin(), values.end(), [](float v) { return std::isfinite(v); }));
    } else {
        const std::vector<double> sorted = sortedFinite(values);
        finite = sorted.size();
        if (!sorted.empty()) lo = percentileOf(sorted, 2.0), hi = percentileOf(sorted, 98.0);
    }
    const std::uint64_t noValue = all - finite;
    if (noValue)
        ctx.warn(std::to_string(noValue) + " vertices have no finite " + measure + ": coloured grey (128, 128, 128)");
    const ColorMap map = *colorMapFromString(p.getString("colormap"));
    addColorColumns(out->mesh, measure, map, lo, hi);
    out->info["color"] = {{"measure", measure}, {"colormap", toString(map)}, {"range", {lo, hi}},
        {"range_source", given ? "given" : "2nd and 98th percentiles"}, {"no_value", noValue}};
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// C2: `in_box` = |p - centre| <= size / 2 on every axis (closed box, in double).
void cookBoxSelect(CookContext& ctx)
{
    const auto c = ctx.parms.getVec3("center");
    const auto s = ctx.parms.getVec3("size");
    auto out = ctx.takeMesh("mesh");
    const std::vector<openvdb::Vec3s>& pos = out->mesh.positions;
    std::vector<std::uint8_t>& in = out->mesh.vertexAttributes.add<std::uint8_t>(col::kInBox, pos.size());
    std::size_t count = 0;
    for (std::size_t v = 0; v < pos.size(); ++v) {
        bool inside = true;
        for (int a = 0; a < 3; ++a) inside = inside && std::fabs(double(pos[v][a]) - c[a]) <= 0.5 * s[a];
        count += in[v] = inside;
    }
    out->info["box"] = {{"center", c}, {"size", s}, {"inside", count}, {"vertices", pos.size()}};
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// t_<method> of a method menu token (the menus only hold valid tokens).
std::string tColumnName(const std::string& method)
{
    return std::string(tColumn(*edgeMethodFromString(method)));
}

/// World position of parameter t along a vertex's source edge: M (ijk + t e_axis, 1).
struct EdgePlacer {
    const Mesh& mesh;
    const std::vector<std::int32_t> &i, &j, &k;
    const std::vector<std::uint8_t>& axis;

    static EdgePlacer of(const MeshData& m)
    {
        const AttributeTable& a = m.mesh.vertexAttributes;
        const auto* i = a.find<std::int32_t>(col::kEdgeI);
        const auto* j = a.find<std::int32_t>(col::kEdgeJ);
        const auto* k = a.find<std::int32_t>(col::kEdgeK);
        const auto* ax = a.find<std::uint8_t>(col::kEdgeAxis);
        if (!i || !j || !k || !ax) throw std::invalid_argument("input 'mesh' has no edge_i edge_j edge_k edge_axis");
        return {m.mesh, *i, *j, *k, *ax};
    }
    openvdb::Vec3d operator()(std::size_t v, double t) const
    {
        double idx[3] = {double(i[v]), double(j[v]), double(k[v])};
        idx[axis[v]] += t;
        const auto& M = mesh.indexToWorld;
        openvdb::Vec3d w;
        for (int r = 0; r < 3; ++r) w[r] = M[4 * r] * idx[0] + M[4 * r + 1] * idx[1] + M[4 * r + 2] * idx[2] + M[4 * r + 3];
        return w;
    }
};

/// C3: selected vertices at the `inside` method's crossing, the others at `outside`'s.
/// Refined (hidden) vertices and vertices without a finite t keep their position.
void cookMethodBlend(CookContext& ctx)
{
    const ParmValues& p = ctx.parms;
    const std::string selection = p.getString("selection");
    const std::string inside = p.getString("inside"), outside = p.getString("outside");
    auto out = ctx.takeMesh("mesh");
    const auto* selected = out->mesh.vertexAttributes.find<std::uint8_t>(selection);
    if (!selected)
        throw std::invalid_argument("parameter 'selection': input 'mesh' has no per-vertex '" + selection +
            "' (connect a " + (selection == col::kAbove ? "threshold" : "box_select") + " node before)");
    const std::string hint = " (mesh without linear_only)";
    const std::vector<float>& tIn = floatColumn(*out, tColumnName(inside), hint);
    const std::vector<float>& tOut = floatColumn(*out, tColumnName(outside), hint);
    const EdgePlacer place = EdgePlacer::of(*out);
    const auto* hidden = hiddenColumn(*out);
    std::size_t moved = 0, kept = 0, count = 0;
    for (std::size_t v = 0; v < out->mesh.vertexCount(); ++v) {
        const bool sel = (*selected)[v];
        count += sel;
        const float t = sel ? tIn[v] : tOut[v];
        if ((hidden && (*hidden)[v]) || !std::isfinite(t)) {
            ++kept;
            continue;
        }
        const openvdb::Vec3s next(place(v, t));
        moved += next != out->mesh.positions[v];
        out->mesh.positions[v] = next;
    }
    if (kept) ctx.warn("kept the position of " + std::to_string(kept) + " refined or unplaced vertices");
    out->method = "blend";
    out->info["blend"] = {{"selection", selection}, {"inside", inside}, {"outside", outside},
        {"selected", count}, {"moved", moved}};
    ctx.outputs["mesh"].mesh = std::move(out);
}

struct EdgeKey {
    std::int32_t i, j, k;
    std::uint8_t axis;
    bool operator==(const EdgeKey& o) const { return i == o.i && j == o.j && k == o.k && axis == o.axis; }
};
struct EdgeKeyHash {
    std::size_t operator()(const EdgeKey& e) const
    {
        std::size_t h = std::hash<std::int64_t>()((std::int64_t(e.i) * 73856093) ^ (std::int64_t(e.j) * 19349663) ^
                                                  (std::int64_t(e.k) * 83492791));
        return h * 4 + e.axis;
    }
};

/// `compare_dist` per vertex: |x_a - x_b| of two methods' crossings, or with a second mesh
/// the distance to its vertex on the same source edge (NaN when it has none).
void cookCompare(CookContext& ctx)
{
    auto out = ctx.takeMesh("mesh");
    const std::size_t n = out->mesh.vertexCount();
    std::vector<float> dist(n, kNaN);
    const EdgePlacer place = EdgePlacer::of(*out);
    const auto* hidden = hiddenColumn(*out);
    nlohmann::json block;
    if (const NodeValue* other = ctx.input("other")) {
        const MeshData& b = *other->mesh;
        const EdgePlacer placeB = EdgePlacer::of(b);
        const auto* hiddenB = hiddenColumn(b);
        std::unordered_map<EdgeKey, std::size_t, EdgeKeyHash> index;
        for (std::size_t v = 0; v < b.mesh.vertexCount(); ++v)
            if (!hiddenB || !(*hiddenB)[v]) index[{placeB.i[v], placeB.j[v], placeB.k[v], placeB.axis[v]}] = v;
        std::size_t unmatched = 0;
        for (std::size_t v = 0; v < n; ++v) {
            auto it = (hidden && (*hidden)[v]) ? index.end() : index.find({place.i[v], place.j[v], place.k[v], place.axis[v]});
            if (it == index.end()) {
                ++unmatched;
                continue;
            }
            dist[v] = float((openvdb::Vec3d(out->mesh.positions[v]) - openvdb::Vec3d(b.mesh.positions[it->second])).length());
        }
        if (unmatched) ctx.warn(std::to_string(unmatched) + " vertices have no vertex on the same edge in 'other'");
        block = {{"mode", "meshes"}, {"unmatched", unmatched}};
    } else {
        const std::string a = ctx.parms.getString("method_a"), bName = ctx.parms.getString("method_b");
        const std::string hint = " (mesh without linear_only)";
        const std::vector<float>& ta = floatColumn(*out, tColumnName(a), hint);
        const std::vector<float>& tb = floatColumn(*out, tColumnName(bName), hint);
        for (std::size_t v = 0; v < n; ++v)
            if (!(hidden && (*hidden)[v])) dist[v] = float((place(v, ta[v]) - place(v, tb[v])).length());
        block = {{"mode", "methods"}, {"method_a", a}, {"method_b", bName}};
    }
    block[std::string(col::kCompareDist)] = statistics(dist);
    out->mesh.vertexAttributes.add<float>(col::kCompareDist, n) = std::move(dist);
    out->info["compare"] = block;
    ctx.outputs["stats"].json = block;
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// C7: the SPEC §8 summary with the views' blocks (threshold, box, blend, compare, hidden).
/// Where the meshes go (the first mesh writer of each input) and the upstream cook times.
void cookSummary(CookContext& ctx)
{
    const auto start = std::chrono::steady_clock::now();
    const MeshData& m = inputMesh(ctx);
    if (ctx.ranks && !m.piece) throw std::invalid_argument("input 'mesh' is not a mesh made by pieces");
    nlohmann::json s = ctx.ranks ? summarizeOnRanks(*ctx.ranks, m.mesh, *m.piece) : summarizeMesh(m.mesh);
    s["isovalue"] = m.isovalue;
    s["method"] = m.method;
    for (const auto& [key, value] : m.info.items()) s[key] = value;
    if (const auto paths = ctx.destinations("mesh"); !paths.empty()) s["output"] = paths.front();
    // C7's "components before and after hidden-feature recovery" beside the views' blocks.
    if (const NodeValue* hidden = ctx.input("hidden")) {
        if (!hidden->mesh || !hidden->mesh->info.contains("hidden"))
            throw std::invalid_argument("input 'hidden' is not the output of a hidden_features node");
        s["hidden"] = hidden->mesh->info["hidden"];
        if (const auto paths = ctx.destinations("hidden"); !paths.empty()) s["hidden"]["output"] = paths.front();
    }
    nlohmann::json timings = ctx.upstreamTimings();
    timings["measure"] = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    s["timings_ms"] = timings;
    if (ctx.ranks) addRanksBlock(*ctx.ranks, m, timings, s); // SPEC §10 "MPI"
    ctx.outputs["summary"].json = s;
}

} // namespace

void addAnalysisNodes(std::vector<NodeType>& types)
{
    types.push_back({"threshold", "Threshold",
        "C1 (paper sec. 4.3, SPEC §7): marks the vertices whose measure is above a value or a percentile "
        "(numpy's linear percentile of the finite values) as `above`, and gives the CDF.",
        {
            menuParm("measure", "Measure", measureColumns(), measureColumns().front(), "Per-vertex measure to threshold"),
            menuParm("mode", "Mode", {"value", "percentile"}, "percentile", "Threshold by value or by percentile"),
            ranged(parm("value", "Value", ParmType::Float, 0.0, "mode=value: the threshold, world units"),
                std::make_pair(0.0, 0.1), std::nullopt),
            ranged(parm("percentile", "Percentile", ParmType::Float, 90.0,
                       "mode=percentile: the threshold is this percentile of the measure"),
                std::make_pair(50.0, 100.0), std::make_pair(0.0, 100.0)),
        },
        {{"mesh", "mesh", "A mesh with the measure"}},
        {{"mesh", "mesh", "The mesh with `above` (uint8)"},
            {"cdf", "json", "measure, threshold, above count and the CDF sampled at up to 1001 ranks"}},
        cookThreshold});

    types.push_back({"box_select", "Box Select",
        "C2 (SPEC §7): marks the vertices inside an axis-aligned box (closed) as `in_box`.",
        {
            parm("center", "Center", ParmType::Vec3, nlohmann::json::array({0.0, 0.0, 0.0}), "Box centre, world units"),
            ranged(parm("size", "Size", ParmType::Vec3, nlohmann::json::array({0.5, 0.5, 0.5}),
                       "Box edge lengths, world units"),
                std::nullopt, std::make_pair(0.0, kInf)),
        },
        {{"mesh", "mesh", "Any mesh"}}, {{"mesh", "mesh", "The mesh with `in_box` (uint8)"}}, cookBoxSelect});

    types.push_back({"method_blend", "Method Blend",
        "C3 (SPEC §7): places the selected vertices at one method's crossing and the others at another's, "
        "from the per-vertex edge and t columns (SPEC §6).",
        {
            menuParm("selection", "Selection", {std::string(col::kInBox), std::string(col::kAbove)},
                std::string(col::kInBox), "The uint8 column that selects"),
            menuParm("inside", "Inside Method", methodMenu(), "weno", "Method for the selected vertices"),
            menuParm("outside", "Outside Method", methodMenu(), "linear", "Method for the other vertices"),
        },
        {{"mesh", "mesh", "A mesh with the selection column and t_<method> columns"}},
        {{"mesh", "mesh", "The mesh with blended positions"}}, cookMethodBlend});

    types.push_back({"compare", "Compare",
        "C5/C6 data (SPEC §7): per-vertex `compare_dist`, the distance between two methods' crossings, or to "
        "the vertex on the same source edge of a second mesh.",
        {
            menuParm("method_a", "Method A", methodMenu(), "linear", "Without 'other': the first method"),
            menuParm("method_b", "Method B", methodMenu(), "weno", "Without 'other': the second method"),
        },
        {{"mesh", "mesh", "The mesh that receives compare_dist"},
            {"other", "mesh", "A second mesh of the same volume (e.g. another isovalue or method)", true}},
        {{"mesh", "mesh", "The mesh with `compare_dist` (float)"},
            {"stats", "json", "Mode and {min, max, mean, rms, count} of compare_dist"}},
        cookCompare});

    std::vector<std::string> colorMaps;
    for (ColorMap m : kAllColorMaps) colorMaps.push_back(toString(m));
    types.push_back({"color_map", "Color Map",
        "C4 for viewers without isouq (SPEC §10 \"Formats\"): per-vertex `red green blue` (uint8) from a colour "
        "map of a measure over a range, and `quality` (the measure, MeshLab's vertex quality), so Blender's own "
        "PLY importer, MeshLab and Open3D show the heat map (docs/ply-format.md \"Colours\").",
        {
            menuParm("measure", "Measure", measureColumns(), measureColumns().front(),
                "Per-vertex measure to colour (isouq mesh: adds red green blue quality to the PLY)", "--color-by"),
            menuParm("colormap", "Color Map", colorMaps, colorMaps.front(),
                "Colour map: viridis, coolwarm (diverging) or gray", "--colormap"),
            parm("range", "Range", ParmType::Vec2, nullptr,
                "Measure values at the two ends of the map, LO,HI (unset: the 2nd and 98th percentiles of the "
                "finite values)",
                "--color-range"),
        },
        {{"mesh", "mesh", "A mesh with the measure"}},
        {{"mesh", "mesh", "The mesh with `red green blue` (uint8) and `quality` (float)"}}, cookColorMap,
        /*meshWriter=*/false, /*onRanks=*/true});

    types.push_back({"summary", "Summary",
        "C7 (SPEC §7, §8): counts, topology, {min, max, mean, rms} of each measure, and the blocks of the "
        "views upstream (threshold with its count above, box, blend, compare, hidden with components before "
        "and after recovery), where the meshes are written and the upstream nodes' cook times.",
        {},
        {{"mesh", "mesh", "The mesh to summarise"},
            {"hidden", "mesh", "Optional: the hidden-feature mesh, for components before and after recovery", true}},
        {{"summary", "json", "The summary"}}, cookSummary, /*meshWriter=*/false, /*onRanks=*/true});
}

} // namespace isouq::nodes::nodes_internal
