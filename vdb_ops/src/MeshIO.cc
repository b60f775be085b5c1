// isouq: PLY writer and reader (SPEC §6) and atomic writes (SPEC §8: no output is left behind
// on failure, an existing output is never clobbered). Header layout: docs/ply-format.md.
#include "MeshIOInternal.h"
#include "isouq/Threads.h"

#include <tbb/task_group.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <climits>
#include <iterator>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string_view>
#include <type_traits>

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the PLY writer assumes little endian");

namespace isouq {
namespace meshio_internal {

// ---------------------------------------------------------------------------------------
// Atomic writing
// ---------------------------------------------------------------------------------------

/// The temporary files alive in this process, for removeTemporaryFiles() from a signal handler:
/// fixed slots claimed and released with atomics, so the handler neither allocates nor locks.
struct TempSlot {
    std::atomic<bool> used{false}, ready{false};
    char name[PATH_MAX];
};
TempSlot sTempSlots[64];
std::atomic<unsigned> sTempCounter{0};

int claimTempSlot(const std::string& path)
{
    if (path.size() >= PATH_MAX) return -1;
    for (int i = 0; i < int(std::size(sTempSlots)); ++i) {
        bool expected = false;
        if (!sTempSlots[i].used.compare_exchange_strong(expected, true)) continue;
        std::memcpy(sTempSlots[i].name, path.c_str(), path.size() + 1);
        sTempSlots[i].ready.store(true);
        return i;
    }
    return -1; // more than 64 at once: still removed by the destructor, not by a signal
}

void releaseTempSlot(int slot)
{
    if (slot < 0) return;
    sTempSlots[slot].ready.store(false);
    sTempSlots[slot].used.store(false);
}

// A short temporary name `.isouq-<pid>-<n>.tmp` next to the target, renamed over it by commit().
// Everything the rename could still refuse is checked here, before any work (checkWritable):
// a name too long for the folder's file system, a folder, a device, FIFO or socket (which a
// rename would replace). A symbolic link is written through: the file it names is replaced,
// with its permissions, and the link stays.
AtomicFile::AtomicFile(const std::string& path) : mPath(path)
{
    struct stat st;
    if (::lstat(mPath.c_str(), &st) == 0 && S_ISLNK(st.st_mode)) {
        char* target = ::realpath(mPath.c_str(), nullptr);
        if (!target) fail("a symbolic link to a missing file");
        mPath = target;
        std::free(target);
    }
    const std::size_t slash = mPath.find_last_of('/');
    const std::string dir = slash == std::string::npos ? "" : mPath.substr(0, slash + 1);
    const std::string name = slash == std::string::npos ? mPath : mPath.substr(slash + 1);
    if (name.empty() || name == "." || name == "..") fail("not a file name");
    const long nameMax = ::pathconf(dir.empty() ? "." : dir.c_str(), _PC_NAME_MAX);
    if (mPath.size() >= PATH_MAX || name.size() > std::size_t(nameMax > 0 ? nameMax : NAME_MAX))
        fail(std::strerror(ENAMETOOLONG));
    int mode = -1;
    if (::stat(mPath.c_str(), &st) == 0) {
        if (S_ISDIR(st.st_mode)) fail(std::strerror(EISDIR));
        if (!S_ISREG(st.st_mode)) fail("not a regular file (a device, FIFO or socket), which the output would replace");
        if (::access(mPath.c_str(), W_OK) != 0) fail(std::strerror(errno));
        mode = int(st.st_mode & 07777);
    }
    const std::string temp = dir + ".isouq-" + std::to_string(::getpid()) + "-" +
        std::to_string(sTempCounter.fetch_add(1)) + ".tmp";
    mSlot = claimTempSlot(temp);
    mFd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0666);
    if (mFd >= 0 && mode >= 0 && ::fchmod(mFd, mode_t(mode)) != 0) {
        const int error = errno;
        ::close(mFd), ::unlink(temp.c_str());
        mFd = -1, errno = error;
    }
    if (mFd < 0) {
        releaseTempSlot(mSlot);
        fail(std::strerror(errno));
    }
    mTemp = temp;
}

AtomicFile::~AtomicFile()
{
    if (mFd >= 0) ::close(mFd);
    if (!mTemp.empty()) ::unlink(mTemp.c_str());
    releaseTempSlot(mSlot);
}

void AtomicFile::write(const char* data, std::size_t size)
{
    while (size > 0) {
        const ssize_t n = ::write(mFd, data, size);
        if (n < 0) {
            if (errno == EINTR) continue;
            fail(std::strerror(errno));
        }
        data += n;
        size -= static_cast<std::size_t>(n);
    }
}

void AtomicFile::commit()
{
    const int fd = mFd;
    mFd = -1;
    if (::close(fd) != 0) fail(std::strerror(errno));
    if (::rename(mTemp.c_str(), mPath.c_str()) != 0) fail(std::strerror(errno));
    mTemp.clear();
    releaseTempSlot(mSlot);
    mSlot = -1;
}

void AtomicFile::fail(const std::string& reason) const
{
    throw IoError("cannot write " + mPath + ": " + reason);
}

// ---------------------------------------------------------------------------------------
// Writer
// ---------------------------------------------------------------------------------------

/// PLY type names of the AttributeData alternatives (float, int32, uint8). `uint8`, not
/// `uchar`: meshio 7 reads binary `uchar` as int8 (docs/ply-format.md "Other readers").
constexpr const char* sPlyTypeNames[] = {"float", "int", "uint8"};
constexpr std::size_t sPlyTypeSizes[] = {4, 4, 1};

std::string formatDouble(double v)
{
    char buf[40];
    const auto r = std::to_chars(buf, buf + sizeof(buf), v, std::chars_format::general, 17);
    return std::string(buf, r.ptr); // same text as printf("%.17g") in the C locale
}

std::string formatFloat(float v)
{
    char buf[40];
    const auto r = std::to_chars(buf, buf + sizeof(buf), v); // shortest round trip
    return std::string(buf, r.ptr);
}

/// Copies rows [0, rows) of one column into the interleaved chunk at byte stride @a stride.
template <typename T>
void interleave(const T* src, std::size_t rows, char* dst, std::size_t stride)
{
    for (std::size_t r = 0; r < rows; ++r, dst += stride) std::memcpy(dst, src + r, sizeof(T));
}

void checkColumns(const AtomicFile& file, const AttributeTable& table, std::size_t size,
    const char* element, std::initializer_list<const char*> reserved)
{
    const auto& cols = table.columns();
    for (std::size_t c = 0; c < cols.size(); ++c) {
        const std::string& name = cols[c].name;
        const bool badChar = std::any_of(name.begin(), name.end(),
            [](char ch) { return static_cast<unsigned char>(ch) <= ' ' || ch == 127; });
        if (name.empty() || badChar)
            file.fail(std::string(element) + " column '" + name + "' is not a PLY property name");
        for (const char* r : reserved)
            if (name == r) file.fail(std::string(element) + " column '" + name + "' is reserved");
        for (std::size_t d = 0; d < c; ++d)
            if (cols[d].name == name) file.fail(std::string(element) + " column '" + name + "' twice");
        if (attributeSize(cols[c].data) != size)
            file.fail(std::string(element) + " column '" + name + "' has " +
                      std::to_string(attributeSize(cols[c].data)) + " values for " +
                      std::to_string(size) + (std::string(element) == "vertex" ? " vertices" : " faces"));
    }
}

std::vector<std::string> headerComments(const AtomicFile& file, const Mesh& mesh, const MeshFileOptions& options)
{
    std::vector<std::string> comments;
    if (!options.version.empty()) comments.push_back("isouq version " + options.version);
    std::string m = "isouq index_to_world";
    for (double v : mesh.indexToWorld) m += " " + formatDouble(v);
    comments.push_back(m);
    if (options.isovalue) comments.push_back("isouq isovalue " + formatFloat(*options.isovalue));
    if (!options.method.empty()) comments.push_back("isouq method " + options.method);
    comments.insert(comments.end(), options.comments.begin(), options.comments.end());
    for (const std::string& c : comments)
        if (c.find_first_of("\r\n") != std::string::npos) file.fail("comment with a line break");
    return comments;
}

std::string plyHeader(const AtomicFile& file, const Mesh& mesh, const PlyOptions& options,
    std::size_t vertices, std::size_t faces)
{
    std::string h = "ply\nformat ";
    h += options.encoding == PlyEncoding::Ascii ? "ascii" : "binary_little_endian";
    h += " 1.0\n";
    for (const std::string& c : headerComments(file, mesh, options)) h += "comment " + c + "\n";
    h += "element vertex " + std::to_string(vertices) + "\n";
    h += "property float x\nproperty float y\nproperty float z\n";
    for (const Attribute& a : mesh.vertexAttributes.columns())
        h += std::string("property ") + sPlyTypeNames[a.data.index()] + " " + a.name + "\n";
    h += "element face " + std::to_string(faces) + "\n";
    h += "property list uchar int vertex_indices\n";
    for (const Attribute& a : mesh.faceAttributes.columns())
        h += std::string("property ") + sPlyTypeNames[a.data.index()] + " " + a.name + "\n";
    return h + "end_header\n";
}

std::size_t rowBytes(const AttributeTable& table, std::size_t fixed)
{
    for (const Attribute& a : table.columns()) fixed += sPlyTypeSizes[a.data.index()];
    return fixed;
}

/// Interleaves the columns of rows [begin, begin + rows) after the first @a offset bytes.
void interleaveColumns(const AttributeTable& table, std::size_t begin, std::size_t rows,
    char* chunk, std::size_t offset, std::size_t stride)
{
    for (const Attribute& a : table.columns()) {
        std::visit([&](const auto& v) { interleave(v.data() + begin, rows, chunk + offset, stride); },
            a.data);
        offset += sPlyTypeSizes[a.data.index()];
    }
}

/// Fails unless the vertex indices of triangle @a f are below @a nv.
template <typename Fail>
void checkTriangle(const Mesh& mesh, std::size_t f, std::size_t nv, const Fail& fail)
{
    const openvdb::Vec3I& t = mesh.triangles[f];
    if (t[0] >= nv || t[1] >= nv || t[2] >= nv) fail("triangle " + std::to_string(f) + " has a vertex index out of range");
}

/// The binary rows of @a mesh in chunks: sink(false, ...) for the vertex rows, then
/// sink(true, ...) for the face rows, every call on the calling thread (an MPI sink must be:
/// MPI_THREAD_FUNNELED); vertex indices must be below @a nv. While the sink takes one chunk (the
/// kernel copying it into the page cache, the writes' serial part), a task interleaves the next.
template <typename Sink, typename Fail>
void binaryRows(const Mesh& mesh, std::size_t nv, const Sink& sink, const Fail& fail)
{
    const std::size_t nf = mesh.triangleCount(), rowsV = mesh.vertexCount();
    const std::size_t vStride = rowBytes(mesh.vertexAttributes, 12);
    const std::size_t fStride = rowBytes(mesh.faceAttributes, 13);
    const std::size_t vChunk = std::max<std::size_t>(1, kChunkBytes / vStride);
    const std::size_t fChunk = std::max<std::size_t>(1, kChunkBytes / fStride);
    const std::size_t vChunks = (rowsV + vChunk - 1) / vChunk, chunks = vChunks + (nf + fChunk - 1) / fChunk;
    // Chunk k's rows into out; returns their bytes.
    const auto format = [&](std::size_t k, std::vector<char>& out) {
        if (k < vChunks) {
            const std::size_t begin = k * vChunk, rows = std::min(vChunk, rowsV - begin);
            out.resize(rows * vStride);
            char* row = out.data();
            for (std::size_t r = 0; r < rows; ++r, row += vStride)
                std::memcpy(row, mesh.positions[begin + r].asPointer(), 12);
            interleaveColumns(mesh.vertexAttributes, begin, rows, out.data(), 12, vStride);
            return rows * vStride;
        }
        const std::size_t begin = (k - vChunks) * fChunk, rows = std::min(fChunk, nf - begin);
        out.resize(rows * fStride);
        char* row = out.data();
        for (std::size_t r = 0; r < rows; ++r, row += fStride) {
            checkTriangle(mesh, begin + r, nv, fail);
            const openvdb::Vec3I& t = mesh.triangles[begin + r];
            const std::int32_t idx[3] = {std::int32_t(t[0]), std::int32_t(t[1]), std::int32_t(t[2])};
            row[0] = 3;
            std::memcpy(row + 1, idx, 12);
        }
        interleaveColumns(mesh.faceAttributes, begin, rows, out.data(), 13, fStride);
        return rows * fStride;
    };
    // Two buffers when another thread can fill one meanwhile; else one, still in cache when refilled.
    const bool overlap = threadsInUse() > 1;
    // What the task writes lives outside the loop and before the task group, whose destructor
    // waits for the task when the sink throws.
    std::array<std::vector<char>, 2> buffers;
    std::size_t nextBytes = 0;
    tbb::task_group next;
    std::size_t bytes = chunks > 0 ? format(0, buffers[0]) : 0;
    for (std::size_t k = 0; k < chunks; ++k) {
        nextBytes = 0;
        if (overlap && k + 1 < chunks) next.run([&, k] { nextBytes = format(k + 1, buffers[(k + 1) % 2]); });
        sink(k >= vChunks, buffers[overlap ? k % 2 : 0].data(), bytes);
        next.wait(); // rethrows the task's failure
        if (!overlap && k + 1 < chunks) nextBytes = format(k + 1, buffers[0]);
        bytes = nextBytes;
    }
}

void writeBinaryBody(AtomicFile& file, const Mesh& mesh)
{
    binaryRows(mesh, mesh.vertexCount(), [&](bool, const char* data, std::size_t size) { file.write(data, size); },
        [&](const std::string& reason) { file.fail(reason); });
}

/// Appends " value" of row @a r of every column.
void appendAsciiRow(std::string& out, const AttributeTable& table, std::size_t r)
{
    for (const Attribute& a : table.columns())
        std::visit([&](const auto& v) {
            using T = typename std::decay_t<decltype(v)>::value_type;
            out += ' ';
            if constexpr (std::is_same_v<T, float>) out += formatFloat(v[r]);
            else out += std::to_string(v[r]);
        }, a.data);
}

/// Lines [begin, end) of the vertices (or with @a faces the faces) appended to @a out: one line
/// a row, floats as their shortest round-trip text; vertex indices must be below @a nv.
template <typename Fail>
void appendAsciiRows(std::string& out, const Mesh& mesh, bool faces, std::size_t begin, std::size_t end, std::size_t nv,
    const Fail& fail)
{
    for (std::size_t r = begin; r < end; ++r) {
        if (faces) {
            checkTriangle(mesh, r, nv, fail);
            const openvdb::Vec3I& t = mesh.triangles[r];
            out += "3 " + std::to_string(t[0]) + ' ' + std::to_string(t[1]) + ' ' + std::to_string(t[2]);
        } else {
            const openvdb::Vec3s& p = mesh.positions[r];
            out += formatFloat(p[0]) + ' ' + formatFloat(p[1]) + ' ' + formatFloat(p[2]);
        }
        appendAsciiRow(out, faces ? mesh.faceAttributes : mesh.vertexAttributes, r);
        out += '\n';
    }
}

void writeAsciiBody(AtomicFile& file, const Mesh& mesh)
{
    std::string out;
    for (const bool faces : {false, true}) {
        const std::size_t rows = faces ? mesh.triangleCount() : mesh.vertexCount();
        for (std::size_t begin = 0; begin < rows; begin += kAsciiChunkRows) {
            appendAsciiRows(out, mesh, faces, begin, std::min(rows, begin + kAsciiChunkRows), mesh.vertexCount(),
                [&](const std::string& reason) { file.fail(reason); });
            file.write(out), out.clear();
        }
    }
}

// ---------------------------------------------------------------------------------------
// Reader
// ---------------------------------------------------------------------------------------

enum class PlyType : std::uint8_t { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

std::size_t typeSize(PlyType t)
{
    constexpr std::size_t sizes[] = {1, 1, 2, 2, 4, 4, 4, 8};
    return sizes[static_cast<int>(t)];
}

bool parseType(std::string_view s, PlyType& t)
{
    struct Name { const char* a; const char* b; PlyType t; };
    static constexpr Name names[] = {{"char", "int8", PlyType::Int8},
        {"uchar", "uint8", PlyType::UInt8}, {"short", "int16", PlyType::Int16},
        {"ushort", "uint16", PlyType::UInt16}, {"int", "int32", PlyType::Int32},
        {"uint", "uint32", PlyType::UInt32}, {"float", "float32", PlyType::Float32},
        {"double", "float64", PlyType::Float64}};
    for (const Name& n : names)
        if (s == n.a || s == n.b) { t = n.t; return true; }
    return false;
}

struct PlyProperty {
    std::string name;
    PlyType type = PlyType::Float32;
    bool isList = false;
    PlyType countType = PlyType::UInt8;
};

struct PlyElement {
    std::string name;
    std::uint64_t count = 0;
    std::vector<PlyProperty> properties;
};

[[noreturn]] void readFail(const std::string& path, const std::string& reason)
{
    throw IoError("cannot read " + path + ": " + reason);
}

std::vector<std::string_view> splitWords(std::string_view line)
{
    std::vector<std::string_view> words;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
        const std::size_t start = i;
        while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
        if (i > start) words.push_back(line.substr(start, i - start));
    }
    return words;
}

template <typename T>
bool parseNumber(std::string_view s, T& value)
{
    const auto r = std::from_chars(s.data(), s.data() + s.size(), value);
    return r.ec == std::errc() && r.ptr == s.data() + s.size();
}

/// Reads fixed-size binary values through a large buffer, swapping bytes for big endian.
class BinarySource {
public:
    BinarySource(std::FILE* file, bool swap, const std::string& path)
        : mFile(file), mSwap(swap), mPath(path), mBuf(kChunkBytes) {}

