// isouq: NRRD scans, `.nrrd` (attached) and `.nhdr` (detached, `data file:`), through teem
// (libteem; SPEC §10 "Formats"; docs/inputs.md). teem parses the header and opens the data;
// raw and gzip data in one file are then streamed slice by slice like a raw scan, the other
// encodings (bzip2, ascii, hex) and data split over several files are decoded by teem whole.
// World coordinates from `space directions` and `space origin` in the file's own `space`,
// else from `spacings` (1 where missing) and the origin 0.
#include "SourcesInternal.h"

#include "Memory.h"

#include <teem/nrrd.h>
#include <zlib.h>

#include <unistd.h>

#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <vector>

namespace isouq::sources_internal {
namespace {

namespace fs = std::filesystem;

std::optional<SampleType> sampleTypeOf(int type)
{
    switch (type) {
    case nrrdTypeChar: return SampleType::Int8;
    case nrrdTypeUChar: return SampleType::UInt8;
    case nrrdTypeShort: return SampleType::Int16;
    case nrrdTypeUShort: return SampleType::UInt16;
    case nrrdTypeInt: return SampleType::Int32;
    case nrrdTypeUInt: return SampleType::UInt32;
    case nrrdTypeLLong: return SampleType::Int64;
    case nrrdTypeULLong: return SampleType::UInt64;
    case nrrdTypeFloat: return SampleType::Float32;
    case nrrdTypeDouble: return SampleType::Float64;
    default: return std::nullopt;
    }
}

struct NrrdNuke {
    void operator()(Nrrd* n) const { nrrdNuke(n); }
};
struct IoStateNix {
    void operator()(NrrdIoState* s) const { nrrdIoStateNix(s); }
};

/// teem's error text (biff, several lines) as one line.
std::string teemError()
{
    char* text = biffGetDone(NRRD);
    std::string s = text ? text : "unknown teem error";
    std::free(text);
    // biff stacks one "[nrrd] function: message" line per call level; the innermost says most.
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    const std::size_t last = s.rfind('\n');
    if (last != std::string::npos) s = s.substr(last + 1);
    if (s.rfind("[nrrd] ", 0) == 0) s = s.substr(7);
    return s;
}

/// Data that teem decodes whole (bzip2, ascii, hex, several data files), in the file's type
/// and native byte order.
class NrrdSlices : public SliceSource {
public:
    NrrdSlices(const Nrrd& nrrd, SampleType type) : mData(static_cast<const char*>(nrrd.data)), mType(type)
    {
        dims = Coord(int(nrrd.axis[0].size), int(nrrd.axis[1].size), int(nrrd.axis[2].size));
    }
    void read(int z0, int count, float* out) override
    {
        const std::size_t slice = std::size_t(dims.x()) * dims.y();
        decodeSamples(mData + std::size_t(z0) * slice * sampleBytes(mType), slice * count, mType,
            __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__, 1.0, 0.0, out);
    }

private:
    const char* mData;
    SampleType mType;
};

/// Raw or gzip data of one data file, read slice by slice from where the header ends (teem
/// leaves that file open at the data: keepNrrdDataFileOpen). Raw data in this machine's byte
/// order is also a rawArray of @a dataPath (the header itself when the data are attached).
class NrrdStreamSlices : public SliceSource {
public:
    NrrdStreamSlices(const std::string& path, const std::string& dataPath, std::FILE* file, bool gzip, bool bigEndian,
        SampleType type, Coord size, long byteSkip)
        : mPath(path), mFile(file), mType(type), mBigEndian(bigEndian)
    {
        dims = size;
        const std::uint64_t bytes = std::uint64_t(dims.x()) * dims.y() * dims.z() * sampleBytes(type);
        std::error_code ec;
        if (!gzip) {
            if (byteSkip < 0) { // "byte skip: -1": the data are the file's last bytes
                std::fseek(mFile, 0, SEEK_END);
                std::fseek(mFile, std::ftell(mFile) - long(bytes), SEEK_SET);
            }
            mStart = std::ftell(mFile);
            std::fseek(mFile, 0, SEEK_END);
            const long end = std::ftell(mFile);
            if (mStart < 0 || end < mStart || std::uint64_t(end - mStart) < bytes) {
                throw InputError("cannot read the data of '" + path + "': " + std::to_string(bytes)
                    + " bytes of data needed, " + std::to_string(end - mStart) + " in the file");
            }
            const bool nativeOrder = sampleBytes(type) == 1 || bigEndian == (__BYTE_ORDER__ == __ORDER_BIG_ENDIAN__);
            if (isRawArrayType(type) && nativeOrder)
                mRaw = std::make_unique<RawSlabReader>(dataPath, dims, type, std::uint64_t(mStart));
            return;
        }
        // zlib reads the gzip stream from the descriptor's offset: the stream starts where the
        // header (or the byte skip) ends, and gzrewind comes back there.
        const int fd = ::dup(fileno(mFile));
        if (fd < 0 || ::lseek(fd, std::ftell(mFile), SEEK_SET) < 0 || !(mGz = gzdopen(fd, "rb"))) {
            if (fd >= 0) ::close(fd);
            throw InputError("cannot read the gzip data of '" + path + "'");
        }
        mPosition = 0; // the stream is at the first sample
    }
    ~NrrdStreamSlices() override
    {
        if (mGz) gzclose(mGz);
    }
    const RawSlabReader* rawArray() const override { return mRaw.get(); }
    NrrdStreamSlices(const NrrdStreamSlices&) = delete;
    NrrdStreamSlices& operator=(const NrrdStreamSlices&) = delete;

