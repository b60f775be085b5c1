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
// By pieces (MPI ranks; SPEC §9, §10): addHiddenFeaturesByPieces runs the same passes on each
// piece's blocks, the lists of refined cells and of fine keys shared, and the result's
// sections cut into one run per piece (docs/mpi.md "Hidden features").
#include "HiddenInternal.h"
#include "isouq/Columns.h"

#include "isouq/Bricks.h"
#include "isouq/GridMetadata.h"
#include "Stage.h"

#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <cstring>
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

/// Removes the isProvenanceColumn columns (the caller did not ask for them).
void dropProvenance(Mesh& mesh)
{
    auto& columns = mesh.vertexAttributes.columns();
    columns.erase(std::remove_if(columns.begin(), columns.end(), [](const Attribute& a) { return isProvenanceColumn(a.name); }),
        columns.end());
}

void checkHiddenSettings(int m, float isovalue)
{
    if (m < 1 || m > kMaxSubdivisions)
        OPENVDB_THROW(openvdb::ValueError, "hidden features: subdivisions must be between 1 and 64 (got "
                                               + std::to_string(m) + ")");
    if (!std::isfinite(isovalue)) OPENVDB_THROW(openvdb::ValueError, "the isovalue must be a finite number");
}

/// Marks @a refined and their 18 face and edge neighbours (which are meshed, detection asks
/// that, and so lie in the block set) as replaced.
void markReplaced(const BlockSet& blocks, const std::vector<Coord>& refined, BlockCells& refinedCells,
    BlockCells& replacedCells)
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

/// The transition cells (replaced, not refined) of the blocks [begin, end), in block order, then
/// x, y, z.
std::vector<Coord> transitionCells(const BlockSet& blocks, const BlockCells& refinedCells,
    const BlockCells& replacedCells, std::size_t begin, std::size_t end)
{
    std::vector<Coord> transition;
    for (std::size_t b = begin; b < end; ++b) {
        const auto& replaced = replacedCells.words(std::int32_t(b));
        const auto& refinedWords = refinedCells.words(std::int32_t(b));
        for (int x = 0; x < kBlockDim; ++x)
            for (std::uint64_t bits = replaced[std::size_t(x)] & ~refinedWords[std::size_t(x)]; bits; bits &= bits - 1) {
                const int bit = __builtin_ctzll(bits);
                transition.push_back(blocks.origins[b].offsetBy(x, bit >> 3, bit & 7));
            }
    }
    return transition;
}

/// The keys of the region of @a refined (not empty).
Packer packerOf(const std::vector<Coord>& refined, int m)
{
    CoordBBox region;
    for (const Coord& c : refined) region.expand(c);
    Packer packer;
    packer.voxelOrigin = region.min().offsetBy(-1);
    packer.fineOrigin = times(packer.voxelOrigin, m);
    for (int i = 0; i < 3; ++i)
        if (std::int64_t(region.dim()[i] + 3) * m >= (std::int64_t(1) << kCoordBits))
            OPENVDB_THROW(openvdb::ValueError, "hidden features: the refined cells span more than 2^20 / "
                                                   + std::to_string(m) + " voxels; use fewer subdivisions");
    return packer;
}

