// isouq: a DICOM series, a folder of one series' slices, through GDCM (libgdcm; SPEC §10
// "Formats"; docs/inputs.md). Slices are sorted by their Image Position (Patient) along the
// normal of the Image Orientation (Patient); values are RescaleSlope * v + RescaleIntercept of
// each slice; world coordinates are DICOM's patient coordinates (LPS millimetres): column i
// along the row cosines times the column spacing, row j along the column cosines times the row
// spacing, slice k along the step between the first and the last positions.
#include "GdcmServer.h"
#include "Quarantine.h"
#include "SourcesInternal.h"

#include <dlfcn.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <set>
#include <vector>

namespace isouq::sources_internal {
namespace {

namespace fs = std::filesystem;

using Vec3 = openvdb::Vec3d;

/// What isouq needs of one slice's header.
struct Slice {
    std::string file;
    unsigned columns = 0, rows = 0;
    SampleType type = SampleType::UInt16;
    Vec3 position, rowCosines, columnCosines;
    double columnSpacing = 1, rowSpacing = 1;
    double along = 0; ///< position along the slice normal
};

/// GDCM allocates each element's value at its announced length before reading it, so a 7 KB
/// file announcing a 4 GB element costs 4 GB (a fuzzing finding, docs/hardening.md). Before GDCM
/// sees a file, this walks its elements (PS3.5 §7: the explicit-VR file meta group, then the
/// data set in its transfer syntax; sequences, items and encapsulated fragments as in §7.5 and
/// A.4) and refuses any element, item or fragment longer than the bytes left in its file or
/// its enclosing sequence or item. A deflated data set (A.5) is inflated and walked the same
/// way (a 4.6 KB file inflated to an element of 2.3 GB, fuzz_dicom's oom-4acf4ed7).
class ElementWalk {
public:
    explicit ElementWalk(const std::string& file) : mFile(file), mIn(file, std::ios::binary)
    {
        std::error_code ec;
        mSize = fs::file_size(file, ec);
        if (ec || !mIn) throw InputError("cannot read '" + file + "'");
    }

    /// @return false when the file is no DICOM file at all (no preamble, no group 0002 or 0008
    ///         at its start); @throw InputError when it is one whose lengths do not fit.
    bool run()
    {
        std::uint64_t pos = 0;
        unsigned char head[4];
        if (mSize >= 132 && readAt(128, head, 4) && std::memcmp(head, "DICM", 4) == 0) pos = 132;
        else if (!(mSize >= 8 && readAt(0, head, 4) && (head[0] == 2 || head[0] == 8) && head[1] == 0)) return false;
        // The file meta group is explicit VR little endian (PS3.10 §7.1); it names the syntax.
        Syntax syntax{true, false};
        std::string transfer;
        while (pos + 8 <= mSize && readAt(pos, head, 2) && head[0] == 2 && head[1] == 0)
            pos = element(pos, mSize, syntax, 0, &transfer);
        while (!transfer.empty() && (transfer.back() == '\0' || transfer.back() == ' ')) transfer.pop_back();
        if (transfer == "1.2.840.10008.1.2.1.99") { // deflated explicit VR little endian
            inflateFrom(pos);
            pos = 0;
        }
        if (transfer == "1.2.840.10008.1.2") syntax = {false, false};
        else if (transfer == "1.2.840.10008.1.2.2") syntax = {true, true};
        // No meta group, or a data set written in implicit VR under an explicit syntax's name
        // (GDCM and pydicom read both): the first element tells.
        if (syntax.explicitVr && pos + 8 <= mSize && !validVr(pos + 4)) syntax.explicitVr = false;
        elements(pos, mSize, syntax, 0, false);
        // Debian's GDCM keeps its assertions, and one aborts the process on a multi-frame
        // image whose Frame Increment Pointer names frames it does not count (pydicom's
        // rtdose_1frame.dcm); PS3.3 C.7.6.6 makes (0028,0008) Type 1 beside (0028,0009).
        if (has(0x0028, 0x0009) && !has(0x0028, 0x0008))
            throw InputError("'" + mFile + "' is a damaged DICOM file: it has a Frame Increment Pointer (0028,0009) "
                "but no Number of Frames (0028,0008)");
        return true;
    }

private:
    struct Syntax {
        bool explicitVr, bigEndian;
    };
    static constexpr std::uint32_t kUndefined = 0xffffffffu;
    static constexpr int kMaxDepth = 64;

