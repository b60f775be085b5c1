// isouq: sparse primal marching cubes (SPEC §1, §8, §9; DESIGN.md "Pass structure").
//
// Blocks are 8^3 regions aligned with the grid's leaves. The block set is every block within one
// voxel of an active voxel or of the border of an active tile, so every cell with an active corner
// and every edge such a cell uses is owned by exactly one block: cells and edges are owned by the
// block holding their lower corner (SPEC §9). Two passes over the blocks, both parallel:
//   count: gather the block's values with a halo into a small dense array, classify cells, and
//          record which owned edges carry a vertex (a 1536-bit mask) and how many triangles it has;
//   fill:  after a serial prefix sum, write each block's vertices and triangles at its offsets.
// A vertex's global index is its block's offset plus the rank of its bit in the block's mask, so
// the output never depends on the thread count and needs no hash map.
#include "isouq/MarchingCubes.h"
#include "isouq/McTables.h"

#include <openvdb/thread/Threading.h>
#include <openvdb/tools/Morphology.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <cmath>
#include <cstring>

namespace isouq {
namespace mc_internal {

using openvdb::Coord;
using openvdb::CoordBBox;

constexpr int kBlockDim = 8;
constexpr int kWords = 3 * 512 / 64; // one bit per (voxel, axis) owned by a block

inline int voxelOffset(int x, int y, int z) { return (x << 6) | (y << 3) | z; }

/// What the count pass learns about one block and the fill pass needs again.
struct BlockRecord {
    std::array<std::uint64_t, kWords> edgeMask{}; // bit 3*voxelOffset + axis: the edge has a vertex
    std::array<std::uint32_t, kWords> rankBase{}; // set bits in the words before
    std::uint32_t vertexCount = 0;
    std::uint32_t triangleCount = 0;

    std::uint32_t rank(int bit) const
    {
        const int word = bit >> 6;
        const std::uint64_t below = (std::uint64_t(1) << (bit & 63)) - 1;
        return rankBase[word] + std::uint32_t(__builtin_popcountll(edgeMask[word] & below));
    }
};

/// The blocks to visit, in a deterministic order, and a lookup from block to index.
struct BlockSet {
    std::vector<Coord> origins;
    openvdb::Int32Tree index{-1}; // one voxel per block (coordinates >> 3); value = block index

    std::int32_t find(const Coord& origin) const { return index.getValue(origin >> 3); }
};

template <typename TreeT>
void buildBlockSet(const TreeT& tree, BlockSet& blocks, bool threaded)
{
    openvdb::Int32Tree& coarse = blocks.index;
    // Leaves with an active voxel, dilated by one block: cells with an active corner and the
    // edges they use lie within one voxel of that voxel.
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
        if (!leaf->isEmpty()) coarse.setValueOn(leaf->origin() >> 3, 0);
    }
    openvdb::tools::dilateActiveValues(coarse, 1, openvdb::tools::NN_FACE_EDGE_VERTEX,
        openvdb::tools::IGNORE_TILES, threaded);
    // Active tiles: only the blocks within one voxel of a tile's border can hold a crossing
    // between the tile and its surroundings; the tile's interior is constant and is skipped.
    typename TreeT::ValueOnCIter tile = tree.cbeginValueOn();
    tile.setMaxDepth(TreeT::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile) {
        CoordBBox box;
        tile.getBoundingBox(box);
        const Coord lo = box.min() >> 3, hi = box.max() >> 3;
        coarse.fill(CoordBBox(lo.offsetBy(-1), hi.offsetBy(1)), 0, true);
        if (hi[0] - lo[0] >= 2 && hi[1] - lo[1] >= 2 && hi[2] - lo[2] >= 2)
            coarse.fill(CoordBBox(lo.offsetBy(1), hi.offsetBy(-1)), -1, false);
    }
    coarse.voxelizeActiveTiles(threaded);
    std::int32_t next = 0;
    for (auto leaf = coarse.beginLeaf(); leaf; ++leaf) {
        for (auto v = leaf->beginValueOn(); v; ++v) {
            v.setValue(next++);
            blocks.origins.push_back(v.getCoord() << 3);
        }
    }
}

/// A block's values, active states and cell cases, gathered with a halo into dense arrays that
/// stay in cache. Coordinates are relative to the block origin and range over [lo, lo + width).
template <typename TreeT>
class BlockScratch {
public:
    using LeafT = typename TreeT::LeafNodeType;

