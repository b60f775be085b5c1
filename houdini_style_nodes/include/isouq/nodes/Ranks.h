// isouq nodes: the ranks a graph runs on (SPEC §9, §10 "MPI"; docs/mpi.md; STYLE "MPI":
// VTK's vtkMultiProcessController). runGraph with a Ranks runs the same graph on every rank:
// read_volume reads the rank's piece of the block order (and its halo), mesh meshes it, summary
// joins the pieces into the one-process summary, write_ply writes the rank's rows into one file.
// This header knows no communication library: the MPI implementation lives in the executable
// (Distributed.h), so the library and its users never load MPI.
#pragma once

#include <isouq/Bricks.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace isouq::nodes {

using Words = PieceComm::Words;

/// A file that every rank writes at its own offsets (MPI-IO); the destructor closes it on
/// every rank (collective).
class SharedFile {
public:
    virtual ~SharedFile() = default;
    /// @throw IoError naming @a what.
    virtual void writeAt(std::uint64_t offset, const char* data, std::size_t bytes, const std::string& what) = 0;
};

/// The ranks of one run and the collective operations the distributed nodes use (rank, size,
/// allgather and exchange are PieceComm's, which the volume sources read by pieces use). Every
/// collective is called by every rank in the same order.
class Ranks : public PieceComm {
public:
    /// Each rank's @a words on rank 0 (empty elsewhere).
    virtual std::vector<Words> gather(const Words& words) const = 0;
    /// @a words of rank @a root on every rank.
    virtual Words broadcast(const Words& words, int root) const = 0;
    /// Point to point: @a words to rank @a to; the next words from rank @a from.
    virtual void send(const Words& words, int to) const = 0;
    virtual Words receive(int from) const = 0;
    /// Opens the existing file @a path, to be @a bytes long, for writing on every rank; on
    /// every rank nullptr with @a why when it cannot be (no space for @a bytes, say).
    virtual std::unique_ptr<SharedFile> openShared(const std::string& path, std::uint64_t bytes, std::string& why) const = 0;
    /// Whether a signal arrived on this rank.
    virtual bool interrupted() const = 0;
    /// The ranks of @a color among these, in rank order (collective: a group of ranks that
    /// runs graphs of its own, a sequence's frame job).
    virtual std::unique_ptr<Ranks> split(int color) const = 0;

    /// Runs @a body, then agrees: when it failed on any rank, every rank throws at the same
    /// point, InterruptedError if a rank was interrupted, else InputError with the message of
    /// the lowest failing rank (after @a where). Steps nest: an inner failure is one on every
    /// rank, so the outer agreement sees the same everywhere.
    void step(const std::function<void()>& body, const std::string& where = std::string()) const;
    void agree(const std::function<void()>& body) const override { step(body); }

    /// Sums carried in rank order (bit-equal to one pass over the whole): rank 0 applies @a add
    /// to @a start, every later rank to what the rank before it passed on; the last rank's
    /// words are returned on every rank.
    Words carry(const Words& start, const std::function<Words(const Words&)>& add) const;
};

/// What a rank read of a volume (the read_volume node's output on ranks).
struct VolumePiece {
    std::shared_ptr<const BrickPlan> plan; ///< the block order cut into one piece per rank
    /// Samples read from the file; unset for a .vdb read with delayed loading, whose leaves are
    /// read when first touched (counted after meshing, loadedLeafVoxels).
    std::optional<std::uint64_t> voxelsRead;
};

/// Where a rank's piece of a mesh sits in the whole mesh (the mesh and hidden_features nodes'
/// output on ranks). The whole mesh's vertices (and triangles) are sections of rows, each cut
/// into one run per rank: rank r's run of section s is [begin[s P + r], begin[s P + r + 1]),
/// and a piece holds its runs in section order. A mesh node's piece has one section; a
/// hidden-feature mesh has three (HiddenPiece).
struct MeshPiece {
    std::shared_ptr<const BrickPlan> plan;
    std::vector<std::uint64_t> vertexBegin, triangleBegin; ///< per section and rank, then the totals
    std::uint64_t voxelsRead = 0; ///< samples this rank read (VolumePiece)
};

/// Text as words and back (messages, JSON between ranks).
Words wordsOfText(const std::string& text);
std::string textOfWords(const Words& words);

} // namespace isouq::nodes