    bool readAt(std::uint64_t pos, unsigned char* out, std::size_t n)
    {
        if (pos + n > mSize) return false;
        if (mInflated) {
            std::memcpy(out, mInflated->data() + pos, n);
            return true;
        }
        mIn.clear();
        mIn.seekg(std::streamoff(pos));
        return bool(mIn.read(reinterpret_cast<char*>(out), std::streamsize(n)));
    }
    [[noreturn]] void damaged(std::uint64_t pos, const std::string& why) const
    {
        throw InputError("'" + mFile + "' is a damaged DICOM file: at byte " + std::to_string(pos)
            + (mInflated ? " of its inflated data set" : "") + ", " + why);
    }
    /// From here on, the data set is the raw deflate stream (RFC 1951) from @a pos, inflated.
    /// Deflate expands at most 1032 to 1, so the data set is at most that times the file.
    void inflateFrom(std::uint64_t pos)
    {
        std::string packed(std::size_t(mSize - pos), '\0');
        if (!readAt(pos, reinterpret_cast<unsigned char*>(packed.data()), packed.size())) damaged(pos, "it cannot be read");
        z_stream z{};
        if (inflateInit2(&z, -MAX_WBITS) != Z_OK) throw InputError("cannot inflate '" + mFile + "'");
        std::string out;
        z.next_in = reinterpret_cast<Bytef*>(packed.data());
        z.avail_in = uInt(std::min<std::size_t>(packed.size(), std::numeric_limits<uInt>::max()));
        int status = Z_OK;
        while (status == Z_OK) {
            const std::size_t done = out.size();
            out.resize(done + (std::size_t(1) << 20));
            z.next_out = reinterpret_cast<Bytef*>(out.data() + done);
            z.avail_out = 1u << 20;
            status = inflate(&z, Z_NO_FLUSH);
            out.resize(done + (std::size_t(1) << 20) - z.avail_out);
        }
        inflateEnd(&z);
        if (status != Z_STREAM_END) damaged(pos, "its deflated data set does not inflate");
        mInflated = std::move(out);
        mSize = mInflated->size();
    }
    std::uint32_t number(std::uint64_t pos, int bytes, bool bigEndian)
    {
        unsigned char b[4];
        if (!readAt(pos, b, std::size_t(bytes))) damaged(pos, "it ends inside an element header");
        std::uint32_t v = 0;
        for (int k = 0; k < bytes; ++k) v |= std::uint32_t(b[bigEndian ? bytes - 1 - k : k]) << (8 * k);
        return v;
    }
    bool validVr(std::uint64_t pos)
    {
        static const std::set<std::string> kVrs{"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FL", "FD", "IS", "LO",
            "LT", "OB", "OD", "OF", "OL", "OV", "OW", "PN", "SH", "SL", "SQ", "SS", "ST", "SV", "TM", "UC", "UI",
            "UL", "UN", "UR", "US", "UT", "UV"};
        unsigned char vr[2];
        return readAt(pos, vr, 2) && kVrs.count(std::string(reinterpret_cast<char*>(vr), 2));
    }
    void fits(std::uint64_t pos, std::uint64_t length, std::uint64_t end, const char* what)
    {
        if (length > end - pos) {
            damaged(pos, std::string(what) + " announces " + std::to_string(length) + " bytes where "
                + std::to_string(end - pos) + " are left");
        }
    }

    /// Elements from pos to end, or to the item delimiter when inItem (undefined-length item).
    std::uint64_t elements(std::uint64_t pos, std::uint64_t end, Syntax syntax, int depth, bool inItem)
    {
        while (pos < end) {
            if (inItem && number(pos, 2, syntax.bigEndian) == 0xfffe && number(pos + 2, 2, syntax.bigEndian) == 0xe00d)
                return pos + 8;
            if (depth == 0) mTopLevel.insert(number(pos, 2, syntax.bigEndian) << 16 | number(pos + 2, 2, syntax.bigEndian));
            pos = element(pos, end, syntax, depth, nullptr);
        }
        if (inItem) damaged(pos, "an item has no delimiter");
        return pos;
    }

