// isouq: VTK XML PolyData reader (docs/vtp-format.md "Reading"), for what writeVtp writes and
// what VTK's vtkXMLPolyDataWriter writes uncompressed with raw appended data (or ascii arrays):
// the XML before the appended data is parsed with expat, then each array is read from its
// block. `isouq mesh --resume` reads a kept .vtp frame back with it, as a .ply with readPly.
#include "isouq/MeshIO.h"

#include <expat.h>

#include <algorithm>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <fcntl.h>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>
#include <sys/stat.h>
#include <unistd.h>

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the VTP reader assumes little endian");

namespace isouq {
namespace {

/// The XML before the appended data can be at most this long (field data in ascii included).
constexpr std::size_t kMaxHeadBytes = std::size_t(64) << 20;

/// One <DataArray> (or <Array>, a string array) and the element it sits in.
struct Array {
    std::string group, type, name, format;
    std::uint64_t components = 1, tuples = 0, offset = 0;
    bool hasTuples = false;
    std::string text; ///< an ascii array's values
};

/// What the XML says: the file's settings, the piece's counts, the arrays; the first problem.
struct Head {
    std::vector<std::string> open; ///< the element stack
    std::vector<Array> arrays;
    int current = -1; ///< the ascii array whose text is being read
    std::string type, byteOrder, headerType = "UInt32", compressor, encoding;
    int pieces = 0;
    std::uint64_t points = 0, polys = 0, others = 0; ///< others: verts, lines and strips
    std::string error;
};

bool parseCount(const char* text, std::uint64_t& out)
{
    const char* end = text + std::strlen(text);
    const auto [at, error] = std::from_chars(text, end, out);
    return error == std::errc() && at == end;
}

bool isArray(const std::string& element) { return element == "DataArray" || element == "Array"; }

void XMLCALL startElement(void* data, const XML_Char* name, const XML_Char** attributes)
{
    Head& h = *static_cast<Head*>(data);
    const std::string element = name, parent = h.open.empty() ? "" : h.open.back();
    h.open.push_back(element);
    const auto count = [&](const char* value, std::uint64_t& out) {
        if (!parseCount(value, out) && h.error.empty()) h.error = element + " has a malformed count '" + value + "'";
    };
    if (isArray(element)) {
        Array a;
        a.group = parent;
        for (const XML_Char** p = attributes; *p; p += 2) {
            const std::string key = p[0];
            if (key == "type") a.type = p[1];
            else if (key == "Name") a.name = p[1];
            else if (key == "format") a.format = p[1];
            else if (key == "NumberOfComponents") count(p[1], a.components);
            else if (key == "NumberOfTuples") count(p[1], a.tuples), a.hasTuples = true;
            else if (key == "offset") count(p[1], a.offset);
        }
        h.current = int(h.arrays.size());
        h.arrays.push_back(std::move(a));
        return;
    }
    for (const XML_Char** p = attributes; *p; p += 2) {
        const std::string key = p[0];
        if (element == "VTKFile") {
            if (key == "type") h.type = p[1];
            else if (key == "byte_order") h.byteOrder = p[1];
            else if (key == "header_type") h.headerType = p[1];
            else if (key == "compressor") h.compressor = p[1];
        } else if (element == "Piece") {
            std::uint64_t n = 0;
            if (key == "NumberOfPoints") count(p[1], h.points);
            else if (key == "NumberOfPolys") count(p[1], h.polys);
            else if (key == "NumberOfVerts" || key == "NumberOfLines" || key == "NumberOfStrips") count(p[1], n), h.others += n;
        } else if (element == "AppendedData" && key == "encoding") {
            h.encoding = p[1];
        }
    }
    if (element == "Piece") ++h.pieces;
}

void XMLCALL endElement(void* data, const XML_Char*)
{
    Head& h = *static_cast<Head*>(data);
    if (isArray(h.open.back())) h.current = -1;
    h.open.pop_back();
}

/// An ascii array's values: its own text, not that of elements inside it (VTK's InformationKey).
void XMLCALL characters(void* data, const XML_Char* text, int length)
{
    Head& h = *static_cast<Head*>(data);
    if (h.current >= 0 && isArray(h.open.back()) && h.arrays[std::size_t(h.current)].format == "ascii")
        h.arrays[std::size_t(h.current)].text.append(text, std::size_t(length));
}

std::size_t typeSize(const std::string& type)
{
    if (type == "Int8" || type == "UInt8" || type == "String") return 1;
    if (type == "Int16" || type == "UInt16") return 2;
    if (type == "Int32" || type == "UInt32" || type == "Float32") return 4;
    if (type == "Int64" || type == "UInt64" || type == "Float64") return 8;
    return 0;
}

class VtpReader {
public:
    explicit VtpReader(const std::string& path) : mPath(path) {}
    ~VtpReader()
    {
        if (mFd >= 0) ::close(mFd);
    }
    VtpReader(const VtpReader&) = delete;
    VtpReader& operator=(const VtpReader&) = delete;

