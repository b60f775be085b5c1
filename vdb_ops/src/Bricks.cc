// isouq: meshing a piece of the block order (SPEC §9, §10 "MPI"; Bricks.h). The passes are the
// one-process mesher's (MeshPasses.h) restricted to the piece's blocks; the piece's vertex and
// triangle offsets become those of the whole mesh, and the masks of + neighbours owned by other
// pieces come from them, so the triangles name the whole mesh's vertices.
#include "isouq/Bricks.h"

#include "MeshPasses.h"
#include "Stage.h"

#include <tbb/enumerable_thread_specific.h>

#include <cmath>

namespace isouq {
namespace mc_internal {

struct BrickPlanData {
    BlockSet blocks;
    std::vector<std::size_t> bounds;      // piece p: blocks [bounds[p], bounds[p + 1])
    std::vector<std::uint64_t> weights;   // per piece
};

struct BrickMesherData {
    const openvdb::FloatGrid& grid;
    MeshSettings settings;
    const BrickPlan& plan;
    std::size_t begin, end;
    PageVector<BlockCounts> counts;            // per block of the piece
    PageVector<std::uint64_t> vertexOffsets;   // per block of the order: the whole mesh's
    PageVector<std::uint64_t> triangleOffsets; // per block of the piece, then the total
    FoundMasks found;                          // the piece's masks, as the count pass found them
    EdgeMasks masks;                           // slots for the order's blocks
    std::uint64_t vertices = 0, firstVertex = 0, firstTriangle = 0;
    bool counted = false, placed = false;
};

} // namespace mc_internal

using namespace mc_internal;

namespace {

template <typename TreeT>
void planPieces(const TreeT& tree, int pieces, bool threaded, BrickPlanData& data)
{
    if (pieces < 1) OPENVDB_THROW(openvdb::ValueError, "a brick plan needs at least one piece");
    buildBlockSet(tree, data.blocks, threaded);
    const PageVector<Coord>& origins = data.blocks.origins;
    // Leaves by iteration, not by accessor: an accessor that finds a leaf caches its values,
    // which loads a delay-loaded buffer. The value masks are topology.
    std::vector<std::uint64_t> prefix(origins.size() + 1, 1);
    prefix[0] = 0;
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
        const std::int32_t b = data.blocks.find(leaf->origin());
        if (b >= 0) prefix[std::size_t(b) + 1] += leaf->onVoxelCount();
    }
    for (std::size_t b = 0; b < origins.size(); ++b) prefix[b + 1] += prefix[b];
    const std::uint64_t total = prefix.back();
    data.bounds.assign(std::size_t(pieces) + 1, origins.size());
    data.weights.assign(std::size_t(pieces), 0);
    data.bounds[0] = 0;
    for (int p = 1; p < pieces; ++p) {
        const std::uint64_t target = total / std::uint64_t(pieces) * std::uint64_t(p) +
            total % std::uint64_t(pieces) * std::uint64_t(p) / std::uint64_t(pieces);
        // The first block whose weight starts at or after the target.
        data.bounds[std::size_t(p)] = std::size_t(std::lower_bound(prefix.begin(), prefix.end() - 1, target) - prefix.begin());
    }
    for (int p = 0; p < pieces; ++p)
        data.weights[std::size_t(p)] = prefix[data.bounds[std::size_t(p) + 1]] - prefix[data.bounds[std::size_t(p)]];
}

} // namespace

BrickPlan::BrickPlan(const openvdb::FloatGrid& grid, int pieces, bool threaded)
    : mData(std::make_unique<BrickPlanData>())
{
    planPieces(grid.tree(), pieces, threaded, *mData);
}

BrickPlan::BrickPlan(const openvdb::MaskTree& topology, int pieces, bool threaded)
    : mData(std::make_unique<BrickPlanData>())
{
    planPieces(topology, pieces, threaded, *mData);
}

BrickPlan::~BrickPlan() = default;

int BrickPlan::pieces() const { return int(mData->weights.size()); }
std::size_t BrickPlan::blockCount() const { return mData->blocks.origins.size(); }
std::size_t BrickPlan::begin(int piece) const { return mData->bounds[std::size_t(piece)]; }
std::size_t BrickPlan::end(int piece) const { return mData->bounds[std::size_t(piece) + 1]; }
std::uint64_t BrickPlan::weight(int piece) const { return mData->weights[std::size_t(piece)]; }
const Coord& BrickPlan::origin(std::size_t block) const { return mData->blocks.origins[block]; }