    /// One element at pos; its value's end. transfer, if given, receives (0002,0010).
    std::uint64_t element(std::uint64_t pos, std::uint64_t end, Syntax syntax, int depth, std::string* transfer)
    {
        if (end - pos < 8) damaged(pos, "it ends inside an element header");
        const std::uint32_t group = number(pos, 2, syntax.bigEndian), elem = number(pos + 2, 2, syntax.bigEndian);
        std::string vr;
        std::uint64_t length, value;
        if (syntax.explicitVr && group != 0xfffe) {
            if (!validVr(pos + 4)) damaged(pos, "an element has no valid value representation");
            unsigned char b[2];
            readAt(pos + 4, b, 2);
            vr.assign(reinterpret_cast<char*>(b), 2);
            static const std::set<std::string> kLong{"OB", "OD", "OF", "OL", "OV", "OW", "SQ", "SV", "UC", "UN",
                "UR", "UT", "UV"};
            if (kLong.count(vr)) {
                if (end - pos < 12) damaged(pos, "it ends inside an element header");
                length = number(pos + 8, 4, syntax.bigEndian);
                value = pos + 12;
            } else {
                length = number(pos + 6, 2, syntax.bigEndian);
                value = pos + 8;
            }
        } else {
            length = number(pos + 4, 4, syntax.bigEndian);
            value = pos + 8;
        }
        if (group == 0xfffe) damaged(pos, "an item or delimiter stands outside a sequence");
        const bool pixelData = group == 0x7fe0 && elem == 0x0010;
        if (length == kUndefined) {
            if (depth >= kMaxDepth) damaged(pos, "sequences nest deeper than " + std::to_string(kMaxDepth));
            // An undefined-length UN holds an implicit VR sequence (PS3.5 §6.2.2).
            const Syntax inner = vr == "UN" || (syntax.explicitVr && vr != "SQ" && !pixelData)
                ? Syntax{false, syntax.bigEndian} : syntax;
            return items(value, end, inner, depth + 1, pixelData, true);
        }
        fits(value, length, end, "an element");
        // GDCM reads the image pixel module's unsigned shorts (samples per pixel, planar
        // configuration, rows, columns, bits allocated, stored, high bit, pixel representation)
        // through gdcm::Attribute, which asserts (an abort) on any length but 0 or 2 (fuzz_dicom).
        static const std::set<std::uint32_t> kPixelUs{0x0002, 0x0006, 0x0010, 0x0011, 0x0100, 0x0101, 0x0102, 0x0103};
        if (depth == 0 && group == 0x0028 && kPixelUs.count(elem) && length != 0 && length != 2) {
            char tag[16];
            std::snprintf(tag, sizeof tag, "(0028,%04X)", unsigned(elem));
            damaged(pos, std::string(tag) + " is one unsigned short (2 bytes) but announces " + std::to_string(length));
        }
        // GDCM's PixelFormat::SetSamplesPerPixel asserts 1, 3 or 4 (PS3.3 C.7.6.3.1.1; fuzz_dicom).
        if (depth == 0 && group == 0x0028 && elem == 0x0002 && length == 2) {
            const std::uint32_t samples = number(value, 2, syntax.bigEndian);
            if (samples != 1 && samples != 3 && samples != 4)
                damaged(pos, "Samples per Pixel (0028,0002) is " + std::to_string(samples) + "; DICOM allows 1 or 3 (4 in retired data)");
        }
        if (transfer && group == 0x0002 && elem == 0x0010 && length < 256) {
            transfer->resize(std::size_t(length));
            readAt(value, reinterpret_cast<unsigned char*>(transfer->data()), std::size_t(length));
        }
        // A defined-length sequence: SQ, or in implicit VR a value that starts with an item.
        const bool sequence = vr == "SQ"
            || (!syntax.explicitVr && length >= 8 && number(value, 2, syntax.bigEndian) == 0xfffe
                && number(value + 2, 2, syntax.bigEndian) == 0xe000);
        if (sequence && length > 0) {
            if (depth >= kMaxDepth) damaged(pos, "sequences nest deeper than " + std::to_string(kMaxDepth));
            items(value, value + length, syntax, depth + 1, false, false);
        }
        return value + length;
    }