    Mesh read(PlyInfo* info)
    {
        struct stat st;
        if (::stat(mPath.c_str(), &st) != 0) fail(std::strerror(errno));
        if (!S_ISREG(st.st_mode)) fail("not a regular file");
        mSize = std::uint64_t(st.st_size);
        mFd = ::open(mPath.c_str(), O_RDONLY | O_CLOEXEC);
        if (mFd < 0) fail(std::strerror(errno));
        parseHead();

        Mesh mesh;
        PlyInfo found;
        found.format = "vtp";
        const Array* points = nullptr;
        const Array *connectivity = nullptr, *offsets = nullptr;
        for (const Array& a : mHead.arrays) {
            if (a.group == "Points") points = &a;
            else if (a.group == "Polys" && a.name == "connectivity") connectivity = &a;
            else if (a.group == "Polys" && a.name == "offsets") offsets = &a;
        }
        if (mHead.points > 0 && !points) fail("no Points array");
        if (points) {
            if (points->components != 3) fail("Points has " + std::to_string(points->components) + " components, not 3");
            const std::vector<float> xyz = values<float>(*points, mHead.points * 3);
            mesh.positions.resize(std::size_t(mHead.points));
            for (std::size_t v = 0; v < mesh.positions.size(); ++v)
                mesh.positions[v] = openvdb::Vec3s(xyz[3 * v], xyz[3 * v + 1], xyz[3 * v + 2]);
        }
        if (mHead.polys > 0) {
            if (!connectivity || !offsets) fail("Polys without connectivity and offsets");
            const std::vector<std::int64_t> ends = values<std::int64_t>(*offsets, mHead.polys);
            const std::vector<std::int64_t> ids = values<std::int64_t>(*connectivity, mHead.polys * 3);
            mesh.triangles.resize(std::size_t(mHead.polys));
            for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
                if (ends[f] != std::int64_t(3 * (f + 1))) fail("polygon " + std::to_string(f) + " is not a triangle");
                for (int c = 0; c < 3; ++c) {
                    const std::int64_t v = ids[3 * f + std::size_t(c)];
                    if (v < 0 || std::uint64_t(v) >= mHead.points)
                        fail("triangle " + std::to_string(f) + " has a vertex index out of range");
                    mesh.triangles[f][c] = openvdb::Index32(v);
                }
            }
        }
        for (const Array& a : mHead.arrays) {
            if (a.group == "PointData" && a.components == 1) column(a, mesh.vertexAttributes, mHead.points);
            else if (a.group == "CellData" && a.components == 1) column(a, mesh.faceAttributes, mHead.polys);
            else if (a.group == "FieldData") fieldData(a, mesh, found);
        }
        if (info) *info = std::move(found);
        return mesh;
    }

private:
    [[noreturn]] void fail(const std::string& reason) const { throw IoError("cannot read " + mPath + ": " + reason); }

    /// Reads @a bytes at @a offset, or fails naming the file as truncated.
    void readAt(std::uint64_t offset, char* out, std::uint64_t bytes) const
    {
        if (offset > mSize || bytes > mSize - offset) fail("truncated data (an array ends past the end of the file)");
        for (std::uint64_t done = 0; done < bytes;) {
            const ssize_t n = ::pread(mFd, out + done, std::size_t(bytes - done), off_t(offset + done));
            if (n <= 0) fail(n < 0 ? std::strerror(errno) : "truncated data");
            done += std::uint64_t(n);
        }
    }