    double scalar(PlyType t)
    {
        const char* p = take(typeSize(t));
        switch (t) {
        case PlyType::Int8: return load<std::int8_t>(p);
        case PlyType::UInt8: return load<std::uint8_t>(p);
        case PlyType::Int16: return load<std::int16_t>(p);
        case PlyType::UInt16: return load<std::uint16_t>(p);
        case PlyType::Int32: return load<std::int32_t>(p);
        case PlyType::UInt32: return load<std::uint32_t>(p);
        case PlyType::Float32: return load<float>(p);
        case PlyType::Float64: return load<double>(p);
        }
        return 0;
    }

private:
    template <typename T>
    T load(const char* p) const
    {
        char bytes[sizeof(T)];
        if (mSwap) std::reverse_copy(p, p + sizeof(T), bytes);
        else std::memcpy(bytes, p, sizeof(T));
        T v;
        std::memcpy(&v, bytes, sizeof(T));
        return v;
    }

    const char* take(std::size_t n)
    {
        if (mEnd - mPos < n) {
            std::memmove(mBuf.data(), mBuf.data() + mPos, mEnd - mPos);
            mEnd -= mPos;
            mPos = 0;
            mEnd += std::fread(mBuf.data() + mEnd, 1, mBuf.size() - mEnd, mFile);
            if (mEnd < n) readFail(mPath, "truncated data (file ends before the last element)");
        }
        const char* p = mBuf.data() + mPos;
        mPos += n;
        return p;
    }