    /// The items of a sequence (or the fragments of encapsulated pixel data) from pos to end,
    /// or to the sequence delimiter when undefined.
    std::uint64_t items(std::uint64_t pos, std::uint64_t end, Syntax syntax, int depth, bool fragments, bool undefined)
    {
        while (pos < end) {
            if (end - pos < 8) damaged(pos, "it ends inside an item header");
            const std::uint32_t group = number(pos, 2, syntax.bigEndian), elem = number(pos + 2, 2, syntax.bigEndian);
            const std::uint32_t length = number(pos + 4, 4, syntax.bigEndian);
            if (group == 0xfffe && elem == 0xe0dd) {
                if (undefined) return pos + 8;
                damaged(pos, "a sequence delimiter ends a sequence of defined length");
            }
            if (group != 0xfffe || elem != 0xe000) damaged(pos, "a sequence holds something other than items");
            pos += 8;
            if (length == kUndefined && !fragments) {
                pos = elements(pos, end, syntax, depth, true);
                continue;
            }
            if (length == kUndefined) damaged(pos - 8, "a pixel data fragment has no length");
            fits(pos, length, end, "an item");
            if (!fragments) elements(pos, pos + length, syntax, depth, false);
            pos += length;
        }
        if (undefined) damaged(pos, "a sequence has no delimiter");
        return pos;
    }

    bool has(std::uint32_t group, std::uint32_t elem) const { return mTopLevel.count(group << 16 | elem) > 0; }

    std::string mFile;
    std::set<std::uint32_t> mTopLevel; ///< the data set's own tags, group << 16 | element
    std::ifstream mIn;
    std::optional<std::string> mInflated; ///< the data set, when deflated in the file
    std::uint64_t mSize = 0;
};

// ---- GDCM in a child process (Quarantine.h) ------------------------------------------------
// Debian's GDCM aborts on some damaged files (its assertions are on) and writes past its
// buffers on others (JPEG 2000); the six fuzz_dicom findings of 3 December 2026. Every GDCM
// call runs in a child process forked per series, through the module GdcmServer.h, loaded in
// the parent before the first fork.

/// The file this code was linked into (the executable, or the Python module), from the mapping
/// that holds it: dladdr gives the executable as it was started (argv[0], maybe relative).
fs::path linkedInto()
{
    const auto here = reinterpret_cast<std::uintptr_t>(&linkedInto);
    std::ifstream maps("/proc/self/maps");
    std::string line;
    while (std::getline(maps, line)) {
        unsigned long lo = 0, hi = 0;
        int pathAt = 0;
        // "lo-hi perms offset dev inode path"
        if (std::sscanf(line.c_str(), "%lx-%lx %*s %*s %*s %*s %n", &lo, &hi, &pathAt) < 2 || here < lo || here >= hi)
            continue;
        std::string path = pathAt > 0 ? line.substr(std::size_t(pathAt)) : "";
        const std::string gone = " (deleted)"; // the file was replaced since it was loaded
        if (path.size() > gone.size() && path.compare(path.size() - gone.size(), gone.size(), gone) == 0)
            path.resize(path.size() - gone.size());
        return path;
    }
    return {};
}

/// The module's entry point, loaded once per process. Looked for beside the file this code is
/// linked into (the Python package holds it), in the installed layout relative to it
/// (bin/../lib/isouq, as in the build tree), then where `cmake --install` put it.
GdcmServe gdcmServe()
{
    static std::mutex mutex;
    static GdcmServe serve = nullptr;
    const std::lock_guard<std::mutex> lock(mutex);
    if (serve) return serve;
    const fs::path dir = linkedInto().parent_path();
    std::vector<fs::path> places{fs::path(ISOUQ_MODULE_INSTALLED)};
    if (!dir.empty()) places.insert(places.begin(), {dir, (dir / ISOUQ_MODULE_FROM_BIN).lexically_normal()});
    std::string looked;
    for (const fs::path& place : places) {
        const fs::path path = place / kGdcmModuleName;
        std::error_code ec;
        if (!fs::is_regular_file(path, ec)) {
            looked += (looked.empty() ? "" : ", ") + place.string();
            continue;
        }
        void* handle = ::dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
        if (!handle) throw InputError(std::string("cannot read DICOM: ") + ::dlerror());
        serve = reinterpret_cast<GdcmServe>(::dlsym(handle, kGdcmServeSymbol));
        if (!serve) throw InputError("cannot read DICOM: '" + path.string() + "' is from another version of isouq");
        return serve;
    }
    throw InputError(std::string("cannot read DICOM: isouq's GDCM module ") + kGdcmModuleName + " is in none of "
        + looked + " (reinstall isouq)");
}

Vec3 getVec(Message& m)
{
    const double x = m.get<double>(), y = m.get<double>();
    return Vec3(x, y, m.get<double>());
}

/// In the parent: GDCM's answers, from its child process.
class Gdcm {
public:
    explicit Gdcm(openvdb::util::NullInterrupter* interrupter)
        : mChild("GDCM", [serve = gdcmServe()](Message& request) {
              char* reply = nullptr;
              std::size_t size = 0;
              const int failed = serve(request.bytes().data(), request.bytes().size(), &reply, &size);
              std::string bytes(reply ? reply : "", size);
              std::free(reply);
              if (failed) throw InputError(bytes);
              return Message(std::move(bytes));
          }),
          mInterrupter(interrupter)
    {
    }

