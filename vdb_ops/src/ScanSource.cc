// isouq: what the scans with headers share (NIfTI, NRRD, TIFF, DICOM; docs/inputs.md "Scans
// with headers"): sample decoding, the affine as the grid transform, loading in one process or
// by pieces (SPEC §9; docs/mpi.md), the .raw-only flags, the capture of what their libraries print.
#include "SourcesInternal.h"

#include "isouq/Bricks.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace isouq::sources_internal {

namespace {
std::mutex sStderrMutex;
}

StderrCapture::StderrCapture() : mLock(sStderrMutex)
{
    std::fflush(stderr);
    mFile = std::tmpfile();
    mSaved = mFile ? ::dup(2) : -1;
    if (mSaved < 0 || ::dup2(::fileno(mFile), 2) < 0) restore();
}

std::string StderrCapture::release()
{
    if (!mFile) return mText;
    std::fflush(stderr);
    restore();
    std::rewind(mFile);
    char raw[kPrintedChars];
    mText = printedLine(std::string_view(raw, std::fread(raw, 1, sizeof raw, mFile)));
    std::fclose(mFile);
    mFile = nullptr;
    if (mLock.owns_lock()) mLock.unlock();
    return mText;
}

void StderrCapture::restore()
{
    if (mSaved >= 0) {
        ::dup2(mSaved, 2);
        ::close(mSaved);
        mSaved = -1;
    }
}

std::size_t sampleBytes(SampleType type)
{
    switch (type) {
    case SampleType::UInt8:
    case SampleType::Int8: return 1;
    case SampleType::UInt16:
    case SampleType::Int16: return 2;
    case SampleType::UInt32:
    case SampleType::Int32:
    case SampleType::Float32: return 4;
    case SampleType::UInt64:
    case SampleType::Int64:
    case SampleType::Float64: return 8;
    }
    return 1;
}

const char* toString(SampleType type)
{
    switch (type) {
    case SampleType::UInt8: return "uint8";
    case SampleType::Int8: return "int8";
    case SampleType::UInt16: return "uint16";
    case SampleType::Int16: return "int16";
    case SampleType::UInt32: return "uint32";
    case SampleType::Int32: return "int32";
    case SampleType::UInt64: return "uint64";
    case SampleType::Int64: return "int64";
    case SampleType::Float32: return "float32";
    case SampleType::Float64: return "float64";
    }
    return "uint8";
}

namespace {

template <typename T>
double load(const char* p, bool swap)
{
    char bytes[sizeof(T)];
    if (swap) std::reverse_copy(p, p + sizeof(T), bytes);
    else std::memcpy(bytes, p, sizeof(T));
    T v;
    std::memcpy(&v, bytes, sizeof(T));
    return double(v);
}

template <typename T>
void decode(const char* bytes, std::size_t n, bool swap, double slope, double inter, float* out)
{
    const bool identity = slope == 1.0 && inter == 0.0;
    for (std::size_t i = 0; i < n; ++i, bytes += sizeof(T)) {
        const double v = load<T>(bytes, swap);
        out[i] = float(identity ? v : slope * v + inter);
    }
}

} // namespace

void decodeSamples(const char* bytes, std::size_t n, SampleType type, bool bigEndian, double slope,
    double inter, float* out)
{
    // Slices of a large scan in parallel pieces (each sample on its own: any split gives the same floats).
    constexpr std::size_t kPiece = std::size_t(1) << 16;
    if (n > kPiece) {
        const std::size_t bytesPer = sampleBytes(type);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, kPiece), [&](const auto& r) {
            decodeSamples(bytes + r.begin() * bytesPer, r.size(), type, bigEndian, slope, inter, out + r.begin());
        });
        return;
    }
    const bool swap = bigEndian != (__BYTE_ORDER__ == __ORDER_BIG_ENDIAN__);
    switch (type) {
    case SampleType::UInt8: return decode<std::uint8_t>(bytes, n, swap, slope, inter, out);
    case SampleType::Int8: return decode<std::int8_t>(bytes, n, swap, slope, inter, out);
    case SampleType::UInt16: return decode<std::uint16_t>(bytes, n, swap, slope, inter, out);
    case SampleType::Int16: return decode<std::int16_t>(bytes, n, swap, slope, inter, out);
    case SampleType::UInt32: return decode<std::uint32_t>(bytes, n, swap, slope, inter, out);
    case SampleType::Int32: return decode<std::int32_t>(bytes, n, swap, slope, inter, out);
    case SampleType::UInt64: return decode<std::uint64_t>(bytes, n, swap, slope, inter, out);
    case SampleType::Int64: return decode<std::int64_t>(bytes, n, swap, slope, inter, out);
    case SampleType::Float32: return decode<float>(bytes, n, swap, slope, inter, out);
    case SampleType::Float64: return decode<double>(bytes, n, swap, slope, inter, out);
    }
}

void rejectRawFlags(const VolumeRequest& request, const std::string& format, bool spacingAllowed)
{
    const char* flag = request.dims ? "--dims" : !request.dtype.empty() ? "--dtype"
        : request.spacing && !spacingAllowed ? "--spacing" : nullptr;
    if (flag) {
        const bool spacing = std::string(flag) == "--spacing";
        throw InputError(std::string(flag) + " applies to .raw files" + (spacing ? " and TIFF stacks" : "") + "; '"
            + request.input + "' is " + format + " and its header says");
    }
}