    std::FILE* mFile;
    bool mSwap;
    const std::string& mPath;
    std::vector<char> mBuf;
    std::size_t mPos = 0, mEnd = 0;
};

/// Reads whitespace-separated ascii numbers.
class AsciiSource {
public:
    AsciiSource(std::FILE* file, const std::string& path) : mPath(path)
    {
        char buf[1 << 16];
        std::size_t n;
        while ((n = std::fread(buf, 1, sizeof(buf), file)) > 0) mText.append(buf, n);
    }

    double scalar(PlyType)
    {
        auto isSpace = [](char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; };
        while (mPos < mText.size() && isSpace(mText[mPos])) ++mPos;
        const std::size_t start = mPos;
        while (mPos < mText.size() && !isSpace(mText[mPos])) ++mPos;
        if (mPos == start) readFail(mPath, "truncated data (file ends before the last element)");
        double v;
        const std::string_view word(mText.data() + start, mPos - start);
        if (!parseNumber(word, v)) readFail(mPath, "'" + std::string(word) + "' is not a number");
        return v;
    }

private:
    const std::string& mPath;
    std::string mText;
    std::size_t mPos = 0;
};

/// Where one property's values go.
enum class Sink : std::uint8_t { Skip, X, Y, Z, Float, Int, UInt8, Triangle };

struct Slot {
    const PlyProperty* property;
    Sink sink;
    void* data; ///< the column's first element for Float, Int and UInt8
};

class PlyReader {
public:
    explicit PlyReader(const std::string& path) : mPath(path) {}

