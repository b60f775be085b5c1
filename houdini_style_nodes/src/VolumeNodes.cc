// isouq nodes: the nodes that touch a volume — read_volume, mesh, error_estimate,
// hidden_features, truth (SPEC §3-§5, §8). The only translation unit of the node layer that
// reads grids.
#include "NodeFamilies.h"
#include "Pieces.h"

#include <isouq/Columns.h>

#include <isouq/Diagnostics.h>
#include <isouq/ErrorEstimate.h>
#include <isouq/GridMetadata.h>
#include <isouq/HiddenFeatures.h>
#include <isouq/MarchingCubes.h>
#include <isouq/MeshTopology.h>
#include <isouq/Truth.h>
#include <isouq/VolumeSources.h>

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace isouq::nodes::nodes_internal {
namespace {

const LoadedVolume& inputVolume(const CookContext& ctx)
{
    const NodeValue* v = ctx.input("volume");
    if (!v || !v->volume) throw std::invalid_argument("input 'volume' holds no volume");
    return *v->volume;
}

KeepBlocks keepFromString(const std::string& s)
{
    if (s == "crossing_or_hidden") return KeepBlocks::CrossingOrHidden;
    if (s == "non_constant") return KeepBlocks::NonConstant;
    if (s == "all") return KeepBlocks::All;
    return KeepBlocks::Crossing;
}

/// The isovalue parameter as the float32 the grids hold; beyond float32 it is refused as given,
/// not as the infinity it would round to.
float isovalueParm(const ParmValues& p)
{
    const double k = p.getFloat("isovalue");
    if (std::fabs(k) > double(std::numeric_limits<float>::max()))
        throw std::invalid_argument("parameter 'isovalue': " + nlohmann::json(k).dump() +
            " is beyond float32's range (the samples are float32)");
    return float(k);
}

void cookReadVolume(CookContext& ctx)
{
    const ParmValues& p = ctx.parms;
    VolumeRequest request;
    request.input = p.getString("input");
    if (p.isSet("grid")) request.gridName = p.getString("grid");
    if (p.isSet("dims")) {
        const auto d = p.at("dims").get<std::array<int, 3>>();
        request.dims = openvdb::Vec3i(d[0], d[1], d[2]);
    }
    if (p.isSet("dtype")) request.dtype = p.getString("dtype");
    if (p.isSet("spacing")) {
        const auto s = p.getVec3("spacing");
        request.spacing = openvdb::Vec3d(s[0], s[1], s[2]);
    }
    if (p.isSet("resolution")) request.resolution = p.getInt("resolution");
    if (p.isSet("domain")) {
        const auto d = p.at("domain").get<std::array<double, 2>>();
        request.domain = std::make_pair(d[0], d[1]);
    }
    if (p.isSet("isovalue")) request.isovalue = isovalueParm(p);
    request.keep = keepFromString(p.getString("keep"));
    request.allowEmpty = p.getBool("allow_empty");

    std::shared_ptr<LoadedVolume> volume;
    bool empty = false; // allow_empty and no active voxel: an empty mesh
    if (ctx.ranks) { // this rank's piece of the block order (docs/mpi.md), checked as a whole
        VolumeOnRanks piece = readVolumeOnRanks(*ctx.ranks, request, ctx.interrupter);
        volume = std::move(piece.volume);
        ctx.outputs["volume"].piece = std::move(piece.piece);
        empty = piece.empty;
    } else {
        volume = std::make_shared<LoadedVolume>(loadVolume(request, ctx.interrupter));
        empty = request.allowEmpty && volume->grid->activeVoxelCount() == 0;
        const std::string problem = empty ? "" : checkScalarVolume(*volume->grid, volume->isovalue);
        if (!problem.empty()) throw InputError(problem);
    }
    if (empty) {
        ctx.warn(volume->description + ": the grid is empty; an empty mesh");
        ctx.outputs["volume"].volume = std::move(volume);
        return;
    }
    if (volume->isovalueSource != "given") {
        std::ostringstream line;
        line << "isovalue " << volume->isovalue << " (" << volume->isovalueSource
             << "; set it with the isovalue parameter, --isovalue)";
        ctx.warn(line.str());
    }
    ctx.outputs["volume"].volume = std::move(volume);
}

void cookMesh(CookContext& ctx)
{
    const LoadedVolume& volume = inputVolume(ctx);
    const ParmValues& p = ctx.parms;
    const bool linearOnly = p.getBool("linear_only");
    MeshSettings settings;
    settings.isovalue = p.isSet("isovalue") ? isovalueParm(p) : volume.isovalue;
    if (settings.isovalue != volume.isovalue && volume.keptBlocks < volume.denseBlocks)
        throw std::invalid_argument("parameter 'isovalue': differs from the volume's (" +
            std::to_string(volume.isovalue) + "), and the sparse copy of a dense source only holds "
            "the blocks near that one; set the isovalue on the read_volume node");
    settings.uncertainty = !linearOnly;
    settings.provenance = true;
    settings.method = *edgeMethodFromString(p.getString("method"));
    // The paper's "extraction plus estimate" (sec. 4.1; SPEC §3): linear crossings, e and e_b.
    settings.highOrder = p.getBool("high_order");
    if (!settings.highOrder && !linearOnly && settings.method != EdgeMethod::Linear)
        throw std::invalid_argument("parameter 'high_order': off computes no " + p.getString("method") +
            " crossings; use method linear");
    auto out = std::make_shared<MeshData>();
    if (ctx.ranks) { // this rank's piece (docs/mpi.md)
        const NodeValue* in = ctx.input("volume");
        if (!in->piece) throw std::invalid_argument("input 'volume' was not read by pieces");
        out->piece = meshOnRanks(*ctx.ranks, *volume.grid, *in->piece, settings, out->mesh, ctx.interrupter);
    } else
        out->mesh = extractIsosurface(*volume.grid, settings, ctx.interrupter);
    out->isovalue = settings.isovalue;
    out->method = linearOnly ? "linear" : p.getString("method");
    out->uncertainty = !linearOnly;
    out->info["input"] = volume.input;
    out->info["description"] = volume.description;
    out->info["grid"] = volume.grid->getName(); // a .vdb's grid, or the name a dense source gets
    out->info["isovalue_source"] = settings.isovalue == volume.isovalue ? volume.isovalueSource : "given";
    // The input's affine (SPEC §10 "Formats"), also the PLY's `comment isouq index_to_world`.
    out->info["index_to_world"] = out->mesh.indexToWorld;
    if (!volume.geometry.empty()) out->info["geometry"] = volume.geometry;
    if (volume.denseBlocks > 0)
        out->info["sparse_blocks"] = {{"dense", volume.denseBlocks}, {"kept", volume.keptBlocks}};
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// err_est and err_bound of every vertex's linear crossing from the six voxels along its edge
/// (SPEC §3), read from the grid; stencil voxels outside the data box are missing (SPEC §1).
void cookErrorEstimate(CookContext& ctx)
{
    const LoadedVolume& volume = inputVolume(ctx);
    auto out = ctx.takeMesh("mesh");
    AttributeTable& a = out->mesh.vertexAttributes;
    const std::size_t n = out->mesh.vertexCount();
    // Add the columns before taking references: adding may move the others.
    a.add<float>(col::kErrEst, n);
    a.add<float>(col::kErrBound, n);
    std::vector<float>& est = *a.find<float>(col::kErrEst);
    std::vector<float>& bound = *a.find<float>(col::kErrBound);
    const auto* ei = a.find<std::int32_t>(col::kEdgeI);
    const auto* ej = a.find<std::int32_t>(col::kEdgeJ);
    const auto* ek = a.find<std::int32_t>(col::kEdgeK);
    const auto* axis = a.find<std::uint8_t>(col::kEdgeAxis);
    const auto* tLinear = a.find<float>(col::kTLinear);
    if (!ei || !ej || !ek || !axis || !tLinear)
        throw std::invalid_argument("input 'mesh' has no edge_i edge_j edge_k edge_axis t_linear (provenance)");
    const auto* hidden = a.find<std::uint8_t>(col::kHidden);

    const openvdb::FloatGrid& grid = *volume.grid;
    const std::optional<openvdb::CoordBBox> bounds = dataBounds(grid);
    const openvdb::Vec3d voxel = grid.voxelSize();

    auto acc = grid.getConstAccessor();
    std::size_t skipped = 0;
    for (std::size_t v = 0; v < n; ++v) {
        if ((hidden && (*hidden)[v]) || (*axis)[v] > 2) {
            est[v] = bound[v] = std::numeric_limits<float>::quiet_NaN();
            ++skipped;
            continue;
        }
        const int ax = (*axis)[v];
        std::array<float, 6> f{};
        std::uint8_t available = 0;
        for (int j = 0; j < 6; ++j) {
            openvdb::Coord c((*ei)[v], (*ej)[v], (*ek)[v]);
            c[ax] += j - 2;
            if (bounds && !bounds->isInside(c)) continue;
            f[j] = acc.getValue(c);
            available |= std::uint8_t(1u << j);
        }
        const LinearError e = linearError(f, available, (*tLinear)[v], float(voxel[ax]));
        est[v] = e.estimate;
        bound[v] = e.bound;
        if (v % 4096 == 0 && openvdb::util::wasInterrupted(ctx.interrupter)) throw InterruptedError();
    }
    if (skipped) ctx.warn("skipped " + std::to_string(skipped) + " refined (hidden) vertices: no edge of the grid");
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// The settings a mesh node used, for operators that continue its work.
MeshSettings settingsOf(const MeshData& m)
{
    MeshSettings settings;
    settings.isovalue = m.isovalue;
    settings.uncertainty = m.uncertainty;
    settings.provenance = true;
    const auto method = edgeMethodFromString(m.method);
    if (!method) throw std::invalid_argument("input 'mesh' must come from a mesh node (its method is " + m.method + ")");
    settings.method = *method;
    return settings;
}

/// Paper sec. 4.2, SPEC §4: the standard mesh plus refined flagged cells and fan patches.
void cookHiddenFeatures(CookContext& ctx)
{
    const LoadedVolume& volume = inputVolume(ctx);
    const MeshData& standard = inputMesh(ctx);
    HiddenFeatureSettings hidden;
    hidden.subdivisions = ctx.parms.getInt("subdivisions");
    hidden.filter = ctx.parms.getBool("filter");
    if (volume.keptBlocks < volume.denseBlocks && !ctx.parms.getBool("filter"))
        ctx.warn("a dense source read with keep=crossing may miss hidden features far from crossings; "
                 "read it with keep=crossing_or_hidden");
    HiddenFeatureStats stats;
    auto out = std::make_shared<MeshData>(standard.withoutMesh());
    MeshTopologyStats before, after;
    if (ctx.ranks) { // this rank's runs of the hidden-feature mesh (docs/mpi.md); the statistics on rank 0
        if (!standard.piece) throw std::invalid_argument("input 'mesh' is not a mesh made by pieces");
        HiddenPiece piece = addHiddenFeaturesByPieces(*volume.grid, standard.mesh, standard.piece->vertexBegin,
            *standard.piece->plan, settingsOf(standard), hidden, *ctx.ranks, ctx.interrupter);
        stats = piece.stats;
        out->mesh = std::move(piece.mesh);
        out->piece = std::make_shared<MeshPiece>(MeshPiece{standard.piece->plan, std::move(piece.vertexBegin),
            std::move(piece.triangleBegin), standard.piece->voxelsRead});
        before = topologyOnRanks(*ctx.ranks, standard.mesh, *standard.piece);
        after = topologyOnRanks(*ctx.ranks, out->mesh, *out->piece);
    } else {
        out->mesh = addHiddenFeatures(*volume.grid, standard.mesh, settingsOf(standard), hidden, &stats, ctx.interrupter);
        before = measureTopology(standard.mesh), after = measureTopology(out->mesh);
    }
    out->info["hidden"] = {{"cells_flagged", stats.cellsFlagged}, {"cells_total", stats.cellsTotal},
        {"fraction", stats.fraction()}, {"cells_refined", stats.cellsRefined},
        {"cells_transition", stats.cellsTransition}, {"components_before", before.components},
        {"components_after", after.components}, {"boundary_edges", after.boundaryEdges},
        {"subdivisions", hidden.subdivisions}, {"filter", hidden.filter}};
    ctx.outputs["mesh"].mesh = std::move(out);
}

/// SPEC §3 measured errors where the field is known (field: and formula: inputs).
void cookTruth(CookContext& ctx)
{
    const LoadedVolume& volume = inputVolume(ctx);
    if (!volume.truth) throw std::invalid_argument("input 'volume' has no exact field (only field: and formula: inputs do)");
    auto out = ctx.takeMesh("mesh");
    TruthSettings settings;
    settings.perMethodDistance = ctx.parms.getBool("per_method_distance");
    TruthReport report = addTruthColumns(out->mesh, *volume.truth, out->isovalue, settings);
    if (ctx.ranks) { // each vertex on its own: a rank's piece gives its vertices' columns, the counts add up
        const Words w = ctx.ranks->sum({report.vertices, report.multiRootEdges, report.noRootEdges, report.failedProjections});
        report.vertices = std::size_t(w[0]);
        report.multiRootEdges = std::size_t(w[1]);
        report.noRootEdges = std::size_t(w[2]);
        report.failedProjections = std::size_t(w[3]);
    }
    if (report.failedProjections)
        ctx.warn(std::to_string(report.failedProjections) + " vertices: the projection on the true surface "
            "did not converge (dist_true is NaN there)");
    out->info["truth"] = {{"multi_root_edges", report.multiRootEdges}, {"no_root_edges", report.noRootEdges},
        {"failed_projections", report.failedProjections}};
    ctx.outputs["mesh"].mesh = std::move(out);
}

} // namespace

void addVolumeNodes(std::vector<NodeType>& types)
{
    types.push_back({"read_volume", "Read Volume",
        "Loads a .vdb grid, a raw scan, a scan with a header (NIfTI, NRRD, TIFF stack, DICOM series), a SPEC §5 "
        "field or a formula as a sparse FloatGrid and decides the isovalue (SPEC §8, §10; docs/inputs.md).",
        {
            parm("input", "Input", ParmType::String, "field:teardrop",
                "FILE.vdb, NAME_XxYxZ_DTYPE.raw, .nii[.gz], .nrrd, .nhdr, .tif[f] or a folder (TIFF slices, one DICOM "
                "series), field:NAME or formula:EXPR",
                "INPUT"),
            parm("grid", "Grid", ParmType::String, nullptr, ".vdb: the float grid to read (unset: the first)", "--grid"),
            ranged(parm("dims", "Dimensions", ParmType::Int3, nullptr, ".raw: X,Y,Z (unset: from the file name)", "--dims"),
                std::nullopt, std::make_pair(1.0, 1.0e6)),
            menuParm("dtype", "Data Type", {"uint8", "uint16", "int16", "float32", "float64"}, nullptr,
                ".raw: sample type (unset: from the file name)", "--dtype"),
            ranged(parm("spacing", "Spacing", ParmType::Vec3, nullptr,
                       ".raw and TIFF: voxel spacing X,Y,Z (unset: 1,1,1, or a TIFF's ImageJ spacing)", "--spacing"),
                std::nullopt, std::make_pair(0.0, kInf)),
            ranged(parm("resolution", "Resolution", ParmType::Int, nullptr,
                       "field:/formula:: samples per axis, both domain ends included (unset: the paper's; 64)",
                       "--resolution,-n"),
                std::make_pair(16.0, 512.0), std::make_pair(2.0, 4096.0)),
            parm("domain", "Domain", ParmType::Vec2, nullptr, "formula:: the cube [LO,HI]^3 (unset: -1,1)", "--domain"),
            parm("isovalue", "Isovalue", ParmType::Float, nullptr,
                "Isovalue k (unset: 0 for level sets, SPEC §5's value for fields, else Otsu's threshold "
                "as a starting value; the value used is reported)",
                "--isovalue,-k"),
            menuParm("keep", "Keep Blocks", {"crossing", "crossing_or_hidden", "non_constant", "all"}, "crossing",
                "Dense sources: which 8^3 blocks stay active (crossing_or_hidden for hidden features; "
                "non_constant to mesh at other isovalues)"),
            parm("allow_empty", "Allow Empty", ParmType::Bool, false,
                "An empty grid (or, with a grid name, an absent one) gives an empty mesh instead of an "
                "error: frames of a simulation cache (docs/sequences.md)"),
        },
        {}, {{"volume", "volume", "The grid, its isovalue and, for fields and formulas, the exact field"}},
        cookReadVolume, /*meshWriter=*/false, /*onRanks=*/true});

    types.push_back({"mesh", "Mesh",
        "Marching cubes on the sparse grid with linear, cubic and WENO crossings and the per-vertex estimates "
        "and method differences (paper sec. 3, 4.1; SPEC §2, §3, §6).",
        {
            menuParm("method", "Method", methodMenu(), "weno", "Method that places the vertices (all are recorded)",
                "--method,-m"),
            parm("isovalue", "Isovalue", ParmType::Float, nullptr,
                "Isovalue k (unset: the volume's; a dense source must be read at the same one)"),
            parm("linear_only", "Linear Only", ParmType::Bool, false, "Linear crossings only, no estimates: fastest",
                "--linear-only"),
            parm("high_order", "High Order", ParmType::Bool, true,
                "Cubic and WENO crossings and their estimates and differences; off (method linear): linear "
                "crossings with err_est and err_bound only, the paper's extraction plus estimate (Blender's "
                "live mode while only those are shown)"),
        },
        {{"volume", "volume", "The volume to mesh"}},
        {{"mesh", "mesh", "Triangles, positions of the chosen method and SPEC §6 attributes"}}, cookMesh,
        /*meshWriter=*/false, /*onRanks=*/true});

    types.push_back({"error_estimate", "Error Estimate",
        "Recomputes the paper's estimate e (err_est) and the standard bound e_b (err_bound) of every vertex's "
        "linear crossing from the grid (paper sec. 4.1, SPEC §3); after a linear-only mesh it adds them.",
        {},
        {{"volume", "volume", "The volume the mesh came from"},
            {"mesh", "mesh", "A mesh with provenance (edge_i edge_j edge_k edge_axis t_linear)"}},
        {{"mesh", "mesh", "The mesh with err_est and err_bound"}}, cookErrorEstimate});

    types.push_back({"hidden_features", "Hidden Features",
        "Refines the cells where the data turns around (slope rule) into m^3 tricubic subcells and patches "
        "transition cells with fans, without cracks (paper sec. 4.2, SPEC §4). Refined vertices have "
        "hidden = 1 and NaN method attributes.",
        {
            ranged(parm("subdivisions", "Subdivisions", ParmType::Int, 4, "m: each refined cell becomes m^3 subcells",
                       "--subdivisions"),
                std::make_pair(2.0, 8.0), std::make_pair(1.0, 64.0)),
            parm("filter", "Filter", ParmType::Bool, true,
                "Refine only where marching cubes cannot see what the tricubic shows (a sign the corners "
                "hide, or how an ambiguous cell's pieces connect): as many reconnections, far fewer cells "
                "and noise bubbles on scans; --no-hidden-filter refines every flagged cell the tricubic "
                "surface passes through (docs/hidden-features.md)",
                "--hidden-filter"),
        },
        {{"volume", "volume", "The volume the mesh came from"},
            {"mesh", "mesh", "The standard mesh, straight from a mesh node"}},
        {{"mesh", "mesh", "The mesh with hidden features and the `hidden` block (components before and after)"}},
        cookHiddenFeatures, /*meshWriter=*/false, /*onRanks=*/true});

    types.push_back({"truth", "Truth",
        "Measured errors against the exact field of a field: or formula: input (SPEC §3): err_true_<method> on "
        "each vertex's edge and dist_true to the true surface.",
        {parm("per_method_distance", "Per-Method Distance", ParmType::Bool, false,
            "Also dist_true_<method> for every method's crossing")},
        {{"volume", "volume", "A field: or formula: volume"}, {"mesh", "mesh", "A mesh of it with provenance"}},
        {{"mesh", "mesh", "The mesh with err_true_* and dist_true"}}, cookTruth, /*meshWriter=*/false, /*onRanks=*/true});
}

} // namespace isouq::nodes::nodes_internal
