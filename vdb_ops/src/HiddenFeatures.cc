// isouq: marching cubes with hidden features (paper sec. 4.2; SPEC §4, §6; docs/hidden-features.md).
//
// Passes, each parallel over a list whose order depends only on the grid:
//   detect:     the cells to refine, R (HiddenDetect.cc);
//   replace:    subcell marching cubes in R, fan patches in the unrefined cells sharing a face or
//               an edge with R, the transition cells T (HiddenPatches.cc);
//   merge:      the standard mesh's triangles of cells outside R and T, then the new triangles;
//               new vertices are keyed by their subcell edge on the fine lattice m * voxel + sub,
//               sorted and shared, so neighbours meet exactly and no hash map is needed.
// Why no cracks: a face shared by R and T is cut by the same subface rule on the same tricubic
// values on both sides; a face of T with a refined edge is cut by the face-consistent rule
// (McTables.h) on the crossings of that edge's subdivision; a face between T and an ordinary
// cell has no refined edge (else that cell would be in T) and is cut exactly as marching cubes
// cuts it. Every crossing is the start of one face segment and the end of another, so the
// segments of a transition cell form closed loops.
#include "HiddenInternal.h"
#include "isouq/Columns.h"

#include "isouq/GridMetadata.h"

#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace isouq {
namespace hidden_internal {
namespace {

using openvdb::Vec3d;

inline Coord times(const Coord& c, int s) { return Coord(c[0] * s, c[1] * s, c[2] * s); }

std::optional<CoordBBox> dataBoundsOf(const openvdb::FloatGrid& grid, const MeshSettings& settings)
{
    if (settings.dataBounds) return settings.dataBounds;
    return dataBounds(grid);
}

/// The standard vertex columns extractWithHiddenFeatures asked for only to merge (SPEC §6
/// provenance, and t_linear, which the mesher writes with it).
bool isProvenanceColumn(const std::string& name)
{
    return name == col::kEdgeI || name == col::kEdgeJ || name == col::kEdgeK || name == col::kEdgeAxis || name == col::kTLinear;
}

/// addHiddenFeatures; without @a keepProvenance the result has no isProvenanceColumn columns.
/// @a standard becomes the result (its storage is reused).
Mesh mergeHiddenFeatures(const openvdb::FloatGrid& grid, Mesh standard, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* statsOut, openvdb::util::NullInterrupter* interrupter,
    bool keepProvenance)
{
    const int m = hidden.subdivisions;
    if (m < 1 || m > kMaxSubdivisions)
        OPENVDB_THROW(openvdb::ValueError, "hidden features: subdivisions must be between 1 and 64 (got "
                                               + std::to_string(m) + ")");
    if (!std::isfinite(settings.isovalue))
        OPENVDB_THROW(openvdb::ValueError, "the isovalue must be a finite number");
    const auto* edgeI = standard.vertexAttributes.find<std::int32_t>(col::kEdgeI);
    const auto* edgeJ = standard.vertexAttributes.find<std::int32_t>(col::kEdgeJ);
    const auto* edgeK = standard.vertexAttributes.find<std::int32_t>(col::kEdgeK);
    const auto* edgeAxis = standard.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis);
    if (!edgeI || !edgeJ || !edgeK || !edgeAxis)
        OPENVDB_THROW(openvdb::ValueError,
            "hidden features: the standard mesh needs provenance (edge_i edge_j edge_k edge_axis)");

    if (interrupter) interrupter->start("Hidden features");
    struct EndGuard {
        openvdb::util::NullInterrupter* i;
        ~EndGuard() { if (i) i->end(); }
    } endGuard{interrupter};

    const float k = settings.isovalue;
    const bool threaded = settings.threaded;
    const openvdb::FloatTree& tree = grid.tree();
    BlockSet blocks;
    mc_internal::buildBlockSet(tree, blocks, threaded, mc_internal::BlockReach::Below);
    throwIfInterrupted(interrupter);

    Detection detection = detectRefinedCells(tree, blocks, k, dataBoundsOf(grid, settings), hidden, threaded,
        interrupter);
    const std::vector<Coord>& refined = detection.refined;
    HiddenFeatureStats stats;
    stats.cellsTotal = detection.cellsTotal;
    stats.cellsFlagged = detection.cellsFlagged;
    stats.cellsRefined = refined.size();