    /// The XML up to the appended data's `_` (the whole file without appended data), parsed.
    void parseHead()
    {
        std::string head(std::size_t(std::min<std::uint64_t>(mSize, kMaxHeadBytes)), '\0');
        readAt(0, head.data(), head.size());
        const std::size_t tag = head.find("<AppendedData");
        std::size_t xmlEnd = head.size();
        if (tag != std::string::npos) {
            const std::size_t close = head.find('>', tag);
            const std::size_t underscore = close == std::string::npos ? close : head.find_first_not_of(" \t\r\n", close + 1);
            if (underscore == std::string::npos || head[underscore] != '_') fail("no '_' opens the appended data");
            xmlEnd = underscore;
            mDataStart = underscore + 1;
        } else if (mSize > kMaxHeadBytes) {
            fail("no appended data in the first " + std::to_string(kMaxHeadBytes >> 20) + " MiB");
        }
        const std::string xml = head.substr(0, xmlEnd) + (tag != std::string::npos ? "</AppendedData></VTKFile>" : "");
        std::unique_ptr<std::remove_pointer_t<XML_Parser>, void (*)(XML_Parser)> parser(XML_ParserCreate(nullptr), XML_ParserFree);
        XML_SetUserData(parser.get(), &mHead);
        XML_SetElementHandler(parser.get(), startElement, endElement);
        XML_SetCharacterDataHandler(parser.get(), characters);
        if (XML_Parse(parser.get(), xml.data(), int(xml.size()), XML_TRUE) != XML_STATUS_OK)
            fail(std::string("not VTK XML (") + XML_ErrorString(XML_GetErrorCode(parser.get())) + " at line " +
                std::to_string(XML_GetCurrentLineNumber(parser.get())) + ")");
        if (!mHead.error.empty()) fail(mHead.error);
        if (mHead.type != "PolyData") fail("not VTK XML PolyData (VTKFile type '" + mHead.type + "')");
        if (mHead.byteOrder != "LittleEndian") fail("byte order '" + mHead.byteOrder + "'; only LittleEndian is read");
        if (mHead.headerType != "UInt32" && mHead.headerType != "UInt64") fail("header_type '" + mHead.headerType + "'");
        if (!mHead.compressor.empty()) fail("compressed data (" + mHead.compressor + "); write it uncompressed");
        if (tag != std::string::npos && mHead.encoding != "raw") fail("appended data in " + mHead.encoding + "; only raw is read");
        if (mHead.pieces != 1) fail(std::to_string(mHead.pieces) + " pieces; one is read");
        if (mHead.others > 0) fail("vertices, lines or strips; only triangles (Polys) are read");
    }

    /// The size of appended array @a a's block, checked to hold @a count values (a String any
    /// number of bytes) and to end in the file, before anything is allocated for it.
    std::uint64_t blockBytes(const Array& a, std::uint64_t count) const
    {
        const std::size_t size = typeSize(a.type);
        if (size == 0) fail("array '" + a.name + "' has type '" + a.type + "'");
        if (a.format != "appended") fail("array '" + a.name + "' is " + a.format + "; appended and ascii are read");
        if (a.offset > mSize - mDataStart) fail("truncated data (an array ends past the end of the file)"); // no wrap below
        std::uint64_t bytes = 0;
        readAt(mDataStart + a.offset, reinterpret_cast<char*>(&bytes), sizeWord());
        if (a.type != "String" && (count > std::numeric_limits<std::uint64_t>::max() / size || bytes != count * size))
            fail("array '" + a.name + "' holds " + std::to_string(bytes) + " bytes, not " + std::to_string(count) + " values");
        // A size word that agrees with a huge declared count still has to end in the file.
        if (bytes > mSize - mDataStart - a.offset - sizeWord()) fail("truncated data (an array ends past the end of the file)");
        return bytes;
    }

    /// The @a bytes of appended array @a a's block (blockBytes) into @a out.
    void readBlock(const Array& a, std::uint64_t bytes, char* out) const
    {
        readAt(mDataStart + a.offset + sizeWord(), out, bytes);
    }

    std::size_t sizeWord() const { return mHead.headerType == "UInt64" ? 8 : 4; }