    BlockScratch(const TreeT& tree, int halo)
        : mAccessor(tree), mLo(-halo), mWidth(kBlockDim + 2 * halo),
          mValues(std::size_t(mWidth) * mWidth * mWidth),
          mActive(mValues.size()), mCases(9 * 9 * 9), mProcessed(9 * 9 * 9)
    {
    }

    int index(int x, int y, int z) const { return ((x - mLo) * mWidth + (y - mLo)) * mWidth + (z - mLo); }
    float value(int x, int y, int z) const { return mValues[index(x, y, z)]; }

    /// Copies values and active states of [lo, lo + width)^3 around @a origin, one leaf probe
    /// per neighbouring block; a missing leaf is a constant tile or background.
    void gather(const Coord& origin)
    {
        const int hi = mLo + mWidth;
        const int firstBlock = (mLo - (kBlockDim - 1)) / kBlockDim; // floor division for mLo < 0
        const int lastBlock = (hi - 1) / kBlockDim;
        for (int bx = firstBlock; bx <= lastBlock; ++bx)
            for (int by = firstBlock; by <= lastBlock; ++by)
                for (int bz = firstBlock; bz <= lastBlock; ++bz)
                    gatherNeighbour(origin, bx, by, bz, hi);
    }

    /// Classifies the cells with minimum corner in [-1, 8)^3: marching-cubes case and whether the
    /// cell is meshed (an active corner, and all corners inside the data bounds if there are any).
    void classify(const Coord& origin, float isovalue, const std::optional<CoordBBox>& bounds)
    {
        for (int x = -1; x < kBlockDim; ++x)
            for (int y = -1; y < kBlockDim; ++y)
                for (int z = -1; z < kBlockDim; ++z) {
                    const int cell = cellIndex(x, y, z);
                    int cubeCase = 0;
                    bool anyActive = false;
                    for (int c = 0; c < 8; ++c) {
                        const auto& d = kMcCornerOffset[c];
                        const int v = index(x + d.x, y + d.y, z + d.z);
                        cubeCase |= int(mValues[v] >= isovalue) << c;
                        anyActive |= mActive[v] != 0;
                    }
                    if (anyActive && bounds) {
                        const Coord cmin = origin.offsetBy(x, y, z);
                        anyActive = bounds->isInside(cmin) && bounds->isInside(cmin.offsetBy(1));
                    }
                    mCases[cell] = std::uint8_t(cubeCase);
                    mProcessed[cell] = anyActive;
                }
    }

    static int cellIndex(int x, int y, int z) { return ((x + 1) * 9 + (y + 1)) * 9 + (z + 1); }
    std::uint8_t cubeCase(int x, int y, int z) const { return mCases[cellIndex(x, y, z)]; }
    bool processed(int x, int y, int z) const { return mProcessed[cellIndex(x, y, z)] != 0; }

private:
    void gatherNeighbour(const Coord& origin, int bx, int by, int bz, int hi)
    {
        const Coord nOrigin = origin.offsetBy(bx * kBlockDim, by * kBlockDim, bz * kBlockDim);
        const int x0 = std::max(mLo, bx * kBlockDim), x1 = std::min(hi, (bx + 1) * kBlockDim);
        const int y0 = std::max(mLo, by * kBlockDim), y1 = std::min(hi, (by + 1) * kBlockDim);
        const int z0 = std::max(mLo, bz * kBlockDim), z1 = std::min(hi, (bz + 1) * kBlockDim);
        if (x0 >= x1 || y0 >= y1 || z0 >= z1) return;
        const int zCount = z1 - z0;
        if (const LeafT* leaf = mAccessor.probeConstLeaf(nOrigin)) {
            const float* buffer = leaf->buffer().data();
            const auto& mask = leaf->getValueMask();
            for (int x = x0; x < x1; ++x)
                for (int y = y0; y < y1; ++y) {
                    const int src = voxelOffset(x - bx * kBlockDim, y - by * kBlockDim, z0 - bz * kBlockDim);
                    const int dst = index(x, y, z0);
                    std::memcpy(&mValues[dst], buffer + src, sizeof(float) * std::size_t(zCount));
                    for (int z = 0; z < zCount; ++z) mActive[dst + z] = mask.isOn(Index(src + z));
                }
        } else {
            const float tileValue = mAccessor.getValue(nOrigin);
            const std::uint8_t tileActive = mAccessor.isValueOn(nOrigin);
            for (int x = x0; x < x1; ++x)
                for (int y = y0; y < y1; ++y) {
                    const int dst = index(x, y, z0);
                    std::fill_n(&mValues[dst], zCount, tileValue);
                    std::fill_n(&mActive[dst], zCount, tileActive);
                }
        }
    }
    using Index = openvdb::Index;

