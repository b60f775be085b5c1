// isouq: VTK XML PolyData writer (SPEC §10 "Formats"; layout in docs/vtp-format.md), written
// from VTK's documented file format ("VTK File Formats", XML section): no VTK library. One
// Piece, every array raw binary in one <AppendedData> block, each block a UInt64 byte count
// then the little-endian values.
#include "MeshIOInternal.h"

#include "isouq/Columns.h"

#include <algorithm>
#include <cstdint>
#include <cstring>

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the VTP writer assumes little endian");

namespace isouq::meshio_internal {
namespace {

/// VTK type names and sizes of the AttributeData alternatives (float, int32, uint8).
constexpr const char* sVtkTypeNames[] = {"Float32", "Int32", "UInt8"};
constexpr std::size_t sVtkTypeSizes[] = {4, 4, 1};

std::string xmlEscaped(const std::string& s)
{
    std::string out;
    for (char c : s) {
        switch (c) {
        case '&': out += "&amp;"; break;
        case '<': out += "&lt;"; break;
        case '>': out += "&gt;"; break;
        case '"': out += "&quot;"; break;
        default: out += c;
        }
    }
    return out;
}

/// One appended array of a .vtp (docs/vtp-format.md): its XML attributes, which rows it holds
/// (vertices or faces) and its bytes per row.
struct Block {
    enum Kind { VertexColumn, FaceColumn, Points, Connectivity, Offsets } kind;
    std::size_t column; ///< the column's index in its table (a column block)
    const char* type;
    std::string name;
    int components;
    std::size_t rowBytes;
    bool faces() const { return kind == FaceColumn || kind == Connectivity || kind == Offsets; }
};

/// The appended arrays of a mesh with @a mesh's columns, in file order: point data, cell data,
/// points, connectivity, offsets.
std::vector<Block> blocksOf(const Mesh& mesh)
{
    std::vector<Block> blocks;
    const auto columns = [&](const AttributeTable& table, Block::Kind kind) {
        for (std::size_t i = 0; i < table.columns().size(); ++i) {
            const Attribute& a = table.columns()[i];
            blocks.push_back({kind, i, sVtkTypeNames[a.data.index()], a.name, 1, sVtkTypeSizes[a.data.index()]});
        }
    };
    columns(mesh.vertexAttributes, Block::VertexColumn);
    columns(mesh.faceAttributes, Block::FaceColumn);
    blocks.push_back({Block::Points, 0, "Float32", "Points", 3, 12});
    blocks.push_back({Block::Connectivity, 0, "Int64", "connectivity", 1, 24});
    blocks.push_back({Block::Offsets, 0, "Int64", "offsets", 1, 8});
    return blocks;
}

/// Where each block starts after the `_` of the appended data, then the end of the last.
std::vector<std::uint64_t> blockStarts(const std::vector<Block>& blocks, std::uint64_t nv, std::uint64_t nf)
{
    std::vector<std::uint64_t> starts{0};
    for (const Block& b : blocks) starts.push_back(starts.back() + 8 + (b.faces() ? nf : nv) * b.rowBytes);
    return starts;
}

std::string arrayXml(const Block& b, std::uint64_t offset)
{
    std::string line = "<DataArray type=\"" + std::string(b.type) + "\" Name=\"" + xmlEscaped(b.name) + "\"";
    if (b.components != 1) line += " NumberOfComponents=\"" + std::to_string(b.components) + "\"";
    return line + " format=\"appended\" offset=\"" + std::to_string(offset) + "\"/>\n";
}

constexpr const char* sTail = "\n  </AppendedData>\n</VTKFile>\n";

std::string fieldData(const AtomicFile& file, const Mesh& mesh, const MeshFileOptions& options)
{
    std::string x = "    <FieldData>\n"
                    "      <DataArray type=\"Float64\" Name=\"index_to_world\" NumberOfComponents=\"16\" "
                    "NumberOfTuples=\"1\" format=\"ascii\">\n       ";
    for (double v : mesh.indexToWorld) x += " " + formatDouble(v);
    x += "\n      </DataArray>\n";
    if (options.isovalue)
        x += "      <DataArray type=\"Float32\" Name=\"isovalue\" NumberOfTuples=\"1\" format=\"ascii\">\n        " +
             formatFloat(*options.isovalue) + "\n      </DataArray>\n";
    // A vtkStringArray in ascii: the bytes of each string as decimal numbers, each string
    // ended by 0 (what VTK's XML writer produces for type="String").
    const std::vector<std::string> comments = headerComments(file, mesh, options);
    x += "      <Array type=\"String\" Name=\"comments\" NumberOfTuples=\"" + std::to_string(comments.size()) +
         "\" format=\"ascii\">\n";
    for (const std::string& c : comments) {
        x += "       ";
        for (unsigned char ch : c) x += " " + std::to_string(unsigned(ch));
        x += " 0\n";
    }
    return x + "      </Array>\n    </FieldData>\n";
}

/// Rows [begin, begin + rows) of @a b as the file holds them, in chunks: sink(data, bytes).
/// Connectivity is checked against @a nv (the whole mesh's vertices); offsets count from the
/// whole mesh's triangle @a first (3 (f + 1) for triangle f).
template <typename Sink, typename Fail>
void blockRows(const Mesh& mesh, const Block& b, std::size_t begin, std::size_t rows, std::uint64_t first,
    std::uint64_t nv, const Sink& sink, const Fail& fail)
{
    if (b.kind == Block::VertexColumn || b.kind == Block::FaceColumn) {
        const AttributeTable& table = b.kind == Block::VertexColumn ? mesh.vertexAttributes : mesh.faceAttributes;
        std::visit([&](const auto& v) { sink(reinterpret_cast<const char*>(v.data() + begin), rows * sizeof(v[0])); },
            table.columns()[b.column].data);
        return;
    }
    static_assert(sizeof(openvdb::Vec3s) == 12, "positions are packed float triples");
    if (b.kind == Block::Points) return sink(reinterpret_cast<const char*>(mesh.positions.data() + begin), rows * 12);
    const bool offsets = b.kind == Block::Offsets;
    const std::size_t perFace = offsets ? 1 : 3, chunkFaces = kChunkBytes / 24;
    std::vector<std::int64_t> chunk(std::min(rows, chunkFaces) * perFace);
    for (std::size_t done = 0; done < rows; done += chunkFaces) {
        const std::size_t n = std::min(chunkFaces, rows - done);
        for (std::size_t r = 0; r < n; ++r) {
            const std::size_t f = begin + done + r;
            if (offsets) {
                chunk[r] = std::int64_t(3 * (first + done + r + 1));
                continue;
            }
            const openvdb::Vec3I& t = mesh.triangles[f];
            if (t[0] >= nv || t[1] >= nv || t[2] >= nv)
                fail("triangle " + std::to_string(first + done + r) + " has a vertex index out of range");
            for (int c = 0; c < 3; ++c) chunk[3 * r + c] = std::int64_t(t[c]);
        }
        sink(reinterpret_cast<const char*>(chunk.data()), n * perFace * 8);
    }
}

} // namespace

std::string vtpHead(const AtomicFile& file, const Mesh& mesh, std::uint64_t nv, std::uint64_t nf,
    const MeshFileOptions& options)
{
    checkColumns(file, mesh.vertexAttributes, mesh.vertexCount(), "vertex", {"x", "y", "z"});
    checkColumns(file, mesh.faceAttributes, mesh.triangleCount(), "face", {});
    const std::vector<Block> blocks = blocksOf(mesh);
    const std::vector<std::uint64_t> starts = blockStarts(blocks, nv, nf);
    std::string x = "<?xml version=\"1.0\"?>\n"
                    "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n"
                    "  <PolyData>\n";
    x += fieldData(file, mesh, options);
    x += "    <Piece NumberOfPoints=\"" + std::to_string(nv) + "\" NumberOfVerts=\"0\" NumberOfLines=\"0\" "
         "NumberOfStrips=\"0\" NumberOfPolys=\"" + std::to_string(nf) + "\">\n";
    // err_est is the active scalar where present, so ParaView colours by it on opening (C4).
    const bool hasErrEst = mesh.vertexAttributes.find<float>(col::kErrEst) != nullptr;
    x += hasErrEst ? "      <PointData Scalars=\"" + std::string(col::kErrEst) + "\">\n" : std::string("      <PointData>\n");
    // The groups' closing and opening tags, before the first block of each group.
    const char* groups[] = {"", "      </PointData>\n      <CellData>\n", "      </CellData>\n      <Points>\n",
        "      </Points>\n      <Polys>\n"};
    int group = 0;
    for (std::size_t i = 0; i < blocks.size(); ++i) {
        const int g = std::min<int>(blocks[i].kind, 3);
        while (group < g) x += groups[++group];
        x += "        " + arrayXml(blocks[i], starts[i]);
    }
    return x + "      </Polys>\n    </Piece>\n  </PolyData>\n  <AppendedData encoding=\"raw\">\n   _";
}

void writeVtpTo(AtomicFile& file, const Mesh& mesh, const MeshFileOptions& options)
{
    const std::size_t nv = mesh.vertexCount(), nf = mesh.triangleCount();
    file.write(vtpHead(file, mesh, nv, nf, options));
    const auto write = [&](const char* data, std::size_t bytes) { file.write(data, bytes); };
    const auto fail = [&](const std::string& reason) { file.fail(reason); };
    for (const Block& b : blocksOf(mesh)) {
        const std::uint64_t bytes = (b.faces() ? nf : nv) * b.rowBytes;
        file.write(reinterpret_cast<const char*>(&bytes), sizeof(bytes));
        blockRows(mesh, b, 0, b.faces() ? nf : nv, 0, nv, write, fail);
    }
    file.write(std::string(sTail));
}

} // namespace isouq::meshio_internal