    /// @a count values of @a a (appended or ascii) as T.
    template <typename T>
    std::vector<T> values(const Array& a, std::uint64_t count) const
    {
        std::vector<T> out;
        if (a.format == "ascii") {
            std::string_view text = a.text;
            while (!text.empty()) {
                const std::size_t start = text.find_first_not_of(" \t\r\n");
                if (start == std::string_view::npos) break;
                text.remove_prefix(start);
                double v = 0;
                const auto [at, error] = std::from_chars(text.data(), text.data() + text.size(), v);
                if (error != std::errc() || out.size() >= count) fail("array '" + a.name + "' has malformed or extra values");
                if constexpr (std::is_integral_v<T>)
                    if (!(v >= double(std::numeric_limits<T>::lowest()) && v <= double(std::numeric_limits<T>::max())))
                        fail("array '" + a.name + "' has a value beyond its type");
                out.push_back(T(v));
                text.remove_prefix(std::size_t(at - text.data()));
            }
            if (out.size() != count) fail("array '" + a.name + "' has " + std::to_string(out.size()) + " values, not " + std::to_string(count));
            return out;
        }
        // A String block's size is not checked against a count: refused before the count's allocation.
        if (a.type == "String") fail("array '" + a.name + "' has type 'String'");
        const std::uint64_t bytes = blockBytes(a, count);
        out.resize(std::size_t(count));
        const auto convert = [&](auto tag) {
            using S = decltype(tag);
            if constexpr (std::is_same_v<S, T>) { // stored as wanted (all of writeVtp's arrays): no copy
                readBlock(a, bytes, reinterpret_cast<char*>(out.data()));
            } else {
                std::vector<char> raw(static_cast<std::size_t>(bytes));
                readBlock(a, bytes, raw.data());
                for (std::size_t i = 0; i < out.size(); ++i) {
                    S s;
                    std::memcpy(&s, raw.data() + i * sizeof(S), sizeof(S));
                    out[i] = T(s);
                }
            }
        };
        const std::string& t = a.type;
        if (t == "Float32") convert(float());
        else if (t == "Float64") convert(double());
        else if (t == "Int8") convert(std::int8_t());
        else if (t == "UInt8") convert(std::uint8_t());
        else if (t == "Int16") convert(std::int16_t());
        else if (t == "UInt16") convert(std::uint16_t());
        else if (t == "Int32") convert(std::int32_t());
        else if (t == "UInt32") convert(std::uint32_t());
        else if (t == "Int64") convert(std::int64_t());
        else if (t == "UInt64") convert(std::uint64_t());
        else fail("array '" + a.name + "' has type '" + t + "'");
        return out;
    }

    /// A scalar point or cell array as a column, typed as readPly types them: float from
    /// Float32 and Float64, uint8 from UInt8, int32 from any other integer.
    void column(const Array& a, AttributeTable& table, std::uint64_t rows) const
    {
        if (a.name.empty() || table.has(a.name)) fail("array name '" + a.name + "' is empty or appears twice");
        if (a.type == "Float32" || a.type == "Float64") table.add<float>(a.name, 0) = values<float>(a, rows);
        else if (a.type == "UInt8") table.add<std::uint8_t>(a.name, 0) = values<std::uint8_t>(a, rows);
        else table.add<std::int32_t>(a.name, 0) = values<std::int32_t>(a, rows);
    }

    /// writeVtp's field data: index_to_world, isovalue and the comment lines.
    void fieldData(const Array& a, Mesh& mesh, PlyInfo& info) const
    {
        const std::uint64_t tuples = a.hasTuples ? a.tuples : 1;
        if (a.name == "index_to_world" && a.components == 16 && tuples == 1) {
            const std::vector<double> m = values<double>(a, 16);
            std::copy(m.begin(), m.end(), mesh.indexToWorld.begin());
            info.hasIndexToWorld = true;
        } else if (a.name == "isovalue" && a.components == 1 && tuples == 1) {
            info.isovalue = values<float>(a, 1)[0];
        } else if (a.name == "comments" && a.type == "String") {
            // Each string's bytes ended by 0: decimal numbers in ascii, the bytes themselves appended.
            std::string bytes;
            if (a.format == "ascii") {
                std::string_view text = a.text;
                for (std::size_t start; (start = text.find_first_not_of(" \t\r\n")) != std::string_view::npos;) {
                    text.remove_prefix(start);
                    unsigned v = 0;
                    const auto [at, error] = std::from_chars(text.data(), text.data() + text.size(), v);
                    if (error != std::errc() || v > 255) fail("array 'comments' has a malformed byte");
                    bytes += char(v);
                    text.remove_prefix(std::size_t(at - text.data()));
                }
            } else {
                bytes.resize(std::size_t(blockBytes(a, 0)));
                readBlock(a, bytes.size(), bytes.data());
            }
            for (std::size_t at = 0; at < bytes.size();) {
                const std::size_t end = std::min(bytes.find('\0', at), bytes.size());
                const std::string line = bytes.substr(at, end - at);
                at = end + 1;
                if (line.rfind("isouq version ", 0) == 0) info.version = line.substr(14);
                else if (line.rfind("isouq method ", 0) == 0) info.method = line.substr(13);
                else if (line.rfind("isouq index_to_world ", 0) != 0 && line.rfind("isouq isovalue ", 0) != 0)
                    info.comments.push_back(line);
            }
        }
    }

    std::string mPath;
    int mFd = -1;
    std::uint64_t mSize = 0, mDataStart = 0;
    Head mHead;
};

} // namespace

Mesh readVtp(const std::string& path, PlyInfo* info)
{
    return VtpReader(path).read(info);
}

} // namespace isouq