    openvdb::tree::ValueAccessor<const TreeT> mAccessor;
    int mLo, mWidth;
    std::vector<float> mValues;
    std::vector<std::uint8_t> mActive;
    std::vector<std::uint8_t> mCases;     // cells [-1, 8)^3
    std::vector<std::uint8_t> mProcessed; // cells [-1, 8)^3
};

/// Count pass for one block: which owned edges carry a vertex, and the block's triangle count.
/// An edge carries a vertex when it crosses and at least one of its four cells is meshed.
template <typename TreeT>
void countBlock(const BlockScratch<TreeT>& s, BlockRecord& record)
{
    record = BlockRecord{};
    for (int x = -1; x < kBlockDim; ++x)
        for (int y = -1; y < kBlockDim; ++y)
            for (int z = -1; z < kBlockDim; ++z) {
                if (!s.processed(x, y, z)) continue;
                const int cubeCase = s.cubeCase(x, y, z);
                if (cubeCase == 0 || cubeCase == 255) continue;
                const bool ownsCell = x >= 0 && y >= 0 && z >= 0;
                if (ownsCell) record.triangleCount += kMcCases.triangleCount[cubeCase];
                const std::uint16_t crossing = kMcCases.crossingEdges[cubeCase];
                for (int e = 0; e < 12; ++e) {
                    if (!((crossing >> e) & 1)) continue;
                    const McEdge& edge = kMcEdges[e];
                    const int vx = x + edge.dx, vy = y + edge.dy, vz = z + edge.dz;
                    if (vx < 0 || vy < 0 || vz < 0 || vx >= kBlockDim || vy >= kBlockDim || vz >= kBlockDim)
                        continue; // owned by another block
                    const int bit = 3 * voxelOffset(vx, vy, vz) + edge.axis;
                    record.edgeMask[bit >> 6] |= std::uint64_t(1) << (bit & 63);
                }
            }
    std::uint32_t total = 0;
    for (int w = 0; w < kWords; ++w) {
        record.rankBase[w] = total;
        total += std::uint32_t(__builtin_popcountll(record.edgeMask[w]));
    }
    record.vertexCount = total;
}

/// Output columns the fill pass writes into (null when not requested).
struct VertexColumns {
    openvdb::Vec3s* positions = nullptr;
    std::int32_t* edgeI = nullptr;
    std::int32_t* edgeJ = nullptr;
    std::int32_t* edgeK = nullptr;
    std::uint8_t* edgeAxis = nullptr;
    float* tLinear = nullptr;
};

/// Index-to-world map, applied without a virtual call when the transform is affine.
class WorldMap {
public:
    explicit WorldMap(const openvdb::math::Transform& xform) : mTransform(xform)
    {
        mAffine = xform.isLinear();
        if (mAffine) mMatrix = xform.baseMap()->getAffineMap()->getMat4();
    }
    openvdb::Vec3s operator()(const openvdb::Vec3d& ijk) const
    {
        return openvdb::Vec3s(mAffine ? mMatrix.transform(ijk) : mTransform.indexToWorld(ijk));
    }
    /// Row-major, column-vector convention (Mesh::indexToWorld).
    std::array<double, 16> rowMajor() const
    {
        openvdb::Mat4d m = mAffine ? mMatrix : openvdb::Mat4d::identity();
        std::array<double, 16> out{};
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) out[4 * r + c] = m(c, r); // OpenVDB multiplies row vectors
        return out;
    }

private:
    const openvdb::math::Transform& mTransform;
    bool mAffine = false;
    openvdb::Mat4d mMatrix;
};

template <typename TreeT>
void fillVertices(const BlockScratch<TreeT>& s, const Coord& origin, const BlockRecord& record,
    std::size_t offset, float isovalue, const WorldMap& toWorld, const VertexColumns& out)
{
    std::size_t n = offset;
    for (int w = 0; w < kWords; ++w) {
        for (std::uint64_t bits = record.edgeMask[w]; bits; bits &= bits - 1) {
            const int bit = 64 * w + __builtin_ctzll(bits);
            const int voxel = bit / 3, axis = bit % 3;
            const int x = voxel >> 6, y = (voxel >> 3) & 7, z = voxel & 7;
            const float f0 = s.value(x, y, z);
            const float f1 = s.value(x + (axis == 0), y + (axis == 1), z + (axis == 2));
            // SPEC §2 linear crossing, always measured from the lower end of the edge.
            const float t = std::clamp((isovalue - f0) / (f1 - f0), 0.0f, 1.0f);
            const Coord ijk = origin.offsetBy(x, y, z);
            openvdb::Vec3d p(ijk[0], ijk[1], ijk[2]);
            p[axis] += double(t);
            out.positions[n] = toWorld(p);
            if (out.edgeI) {
                out.edgeI[n] = ijk[0];
                out.edgeJ[n] = ijk[1];
                out.edgeK[n] = ijk[2];
                out.edgeAxis[n] = std::uint8_t(axis);
                out.tLinear[n] = t;
            }
            ++n;
        }
    }
}