    void read(int z0, int count, float* out) override
    {
        const std::size_t n = std::size_t(dims.x()) * dims.y() * count, bytes = n * sampleBytes(mType);
        const std::int64_t at = std::int64_t(z0) * dims.x() * dims.y() * std::int64_t(sampleBytes(mType));
        mBuffer.resize(bytes);
        bool ok = true;
        if (mGz) {
            if (at < mPosition) ok = gzrewind(mGz) == 0, mPosition = 0;
            while (ok && mPosition < at) { // skip forward by decompressing
                const int skip = int(std::min<std::int64_t>(at - mPosition, std::int64_t(bytes)));
                ok = gzread(mGz, mBuffer.data(), unsigned(skip)) == skip;
                mPosition += skip;
            }
            ok = ok && gzread(mGz, mBuffer.data(), unsigned(bytes)) == int(bytes);
        } else {
            ok = (at == mPosition || std::fseek(mFile, mStart + long(at), SEEK_SET) == 0)
                && std::fread(mBuffer.data(), 1, bytes, mFile) == bytes;
        }
        if (!ok) {
            mPosition = -1;
            throw InputError("cannot read the data of '" + mPath + "': slices " + std::to_string(z0) + ".."
                + std::to_string(z0 + count - 1) + " of " + std::to_string(dims.z()) + " are missing or damaged");
        }
        mPosition = at + std::int64_t(bytes);
        decodeSamples(mBuffer.data(), n, mType, mBigEndian, 1.0, 0.0, out);
    }

private:
    std::string mPath;
    std::FILE* mFile; // owned by the NrrdIoState
    gzFile mGz = nullptr;
    long mStart = 0;
    std::int64_t mPosition = -1;
    SampleType mType;
    bool mBigEndian;
    std::vector<char> mBuffer;
    std::unique_ptr<RawSlabReader> mRaw;
};

/// A `data file:` pattern `FORMAT MIN MAX STEP [SUBDIM]` expanded, its FORMAT holding exactly
/// one `%d` (with flags and width, as `%03d`) and `%%` otherwise. @throw InputError.
std::vector<std::string> expandPattern(const std::string& path, const std::string& format, long lo, long hi, long step)
{
    int conversions = 0;
    for (std::size_t i = 0; i < format.size(); ++i) {
        if (format[i] != '%') continue;
        if (i + 1 < format.size() && format[i + 1] == '%') { ++i; continue; }
        std::size_t j = i + 1;
        while (j < format.size() && std::isdigit(static_cast<unsigned char>(format[j]))) ++j;
        if (j >= format.size() || format[j] != 'd' || ++conversions > 1) conversions = 2;
        i = j;
    }
    constexpr long kInt = std::numeric_limits<int>::max();
    const auto small = [](long v) { return -kInt <= v && v <= kInt; };
    const bool inRange = small(lo) && small(hi) && small(step) && step != 0;
    const long count = inRange ? (hi - lo) / step + 1 : -1;
    if (conversions != 1 || count < 1 || count > 1000000) {
        throw InputError("'" + path + "': the data file pattern '" + format + " " + std::to_string(lo) + " "
            + std::to_string(hi) + " " + std::to_string(step) + "' must hold one %d (e.g. slice%03d.raw) and "
            "name 1 to 1000000 files");
    }
    std::vector<std::string> names;
    for (long k = 0, v = lo; k < count; ++k, v += step) {
        char name[4096];
        if (std::snprintf(name, sizeof(name), format.c_str(), int(v)) >= int(sizeof(name)))
            throw InputError("'" + path + "': a data file name is longer than 4095 bytes");
        names.emplace_back(name);
    }
    return names;
}

} // namespace

std::vector<std::string> nrrdDataFiles(const std::string& path)
{
    // The header as teem reads it (formatNRRD.c): lines up to the first empty one (attached) or
    // the end of the file (detached); `data file:` (or `datafile:`) names one file, a pattern,
    // or LIST followed by one name per line to the header's end. Names are relative to the
    // header's folder unless absolute.
    // Only a regular file is read (a FIFO would block, a device never end); the load that
    // follows says what else it is. Lines are read in bounded chunks, so a header with no line
    // break (/dev/zero behind a symlink) stops at 16 MiB too.
    constexpr std::size_t kMaxHeader = 16u << 20;
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) return {};
    std::ifstream in(path, std::ios::binary);
    std::vector<std::string> lines;
    std::size_t bytes = 0;
    std::string line;
    for (char chunk[4096]; in.getline(chunk, sizeof(chunk)) || in.gcount() > 0;) {
        const std::size_t got = std::size_t(in.gcount());
        const bool more = in.fail() && !in.eof(); // the chunk filled before the line ended
        if ((bytes += got) > kMaxHeader) throw InputError("'" + path + "' has a NRRD header longer than 16 MiB");
        line.append(chunk, more ? got : got - (in.eof() ? 0 : 1)); // gcount counts the '\n' taken
        if (more) {
            in.clear();
            continue;
        }
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty()) break;
        lines.push_back(std::move(line));
        line.clear();
        if (in.eof()) break;
    }
    const fs::path folder = fs::path(path).parent_path();
    auto resolve = [&](const std::string& name) {
        return fs::path(name).is_absolute() || folder.empty() ? name : (folder / name).string();
    };
    std::vector<std::string> files;
    for (std::size_t i = 1; i < lines.size(); ++i) {
        const std::string& line = lines[i];
        std::string value;
        for (const char* key : {"data file: ", "datafile: "})
            if (line.rfind(key, 0) == 0) value = line.substr(std::strlen(key));
        if (value.empty()) continue;
        files.clear(); // teem keeps the last field given
        std::istringstream words(value);
        std::string first;
        words >> first;
        if (first == "LIST") {
            for (std::size_t j = i + 1; j < lines.size(); ++j) files.push_back(resolve(lines[j]));
            break;
        }
        long lo = 0, hi = 0, step = 0;
        if (words >> lo >> hi >> step) {
            for (const std::string& name : expandPattern(path, first, lo, hi, step)) files.push_back(resolve(name));
        } else {
            files.push_back(resolve(value));
        }
    }
    return files;
}

