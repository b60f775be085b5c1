// isouq: what the scans with headers share (NIfTI, NRRD, TIFF, DICOM; docs/inputs.md "Scans
// with headers"): sample decoding, the affine as the grid transform, the .raw-only flags, the
// capture of what their libraries print.
#include "SourcesInternal.h"

#include <unistd.h>

#include <algorithm>
#include <cctype>
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

std::string printedLine(std::string_view raw)
{
    std::string text;
    for (const char c : raw.substr(0, kPrintedChars)) text += std::iscntrl(static_cast<unsigned char>(c)) ? ' ' : c;
    const std::size_t first = text.find_first_not_of(' ');
    return first == std::string::npos ? std::string() : text.substr(first, text.find_last_not_of(' ') - first + 1);
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

LoadedVolume loadScan(SliceSource& source, const VolumeRequest& request, const std::string& name,
    const std::array<double, 16>& indexToWorld, const std::string& geometry, const std::string& what,
    openvdb::util::NullInterrupter* interrupter)
{
    // OpenVDB multiplies row vectors: its matrix is the transpose of the column-vector one.
    openvdb::Mat4d m;
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m(c, r) = indexToWorld[4 * r + c];
    bool finite = true;
    for (double v : indexToWorld) finite = finite && std::isfinite(v);
    const double det = m.getMat3().det();
    if (!finite || !(std::fabs(det) > 0.0) || m(0, 3) != 0 || m(1, 3) != 0 || m(2, 3) != 0 || m(3, 3) != 1) {
        std::string text;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 4; ++c) text += (text.empty() ? "" : " ") + fmt(indexToWorld[4 * r + c]);
        throw InputError("'" + request.input + "' has an unusable " + geometry + " (index-to-world rows " + text
            + "): it must be finite and invertible");
    }
    const Coord& d = source.dims;
    if (d.x() < 2 || d.y() < 2 || d.z() < 2) {
        throw InputError("'" + request.input + "': " + std::to_string(d.x()) + "x" + std::to_string(d.y()) + "x"
            + std::to_string(d.z()) + " has no cell (a cell needs 2 samples along each axis): nothing to mesh");
    }
    LoadedVolume volume = loadDense(source, request, interrupter);
    volume.grid->setName(name);
    volume.grid->setTransform(openvdb::math::Transform::createLinearTransform(m));
    volume.geometry = geometry;
    volume.description = what + " " + volume.description + ", world from the " + geometry;
    return volume;
}

} // namespace isouq::sources_internal