/// The patches' subcell-edge crossings, sorted by key and shared (every cell that uses a
/// crossing writes it bit for bit): crossing i of patch c is fine[fineIndex[crossingOffset[c]
/// + i]]. The patches' crossing lists are emptied.
struct FineNumbering {
    std::vector<std::size_t> crossingOffset;
    std::vector<FineCrossing> fine;
    std::vector<std::uint32_t> fineIndex;
};
FineNumbering numberFine(std::vector<Patch>& patches, bool threaded)
{
    FineNumbering out;
    std::vector<std::size_t>& crossingOffset = out.crossingOffset;
    crossingOffset.assign(patches.size() + 1, 0);
    for (std::size_t c = 0; c < patches.size(); ++c)
        crossingOffset[c + 1] = crossingOffset[c] + patches[c].crossings.size();
    if (crossingOffset.back() > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    std::vector<FineCrossing>& fine = out.fine;
    fine.resize(crossingOffset.back());
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
    out.fineIndex.resize(fine.size());
    std::size_t fineCount = 0;
    for (std::size_t i = 0; i < fine.size(); ++i) {
        if (i == 0 || fine[i].key != fine[fineCount - 1].key) fine[fineCount++] = fine[i];
        out.fineIndex[fine[i].slot] = std::uint32_t(fineCount - 1);
    }
    fine.resize(fineCount);
    return out;
}

/// The position of a fine crossing: (P + t e_axis) / m in index space, to world.
openvdb::Vec3s finePosition(const Packer& packer, const FineCrossing& f, const openvdb::math::Transform& xform, int m)
{
    const Coord p = packer.finePoint(f.key);
    Vec3d index(p[0], p[1], p[2]);
    index[Packer::axisOf(f.key)] += double(f.t);
    return openvdb::Vec3s(xform.indexToWorld(index / double(m)));
}

/// Which standard triangles stay (those of cells outside the replaced ones), and the vertices of
/// the others per chunk of kTriangleChunk triangles. @a edgeOf(v) is vertex v's grid edge (its
/// lower voxel and axis). A standard triangle's cell is the least of its vertices' edge voxels
/// per axis: each edge's lower voxel is at c or c + 1 on every axis, and no triangle of the case
/// tables has its three vertices on one face of its cell (McTables.h), so on every axis some
/// vertex has c.
constexpr std::size_t kTriangleChunk = 4096;
struct KeptTriangles {
    std::vector<std::uint8_t> keep;
    std::vector<std::vector<std::uint32_t>> removedVertices;
    std::size_t keptCount() const
    {
        std::size_t n = keep.size();
        for (const std::vector<std::uint32_t>& removed : removedVertices) n -= removed.size() / 3;
        return n;
    }
};
template <typename EdgeOf>
KeptTriangles keepTriangles(const std::vector<openvdb::Vec3I>& triangles, const EdgeOf& edgeOf, const BlockSet& blocks,
    const BlockCells& replacedCells, bool threaded, openvdb::util::NullInterrupter* interrupter)
{
    KeptTriangles out;
    out.keep.assign(triangles.size(), 1);
    out.removedVertices.resize((triangles.size() + kTriangleChunk - 1) / kTriangleChunk);
    forEachChunk(triangles.size(), kTriangleChunk, threaded, interrupter, [&](std::size_t begin, std::size_t end) {
        BlockFinder finder(blocks);
        std::vector<std::uint32_t>& removed = out.removedVertices[begin / kTriangleChunk];
        for (std::size_t t = begin; t < end; ++t) {
            const openvdb::Vec3I& tri = triangles[t];
            Coord cell = edgeOf(tri[0]).first;
            for (int i = 1; i < 3; ++i) cell.minComponent(edgeOf(tri[i]).first);
            const std::int32_t block = finder.find(cell);
            if (block < 0 || !replacedCells.test(block, BlockFinder::local(cell))) continue;
            out.keep[t] = 0;
            removed.insert(removed.end(), {tri[0], tri[1], tri[2]});
        }
    });
    return out;
}

/// Standard vertices used by transition loops, found by their grid edge: coarseVertex[i] is the
/// vertex of coarse[i]. A transition cell's loops use the standard vertices of its crossing
/// unrefined edges, and its own standard polygon (removed) has a vertex on every crossing edge:
/// only those are searched.
struct CoarseVertices {
    std::vector<Ref> coarse;
    std::vector<std::uint32_t> coarseVertex;
    std::uint32_t of(Ref r) const
    {
        return coarseVertex[std::size_t(std::lower_bound(coarse.begin(), coarse.end(), r) - coarse.begin())];
    }
};
template <typename EdgeOf>
CoarseVertices findCoarse(const ReplacedSurface& surface, const KeptTriangles& triangles, const EdgeOf& edgeOf,
    const Packer& packer)
{
    CoarseVertices out;
    std::vector<Ref>& coarse = out.coarse;
    for (std::size_t c = surface.refinedChunks; c < surface.patches.size(); ++c)
        for (Ref r : surface.patches[c].members)
            if ((r & kKindMask) == kCoarseRef) coarse.push_back(r);
    std::sort(coarse.begin(), coarse.end());
    coarse.erase(std::unique(coarse.begin(), coarse.end()), coarse.end());
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    out.coarseVertex.assign(coarse.size(), kNone);
    for (const std::vector<std::uint32_t>& removed : triangles.removedVertices)
        for (std::uint32_t v : removed) {
            const std::pair<Coord, int> edge = edgeOf(v);
            if (!packer.coarseFits(edge.first)) continue;
            const Ref key = packer.coarse(edge.first, edge.second);
            const auto it = std::lower_bound(coarse.begin(), coarse.end(), key);
            if (it != coarse.end() && *it == key) out.coarseVertex[std::size_t(it - coarse.begin())] = v;
        }
    for (std::uint32_t v : out.coarseVertex)
        if (v == kNone) throw std::logic_error("hidden features: a transition cell's grid edge has no standard vertex");
    return out;
}

/// Whether new triangles are flipped, as standard MC flips them.
bool flips(const openvdb::FloatGrid& grid, const MeshSettings& settings)
{
    return settings.orientation == Orientation::TowardsHigher ||
           (settings.orientation == Orientation::Auto && grid.getGridClass() == openvdb::GRID_LEVEL_SET);
}

/// The hidden-feature mesh from @a mesh, the standard mesh (or a piece of it), which becomes the
/// result in place: its vertices @a kept (ascending) in order, then @a fine, then the fan centres
/// of @a surface (centreOffset[c] before patch c's); its kept triangles (@a remap gives a
/// standard vertex's index in the result), then the patches' triangles (@a indexOf gives a
/// Ref's, @a positionOf a loop member's position from the result's positions so far).
template <typename Remap, typename IndexOf, typename PositionOf>
Mesh assembleHidden(Mesh mesh, const std::vector<std::uint32_t>& kept, const KeptTriangles& keptTriangles,
    const Remap& remap, const std::vector<FineCrossing>& fine, const ReplacedSurface& surface,
    const std::vector<std::size_t>& centreOffset, const IndexOf& indexOf, const PositionOf& positionOf,
    const Packer& packer, int m, const openvdb::math::Transform& xform, bool flip, bool keepProvenance, bool threaded)
{
    const std::vector<Patch>& patches = surface.patches;
    const std::vector<std::uint8_t>& keep = keptTriangles.keep;
    const std::size_t keptTriangleCount = keptTriangles.keptCount();
    std::vector<std::size_t> triangleOffset(patches.size() + 1, 0);
    triangleOffset[0] = keptTriangleCount;
    for (std::size_t c = 0; c < patches.size(); ++c) triangleOffset[c + 1] = triangleOffset[c] + patches[c].triangles.size();
    const std::size_t fineBase = kept.size(), centreBase = fineBase + fine.size();
    const std::size_t vertexCount = centreBase + centreOffset.back();

    // In place: kept vertices and triangles (and their columns) move down in order (kept[i] >= i,
    // and a kept triangle's new index is at most its old one), then the new ones follow.
    // Positions: standard, then fine (index space (P + t e_axis) / m), then fan centres.
    for (std::size_t i = 0; i < kept.size(); ++i) mesh.positions[i] = mesh.positions[kept[i]];
    mesh.positions.resize(vertexCount);
    forEach(fine.size(), 4096, threaded, nullptr,
        [&](std::size_t i) { mesh.positions[fineBase + i] = finePosition(packer, fine[i], xform, m); });
    // Triangles: kept standard ones, then refined cells', then transition cells'.
    for (std::size_t t = 0, n = 0; t < keep.size(); ++t) {
        if (!keep[t]) continue;
        const openvdb::Vec3I tri = mesh.triangles[t];
        mesh.triangles[n++] = openvdb::Vec3I(remap(tri[0]), remap(tri[1]), remap(tri[2]));
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
            for (std::uint32_t j = begin; j < end; ++j) sum += Vec3d(positionOf(p.members[j], c, mesh.positions));
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
        for (std::size_t c = surface.refinedChunks; c < patches.size(); ++c)
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
            std::fill(dst.begin() + std::ptrdiff_t(keptTriangleCount), dst.end(), T{});
        }, column.data);
    }
    auto& hiddenFace = mesh.faceAttributes.add<std::uint8_t>(col::kHidden, mesh.triangleCount());
    std::fill(hiddenFace.begin() + std::ptrdiff_t(keptTriangleCount), hiddenFace.end(), std::uint8_t(1));
    if (!keepProvenance) dropProvenance(mesh);
    return mesh;
}

