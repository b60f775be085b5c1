// isouq: binary PLY output and input of meshes with named attributes (SPEC §6, §8), and
// atomic file writing. The exact header is documented in docs/ply-format.md.
#pragma once

#include "isouq/Errors.h"
#include "isouq/MeshAttributes.h"

#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace isouq {

/// Header comments of a PLY file written by isouq, in this order (docs/ply-format.md):
/// `comment isouq version V`, `comment isouq index_to_world m00 ... m33` (always),
/// `comment isouq isovalue K`, `comment isouq method M`, then each extra comment.
struct PlyOptions {
    std::string version;               ///< omitted when empty
    std::optional<float> isovalue;     ///< shortest text that reads back as the same float
    std::string method;                ///< e.g. "weno"; omitted when empty
    std::vector<std::string> comments; ///< each written as `comment <text>`, one line each
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

/// Writes @a mesh as binary little-endian PLY: `element vertex` with float x y z and every
/// vertex column in table order, `element face` with `list uchar int vertex_indices` and
/// every face column (PLY types float, int, uchar). Atomic: the data go to a temporary file
/// in the target's directory that is renamed onto @a path only when complete, so an existing
/// target is never clobbered by a failed write.
/// @throw IoError if the file cannot be written or the mesh is inconsistent (a column of the
/// wrong length, a name with spaces, a vertex index out of range).
void writePly(const Mesh& mesh, const std::string& path, const PlyOptions& options = {});

/// Reads a PLY file (binary little or big endian, or ascii): x y z become positions, other
/// scalar vertex and face properties become columns (float and double as float; uchar and
/// uint8 as uint8; other integers as int32), `vertex_indices` (or `vertex_index`) becomes the
/// triangles. Other elements and other list properties are skipped.
/// @throw IoError if the file is missing, truncated, malformed, has a non-triangle face or
/// a vertex index out of range.
Mesh readPly(const std::string& path, PlyInfo* info = nullptr);

/// Fails early, before any heavy work, if @a path could not be written atomically: creates
/// and removes a temporary file next to it.
/// @throw IoError naming the path and the reason.
void checkWritable(const std::string& path);

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
    /// @throw IoError as writeTextFileAtomic.
    void addText(const std::string& path, const std::string& text);
    /// @throw IoError naming the first path that could not be renamed.
    void commit();

private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
};

/// Removes every temporary file this process is writing (async-signal-safe: for a handler of
/// a second Ctrl-C, SIGTERM or SIGHUP that must end the process at once).
void removeTemporaryFiles() noexcept;

/// Writes @a text to @a path atomically (e.g. the `--summary` JSON).
/// @throw IoError naming the path and the reason.
void writeTextFileAtomic(const std::string& path, const std::string& text);

} // namespace isouq