    Mesh read(PlyInfo* info)
    {
        struct stat st;
        if (::stat(mPath.c_str(), &st) != 0) fail(std::strerror(errno));
        if (S_ISDIR(st.st_mode)) fail(std::strerror(EISDIR));
        std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(mPath.c_str(), "rb"), &std::fclose);
        if (!file) fail(std::strerror(errno));

        Mesh mesh;
        PlyInfo header;
        readHeader(file.get(), header, mesh);
        const long at = std::ftell(file.get());
        checkSizes(static_cast<std::uint64_t>(st.st_size) - static_cast<std::uint64_t>(at),
            header.format == "ascii");
        if (header.format == "ascii") {
            AsciiSource source(file.get(), mPath);
            readBody(source, mesh);
        } else {
            BinarySource source(file.get(), header.format == "binary_big_endian", mPath);
            readBody(source, mesh);
        }
        if (info) *info = std::move(header);
        return mesh;
    }

private:
    [[noreturn]] void fail(const std::string& reason) const { readFail(mPath, reason); }

    void readHeader(std::FILE* file, PlyInfo& info, Mesh& mesh)
    {
        constexpr std::size_t kMaxHeader = std::size_t(1) << 20;
        std::size_t total = 0;
        for (int lineNo = 0;; ++lineNo) {
            std::string line;
            int c;
            while ((c = std::fgetc(file)) != EOF && c != '\n') {
                line += static_cast<char>(c);
                if (++total > kMaxHeader) fail("header longer than 1 MiB");
            }
            if (c == EOF && lineNo == 0 && line.empty()) fail("empty file");
            if (c == EOF) fail(lineNo == 0 ? "not a PLY file" : "truncated header (no end_header)");
            if (!line.empty() && line.back() == '\r') line.pop_back();
            if (lineNo == 0) {
                if (line != "ply") fail("not a PLY file (first line is not 'ply')");
                continue;
            }
            if (parseHeaderLine(line, info, mesh)) break;
        }
        if (info.format.empty()) fail("no format line in the header");
    }