/// Nothing refined: the standard mesh, all of it standard.
Mesh allStandard(Mesh mesh, bool keepProvenance)
{
    if (!keepProvenance) dropProvenance(mesh);
    mesh.vertexAttributes.add<std::uint8_t>(col::kHidden, mesh.vertexCount());
    mesh.faceAttributes.add<std::uint8_t>(col::kHidden, mesh.triangleCount());
    return mesh;
}

/// addHiddenFeatures; without @a keepProvenance the result has no isProvenanceColumn columns.
/// @a standard becomes the result (its storage is reused).
Mesh mergeHiddenFeatures(const openvdb::FloatGrid& grid, Mesh standard, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, HiddenFeatureStats* statsOut, openvdb::util::NullInterrupter* interrupter,
    bool keepProvenance)
{
    const int m = hidden.subdivisions;
    checkHiddenSettings(m, settings.isovalue);
    const auto* edgeI = standard.vertexAttributes.find<std::int32_t>(col::kEdgeI);
    const auto* edgeJ = standard.vertexAttributes.find<std::int32_t>(col::kEdgeJ);
    const auto* edgeK = standard.vertexAttributes.find<std::int32_t>(col::kEdgeK);
    const auto* edgeAxis = standard.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis);
    if (!edgeI || !edgeJ || !edgeK || !edgeAxis)
        OPENVDB_THROW(openvdb::ValueError,
            "hidden features: the standard mesh needs provenance (edge_i edge_j edge_k edge_axis)");

    const InterrupterStage stage(interrupter, "Hidden features");

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

    // Replaced cells: the refined ones and their 18 face and edge neighbours; transition cells
    // are the unrefined ones.
    BlockCells refinedCells(blocks.origins.size()), replacedCells(blocks.origins.size());
    markReplaced(blocks, refined, refinedCells, replacedCells);
    const std::vector<Coord> transition = transitionCells(blocks, refinedCells, replacedCells, 0, blocks.origins.size());
    stats.cellsTransition = transition.size();
    if (statsOut) *statsOut = stats;
    throwIfInterrupted(interrupter);

    if (refined.empty()) return allStandard(std::move(standard), keepProvenance);
    const Packer packer = packerOf(refined, m);

    ReplacedSurface surface = meshReplacedCells(tree, blocks, refined, refinedCells, transition, packer, m, k,
        threaded, interrupter);
    std::vector<Patch>& patches = surface.patches;

    // New vertices: subcell-edge crossings, sorted by key and shared.
    const FineNumbering fineNumbering = numberFine(patches, threaded);
    const std::vector<std::size_t>& crossingOffset = fineNumbering.crossingOffset;
    const std::vector<FineCrossing>& fine = fineNumbering.fine;
    const std::vector<std::uint32_t>& fineIndex = fineNumbering.fineIndex;

    // Standard triangles of cells outside R and T stay; transition loops use standard vertices.
    const auto edgeOf = [&](std::uint32_t v) {
        return std::make_pair(Coord((*edgeI)[v], (*edgeJ)[v], (*edgeK)[v]), int((*edgeAxis)[v]));
    };
    const KeptTriangles keptTriangles = keepTriangles(standard.triangles, edgeOf, blocks, replacedCells, threaded,
        interrupter);
    const std::vector<std::uint8_t>& keep = keptTriangles.keep;
    const CoarseVertices coarse = findCoarse(surface, keptTriangles, edgeOf, packer);
    const std::size_t standardVertices = standard.vertexCount();
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

    // Vertex numbering: used standard vertices in their order, then fine vertices, then centres.
    std::vector<std::uint32_t> remap(standardVertices, 0);
    for (std::size_t t = 0; t < keep.size(); ++t)
        if (keep[t])
            for (int i = 0; i < 3; ++i) remap[standard.triangles[t][i]] = 1;
    for (std::uint32_t v : coarse.coarseVertex) remap[v] = 1;
    std::vector<std::uint32_t> kept;
    for (std::size_t v = 0; v < standardVertices; ++v) {
        remap[v] = remap[v] ? std::uint32_t(kept.size()) : kNone;
        if (remap[v] != kNone) kept.push_back(std::uint32_t(v));
    }
    std::vector<std::size_t> centreOffset(patches.size() + 1, 0);
    for (std::size_t c = 0; c < patches.size(); ++c) centreOffset[c + 1] = centreOffset[c] + patches[c].memberEnds.size();
    const std::size_t fineBase = kept.size(), centreBase = fineBase + fine.size();
    if (centreBase + centreOffset.back() > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    const auto indexOf = [&](Ref r, std::size_t chunk) -> std::uint32_t {
        switch (r & kKindMask) {
        case kFineRef: return std::uint32_t(fineBase + fineIndex[crossingOffset[chunk] + std::size_t(r)]);
        case kCoarseRef: return remap[coarse.of(r)];
        default: return std::uint32_t(centreBase + centreOffset[chunk] + std::size_t(r & ~kKindMask));
        }
    };
    // A loop member's position: a fine vertex's or a kept standard vertex's, already in place.
    const auto positionOf = [&](Ref r, std::size_t chunk, const std::vector<openvdb::Vec3s>& positions) {
        return positions[indexOf(r, chunk)];
    };
    return assembleHidden(std::move(standard), kept, keptTriangles, [&](std::uint32_t v) { return remap[v]; }, fine,
        surface, centreOffset, indexOf, positionOf, packer, m, grid.transform(), flips(grid, settings), keepProvenance,
        threaded);
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

// ---- By pieces (SPEC §9, §10 "MPI"; docs/mpi.md) -----------------------------------------------

HiddenPiece addHiddenFeaturesByPieces(const openvdb::FloatGrid& grid, const Mesh& standard,
    const std::vector<std::uint64_t>& standardBegin, const BrickPlan& plan, const MeshSettings& settings,
    const HiddenFeatureSettings& hidden, const PieceComm& comm, openvdb::util::NullInterrupter* interrupter)
{
    using namespace hidden_internal;
    using Words = PieceComm::Words;
    constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
    const int pieces = comm.size(), piece = comm.rank(), m = hidden.subdivisions;
    const float k = settings.isovalue;
    const bool threaded = settings.threaded;
    const openvdb::FloatTree& tree = grid.tree();
    const std::uint64_t v0 = standardBegin[std::size_t(piece)];
    const std::size_t nLocal = standard.vertexCount();
    const auto* edgeI = standard.vertexAttributes.find<std::int32_t>(col::kEdgeI);
    const auto* edgeJ = standard.vertexAttributes.find<std::int32_t>(col::kEdgeJ);
    const auto* edgeK = standard.vertexAttributes.find<std::int32_t>(col::kEdgeK);
    const auto* edgeAxis = standard.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis);
    const auto ownerOf = [&](std::uint64_t v) {
        return int(std::upper_bound(standardBegin.begin(), standardBegin.end(), v) - standardBegin.begin()) - 1;
    };
    const auto own = [&](std::uint64_t v) { return v >= v0 && v < v0 + nLocal; };
    HiddenPiece out;
    HiddenFeatureStats& stats = out.stats;

    // Detection on this piece's blocks: a run of the plan's order, and so of the block set's
    // (the same order of a tree over fewer blocks). The refined cells of every piece, in piece
    // order, are the one-process list.
    BlockSet blocks;
    std::size_t first = 0, last = 0;
    Detection detection;
    comm.agree([&] {
        checkHiddenSettings(m, k);
        if (!edgeI || !edgeJ || !edgeK || !edgeAxis)
            OPENVDB_THROW(openvdb::ValueError,
                "hidden features: the standard mesh needs provenance (edge_i edge_j edge_k edge_axis)");
        if (standardBegin.size() != std::size_t(pieces) + 1)
            OPENVDB_THROW(openvdb::ValueError, "hidden features: the standard mesh must be a BrickMesher piece");
        mc_internal::buildBlockSet(tree, blocks, threaded, mc_internal::BlockReach::Below);
        first = blocks.origins.size();
        for (std::size_t b = 0; b < blocks.origins.size(); ++b)
            if (plan.pieceOfCell(blocks.origins[b]) == piece) first = std::min(first, b), last = b + 1;
        first = std::min(first, last);
        detection = detectRefinedCells(tree, blocks, k, dataBoundsOf(grid, settings), hidden, threaded, interrupter,
            first, last);
    });
    Words found = {detection.cellsTotal, detection.cellsFlagged};
    for (const Coord& c : detection.refined)
        for (int a = 0; a < 3; ++a) found.push_back(std::uint64_t(std::int64_t(c[a])));
    std::vector<Coord> refined;
    for (const Words& w : comm.allgather(found)) {
        stats.cellsTotal += std::size_t(w[0]);
        stats.cellsFlagged += std::size_t(w[1]);
        for (std::size_t i = 2; i < w.size(); i += 3)
            refined.emplace_back(int(std::int64_t(w[i])), int(std::int64_t(w[i + 1])), int(std::int64_t(w[i + 2])));
    }
    stats.cellsRefined = refined.size();
    // Section s of piece p holds the rows [begin[s P + p], begin[s P + p + 1]).
    const auto layout = [&](const std::vector<Words>& counts, std::size_t sections, std::size_t at) {
        std::vector<std::uint64_t> begin(sections * std::size_t(pieces) + 1, 0);
        for (std::size_t s = 0; s < sections; ++s)
            for (int p = 0; p < pieces; ++p) {
                const std::size_t i = s * std::size_t(pieces) + std::size_t(p);
                begin[i + 1] = begin[i] + counts[std::size_t(p)][at + s];
            }
        return begin;
    };
    if (refined.empty()) { // nothing refined: the standard mesh, all of it standard
        const std::vector<Words> counts = comm.allgather({nLocal, 0, 0, standard.triangleCount(), 0, 0});
        out.vertexBegin = layout(counts, 3, 0);
        out.triangleBegin = layout(counts, 3, 3);
        out.mesh = allStandard(standard, /*keepProvenance=*/true);
        return out;
    }

    // The refined cells that are, or touch, this piece's cells; the transition cells of its blocks.
    BlockCells refinedCells(blocks.origins.size()), replacedCells(blocks.origins.size());
    std::vector<Coord> transition;
    Packer packer;
    ReplacedSurface surface;
    FineNumbering numbering;
    comm.agree([&] {
        std::vector<Coord> near;
        for (const Coord& c : refined) {
            bool touches = plan.pieceOfCell(c) == piece;
            for (const auto& d : kFaceEdgeNeighbours) touches = touches || plan.pieceOfCell(c.offsetBy(d[0], d[1], d[2])) == piece;
            if (touches) near.push_back(c);
        }
        markReplaced(blocks, near, refinedCells, replacedCells);
        transition = transitionCells(blocks, refinedCells, replacedCells, first, last);
        packer = packerOf(refined, m);
        surface = meshReplacedCells(tree, blocks, detection.refined, refinedCells, transition, packer, m, k, threaded,
            interrupter);
        numbering = numberFine(surface.patches, threaded);
    });
    const std::vector<FineCrossing>& fine = numbering.fine;

    // Fine vertices: every piece's keys, sorted and shared; piece p writes the vertices
    // [N p / P, N (p + 1) / P) of the N, with the t that the pieces that made them send.
    std::vector<Ref> keys;
    {
        Words mine;
        for (const FineCrossing& f : fine) mine.push_back(f.key);
        for (const Words& w : comm.allgather(mine)) keys.insert(keys.end(), w.begin(), w.end());
    }
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    std::vector<std::uint64_t> fineBegin(std::size_t(pieces) + 1);
    for (int p = 0; p <= pieces; ++p) fineBegin[std::size_t(p)] = std::uint64_t(keys.size()) * std::uint64_t(p) / std::uint64_t(pieces);
    std::vector<std::uint32_t> fineGlobal(fine.size());
    std::vector<Words> sent(static_cast<std::size_t>(pieces));
    for (std::size_t i = 0; i < fine.size(); ++i) {
        const std::uint64_t g = std::uint64_t(std::lower_bound(keys.begin(), keys.end(), fine[i].key) - keys.begin());
        fineGlobal[i] = std::uint32_t(g);
        const int to = int(std::upper_bound(fineBegin.begin(), fineBegin.end(), g) - fineBegin.begin()) - 1;
        sent[std::size_t(to)].insert(sent[std::size_t(to)].end(), {g, bitsOf(fine[i].t)});
    }
    std::vector<FineCrossing> fineRows(fineBegin[std::size_t(piece) + 1] - fineBegin[std::size_t(piece)]);
    for (const Words& w : comm.exchange(sent))
        for (std::size_t i = 0; i < w.size(); i += 2)
            fineRows[std::size_t(w[i] - fineBegin[std::size_t(piece)])] = {keys[std::size_t(w[i])], floatOf(w[i + 1]), 0};

    // Ghosts: the vertices of later pieces that this piece's triangles use, with their grid edges
    // and positions.
    std::vector<std::uint32_t> ghosts;
    for (const openvdb::Vec3I& t : standard.triangles)
        for (int c = 0; c < 3; ++c)
            if (!own(t[c])) ghosts.push_back(t[c]);
    std::sort(ghosts.begin(), ghosts.end());
    ghosts.erase(std::unique(ghosts.begin(), ghosts.end()), ghosts.end());
    std::vector<Words> asks(static_cast<std::size_t>(pieces));
    for (std::uint32_t g : ghosts) asks[std::size_t(ownerOf(g))].push_back(g);
    const std::vector<Words> asked = comm.exchange(asks);
    std::vector<Words> answers(static_cast<std::size_t>(pieces));
    for (int r = 0; r < pieces; ++r)
        for (std::uint64_t g : asked[std::size_t(r)]) {
            const std::size_t v = std::size_t(g - v0);
            std::uint64_t position[2] = {0, 0};
            std::memcpy(position, standard.positions[v].asPointer(), 12);
            answers[std::size_t(r)].insert(answers[std::size_t(r)].end(), {std::uint64_t(std::int64_t((*edgeI)[v])),
                std::uint64_t(std::int64_t((*edgeJ)[v])), std::uint64_t(std::int64_t((*edgeK)[v])), (*edgeAxis)[v],
                position[0], position[1]});
        }
    std::vector<std::pair<Coord, int>> ghostEdges(ghosts.size());
    std::vector<openvdb::Vec3s> ghostPositions(ghosts.size());
    const auto ghostOf = [&](std::uint64_t g) {
        return std::size_t(std::lower_bound(ghosts.begin(), ghosts.end(), std::uint32_t(g)) - ghosts.begin());
    };
    {
        const std::vector<Words> answered = comm.exchange(answers);
        for (int r = 0; r < pieces; ++r)
            for (std::size_t i = 0; i < asks[std::size_t(r)].size(); ++i) {
                const std::uint64_t* w = answered[std::size_t(r)].data() + 6 * i;
                const std::size_t at = ghostOf(asks[std::size_t(r)][i]);
                ghostEdges[at] = {Coord(int(std::int64_t(w[0])), int(std::int64_t(w[1])), int(std::int64_t(w[2]))), int(w[3])};
                std::memcpy(ghostPositions[at].asPointer(), w + 4, 12);
            }
    }
    const auto edgeOf = [&](std::uint32_t v) {
        if (!own(v)) return ghostEdges[ghostOf(v)];
        const std::size_t l = std::size_t(v - v0);
        return std::make_pair(Coord((*edgeI)[l], (*edgeJ)[l], (*edgeK)[l]), int((*edgeAxis)[l]));
    };

    // Kept triangles and the standard vertices of transition loops; a vertex stays when a kept
    // triangle or a loop of any piece uses it.
    KeptTriangles keptTriangles;
    CoarseVertices coarse;
    comm.agree([&] {
        keptTriangles = keepTriangles(standard.triangles, edgeOf, blocks, replacedCells, threaded, interrupter);
        coarse = findCoarse(surface, keptTriangles, edgeOf, packer);
    });
    std::vector<std::uint32_t> keptRow(nLocal, 0); // 1 for used, then the row among the kept
    std::vector<Words> uses(static_cast<std::size_t>(pieces));
    const auto use = [&](std::uint32_t v) {
        if (own(v)) keptRow[std::size_t(v - v0)] = 1;
        else uses[std::size_t(ownerOf(v))].push_back(v);
    };
    for (std::size_t t = 0; t < keptTriangles.keep.size(); ++t)
        if (keptTriangles.keep[t])
            for (int i = 0; i < 3; ++i) use(standard.triangles[t][i]);
    for (std::uint32_t v : coarse.coarseVertex) use(v);
    for (const Words& w : comm.exchange(uses))
        for (std::uint64_t v : w) keptRow[std::size_t(v - v0)] = 1;
    std::vector<std::uint32_t> kept;
    for (std::size_t v = 0; v < nLocal; ++v) {
        keptRow[v] = keptRow[v] ? std::uint32_t(kept.size()) : kNone;
        if (keptRow[v] != kNone) kept.push_back(std::uint32_t(v));
    }

    // Where this piece's rows go: (vertices) kept, fine, centres; (triangles) kept, refined cells',
    // transition cells'.
    const std::vector<Patch>& patches = surface.patches;
    std::vector<std::size_t> centreOffset(patches.size() + 1, 0);
    Words counts = {kept.size(), fineRows.size(), 0, keptTriangles.keptCount(), 0, 0, transition.size()};
    for (std::size_t c = 0; c < patches.size(); ++c) {
        centreOffset[c + 1] = centreOffset[c] + patches[c].memberEnds.size();
        counts[c < surface.refinedChunks ? 4 : 5] += patches[c].triangles.size();
    }
    counts[2] = centreOffset.back();
    const std::vector<Words> allCounts = comm.allgather(counts);
    out.vertexBegin = layout(allCounts, 3, 0);
    out.triangleBegin = layout(allCounts, 3, 3);
    for (const Words& w : allCounts) stats.cellsTransition += std::size_t(w[6]);
    if (out.vertexBegin.back() > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    const std::uint64_t keptBase = out.vertexBegin[std::size_t(piece)];
    const std::uint64_t fineBase = out.vertexBegin[std::size_t(pieces)];
    const std::uint64_t centreBase = out.vertexBegin[2 * std::size_t(pieces) + std::size_t(piece)];

    // The kept standard vertices' indices in the whole mesh, the ghosts' from their pieces.
    std::vector<Words> remapAnswers(static_cast<std::size_t>(pieces));
    for (int r = 0; r < pieces; ++r)
        for (std::uint64_t g : asked[std::size_t(r)]) {
            const std::uint32_t row = keptRow[std::size_t(g - v0)];
            remapAnswers[std::size_t(r)].push_back(row == kNone ? kNone : keptBase + row);
        }
    std::vector<std::uint32_t> ghostRemap(ghosts.size());
    {
        const std::vector<Words> answered = comm.exchange(remapAnswers);
        for (int r = 0; r < pieces; ++r)
            for (std::size_t i = 0; i < asks[std::size_t(r)].size(); ++i)
                ghostRemap[ghostOf(asks[std::size_t(r)][i])] = std::uint32_t(answered[std::size_t(r)][i]);
    }
    const auto remap = [&](std::uint32_t v) -> std::uint32_t {
        return own(v) ? std::uint32_t(keptBase + keptRow[std::size_t(v - v0)]) : ghostRemap[ghostOf(v)];
    };
    const auto fineOf = [&](Ref r, std::size_t chunk) {
        return numbering.fineIndex[numbering.crossingOffset[chunk] + std::size_t(r)];
    };
    const auto indexOf = [&](Ref r, std::size_t chunk) -> std::uint32_t {
        switch (r & kKindMask) {
        case kFineRef: return std::uint32_t(fineBase + fineGlobal[fineOf(r, chunk)]);
        case kCoarseRef: return remap(coarse.of(r));
        default: return std::uint32_t(centreBase + centreOffset[chunk] + std::size_t(r & ~kKindMask));
        }
    };
    const openvdb::math::Transform& xform = grid.transform();
    const auto positionOf = [&](Ref r, std::size_t chunk, const std::vector<openvdb::Vec3s>& positions) {
        if ((r & kKindMask) == kFineRef) return finePosition(packer, fine[fineOf(r, chunk)], xform, m);
        const std::uint32_t v = coarse.of(r);
        return own(v) ? positions[keptRow[std::size_t(v - v0)]] : ghostPositions[ghostOf(v)];
    };
    comm.agree([&] {
        out.mesh = assembleHidden(standard, kept, keptTriangles, remap, fineRows, surface, centreOffset, indexOf,
            positionOf, packer, m, xform, flips(grid, settings), /*keepProvenance=*/true, threaded);
    });
    return out;
}

} // namespace isouq