/// Global vertex index of cube edge @a e of the cell at (x, y, z) in the block, using the block
/// and its + neighbours (neighbours[dx][dy][dz], dx, dy, dz in {0, 1}).
inline std::uint32_t vertexOf(int x, int y, int z, int e, const std::int32_t (&neighbours)[2][2][2],
    const std::vector<BlockRecord>& records, const std::vector<std::uint64_t>& vertexOffsets)
{
    const McEdge& edge = kMcEdges[e];
    const int vx = x + edge.dx, vy = y + edge.dy, vz = z + edge.dz;
    const int bx = vx >> 3, by = vy >> 3, bz = vz >> 3;
    const std::int32_t owner = neighbours[bx][by][bz];
    const int bit = 3 * voxelOffset(vx & 7, vy & 7, vz & 7) + edge.axis;
    return std::uint32_t(vertexOffsets[owner] + records[owner].rank(bit));
}

template <typename TreeT>
void fillTriangles(const BlockScratch<TreeT>& s, const std::int32_t (&neighbours)[2][2][2],
    const std::vector<BlockRecord>& records, const std::vector<std::uint64_t>& vertexOffsets,
    bool flip, openvdb::Vec3I* out)
{
    for (int x = 0; x < kBlockDim; ++x)
        for (int y = 0; y < kBlockDim; ++y)
            for (int z = 0; z < kBlockDim; ++z) {
                if (!s.processed(x, y, z)) continue;
                const int cubeCase = s.cubeCase(x, y, z);
                const int count = kMcCases.triangleCount[cubeCase];
                const auto& edges = kMcCases.triangleEdges[cubeCase];
                for (int t = 0; t < count; ++t) {
                    const std::uint32_t a = vertexOf(x, y, z, edges[3 * t], neighbours, records, vertexOffsets);
                    const std::uint32_t b = vertexOf(x, y, z, edges[3 * t + 1], neighbours, records, vertexOffsets);
                    const std::uint32_t c = vertexOf(x, y, z, edges[3 * t + 2], neighbours, records, vertexOffsets);
                    *out++ = flip ? openvdb::Vec3I(a, c, b) : openvdb::Vec3I(a, b, c);
                }
            }
}

template <typename GridT>
std::optional<CoordBBox> dataBoundsOf(const GridT& grid, const MeshSettings& settings)
{
    if (settings.dataBounds) return settings.dataBounds;
    auto lo = grid.template getMetadata<openvdb::Vec3IMetadata>(kDataBoundsMinMeta);
    auto hi = grid.template getMetadata<openvdb::Vec3IMetadata>(kDataBoundsMaxMeta);
    if (!lo || !hi) return std::nullopt;
    return CoordBBox(Coord(lo->value()), Coord(hi->value()));
}

/// Runs @a body(i) for every block in parallel (or serially), polling the interrupter.
template <typename Body>
void forEachBlock(std::size_t count, bool threaded, openvdb::util::NullInterrupter* interrupter,
    std::atomic<std::size_t>& done, std::size_t total, Body&& body)
{
    std::atomic<bool> stop{false};
    auto range = [&](const tbb::blocked_range<std::size_t>& r) {
        if (stop.load(std::memory_order_relaxed)) return;
        const std::size_t before = done.fetch_add(r.size(), std::memory_order_relaxed);
        if (openvdb::util::wasInterrupted(interrupter, int(100 * before / std::max<std::size_t>(total, 1)))) {
            stop = true;
            openvdb::thread::cancelGroupExecution();
            return;
        }
        for (std::size_t i = r.begin(); i < r.end(); ++i) body(i);
    };
    const tbb::blocked_range<std::size_t> all(0, count, 16);
    if (threaded) tbb::parallel_for(all, range);
    else range(all);
    if (stop) throw InterruptedError();
}

} // namespace mc_internal

