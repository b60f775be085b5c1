// isouq (internal): what the mesh writers share (MeshIO.h): the atomic temporary file (SPEC §8:
// no output is left behind on failure), number formatting and the header comments. The PLY
// writer and reader are in MeshIO.cc, the VTK XML PolyData writer in VtpWriter.cc.
#pragma once

#include "isouq/MeshIO.h"

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <string>
#include <vector>

namespace isouq::meshio_internal {

/// A file written under the temporary name `.<name>.tmp-<pid>` next to the target and renamed
/// onto it by commit(). Destroyed without commit, it removes the temporary file.
class AtomicFile {
public:
    /// @throw IoError when the target is a directory, not writable, or its folder is missing.
    explicit AtomicFile(const std::string& path);
    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;
    ~AtomicFile();

    void write(const char* data, std::size_t size);
    void write(const std::string& text) { write(text.data(), text.size()); }
    void commit();
    [[noreturn]] void fail(const std::string& reason) const;
    const std::string& path() const { return mPath; }
    const std::string& temporaryPath() const { return mTemp; }

private:
    std::string mPath, mTemp;
    int mFd = -1;
    int mSlot = -1; ///< its slot for removeTemporaryFiles()
};

/// Bytes per buffered write of the mesh bodies; rows per write of an ascii body.
constexpr std::size_t kChunkBytes = std::size_t(1) << 22;
constexpr std::size_t kAsciiChunkRows = std::size_t(1) << 15;

/// Same text as printf("%.17g") in the C locale: reads back to the same double.
std::string formatDouble(double v);
/// The shortest text that reads back as the same float ("nan", "inf" for non-finite values).
std::string formatFloat(float v);

/// Checks names (no blanks, not reserved, unique) and lengths of a table's columns.
void checkColumns(const AtomicFile& file, const AttributeTable& table, std::size_t size,
    const char* element, std::initializer_list<const char*> reserved);

/// The header comments without the word `comment` (docs/ply-format.md "Header"):
/// `isouq version V`, `isouq index_to_world m00 ... m33`, `isouq isovalue K`,
/// `isouq method M`, then each of @a options.comments. Fails on a line break in a comment.
std::vector<std::string> headerComments(const AtomicFile& file, const Mesh& mesh, const MeshFileOptions& options);

void writePlyTo(AtomicFile& file, const Mesh& mesh, const PlyOptions& options);
void writeVtpTo(AtomicFile& file, const Mesh& mesh, const MeshFileOptions& options); // VtpWriter.cc
/// What writeVtpTo writes before the appended blocks, for a mesh of @a nv vertices and @a nf
/// triangles with @a mesh's columns (checked against @a mesh's own counts).
std::string vtpHead(const AtomicFile& file, const Mesh& mesh, std::uint64_t nv, std::uint64_t nf,
    const MeshFileOptions& options);

} // namespace isouq::meshio_internal