namespace {

/// The grid transform of @a header's affine for a scan of @a dims samples.
/// @throw InputError if the affine is not finite or singular, or the scan has no cell.
openvdb::math::Transform::Ptr scanTransform(const VolumeRequest& request, const ScanHeader& header, const Coord& dims)
{
    const std::array<double, 16>& a = header.indexToWorld;
    // OpenVDB multiplies row vectors: its matrix is the transpose of the column-vector one.
    openvdb::Mat4d m;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m(c, r) = a[std::size_t(4 * r + c)];
    bool finite = true;
    for (double v : a) finite = finite && std::isfinite(v);
    const double det = m.getMat3().det();
    if (!finite || !(std::fabs(det) > 0.0) || m(0, 3) != 0 || m(1, 3) != 0 || m(2, 3) != 0 || m(3, 3) != 1) {
        std::string text;
        for (std::size_t r = 0; r < 3; ++r)
            for (std::size_t c = 0; c < 4; ++c) text += (text.empty() ? "" : " ") + fmt(a[4 * r + c]);
        throw InputError("'" + request.input + "' has an unusable " + header.geometry + " (index-to-world rows " + text
            + "): it must be finite and invertible");
    }
    if (dims.x() < 2 || dims.y() < 2 || dims.z() < 2) {
        throw InputError("'" + request.input + "': " + std::to_string(dims.x()) + "x" + std::to_string(dims.y()) + "x"
            + std::to_string(dims.z()) + " has no cell (a cell needs 2 samples along each axis): nothing to mesh");
    }
    return openvdb::math::Transform::createLinearTransform(m);
}

void nameScan(LoadedVolume& volume, const ScanHeader& header, openvdb::math::Transform::Ptr transform)
{
    volume.grid->setName(header.name);
    volume.grid->setTransform(transform);
    volume.geometry = header.geometry;
    volume.description = header.what + " " + volume.description + ", world from the " + header.geometry;
}

} // namespace

LoadedVolume loadScan(SliceSource& source, const VolumeRequest& request, const ScanHeader& header,
    openvdb::util::NullInterrupter* interrupter)
{
    const openvdb::math::Transform::Ptr transform = scanTransform(request, header, source.dims);
    const RawSlabReader* raw = source.rawArray();
    LoadedVolume volume = raw ? loadRawArray(*raw, request, interrupter) : loadDense(source, request, interrupter);
    nameScan(volume, header, transform);
    return volume;
}

DensePiece loadScanPiece(SliceSource& source, const VolumeRequest& request, const ScanHeader& header,
    const PieceComm& comm, openvdb::util::NullInterrupter* interrupter)
{
    const openvdb::math::Transform::Ptr transform = scanTransform(request, header, source.dims);
    if (const RawSlabReader* raw = source.rawArray()) {
        DensePiece piece = loadRawArrayPiece(*raw, request, comm, interrupter);
        nameScan(piece.volume, header, transform);
        return piece;
    }
    checkLayersFit(source, request.input);
    const int layers = (source.dims.z() + kBlock - 1) / kBlock;
    const int l0 = firstLayerOf(layers, comm.rank(), comm.size()), l1 = firstLayerOf(layers, comm.rank() + 1, comm.size());
    const int z0 = std::min(l0 * kBlock, source.dims.z()), z1 = std::min(l1 * kBlock, source.dims.z());
    float isovalue = 0.0f;
    if (request.isovalue) {
        isovalue = *request.isovalue;
    } else { // otsuOfSource's two passes, each piece over its own slices, joined in piece order
        SourceStats part;
        comm.agree([&] { part = sourceStats(source, z0, z1, nullptr, interrupter); });
        Range range;
        for (const PieceComm::Words& w : comm.allgather({bitsOf(part.range.min), bitsOf(part.range.max)})) {
            Range r;
            r.min = doubleOf(w[0]), r.max = doubleOf(w[1]);
            range.add(r);
        }
        checkOtsuRange(range);
        comm.agree([&] { part = sourceStats(source, z0, z1, &range, interrupter); });
        std::array<std::uint64_t, 256> histogram{};
        const PieceComm::Words total = comm.sum(PieceComm::Words(part.histogram.begin(), part.histogram.end()));
        std::copy(total.begin(), total.end(), histogram.begin());
        isovalue = float(otsuThreshold(histogram, range.min, range.max));
    }
    if (!std::isfinite(isovalue)) throw InputError("isovalue " + fmt(isovalue) + " is not finite");
    SparseResult sparse;
    comm.agree([&] { sparse = sparsify(source, request.keep, isovalue, interrupter, l0, l1); });
    DensePiece piece = spreadLayers(std::move(sparse), source.dims, isovalue, comm);
    piece.volume.isovalueSource = request.isovalue ? "given" : "Otsu (starting value)";
    nameScan(piece.volume, header, transform);
    return piece;
}

} // namespace isouq::sources_internal