    /// Returns true at end_header.
    bool parseHeaderLine(const std::string& line, PlyInfo& info, Mesh& mesh)
    {
        const std::vector<std::string_view> w = splitWords(line);
        if (w.empty()) return false;
        if (w[0] == "comment") {
            const std::size_t start = line.find("comment") + 7;
            parseComment(line.substr(std::min(line.size(), start + 1)), info, mesh);
        } else if (w[0] == "obj_info") {
            return false;
        } else if (w[0] == "format") {
            if (w.size() != 3 || w[2] != "1.0" ||
                (w[1] != "ascii" && w[1] != "binary_little_endian" && w[1] != "binary_big_endian"))
                fail("unsupported format line '" + line + "'");
            info.format = std::string(w[1]);
        } else if (w[0] == "element") {
            PlyElement e;
            if (w.size() != 3 || !parseNumber(w[2], e.count)) fail("bad element line '" + line + "'");
            e.name = std::string(w[1]);
            for (const PlyElement& f : mElements)
                if (f.name == e.name) fail("element '" + e.name + "' appears twice");
            mElements.push_back(std::move(e));
        } else if (w[0] == "property") {
            if (mElements.empty()) fail("property before any element");
            PlyProperty p;
            const bool ok = w.size() >= 3 && w[1] == "list"
                ? w.size() == 5 && parseType(w[2], p.countType) && parseType(w[3], p.type)
                : w.size() == 3 && parseType(w[1], p.type);
            if (!ok) fail("bad property line '" + line + "'");
            p.isList = w[1] == "list";
            p.name = std::string(w.back());
            for (const PlyProperty& q : mElements.back().properties)
                if (q.name == p.name) fail("property '" + p.name + "' appears twice");
            mElements.back().properties.push_back(std::move(p));
        } else if (w[0] == "end_header") {
            return true;
        } else {
            fail("unknown header line '" + line + "'");
        }
        return false;
    }

