// isouq: mesh files with named attributes (SPEC §6, §8, §10 "Formats"): PLY out (binary
// little-endian or ascii) and in, VTK XML PolyData (.vtp) out, and atomic file writing. The
// exact layouts are documented in docs/ply-format.md and docs/vtp-format.md.
#pragma once

#include "isouq/Errors.h"
#include "isouq/MeshAttributes.h"

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace isouq {

/// What a mesh file records besides the mesh, in this order (docs/ply-format.md): PLY header
/// comments `comment isouq version V`, `comment isouq index_to_world m00 ... m33` (always),
/// `comment isouq isovalue K`, `comment isouq method M`, then each extra comment; the same
/// lines are a .vtp's field data (docs/vtp-format.md).
struct MeshFileOptions {
    std::string version;               ///< omitted when empty
    std::optional<float> isovalue;     ///< shortest text that reads back as the same float
    std::string method;                ///< e.g. "weno"; omitted when empty
    std::vector<std::string> comments; ///< each written as `comment <text>`, one line each
};

/// binary_little_endian (SPEC §6, the default) or ascii (what meshio 7 reads face columns
/// from: docs/ply-format.md "Other readers").
enum class PlyEncoding { BinaryLittleEndian, Ascii };

struct PlyOptions : MeshFileOptions {
    PlyEncoding encoding = PlyEncoding::BinaryLittleEndian;
};

/// What readPly found in the header besides the mesh.
struct PlyInfo {
    std::string format; ///< "binary_little_endian", "binary_big_endian" or "ascii"
    std::string version;
    std::optional<float> isovalue;
    std::string method;
    bool hasIndexToWorld = false;      ///< false: mesh.indexToWorld is the identity
    std::vector<std::string> comments; ///< all other comment lines, without "comment "
};

/// Writes @a mesh as PLY (binary little-endian unless @a options.encoding says ascii):
/// `element vertex` with float x y z and every vertex column in table order, `element face`
/// with `list uchar int vertex_indices` and every face column (PLY types float, int, uint8).
/// Atomic: the data go to a temporary file in the target's directory that is renamed onto
/// @a path only when complete, so an existing target is never clobbered by a failed write.
/// @throw IoError if the file cannot be written or the mesh is inconsistent (a column of the
/// wrong length, a name with spaces, a vertex index out of range).
void writePly(const Mesh& mesh, const std::string& path, const PlyOptions& options = {});

/// Writes @a mesh as VTK XML PolyData (docs/vtp-format.md): positions as Points, triangles as
/// Polys, every vertex column as point data and every face column as cell data under its own
/// name and type (Float32, Int32, UInt8), raw binary appended; the header comments of
/// writePly as field data (`index_to_world` as 16 Float64, the lines as strings). Atomic.
/// @throw IoError as writePly.
void writeVtp(const Mesh& mesh, const std::string& path, const MeshFileOptions& options = {});

/// Reads a PLY file (binary little or big endian, or ascii): x y z become positions, other
/// scalar vertex and face properties become columns (float and double as float; uchar and
/// uint8 as uint8; other integers as int32), `vertex_indices` (or `vertex_index`) becomes the
/// triangles. Other elements and other list properties are skipped.
/// @throw IoError if the file is missing, truncated, malformed, has a non-triangle face or
/// a vertex index out of range.
Mesh readPly(const std::string& path, PlyInfo* info = nullptr);

/// Reads a VTK XML PolyData file (docs/vtp-format.md "Reading"): what writeVtp writes, or any
/// .vtp of one Piece of triangles, little-endian and uncompressed, its arrays raw appended (as
/// vtkXMLPolyDataWriter writes with EncodeAppendedData off) or ascii. Points become positions,
/// Polys the triangles, scalar point and cell arrays columns typed as readPly types them;
/// writeVtp's field data fills @a info (format "vtp") and the mesh's index_to_world.
/// @throw IoError if the file is missing, not such a file, truncated, or holds other cells.
Mesh readVtp(const std::string& path, PlyInfo* info = nullptr);

/// Fails early, before any heavy work, if @a path could not be written atomically: creates
/// and removes a temporary file next to it.
/// @throw IoError naming the path and the reason.
void checkWritable(const std::string& path);

class SharedMeshFile;

/// Several outputs that appear together or not at all (a mesh, its hidden-feature mesh and
/// the summary): each is written to its temporary file when added, and commit() renames them
/// all. Destroyed without commit (an error or an interruption), it removes every temporary.
class OutputBatch {
public:
    OutputBatch();
    ~OutputBatch();
    OutputBatch(const OutputBatch&) = delete;
    OutputBatch& operator=(const OutputBatch&) = delete;

    /// @throw IoError as writePly.
    void addPly(const Mesh& mesh, const std::string& path, const PlyOptions& options = {});
    /// @throw IoError as writeVtp.
    void addVtp(const Mesh& mesh, const std::string& path, const MeshFileOptions& options = {});
    /// @throw IoError as writeTextFileAtomic.
    void addText(const std::string& path, const std::string& text);
    /// A file that several processes wrote (SharedMeshFile): renamed with the others.
    void addShared(std::unique_ptr<SharedMeshFile> file);
    /// Moves the files @a other staged (on another thread, say) into this batch, after its own.
    void add(OutputBatch&& other);
    /// @throw IoError naming the first path that could not be renamed.
    void commit();

private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
};

namespace meshio_internal {
class AtomicFile;
}

/// A binary PLY or a .vtp file that several processes write together (SPEC §10 "MPI";
/// docs/mpi.md): one process creates it under a temporary name next to @a path (removed when
/// this object dies uncommitted, and by removeTemporaryFiles()) and writes its header at offset
/// 0; every process writes its piece's rows at offsets from a prefix sum (MPI-IO):
/// plyPieceRows or plyAsciiRows, or VtpPieceLayout::rows; OutputBatch::addShared renames it
/// with the other outputs.
class SharedMeshFile {
public:
    /// @throw IoError as writePly.
    explicit SharedMeshFile(const std::string& path);
    ~SharedMeshFile();
    SharedMeshFile(const SharedMeshFile&) = delete;
    SharedMeshFile& operator=(const SharedMeshFile&) = delete;

    const std::string& temporaryPath() const;
    /// The header of a mesh of @a vertices and @a faces with the columns of @a piece: the bytes
    /// writePly writes before the rows. @throw IoError as writePly.
    std::string plyHeader(const Mesh& piece, std::uint64_t vertices, std::uint64_t faces, const PlyOptions& options) const;
    /// The same for writeVtp: the XML up to the `_` that opens the appended data.
    /// @throw IoError as writeVtp.
    std::string vtpHead(const Mesh& piece, std::uint64_t vertices, std::uint64_t faces, const MeshFileOptions& options) const;

private:
    friend class OutputBatch; // commits it with the run's other outputs

    std::unique_ptr<meshio_internal::AtomicFile> mFile;
};

/// Where a piece's rows sit in the whole mesh, for a file written in pieces: run k is the whole
/// mesh's rows [first[k], last[k]), the piece's rows from local[k] on; runs in piece order.
struct PieceRuns {
    std::vector<std::uint64_t> first, last;
    std::vector<std::size_t> local;
    /// The whole mesh's row of the piece's row @a l (l below the piece's rows).
    std::uint64_t globalOf(std::size_t l) const
    {
        std::size_t r = first.size() - 1;
        while (local[r] > l) --r;
        return first[r] + (l - local[r]);
    }
};

/// The appended data of a .vtp written in pieces (docs/vtp-format.md): the file writeVtp writes
/// for a mesh of @a vertices and @a faces with @a piece's columns, after SharedMeshFile::vtpHead's
/// @a headBytes. Each block's rows are contiguous, so a piece's rows of each block go to one
/// offset per run.
class VtpPieceLayout {
public:
    using Sink = std::function<void(std::uint64_t offset, const char* data, std::size_t size)>;
    VtpPieceLayout(const Mesh& piece, std::uint64_t vertices, std::uint64_t faces, std::uint64_t headBytes);
    std::uint64_t fileBytes() const;
    /// Every block's byte count and the closing tags: the part of one process, with the head.
    void frame(const Sink& sink) const;
    /// The values of @a piece's rows in every block, at their runs' offsets.
    /// @throw IoError if a vertex index is not below the whole mesh's vertices.
    void rows(const Mesh& piece, const PieceRuns& vertexRuns, const PieceRuns& faceRuns, const Sink& sink) const;

private:
    std::uint64_t mVertices, mFaces, mHeadBytes;
    std::vector<std::uint64_t> mStarts; ///< each block's start after the `_`, then the end of the last
};

/// Bytes of one vertex row and of one face row in @a mesh's binary PLY.
std::pair<std::size_t, std::size_t> plyRowBytes(const Mesh& mesh);

/// The binary rows of @a piece exactly as writePly writes them, in chunks of a few MiB:
/// sink(false, ...) for the vertex rows in order, then sink(true, ...) for the face rows.
/// @throw IoError if a vertex index is not below @a vertices (the whole mesh's count).
void plyPieceRows(const Mesh& piece, std::uint64_t vertices,
    const std::function<void(bool faces, const char* data, std::size_t size)>& sink);

/// The ascii lines of @a piece's vertex rows [begin, end) (or with @a faces its face rows)
/// exactly as writePly writes them, appended to @a out.
/// @throw IoError if a vertex index is not below @a vertices (the whole mesh's count).
void plyAsciiRows(const Mesh& piece, bool faces, std::size_t begin, std::size_t end, std::uint64_t vertices, std::string& out);

/// Removes every temporary file this process is writing (async-signal-safe: for a handler of
/// a second Ctrl-C, SIGTERM or SIGHUP that must end the process at once).
void removeTemporaryFiles() noexcept;

/// Writes @a text to @a path atomically (e.g. the `--summary` JSON).
/// @throw IoError naming the path and the reason.
void writeTextFileAtomic(const std::string& path, const std::string& text);

} // namespace isouq
