// isouq: a grid meshed in pieces by several processes (SPEC §9 bricks, §10 "MPI";
// docs/mpi.md). The mesher visits 8^3 blocks in a fixed order and writes each block's vertices
// and triangles in that order, so a contiguous run of blocks yields a contiguous piece of the
// one-process output. A BrickPlan cuts the block order into such runs, balanced by the active
// voxels they hold; a BrickMesher meshes one run. Between its count and fill passes the pieces
// trade what crosses their borders: where each piece starts in the whole mesh, and the edge
// masks of the blocks whose vertices a piece's triangles use but another piece owns (a cell's
// triangles use the edges of its block and of the block's seven + neighbours, which come later
// in the order). No communication library here: the caller moves the words (MPI in the CLI).
#pragma once

#include "isouq/MarchingCubes.h"

#include <openvdb/openvdb.h>

#include <cstdint>
#include <cstring>
#include <functional>
#include <memory>
#include <vector>

namespace isouq {

/// The collectives that a volume read by pieces needs, over the processes that each mesh one
/// piece (MPI ranks in the CLI, nodes/Ranks.h). Every collective is called by every piece in
/// the same order.
class PieceComm {
public:
    using Words = std::vector<std::uint64_t>;
    virtual ~PieceComm() = default;
    virtual int rank() const = 0;
    virtual int size() const = 0;
    /// Each piece's @a words, in piece order, on every piece.
    virtual std::vector<Words> allgather(const Words& words) const = 0;
    /// Sends out[r] to piece r; in[r] becomes what piece r sent here, in the memory in[r]
    /// already has where it is large enough (exchanges in rounds touch no fresh pages after
    /// the first: on a VM every fresh page is the host's to back, bench/README.md).
    virtual void exchangeInto(const std::vector<Words>& out, std::vector<Words>& in) const = 0;
    /// exchangeInto into new vectors.
    std::vector<Words> exchange(const std::vector<Words>& out) const
    {
        std::vector<Words> in;
        exchangeInto(out, in);
        return in;
    }
    /// Runs @a body, then agrees: when it threw on any piece, every piece throws.
    virtual void agree(const std::function<void()>& body) const = 0;
    /// Every piece's @a words (each piece as many) added element by element, on every piece:
    /// counts and histograms of the whole.
    Words sum(const Words& words) const
    {
        Words total(words.size(), 0);
        for (const Words& w : allgather(words))
            for (std::size_t i = 0; i < total.size(); ++i) total[i] += w[i];
        return total;
    }
};

/// Numbers as Words and back, bit for bit, so that what one piece computes reaches the others
/// unchanged (sums carried between pieces stay bit-equal to one process's, SPEC §9).
inline std::uint64_t bitsOf(double v)
{
    std::uint64_t w;
    std::memcpy(&w, &v, sizeof w);
    return w;
}
inline double doubleOf(std::uint64_t w)
{
    double v;
    std::memcpy(&v, &w, sizeof v);
    return v;
}
inline std::uint64_t bitsOf(float v)
{
    std::uint32_t w;
    std::memcpy(&w, &v, sizeof w);
    return w;
}
inline float floatOf(std::uint64_t w)
{
    const std::uint32_t u = std::uint32_t(w);
    float v;
    std::memcpy(&v, &u, sizeof v);
    return v;
}

namespace mc_internal {
struct BrickPlanData;
struct BrickMesherData;
} // namespace mc_internal

/// The mesher's blocks of a grid, in its order, cut into @a pieces contiguous runs. Built from
/// the grid's topology only (leaf masks and tiles): a grid read with delayed loading keeps its
/// leaf buffers on disk. Each block weighs 1 plus the active voxels of its leaf; piece p holds
/// the blocks whose weight prefix lies in [p W / P, (p + 1) W / P).
class BrickPlan {
public:
    BrickPlan(const openvdb::FloatGrid& grid, int pieces, bool threaded = true);
    /// The same plan from the topology alone (active voxels and tiles of a grid whose values
    /// are spread over the pieces: a raw scan read by z-layers).
    BrickPlan(const openvdb::MaskTree& topology, int pieces, bool threaded = true);
    ~BrickPlan();
    BrickPlan(const BrickPlan&) = delete;
    BrickPlan& operator=(const BrickPlan&) = delete;

    int pieces() const;
    std::size_t blockCount() const;
    /// Blocks [begin(p), end(p)) of the order are piece p's.
    std::size_t begin(int piece) const;
    std::size_t end(int piece) const;
    /// The block holding voxel @a ijk (-1 when it is not visited) and the piece of a block.
    std::int64_t blockOf(const openvdb::Coord& ijk) const;
    int pieceOfBlock(std::int64_t block) const;
    /// The piece that meshes the cell with minimum corner @a ijk, -1 when no block holds it.
    int pieceOfCell(const openvdb::Coord& ijk) const;
    const openvdb::Coord& origin(std::size_t block) const;
    /// Sum of the weights of piece p's blocks.
    std::uint64_t weight(int piece) const;

    const mc_internal::BrickPlanData& data() const { return *mData; }

private:
    std::unique_ptr<mc_internal::BrickPlanData> mData;
};

/// Meshes piece @a piece of a BrickPlan exactly as IsosurfaceMesher meshes the whole grid: the
/// result holds the vertices of the piece's blocks (rows firstVertex() on of the whole mesh, in
/// the whole mesh's order, with every column) and the triangles of its cells, whose indices are
/// those of the whole mesh. Steps, in order: count(); setOffsets(); learnBlock() for each of
/// foreignBlocks() (the words describeBlock() gives on the piece that owns it); fill().
class BrickMesher {
public:
    /// Words per block in describeBlock()/learnBlock(): its first vertex, then its edge mask.
    static constexpr int kBlockWords = 25;

    BrickMesher(const openvdb::FloatGrid& grid, const MeshSettings& settings, const BrickPlan& plan, int piece);
    ~BrickMesher();
    BrickMesher(const BrickMesher&) = delete;
    BrickMesher& operator=(const BrickMesher&) = delete;

    /// The count pass over the piece's blocks. @throw as extractIsosurface.
    void count(openvdb::util::NullInterrupter* interrupter = nullptr);
    std::uint64_t vertexCount() const;
    std::uint64_t triangleCount() const;
    /// Where the piece starts in the whole mesh (the counts of the pieces before it), and the
    /// whole mesh's vertex count. @throw openvdb::ValueError past 2^32 vertices.
    void setOffsets(std::uint64_t firstVertex, std::uint64_t firstTriangle, std::uint64_t totalVertices);
    std::uint64_t firstVertex() const;
    std::uint64_t firstTriangle() const;
    /// Blocks of later pieces whose vertices this piece's triangles use, ascending.
    std::vector<std::int64_t> foreignBlocks() const;
    /// kBlockWords words for one of this piece's blocks (after setOffsets).
    void describeBlock(std::int64_t block, std::uint64_t* words) const;
    void learnBlock(std::int64_t block, const std::uint64_t* words);
    /// The fill pass into @a mesh (replacing its content). @throw as extractIsosurface.
    void fill(Mesh& mesh, openvdb::util::NullInterrupter* interrupter = nullptr);

private:
    std::unique_ptr<mc_internal::BrickMesherData> mData;
};

/// Voxels of @a grid's leaves whose values are in memory (all of them, unless the grid was
/// read with delayed loading and some leaves were never touched): what a piece read.
std::uint64_t loadedLeafVoxels(const openvdb::FloatGrid& grid);

} // namespace isouq