    /// The Series Instance UID of each file GDCM parsed (gdcm::Scanner's keys).
    std::vector<std::pair<std::string, std::string>> scan(const std::vector<std::string>& files, const std::string& folder)
    {
        Message request;
        request.put(char(kScan)).put(std::uint64_t(files.size()));
        std::uint64_t size = 0;
        for (const std::string& file : files) {
            request.putString(file);
            size += 1 + 8 + 4096; // keyed, the length of the UID, the UID (64 characters in a valid file)
        }
        Message reply = mChild.call(request, folder, size, mInterrupter);
        std::vector<std::pair<std::string, std::string>> keyed;
        for (const std::string& file : files) {
            const bool key = reply.get<char>() != 0;
            std::string uid = reply.getString();
            if (key) keyed.emplace_back(file, std::move(uid));
        }
        return keyed;
    }

    Slice header(const std::string& file)
    {
        Message request;
        request.put(char(kHeader)).putString(file);
        Message reply = mChild.call(request, file, 1024, mInterrupter);
        Slice s;
        s.file = file;
        s.columns = reply.get<unsigned>();
        s.rows = reply.get<unsigned>();
        s.type = reply.get<SampleType>();
        s.columnSpacing = reply.get<double>();
        s.rowSpacing = reply.get<double>();
        s.position = getVec(reply);
        s.rowCosines = getVec(reply);
        s.columnCosines = getVec(reply);
        return s;
    }

    /// A slice's samples, rescaled into @a out.
    void pixels(const Slice& s, float* out)
    {
        const std::size_t count = std::size_t(s.columns) * s.rows, bytes = count * sampleBytes(s.type);
        Message request;
        request.put(char(kPixels)).putString(s.file).put(std::uint64_t(bytes));
        Message reply = mChild.call(request, s.file, 16 + bytes, mInterrupter);
        const double slope = reply.get<double>(), intercept = reply.get<double>();
        if (reply.left() != bytes) throw InputError("cannot read the pixels of '" + s.file + "'");
        // GDCM gives the pixels in host byte order; each slice has its own rescale (PS3.3 C.11.1).
        decodeSamples(reply.rest(), count, s.type, __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__, slope, intercept, out);
    }

private:
    Quarantine mChild;
    openvdb::util::NullInterrupter* mInterrupter;
};

class DicomSlices : public SliceSource {
public:
    DicomSlices(std::vector<Slice> slices, Gdcm& gdcm) : mSlices(std::move(slices)), mGdcm(gdcm)
    {
        dims = Coord(int(mSlices[0].columns), int(mSlices[0].rows), int(mSlices.size()));
    }