std::int64_t BrickPlan::blockOf(const Coord& ijk) const { return mData->blocks.find(ijk); }

int BrickPlan::pieceOfBlock(std::int64_t block) const
{
    if (block < 0) return -1;
    const auto& bounds = mData->bounds;
    return int(std::upper_bound(bounds.begin(), bounds.end(), std::size_t(block)) - bounds.begin()) - 1;
}

int BrickPlan::pieceOfCell(const Coord& ijk) const { return pieceOfBlock(blockOf(ijk)); }

BrickMesher::BrickMesher(const openvdb::FloatGrid& grid, const MeshSettings& settings, const BrickPlan& plan, int piece)
    : mData(new BrickMesherData{grid, settings, plan, plan.begin(piece), plan.end(piece), {}, {}, {}, {}, {}})
{
}

BrickMesher::~BrickMesher() = default;

void BrickMesher::count(openvdb::util::NullInterrupter* interrupter)
{
    using TreeT = openvdb::FloatTree;
    BrickMesherData& d = *mData;
    const MeshSettings& settings = d.settings;
    if (!std::isfinite(settings.isovalue))
        OPENVDB_THROW(openvdb::ValueError, "the isovalue must be a finite number");
    const BlockSet& blocks = d.plan.data().blocks;
    const float isovalue = settings.isovalue;
    const std::optional<CoordBBox> cellBox = meshedCellBox(dataBoundsOf(d.grid, settings), settings.brick);
    const std::size_t n = d.end - d.begin;

    // Its own stage: under MPI the ranks exchange the counts before the fill ("Meshing").
    const InterrupterStage stage(interrupter, "Counting triangles");
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> scratch(std::cref(d.grid.tree()), std::cref(blocks.index), 1);
    std::atomic<std::size_t> done{0};

    // The sides of the piece's blocks; the others read as mixed, which only means that a block
    // next to them is gathered rather than skipped (mayCross is a shortcut, never a decision).
    PageVector<std::uint8_t> sides;
    assignFresh(sides, blocks.origins.size(), std::uint8_t(kMixed), settings.threaded);
    forEachBlock(n, settings.threaded, interrupter, done, 3 * n, [&](std::size_t i) {
        sides[d.begin + i] = scratch.local().regionSide(blocks.origins[d.begin + i], isovalue);
    });

    assignFresh(d.counts, n, BlockCounts{}, settings.threaded);
    FoundMasks& found = d.found;
    found.clear();
    forEachBlock(n, settings.threaded, interrupter, done, 3 * n, [&](std::size_t i) {
        countPassBlock(scratch.local(), blocks, d.begin + i, isovalue, cellBox, sides, d.counts[i], found);
    });

    assignFresh(d.vertexOffsets, blocks.origins.size() + 1, std::uint64_t(0), settings.threaded);
    assignFresh(d.triangleOffsets, n + 1, std::uint64_t(0), settings.threaded);
    assignFresh(d.masks.byBlock, blocks.origins.size(), static_cast<const EdgeMask*>(nullptr), settings.threaded);
    d.masks.owned.clear();
    std::uint64_t vertices = 0;
    for (std::size_t i = 0; i < n; ++i) {
        d.vertexOffsets[d.begin + i] = vertices;
        vertices += d.counts[i].vertices;
        d.triangleOffsets[i + 1] = d.triangleOffsets[i] + d.counts[i].triangles;
    }
    d.vertexOffsets[d.end] = vertices;
    d.vertices = vertices;
    for (const auto& list : found)
        list.forEach([&](const FoundMask& f) { d.masks.byBlock[std::size_t(f.block)] = &f.mask; });
    d.counted = true;
}

std::uint64_t BrickMesher::vertexCount() const { return mData->vertices; }
std::uint64_t BrickMesher::triangleCount() const { return mData->triangleOffsets.back(); }
std::uint64_t BrickMesher::firstVertex() const { return mData->firstVertex; }
std::uint64_t BrickMesher::firstTriangle() const { return mData->firstTriangle; }