    void parseComment(const std::string& text, PlyInfo& info, Mesh& mesh)
    {
        const std::vector<std::string_view> w = splitWords(text);
        if (w.size() >= 2 && w[0] == "isouq" && w[1] == "index_to_world") {
            bool ok = w.size() == 18;
            for (std::size_t i = 0; ok && i < 16; ++i) ok = parseNumber(w[2 + i], mesh.indexToWorld[i]);
            if (!ok) fail("malformed comment '" + text + "' (expected 16 numbers)");
            info.hasIndexToWorld = true;
        } else if (w.size() == 3 && w[0] == "isouq" && w[1] == "isovalue") {
            float k;
            if (!parseNumber(w[2], k)) fail("malformed comment '" + text + "'");
            info.isovalue = k;
        } else if (w.size() == 3 && w[0] == "isouq" && w[1] == "version") {
            info.version = std::string(w[2]);
        } else if (w.size() == 3 && w[0] == "isouq" && w[1] == "method") {
            info.method = std::string(w[2]);
        } else {
            info.comments.push_back(text);
        }
    }

    /// Refuses counts the file cannot hold before anything is allocated.
    void checkSizes(std::uint64_t remaining, bool ascii) const
    {
        for (const PlyElement& e : mElements) {
            if (e.count == 0) continue;
            if (e.properties.empty()) fail("element '" + e.name + "' has no properties");
            std::uint64_t minRow = 0; // ascii: at least one character per value
            for (const PlyProperty& p : e.properties)
                minRow += ascii ? 1 : typeSize(p.isList ? p.countType : p.type);
            if (e.count > remaining / minRow)
                fail("truncated data (header announces " + std::to_string(e.count) + " " +
                     (e.name == "vertex" ? std::string("vertices") : e.name + "s") + ", the file is too short)");
            remaining -= e.count * minRow;
        }
    }

    template <typename Source>
    void readBody(Source& source, Mesh& mesh)
    {
        const PlyElement* vertex = nullptr;
        for (const PlyElement& e : mElements)
            if (e.name == "vertex") vertex = &e;
        if (!vertex) fail("no vertex element");
        if (vertex->count > std::uint64_t(UINT32_MAX)) fail("more than 2^32 vertices");

        for (const PlyElement& e : mElements) {
            std::vector<Slot> slots;
            for (const PlyProperty& p : e.properties) slots.push_back(makeSlot(e, p, mesh));
            if (&e == vertex) {
                for (Sink s : {Sink::X, Sink::Y, Sink::Z})
                    if (std::none_of(slots.begin(), slots.end(), [s](const Slot& q) { return q.sink == s; }))
                        fail("the vertex element has no float x, y and z");
            }
            for (std::uint64_t r = 0; r < e.count; ++r)
                for (const Slot& s : slots) readValue(source, s, r, mesh);
        }
        const std::size_t nv = mesh.positions.size();
        for (std::size_t f = 0; f < mesh.triangles.size(); ++f)
            for (int c = 0; c < 3; ++c)
                if (mesh.triangles[f][c] >= nv)
                    fail("face " + std::to_string(f) + " refers to vertex " +
                         std::to_string(mesh.triangles[f][c]) + " of " + std::to_string(nv));
    }