    void read(int z0, int count, float* out) override
    {
        const std::size_t slice = std::size_t(dims.x()) * dims.y();
        for (int z = z0; z < z0 + count; ++z) mGdcm.pixels(mSlices[z], out + std::size_t(z - z0) * slice);
    }

private:
    std::vector<Slice> mSlices;
    Gdcm& mGdcm;
};

} // namespace

DensePiece readDicom(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter, const ScanLoader& load)
{
    const std::string& path = request.input;
    rejectRawFlags(request, "a DICOM series", false);
    // The folder's regular files (symlinks followed). Not gdcm::Directory: it stops listing at
    // the first entry that is neither a file nor a folder (a FIFO, a device), which would mesh
    // a shorter series, and a FIFO would block the reads below.
    std::vector<std::string> listed;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(path, ec))
        if (entry.is_regular_file(ec)) listed.push_back(entry.path().string());
    if (ec) throw InputError("cannot list the folder '" + path + "': " + ec.message());
    std::sort(listed.begin(), listed.end());
    // Files that are not DICOM at all are strangers to the series and are ignored; DICOM files
    // whose lengths do not fit are refused before GDCM allocates for them.
    listed.erase(std::remove_if(listed.begin(), listed.end(), [](const std::string& file) {
        return !ElementWalk(file).run();
    }), listed.end());
    // Group the DICOM files by Series Instance UID (0020,000E); other files are ignored.
    Gdcm gdcm(interrupter);
    const std::vector<std::pair<std::string, std::string>> keyed = gdcm.scan(listed, path);
    // A file with the DICOM preamble that GDCM cannot parse is a damaged slice, not a stranger.
    for (const std::string& file : listed) {
        if (std::any_of(keyed.begin(), keyed.end(), [&](const auto& k) { return k.first == file; })) continue;
        char head[132] = {};
        std::ifstream in(file, std::ios::binary);
        if (in.read(head, sizeof(head)) && std::string(head + 128, 4) == "DICM")
            throw InputError("'" + file + "' is a damaged DICOM file (truncated or corrupt)");
    }
    std::set<std::string> series;
    std::vector<std::string> files;
    for (const auto& [file, uid] : keyed) {
        files.push_back(file);
        series.insert(uid);
    }
    if (files.empty())
        throw InputError("the folder '" + path + "' holds no TIFF slices and no DICOM files");
    if (series.size() > 1) {
        throw InputError("the folder '" + path + "' holds " + std::to_string(series.size())
            + " DICOM series; give a folder of one series");
    }
    if (files.size() < 2) throw InputError("the folder '" + path + "' holds one DICOM slice; a volume needs two or more");

    std::vector<Slice> slices;
    for (const std::string& file : files) slices.push_back(gdcm.header(file));
    const Slice& first = slices.front();
    const Vec3 normal = first.rowCosines.cross(first.columnCosines);
    if (!(std::fabs(normal.length() - 1.0) < 1e-3))
        throw InputError("'" + first.file + "' has no usable Image Orientation (Patient)");
    for (Slice& s : slices) {
        if (s.columns != first.columns || s.rows != first.rows || s.type != first.type) {
            throw InputError("'" + s.file + "' is " + std::to_string(s.columns) + "x" + std::to_string(s.rows) + " "
                + toString(s.type) + ", but '" + first.file + "' is " + std::to_string(first.columns) + "x"
                + std::to_string(first.rows) + " " + toString(first.type) + ": every slice of a series must match");
        }
        if ((s.rowCosines - first.rowCosines).length() > 1e-4 || (s.columnCosines - first.columnCosines).length() > 1e-4)
            throw InputError("'" + s.file + "' has another orientation than '" + first.file + "'");
        s.along = s.position.dot(normal);
    }
    std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.along < b.along; });
    // Evenly spaced slices only: the grid has one step (PS3.3 C.7.6.2.1.1).
    const double step = (slices.back().along - slices.front().along) / double(slices.size() - 1);
    if (!(step > 0.0)) throw InputError("the slices of '" + path + "' share one position");
    for (std::size_t k = 1; k < slices.size(); ++k) {
        const double gap = slices[k].along - slices[k - 1].along;
        if (std::fabs(gap - step) > 1e-3 * step + 1e-6) {
            throw InputError("the slices of '" + path + "' are not evenly spaced: " + fmt(gap) + " mm between '"
                + slices[k - 1].file + "' and '" + slices[k].file + "', " + fmt(step) + " on average");
        }
    }
    const Vec3 x = first.rowCosines * slices.front().columnSpacing, y = first.columnCosines * slices.front().rowSpacing;
    const Vec3 z = (slices.back().position - slices.front().position) / double(slices.size() - 1);
    const Vec3 o = slices.front().position;
    const std::array<double, 16> affine{x[0], y[0], z[0], o[0], x[1], y[1], z[1], o[1], x[2], y[2], z[2], o[2], 0, 0, 0, 1};
    const SampleType type = first.type;
    const std::size_t count = slices.size();
    DicomSlices source(std::move(slices), gdcm);
    std::string name = fs::path(path).filename().string();
    if (name.empty()) name = fs::path(path).parent_path().filename().string();
    const std::string what = name + ": DICOM series of " + std::to_string(count) + " slices, " + toString(type);
    return load(source, {name, affine, "DICOM image position and orientation (LPS)", what});
}

} // namespace isouq::sources_internal