template <typename GridT>
Mesh extractIsosurface(const GridT& grid, const MeshSettings& settings,
    openvdb::util::NullInterrupter* interrupter)
{
    using namespace mc_internal;
    using TreeT = typename GridT::TreeType;
    static_assert(std::is_floating_point<typename GridT::ValueType>::value,
        "extractIsosurface needs a scalar floating-point grid");
    if (!std::isfinite(settings.isovalue))
        OPENVDB_THROW(openvdb::ValueError, "the isovalue must be a finite number");

    const float isovalue = settings.isovalue;
    const std::optional<CoordBBox> bounds = dataBoundsOf(grid, settings);
    const bool levelSet = grid.getGridClass() == openvdb::GRID_LEVEL_SET;
    const bool flip = settings.orientation == Orientation::TowardsHigher ||
                      (settings.orientation == Orientation::Auto && levelSet);
    const bool provenance = settings.provenance || settings.uncertainty;

    if (interrupter) interrupter->start("Meshing");
    struct EndGuard {
        openvdb::util::NullInterrupter* i;
        ~EndGuard() { if (i) i->end(); }
    } endGuard{interrupter};

    BlockSet blocks;
    buildBlockSet(grid.tree(), blocks, settings.threaded);
    throwIfInterrupted(interrupter);
    const std::size_t blockCount = blocks.origins.size();
    const int halo = 1;
    tbb::enumerable_thread_specific<BlockScratch<TreeT>> scratch(std::cref(grid.tree()), halo);
    std::atomic<std::size_t> done{0};
    const std::size_t work = 2 * blockCount;

    // Count pass.
    std::vector<BlockRecord> records(blockCount);
    forEachBlock(blockCount, settings.threaded, interrupter, done, work, [&](std::size_t b) {
        BlockScratch<TreeT>& s = scratch.local();
        s.gather(blocks.origins[b]);
        s.classify(blocks.origins[b], isovalue, bounds);
        countBlock(s, records[b]);
    });

    // Serial prefix sums: each block's place in the output, independent of the thread count.
    std::vector<std::uint64_t> vertexOffsets(blockCount + 1), triangleOffsets(blockCount + 1);
    for (std::size_t b = 0; b < blockCount; ++b) {
        vertexOffsets[b + 1] = vertexOffsets[b] + records[b].vertexCount;
        triangleOffsets[b + 1] = triangleOffsets[b] + records[b].triangleCount;
    }
    if (vertexOffsets[blockCount] > std::numeric_limits<std::uint32_t>::max())
        OPENVDB_THROW(openvdb::ValueError, "the mesh would have more than 2^32 vertices");

    Mesh mesh;
    const WorldMap toWorld(grid.transform());
    mesh.indexToWorld = toWorld.rowMajor();
    mesh.positions.resize(vertexOffsets[blockCount]);
    mesh.triangles.resize(triangleOffsets[blockCount]);
    VertexColumns columns;
    columns.positions = mesh.positions.data();
    if (provenance) {
        const std::size_t n = mesh.positions.size();
        columns.edgeI = mesh.vertexAttributes.add<std::int32_t>("edge_i", n).data();
        columns.edgeJ = mesh.vertexAttributes.add<std::int32_t>("edge_j", n).data();
        columns.edgeK = mesh.vertexAttributes.add<std::int32_t>("edge_k", n).data();
        columns.edgeAxis = mesh.vertexAttributes.add<std::uint8_t>("edge_axis", n).data();
        columns.tLinear = mesh.vertexAttributes.add<float>("t_linear", n).data();
    }

    // Fill pass.
    forEachBlock(blockCount, settings.threaded, interrupter, done, work, [&](std::size_t b) {
        if (records[b].vertexCount == 0 && records[b].triangleCount == 0) return;
        const Coord& origin = blocks.origins[b];
        BlockScratch<TreeT>& s = scratch.local();
        s.gather(origin);
        s.classify(origin, isovalue, bounds);
        fillVertices(s, origin, records[b], vertexOffsets[b], isovalue, toWorld, columns);
        if (records[b].triangleCount == 0) return;
        std::int32_t neighbours[2][2][2];
        for (int dx = 0; dx < 2; ++dx)
            for (int dy = 0; dy < 2; ++dy)
                for (int dz = 0; dz < 2; ++dz)
                    neighbours[dx][dy][dz] = blocks.find(origin.offsetBy(8 * dx, 8 * dy, 8 * dz));
        fillTriangles(s, neighbours, records, vertexOffsets, flip, mesh.triangles.data() + triangleOffsets[b]);
    });
    return mesh;
}

template Mesh extractIsosurface<openvdb::FloatGrid>(
    const openvdb::FloatGrid&, const MeshSettings&, openvdb::util::NullInterrupter*);

} // namespace isouq