DensePiece readNrrd(const VolumeRequest& request, openvdb::util::NullInterrupter* /*interrupter*/, const ScanLoader& load)
{
    const std::string& path = request.input;
    fileSize(path);
    rejectRawFlags(request, "NRRD", false);
    // teem opens the data files itself and would wait forever on a FIFO: regular files only.
    const std::vector<std::string> dataFiles = nrrdDataFiles(path);
    for (const std::string& file : dataFiles) {
        std::error_code ec;
        if (!fs::is_regular_file(file, ec)) {
            throw InputError("'" + path + "' names the data file '" + file + "', which is "
                + (fs::exists(file, ec) ? "not a regular file" : "missing"));
        }
    }
    // The header first: refuse what isouq cannot mesh before teem allocates the data.
    std::unique_ptr<Nrrd, NrrdNuke> nrrd(nrrdNew());
    std::unique_ptr<NrrdIoState, IoStateNix> io(nrrdIoStateNew());
    nrrdIoStateSet(io.get(), nrrdIoStateSkipData, AIR_TRUE);
    nrrdIoStateSet(io.get(), nrrdIoStateKeepNrrdDataFileOpen, AIR_TRUE);
    if (nrrdLoad(nrrd.get(), path.c_str(), io.get()))
        throw InputError("'" + path + "' is not a readable NRRD file: " + teemError());
    const Nrrd& n = *nrrd;
    const std::optional<SampleType> type = sampleTypeOf(n.type);
    if (!type) {
        throw InputError("'" + path + "' has NRRD type " + airEnumStr(nrrdType, n.type)
            + "; isouq reads scalar volumes: int8, uint8, int16, uint16, int32, uint32, int64, uint64, float, double");
    }
    if (n.dim != 3) {
        throw InputError("'" + path + "' has dimension " + std::to_string(n.dim)
            + "; isouq meshes one 3-D scalar volume");
    }
    for (unsigned a = 0; a < 3; ++a) {
        if (n.axis[a].size < 1 || n.axis[a].size > kMaxDim) {
            throw InputError("'" + path + "' has " + std::to_string(n.axis[a].size) + " samples on axis "
                + std::to_string(a) + ": each must be 1.." + std::to_string(kMaxDim));
        }
    }

    std::array<double, 16> affine{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    std::string geometry;
    if (n.spaceDim == 3) {
        for (unsigned a = 0; a < 3; ++a)
            for (int r = 0; r < 3; ++r) affine[4 * r + a] = n.axis[a].spaceDirection[r];
        for (int r = 0; r < 3; ++r) affine[4 * r + 3] = std::isnan(n.spaceOrigin[r]) ? 0.0 : n.spaceOrigin[r];
        geometry = "NRRD space directions";
        if (n.space != nrrdSpaceUnknown) geometry += std::string(" (") + airEnumStr(nrrdSpace, n.space) + ")";
    } else if (n.spaceDim != 0) {
        throw InputError("'" + path + "' has a " + std::to_string(n.spaceDim)
            + "-D space; isouq places a 3-D volume in a 3-D space");
    } else {
        for (unsigned a = 0; a < 3; ++a) affine[5 * a] = std::isnan(n.axis[a].spacing) ? 1.0 : n.axis[a].spacing;
        geometry = "NRRD spacings";
    }

    const std::string encoding = io->encoding ? io->encoding->name : "raw";
    const std::string name = fs::path(path).stem().string();
    const std::string what = fs::path(path).filename().string() + ": NRRD " + toString(*type) + " (" + encoding + ")";
    if (io->dataFile && (encoding == "raw" || encoding == "gzip") && dataFiles.size() <= 1) {
        const Coord size(int(n.axis[0].size), int(n.axis[1].size), int(n.axis[2].size));
        NrrdStreamSlices source(path, dataFiles.empty() ? path : dataFiles[0], io->dataFile, encoding == "gzip",
            io->endian == airEndianBig, *type, size, io->byteSkip);
        return load(source, {name, affine, geometry, what});
    }
    // teem allocates the whole volume before it decodes: refuse what cannot fit first.
    const std::uint64_t whole = std::uint64_t(n.axis[0].size) * n.axis[1].size * n.axis[2].size * sampleBytes(*type);
    memory_internal::checkFits(whole, "'" + path + "' (" + std::to_string(n.axis[0].size) + "x"
        + std::to_string(n.axis[1].size) + "x" + std::to_string(n.axis[2].size) + " " + toString(*type) + ", " + encoding
        + " data decoded whole)");
    nrrd.reset(nrrdNew());
    if (nrrdLoad(nrrd.get(), path.c_str(), nullptr))
        throw InputError("cannot read the data of '" + path + "': " + teemError());
    NrrdSlices source(*nrrd, *type);
    return load(source, {name, affine, geometry, what});
}

} // namespace isouq::sources_internal