namespace isouq {

VtpPieceLayout::VtpPieceLayout(const Mesh& piece, std::uint64_t vertices, std::uint64_t faces, std::uint64_t headBytes)
    : mVertices(vertices), mFaces(faces), mHeadBytes(headBytes),
      mStarts(meshio_internal::blockStarts(meshio_internal::blocksOf(piece), vertices, faces))
{
}

std::uint64_t VtpPieceLayout::fileBytes() const
{
    return mHeadBytes + mStarts.back() + std::strlen(meshio_internal::sTail);
}

void VtpPieceLayout::frame(const Sink& sink) const
{
    for (std::size_t i = 0; i + 1 < mStarts.size(); ++i) {
        const std::uint64_t bytes = mStarts[i + 1] - mStarts[i] - 8;
        sink(mHeadBytes + mStarts[i], reinterpret_cast<const char*>(&bytes), sizeof(bytes));
    }
    sink(mHeadBytes + mStarts.back(), meshio_internal::sTail, std::strlen(meshio_internal::sTail));
}

void VtpPieceLayout::rows(const Mesh& piece, const PieceRuns& vertexRuns, const PieceRuns& faceRuns, const Sink& sink) const
{
    using namespace meshio_internal;
    const std::vector<Block> blocks = blocksOf(piece);
    for (std::size_t i = 0; i < blocks.size(); ++i) {
        const Block& b = blocks[i];
        const PieceRuns& runs = b.faces() ? faceRuns : vertexRuns;
        for (std::size_t k = 0; k < runs.first.size(); ++k) {
            std::uint64_t at = mHeadBytes + mStarts[i] + 8 + runs.first[k] * b.rowBytes;
            blockRows(piece, b, runs.local[k], std::size_t(runs.last[k] - runs.first[k]), runs.first[k], mVertices,
                [&](const char* data, std::size_t bytes) { sink(at, data, bytes), at += bytes; },
                [](const std::string& reason) { throw IoError("cannot write a VTP piece: " + reason); });
        }
    }
}

} // namespace isouq
