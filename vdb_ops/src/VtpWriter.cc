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

/// The header of one appended array and the running offset of the next.
class AppendedLayout {
public:
    std::string array(const char* type, const std::string& name, int components, std::uint64_t bytes)
    {
        std::string line = "<DataArray type=\"" + std::string(type) + "\" Name=\"" + xmlEscaped(name) + "\"";
        if (components != 1) line += " NumberOfComponents=\"" + std::to_string(components) + "\"";
        line += " format=\"appended\" offset=\"" + std::to_string(mOffset) + "\"/>\n";
        mOffset += 8 + bytes;
        return line;
    }

private:
    std::uint64_t mOffset = 0;
};

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

void writeBlockSize(AtomicFile& file, std::uint64_t bytes)
{
    file.write(reinterpret_cast<const char*>(&bytes), sizeof(bytes));
}

void writeColumns(AtomicFile& file, const AttributeTable& table)
{
    for (const Attribute& a : table.columns())
        std::visit([&](const auto& v) {
            writeBlockSize(file, v.size() * sizeof(v[0]));
            file.write(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(v[0]));
        }, a.data);
}

/// connectivity (three indices per triangle) or offsets (3, 6, 9, ...), Int64, in chunks.
void writeIndexBlock(AtomicFile& file, const Mesh& mesh, bool offsets)
{
    const std::size_t nf = mesh.triangleCount(), perFace = offsets ? 1 : 3;
    writeBlockSize(file, nf * perFace * 8);
    const std::size_t chunkFaces = kChunkBytes / 24;
    std::vector<std::int64_t> chunk(std::min(nf, chunkFaces) * perFace);
    for (std::size_t begin = 0; begin < nf; begin += chunkFaces) {
        const std::size_t rows = std::min(chunkFaces, nf - begin);
        for (std::size_t r = 0; r < rows; ++r) {
            const std::size_t f = begin + r;
            if (offsets) {
                chunk[r] = std::int64_t(3 * (f + 1));
                continue;
            }
            const openvdb::Vec3I& t = mesh.triangles[f];
            if (t[0] >= mesh.vertexCount() || t[1] >= mesh.vertexCount() || t[2] >= mesh.vertexCount())
                file.fail("triangle " + std::to_string(f) + " has a vertex index out of range");
            for (int c = 0; c < 3; ++c) chunk[3 * r + c] = std::int64_t(t[c]);
        }
        file.write(reinterpret_cast<const char*>(chunk.data()), rows * perFace * 8);
    }
}

} // namespace

void writeVtpTo(AtomicFile& file, const Mesh& mesh, const MeshFileOptions& options)
{
    checkColumns(file, mesh.vertexAttributes, mesh.vertexCount(), "vertex", {"x", "y", "z"});
    checkColumns(file, mesh.faceAttributes, mesh.triangleCount(), "face", {});
    const std::size_t nv = mesh.vertexCount(), nf = mesh.triangleCount();

    // Appended blocks in this order: point data, cell data, points, connectivity, offsets.
    AppendedLayout layout;
    std::string x = "<?xml version=\"1.0\"?>\n"
                    "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n"
                    "  <PolyData>\n";
    x += fieldData(file, mesh, options);
    x += "    <Piece NumberOfPoints=\"" + std::to_string(nv) + "\" NumberOfVerts=\"0\" NumberOfLines=\"0\" "
         "NumberOfStrips=\"0\" NumberOfPolys=\"" + std::to_string(nf) + "\">\n";
    // err_est is the active scalar where present, so ParaView colours by it on opening (C4).
    const bool hasErrEst = mesh.vertexAttributes.find<float>(col::kErrEst) != nullptr;
    x += hasErrEst ? "      <PointData Scalars=\"" + std::string(col::kErrEst) + "\">\n" : std::string("      <PointData>\n");
    for (const Attribute& a : mesh.vertexAttributes.columns())
        x += "        " + layout.array(sVtkTypeNames[a.data.index()], a.name, 1, nv * sVtkTypeSizes[a.data.index()]);
    x += "      </PointData>\n      <CellData>\n";
    for (const Attribute& a : mesh.faceAttributes.columns())
        x += "        " + layout.array(sVtkTypeNames[a.data.index()], a.name, 1, nf * sVtkTypeSizes[a.data.index()]);
    x += "      </CellData>\n      <Points>\n";
    x += "        " + layout.array("Float32", "Points", 3, nv * 12);
    x += "      </Points>\n      <Polys>\n";
    x += "        " + layout.array("Int64", "connectivity", 1, nf * 24);
    x += "        " + layout.array("Int64", "offsets", 1, nf * 8);
    x += "      </Polys>\n    </Piece>\n  </PolyData>\n  <AppendedData encoding=\"raw\">\n   _";
    file.write(x);

    writeColumns(file, mesh.vertexAttributes);
    writeColumns(file, mesh.faceAttributes);
    writeBlockSize(file, nv * 12);
    static_assert(sizeof(openvdb::Vec3s) == 12, "positions are packed float triples");
    file.write(reinterpret_cast<const char*>(mesh.positions.data()), nv * 12);
    writeIndexBlock(file, mesh, /*offsets=*/false);
    writeIndexBlock(file, mesh, /*offsets=*/true);
    file.write(std::string("\n  </AppendedData>\n</VTKFile>\n"));
}

} // namespace isouq::meshio_internal