    // Replaced cells: the refined ones and their 18 face and edge neighbours, which are meshed
    // (detection asks that) and so lie in the block set; transition cells are the unrefined ones.
    BlockCells refinedCells(blocks.origins.size()), replacedCells(blocks.origins.size());
    {
        BlockFinder finder(blocks);
        auto mark = [&](BlockCells& cells, const Coord& c) {
            const std::int32_t block = finder.find(c);
            if (block < 0) throw std::logic_error("hidden features: a replaced cell lies outside the block set");
            cells.set(block, BlockFinder::local(c));
        };
        for (const Coord& c : refined) {
            mark(refinedCells, c);
            mark(replacedCells, c);
            for (const auto& d : kFaceEdgeNeighbours) mark(replacedCells, c.offsetBy(d[0], d[1], d[2]));
        }
    }
    std::vector<Coord> transition; // in block order, then x, y, z
    for (std::size_t b = 0; b < blocks.origins.size(); ++b) {
        const auto& replaced = replacedCells.words(std::int32_t(b));
        const auto& refinedWords = refinedCells.words(std::int32_t(b));
        for (int x = 0; x < kBlockDim; ++x)
            for (std::uint64_t bits = replaced[std::size_t(x)] & ~refinedWords[std::size_t(x)]; bits; bits &= bits - 1) {
                const int bit = __builtin_ctzll(bits);
                transition.push_back(blocks.origins[b].offsetBy(x, bit >> 3, bit & 7));
            }
    }
    stats.cellsTransition = transition.size();
    if (statsOut) *statsOut = stats;
    throwIfInterrupted(interrupter);

    Mesh& mesh = standard; // becomes the result in place
    // Last (edgeI and the others point into the columns): the columns the caller did not ask for.
    auto dropProvenance = [&] {
        if (keepProvenance) return;
        auto& columns = mesh.vertexAttributes.columns();
        columns.erase(std::remove_if(columns.begin(), columns.end(),
                          [](const Attribute& a) { return isProvenanceColumn(a.name); }),
            columns.end());
    };
    if (refined.empty()) { // nothing refined: the standard mesh, all of it standard
        dropProvenance();
        mesh.vertexAttributes.add<std::uint8_t>(col::kHidden, mesh.vertexCount());
        mesh.faceAttributes.add<std::uint8_t>(col::kHidden, mesh.triangleCount());
        return std::move(mesh);
    }
    CoordBBox region;
    for (const Coord& c : refined) region.expand(c);
    Packer packer;
    packer.voxelOrigin = region.min().offsetBy(-1);
    packer.fineOrigin = times(packer.voxelOrigin, m);
    for (int i = 0; i < 3; ++i)
        if (std::int64_t(region.dim()[i] + 3) * m >= (std::int64_t(1) << kCoordBits))
            OPENVDB_THROW(openvdb::ValueError, "hidden features: the refined cells span more than 2^20 / "
                                                   + std::to_string(m) + " voxels; use fewer subdivisions");

    ReplacedSurface surface = meshReplacedCells(tree, blocks, refined, refinedCells, transition, packer, m, k,
        threaded, interrupter);
    std::vector<Patch>& patches = surface.patches;
    const std::size_t refinedChunks = surface.refinedChunks;