    Slot makeSlot(const PlyElement& e, const PlyProperty& p, Mesh& mesh)
    {
        const bool isVertex = e.name == "vertex", isFace = e.name == "face";
        if (p.isList) {
            if (!isFace || (p.name != "vertex_indices" && p.name != "vertex_index"))
                return {&p, Sink::Skip, nullptr};
            if (!mesh.triangles.empty()) fail("two face index lists");
            mesh.triangles.resize(e.count);
            return {&p, Sink::Triangle, nullptr};
        }
        if (!isVertex && !isFace) return {&p, Sink::Skip, nullptr};
        if (isVertex && (p.name == "x" || p.name == "y" || p.name == "z")) {
            mesh.positions.resize(e.count);
            return {&p, p.name == "x" ? Sink::X : p.name == "y" ? Sink::Y : Sink::Z, nullptr};
        }
        AttributeTable& table = isVertex ? mesh.vertexAttributes : mesh.faceAttributes;
        switch (p.type) {
        case PlyType::Float32:
        case PlyType::Float64: return {&p, Sink::Float, table.add<float>(p.name, e.count).data()};
        case PlyType::UInt8: return {&p, Sink::UInt8, table.add<std::uint8_t>(p.name, e.count).data()};
        default: return {&p, Sink::Int, table.add<std::int32_t>(p.name, e.count).data()};
        }
    }

    /// @a value as an integer in [lo, hi], or a failure naming the property.
    double integer(double value, double lo, double hi, const PlyProperty& p) const
    {
        if (!(value >= lo && value <= hi) || value != std::floor(value))
            fail("value " + formatDouble(value) + " of property '" + p.name + "' is out of range");
        return value;
    }

    template <typename Source>
    void readValue(Source& source, const Slot& s, std::uint64_t row, Mesh& mesh) const
    {
        const PlyProperty& p = *s.property;
        if (p.isList) {
            const double n = integer(source.scalar(p.countType), 0, 1e18, p);
            if (s.sink == Sink::Triangle) {
                if (n != 3)
                    fail("face " + std::to_string(row) + " has " + formatDouble(n) +
                         " vertices; only triangles are supported");
                for (int c = 0; c < 3; ++c)
                    mesh.triangles[row][c] = static_cast<std::uint32_t>(
                        integer(source.scalar(p.type), 0, double(UINT32_MAX), p));
            } else {
                for (double i = 0; i < n; ++i) source.scalar(p.type);
            }
            return;
        }
        const double v = source.scalar(p.type);
        switch (s.sink) {
        case Sink::X: mesh.positions[row][0] = static_cast<float>(v); break;
        case Sink::Y: mesh.positions[row][1] = static_cast<float>(v); break;
        case Sink::Z: mesh.positions[row][2] = static_cast<float>(v); break;
        case Sink::Float: static_cast<float*>(s.data)[row] = static_cast<float>(v); break;
        case Sink::Int:
            static_cast<std::int32_t*>(s.data)[row] =
                static_cast<std::int32_t>(integer(v, INT32_MIN, INT32_MAX, p));
            break;
        case Sink::UInt8:
            static_cast<std::uint8_t*>(s.data)[row] = static_cast<std::uint8_t>(integer(v, 0, 255, p));
            break;
        case Sink::Skip:
        case Sink::Triangle: break;
        }
    }

    const std::string& mPath;
    std::vector<PlyElement> mElements;
};

} // namespace meshio_internal

void removeTemporaryFiles() noexcept
{
    for (auto& slot : meshio_internal::sTempSlots)
        if (slot.ready.load()) ::unlink(slot.name);
}

namespace meshio_internal {
void writePlyTo(AtomicFile& file, const Mesh& mesh, const PlyOptions& options)
{
    if (mesh.vertexCount() > std::size_t(INT32_MAX)) file.fail("more vertices than PLY int indices hold");
    checkColumns(file, mesh.vertexAttributes, mesh.vertexCount(), "vertex", {"x", "y", "z"});
    checkColumns(file, mesh.faceAttributes, mesh.triangleCount(), "face", {"vertex_indices"});
    file.write(plyHeader(file, mesh, options, mesh.vertexCount(), mesh.triangleCount()));
    if (options.encoding == PlyEncoding::Ascii) writeAsciiBody(file, mesh);
    else writeBinaryBody(file, mesh);
}
} // namespace meshio_internal