void BrickMesher::setOffsets(std::uint64_t firstVertex, std::uint64_t firstTriangle, std::uint64_t totalVertices)
{
    BrickMesherData& d = *mData;
    if (!d.counted) OPENVDB_THROW(openvdb::RuntimeError, "BrickMesher::setOffsets before count");
    if (totalVertices > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");
    for (std::size_t b = d.begin; b <= d.end; ++b) d.vertexOffsets[b] += firstVertex;
    d.firstVertex = firstVertex;
    d.firstTriangle = firstTriangle;
    d.placed = true;
}

std::vector<std::int64_t> BrickMesher::foreignBlocks() const
{
    const BrickMesherData& d = *mData;
    const BlockSet& blocks = d.plan.data().blocks;
    std::vector<std::int64_t> out;
    for (std::size_t i = 0; i < d.counts.size(); ++i) {
        if (d.counts[i].triangles == 0) continue;
        std::int32_t neighbours[2][2][2];
        blocks.plusNeighbours(blocks.origins[d.begin + i], neighbours);
        for (const auto& plane : neighbours)
            for (const auto& row : plane)
                for (const std::int32_t b : row)
                    if (b >= 0 && std::size_t(b) >= d.end) out.push_back(b);
    }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
}

void BrickMesher::describeBlock(std::int64_t block, std::uint64_t* words) const
{
    const BrickMesherData& d = *mData;
    if (!d.placed || block < std::int64_t(d.begin) || block >= std::int64_t(d.end))
        OPENVDB_THROW(openvdb::ValueError, "block " + std::to_string(block) + " is not this piece's");
    words[0] = d.vertexOffsets[std::size_t(block)];
    const EdgeMask* mask = d.masks.byBlock[std::size_t(block)];
    for (int w = 0; w < kWords; ++w) words[1 + w] = mask ? mask->bits[std::size_t(w)] : 0;
}

void BrickMesher::learnBlock(std::int64_t block, const std::uint64_t* words)
{
    BrickMesherData& d = *mData;
    if (block < 0 || std::size_t(block) >= d.masks.byBlock.size())
        OPENVDB_THROW(openvdb::ValueError, "block " + std::to_string(block) + " is not in the plan");
    EdgeMask mask;
    std::uint32_t total = 0;
    for (int w = 0; w < kWords; ++w) {
        mask.bits[std::size_t(w)] = words[1 + w];
        mask.rankBase[std::size_t(w)] = std::uint16_t(total);
        total += std::uint32_t(__builtin_popcountll(words[1 + w]));
    }
    d.vertexOffsets[std::size_t(block)] = words[0];
    d.masks.own(block, mask);
}

void BrickMesher::fill(Mesh& mesh, openvdb::util::NullInterrupter* interrupter)
{
    using TreeT = openvdb::FloatTree;
    BrickMesherData& d = *mData;
    if (!d.placed) OPENVDB_THROW(openvdb::RuntimeError, "BrickMesher::fill before setOffsets");
    const MeshSettings& settings = d.settings;
    const BlockSet& blocks = d.plan.data().blocks;
    const openvdb::FloatGrid& grid = d.grid;
    const float isovalue = settings.isovalue;
    const std::optional<CoordBBox> bounds = dataBoundsOf(grid, settings);
    const std::optional<CoordBBox> cellBox = meshedCellBox(bounds, settings.brick);
    const bool flip = flipsTriangles(grid, settings);
    const bool provenance = settings.provenance || settings.uncertainty;
    const std::size_t n = d.end - d.begin;
    const std::uint64_t vertices = vertexCount(), triangles = triangleCount();
    checkMeshFits(vertices, triangles, settings, provenance);

    const InterrupterStage stage(interrupter, "Meshing");

    const WorldMap toWorld(grid.transform());
    mesh.indexToWorld = toWorld.rowMajor();
    const VertexColumns columns =
        VertexColumns::allocate(mesh, vertices, triangles, provenance, settings, settings.threaded);
    const VertexContext context{isovalue, toWorld, grid.transform().voxelSize(), bounds,
        settings.stencil, settings.method, settings.uncertainty};
    const FillWindow window = fillWindow(settings);
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> stencilScratch(
        std::cref(grid.tree()), std::cref(blocks.index), window.lo, window.width);
    std::atomic<std::size_t> done{0};
    const FillTarget target{d.masks, d.vertexOffsets, d.firstVertex, context, columns, flip};
    forEachBlock(n, settings.threaded, interrupter, done, n, [&](std::size_t i) {
        if (d.counts[i].empty()) return;
        fillPassBlock(stencilScratch.local(), blocks, d.begin + i, d.counts[i], cellBox, target,
            mesh.triangles.data() + d.triangleOffsets[i]);
    });
}

std::uint64_t loadedLeafVoxels(const openvdb::FloatGrid& grid)
{
    std::uint64_t voxels = 0;
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf)
        if (!leaf->buffer().isOutOfCore()) voxels += openvdb::FloatTree::LeafNodeType::SIZE;
    return voxels;
}

} // namespace isouq