    // New vertices: subcell-edge crossings, sorted by key and shared (every cell that uses a
    // crossing writes it bit for bit); fineIndex maps each patch's crossing to its vertex.
    std::vector<std::size_t> crossingOffset(patches.size() + 1, 0);
    for (std::size_t c = 0; c < patches.size(); ++c)
        crossingOffset[c + 1] = crossingOffset[c] + patches[c].crossings.size();
    if (crossingOffset.back() > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    std::vector<FineCrossing> fine(crossingOffset.back());
    forEach(patches.size(), 1, threaded, nullptr, [&](std::size_t c) {
        std::vector<FineCrossing>& from = patches[c].crossings;
        for (std::size_t i = 0; i < from.size(); ++i) {
            fine[crossingOffset[c] + i] = from[i];
            fine[crossingOffset[c] + i].slot = std::uint32_t(crossingOffset[c] + i);
        }
        std::vector<FineCrossing>().swap(from);
    });
    auto byKey = [](const FineCrossing& a, const FineCrossing& b) { return a.key < b.key; };
    if (threaded && fine.size() > (std::size_t(1) << 16)) tbb::parallel_sort(fine.begin(), fine.end(), byKey);
    else std::sort(fine.begin(), fine.end(), byKey);
    std::vector<std::uint32_t> fineIndex(fine.size());
    std::size_t fineCount = 0;
    for (std::size_t i = 0; i < fine.size(); ++i) {
        if (i == 0 || fine[i].key != fine[fineCount - 1].key) fine[fineCount++] = fine[i];
        fineIndex[fine[i].slot] = std::uint32_t(fineCount - 1);
    }
    fine.resize(fineCount);

    // Standard triangles of cells outside R and T stay. A standard triangle's cell is the least
    // of its vertices' edge voxels per axis: each edge's lower voxel is at c or c + 1 on every
    // axis, and no triangle of the case tables has its three vertices on one face of its cell
    // (McTables.h), so on every axis some vertex has c.
    constexpr std::size_t kTriangleChunk = 4096;
    std::vector<std::uint8_t> keep(standard.triangleCount(), 1);
    std::vector<std::vector<std::uint32_t>> removedVertices((standard.triangleCount() + kTriangleChunk - 1) / kTriangleChunk);
    forEachChunk(standard.triangleCount(), kTriangleChunk, threaded, interrupter, [&](std::size_t begin, std::size_t end) {
        BlockFinder finder(blocks);
        std::vector<std::uint32_t>& removed = removedVertices[begin / kTriangleChunk];
        for (std::size_t t = begin; t < end; ++t) {
            const openvdb::Vec3I& tri = standard.triangles[t];
            Coord cell((*edgeI)[tri[0]], (*edgeJ)[tri[0]], (*edgeK)[tri[0]]);
            for (int i = 1; i < 3; ++i)
                cell.minComponent(Coord((*edgeI)[tri[i]], (*edgeJ)[tri[i]], (*edgeK)[tri[i]]));
            const std::int32_t block = finder.find(cell);
            if (block < 0 || !replacedCells.test(block, BlockFinder::local(cell))) continue;
            keep[t] = 0;
            removed.insert(removed.end(), {tri[0], tri[1], tri[2]});
        }
    });

    // Standard vertices used by transition loops, found by their grid edge. A transition cell's
    // loops use the standard vertices of its crossing unrefined edges, and its own standard
    // polygon (removed above) has a vertex on every crossing edge: only those are searched.
    std::vector<Ref> coarse;
    for (std::size_t c = refinedChunks; c < patches.size(); ++c)
        for (Ref r : patches[c].members)
            if ((r & kKindMask) == kCoarseRef) coarse.push_back(r);
    std::sort(coarse.begin(), coarse.end());
    coarse.erase(std::unique(coarse.begin(), coarse.end()), coarse.end());
    const std::size_t standardVertices = standard.vertexCount();
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    std::vector<std::uint32_t> coarseVertex(coarse.size(), kNone);
    for (const std::vector<std::uint32_t>& removed : removedVertices)
        for (std::uint32_t v : removed) {
            const Coord voxel((*edgeI)[v], (*edgeJ)[v], (*edgeK)[v]);
            if (!packer.coarseFits(voxel)) continue;
            const Ref key = packer.coarse(voxel, (*edgeAxis)[v]);
            const auto it = std::lower_bound(coarse.begin(), coarse.end(), key);
            if (it != coarse.end() && *it == key) coarseVertex[std::size_t(it - coarse.begin())] = v;
        }
    for (std::uint32_t v : coarseVertex)
        if (v == kNone) throw std::logic_error("hidden features: a transition cell's grid edge has no standard vertex");

    // Vertex numbering: used standard vertices in their order, then fine vertices, then centres.
    std::vector<std::uint32_t> remap(standardVertices, 0);
    for (std::size_t t = 0; t < keep.size(); ++t)
        if (keep[t])
            for (int i = 0; i < 3; ++i) remap[standard.triangles[t][i]] = 1;
    for (std::uint32_t v : coarseVertex) remap[v] = 1;
    std::vector<std::uint32_t> kept;
    for (std::size_t v = 0; v < standardVertices; ++v) {
        remap[v] = remap[v] ? std::uint32_t(kept.size()) : kNone;
        if (remap[v] != kNone) kept.push_back(std::uint32_t(v));
    }
    std::size_t keptTriangles = keep.size();
    for (const std::vector<std::uint32_t>& removed : removedVertices) keptTriangles -= removed.size() / 3;
    std::vector<std::size_t> centreOffset(patches.size() + 1, 0), triangleOffset(patches.size() + 1, 0);
    triangleOffset[0] = keptTriangles;
    for (std::size_t c = 0; c < patches.size(); ++c) {
        centreOffset[c + 1] = centreOffset[c] + patches[c].memberEnds.size();
        triangleOffset[c + 1] = triangleOffset[c] + patches[c].triangles.size();
    }
    const std::size_t fineBase = kept.size(), centreBase = fineBase + fine.size();
    const std::size_t vertexCount = centreBase + centreOffset.back();
    if (vertexCount > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    auto indexOf = [&](Ref r, std::size_t chunk) -> std::uint32_t {
        switch (r & kKindMask) {
        case kFineRef: return std::uint32_t(fineBase + fineIndex[crossingOffset[chunk] + std::size_t(r)]);
        case kCoarseRef:
            return remap[coarseVertex[std::size_t(std::lower_bound(coarse.begin(), coarse.end(), r) - coarse.begin())]];
        default: return std::uint32_t(centreBase + centreOffset[chunk] + std::size_t(r & ~kKindMask));
        }
    };

    // In place: kept vertices and triangles (and their columns) move down in order (kept[i] >= i,
    // and a kept triangle's new index is at most its old one), then the new ones follow.
    // Positions: standard, then fine (index space (P + t e_axis) / m), then fan centres.
    for (std::size_t i = 0; i < kept.size(); ++i) mesh.positions[i] = mesh.positions[kept[i]];
    mesh.positions.resize(vertexCount);
    const openvdb::math::Transform& xform = grid.transform();
    forEach(fine.size(), 4096, threaded, nullptr, [&](std::size_t i) {
        const Coord p = packer.finePoint(fine[i].key);
        Vec3d index(p[0], p[1], p[2]);
        index[Packer::axisOf(fine[i].key)] += double(fine[i].t);
        mesh.positions[fineBase + i] = openvdb::Vec3s(xform.indexToWorld(index / double(m)));
    });
    // Triangles: kept standard ones, then refined cells', then transition cells'.
    const bool levelSet = grid.getGridClass() == openvdb::GRID_LEVEL_SET;
    const bool flip = settings.orientation == Orientation::TowardsHigher ||
                      (settings.orientation == Orientation::Auto && levelSet);
    for (std::size_t t = 0, n = 0; t < keep.size(); ++t) {
        if (!keep[t]) continue;
        const openvdb::Vec3I tri = mesh.triangles[t];
        mesh.triangles[n++] = openvdb::Vec3I(remap[tri[0]], remap[tri[1]], remap[tri[2]]);
    }
    mesh.triangles.resize(triangleOffset.back());
    forEach(patches.size(), 1, threaded, nullptr, [&](std::size_t c) {
        const Patch& p = patches[c];
        openvdb::Vec3I* out = mesh.triangles.data() + triangleOffset[c];
        for (const auto& tri : p.triangles) {
            const std::uint32_t a = indexOf(tri[0], c), b = indexOf(tri[1], c), d = indexOf(tri[2], c);
            *out++ = flip ? openvdb::Vec3I(a, d, b) : openvdb::Vec3I(a, b, d);
        }
        for (std::size_t l = 0; l < p.memberEnds.size(); ++l) {
            const std::uint32_t begin = l == 0 ? 0 : p.memberEnds[l - 1], end = p.memberEnds[l];
            Vec3d sum(0.0);
            for (std::uint32_t j = begin; j < end; ++j) sum += Vec3d(mesh.positions[indexOf(p.members[j], c)]);
            mesh.positions[centreBase + centreOffset[c] + l] = openvdb::Vec3s(sum / double(end - begin));
        }
    });

    // Attributes (SPEC §6): standard columns copied; refined vertices as the header documents.
    for (Attribute& column : mesh.vertexAttributes.columns()) {
        if (!keepProvenance && isProvenanceColumn(column.name)) continue;
        std::visit([&](auto& dst) {
            using T = typename std::decay_t<decltype(dst)>::value_type;
            for (std::size_t i = 0; i < kept.size(); ++i) dst[i] = dst[kept[i]];
            dst.resize(vertexCount);
            T fill{};
            if constexpr (std::is_floating_point_v<T>) fill = std::numeric_limits<T>::quiet_NaN();
            std::fill(dst.begin() + std::ptrdiff_t(fineBase), dst.end(), fill);
        }, column.data);
    }
    if (auto* ei = keepProvenance ? mesh.vertexAttributes.find<std::int32_t>(col::kEdgeI) : nullptr) {
        auto& ej = *mesh.vertexAttributes.find<std::int32_t>(col::kEdgeJ);
        auto& ek = *mesh.vertexAttributes.find<std::int32_t>(col::kEdgeK);
        auto& ea = *mesh.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis);
        auto floorDiv = [m](int v) { return v >= 0 ? v / m : -((-v + m - 1) / m); };
        for (std::size_t i = 0; i < fine.size(); ++i) {
            const Coord p = packer.finePoint(fine[i].key);
            (*ei)[fineBase + i] = floorDiv(p[0]);
            ej[fineBase + i] = floorDiv(p[1]);
            ek[fineBase + i] = floorDiv(p[2]);
            ea[fineBase + i] = std::uint8_t(Packer::axisOf(fine[i].key));
        }
        for (std::size_t c = refinedChunks; c < patches.size(); ++c)
            for (std::size_t l = 0; l < patches[c].memberEnds.size(); ++l) {
                const std::size_t v = centreBase + centreOffset[c] + l;
                const Coord& cell = patches[c].centreCells[l];
                (*ei)[v] = cell[0];
                ej[v] = cell[1];
                ek[v] = cell[2];
                ea[v] = 255;
            }
    }
    auto& hiddenVertex = mesh.vertexAttributes.add<std::uint8_t>(col::kHidden, vertexCount);
    std::fill(hiddenVertex.begin() + std::ptrdiff_t(fineBase), hiddenVertex.end(), std::uint8_t(1));
    for (Attribute& column : mesh.faceAttributes.columns()) {
        std::visit([&](auto& dst) {
            using T = typename std::decay_t<decltype(dst)>::value_type;
            for (std::size_t t = 0, f = 0; t < keep.size(); ++t)
                if (keep[t]) dst[f++] = dst[t];
            dst.resize(mesh.triangleCount());
            std::fill(dst.begin() + std::ptrdiff_t(keptTriangles), dst.end(), T{});
        }, column.data);
    }
    auto& hiddenFace = mesh.faceAttributes.add<std::uint8_t>(col::kHidden, mesh.triangleCount());
    std::fill(hiddenFace.begin() + std::ptrdiff_t(keptTriangles), hiddenFace.end(), std::uint8_t(1));
    dropProvenance();
    return std::move(mesh);
}

} // namespace
} // namespace hidden_internal

Mesh addHiddenFeatures(const openvdb::FloatGrid& grid, const Mesh& standard, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* stats, openvdb::util::NullInterrupter* interrupter)
{
    return hidden_internal::mergeHiddenFeatures(grid, Mesh(standard), settings, hidden, stats, interrupter, true);
}

Mesh extractWithHiddenFeatures(const openvdb::FloatGrid& grid, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* stats, openvdb::util::NullInterrupter* interrupter)
{
    if (hidden.subdivisions < 1 || hidden.subdivisions > hidden_internal::kMaxSubdivisions)
        OPENVDB_THROW(openvdb::ValueError, "hidden features: subdivisions must be between 1 and 64 (got "
                                               + std::to_string(hidden.subdivisions) + ")");
    MeshSettings withProvenance = settings;
    withProvenance.provenance = true;
    Mesh standard = extractIsosurface(grid, withProvenance, interrupter);
    // The columns the caller asked for (the mesher writes t_linear with provenance).
    return hidden_internal::mergeHiddenFeatures(grid, std::move(standard), settings, hidden, stats, interrupter,
        settings.provenance || settings.uncertainty);
}

} // namespace isouq