void writePly(const Mesh& mesh, const std::string& path, const PlyOptions& options)
{
    meshio_internal::AtomicFile file(path);
    meshio_internal::writePlyTo(file, mesh, options);
    file.commit();
}

void writeVtp(const Mesh& mesh, const std::string& path, const MeshFileOptions& options)
{
    meshio_internal::AtomicFile file(path);
    meshio_internal::writeVtpTo(file, mesh, options);
    file.commit();
}

struct OutputBatch::Impl {
    std::vector<std::unique_ptr<meshio_internal::AtomicFile>> files;
};

OutputBatch::OutputBatch() : mImpl(std::make_unique<Impl>()) {}
OutputBatch::~OutputBatch() = default;

void OutputBatch::addPly(const Mesh& mesh, const std::string& path, const PlyOptions& options)
{
    auto file = std::make_unique<meshio_internal::AtomicFile>(path);
    meshio_internal::writePlyTo(*file, mesh, options);
    mImpl->files.push_back(std::move(file));
}

void OutputBatch::addVtp(const Mesh& mesh, const std::string& path, const MeshFileOptions& options)
{
    auto file = std::make_unique<meshio_internal::AtomicFile>(path);
    meshio_internal::writeVtpTo(*file, mesh, options);
    mImpl->files.push_back(std::move(file));
}

void OutputBatch::addText(const std::string& path, const std::string& text)
{
    auto file = std::make_unique<meshio_internal::AtomicFile>(path);
    file->write(text.data(), text.size());
    mImpl->files.push_back(std::move(file));
}

void OutputBatch::addShared(std::unique_ptr<SharedMeshFile> file) { mImpl->files.push_back(std::move(file->mFile)); }

void OutputBatch::add(OutputBatch&& other)
{
    for (auto& file : other.mImpl->files) mImpl->files.push_back(std::move(file));
    other.mImpl->files.clear();
}

void OutputBatch::commit()
{
    for (auto& file : mImpl->files) file->commit();
    mImpl->files.clear();
}

SharedMeshFile::SharedMeshFile(const std::string& path)
    : mFile(std::make_unique<meshio_internal::AtomicFile>(path))
{
}

SharedMeshFile::~SharedMeshFile() = default;

const std::string& SharedMeshFile::temporaryPath() const { return mFile->temporaryPath(); }

std::string SharedMeshFile::plyHeader(const Mesh& piece, std::uint64_t vertices, std::uint64_t faces,
    const PlyOptions& options) const
{
    using namespace meshio_internal;
    if (vertices > std::uint64_t(INT32_MAX)) mFile->fail("more vertices than PLY int indices hold");
    checkColumns(*mFile, piece.vertexAttributes, piece.vertexCount(), "vertex", {"x", "y", "z"});
    checkColumns(*mFile, piece.faceAttributes, piece.triangleCount(), "face", {"vertex_indices"});
    return meshio_internal::plyHeader(*mFile, piece, options, std::size_t(vertices), std::size_t(faces));
}

std::string SharedMeshFile::vtpHead(const Mesh& piece, std::uint64_t vertices, std::uint64_t faces,
    const MeshFileOptions& options) const
{
    return meshio_internal::vtpHead(*mFile, piece, vertices, faces, options);
}

std::pair<std::size_t, std::size_t> plyRowBytes(const Mesh& mesh)
{
    return {meshio_internal::rowBytes(mesh.vertexAttributes, 12), meshio_internal::rowBytes(mesh.faceAttributes, 13)};
}

void plyPieceRows(const Mesh& piece, std::uint64_t vertices,
    const std::function<void(bool faces, const char* data, std::size_t size)>& sink)
{
    meshio_internal::binaryRows(piece, std::size_t(vertices), sink,
        [](const std::string& reason) { throw IoError("cannot write a PLY piece: " + reason); });
}

void plyAsciiRows(const Mesh& piece, bool faces, std::size_t begin, std::size_t end, std::uint64_t vertices, std::string& out)
{
    meshio_internal::appendAsciiRows(out, piece, faces, begin, end, std::size_t(vertices),
        [](const std::string& reason) { throw IoError("cannot write a PLY piece: " + reason); });
}

Mesh readPly(const std::string& path, PlyInfo* info)
{
    return meshio_internal::PlyReader(path).read(info);
}

void checkWritable(const std::string& path)
{
    meshio_internal::AtomicFile probe(path); // removed again when it goes out of scope
}

void writeTextFileAtomic(const std::string& path, const std::string& text)
{
    meshio_internal::AtomicFile file(path);
    file.write(text.data(), text.size());
    file.commit();
}

} // namespace isouq
