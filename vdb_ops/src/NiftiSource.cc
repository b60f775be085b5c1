// isouq: NIfTI-1 and NIfTI-2 scans, `.nii` and `.nii.gz`, through nifticlib (libnifti2; SPEC §10
// "Formats"; docs/inputs.md). Values are scl_slope * v + scl_inter when scl_slope is nonzero;
// world coordinates come from the sform, else the qform, else the voxel sizes, as the NIfTI-1
// standard's methods 3, 2 and 1 say (RAS+ millimetres).
#include "SourcesInternal.h"

#include <nifti2_io.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace isouq::sources_internal {
namespace {

namespace fs = std::filesystem;

constexpr int kMsbFirst = 2; // nifti_image::byteorder of big-endian data (nifti2_io.c's MSB_FIRST)

std::optional<SampleType> sampleTypeOf(int datatype)
{
    switch (datatype) {
    case DT_UINT8: return SampleType::UInt8;
    case DT_INT8: return SampleType::Int8;
    case DT_UINT16: return SampleType::UInt16;
    case DT_INT16: return SampleType::Int16;
    case DT_UINT32: return SampleType::UInt32;
    case DT_INT32: return SampleType::Int32;
    case DT_UINT64: return SampleType::UInt64;
    case DT_INT64: return SampleType::Int64;
    case DT_FLOAT32: return SampleType::Float32;
    case DT_FLOAT64: return SampleType::Float64;
    default: return std::nullopt;
    }
}

struct NiftiFree {
    void operator()(nifti_image* image) const { nifti_image_free(image); }
};

/// The image data of a .nii (gzip or not) read slice by slice through znzlib.
class NiftiSlices : public SliceSource {
public:
    NiftiSlices(const std::string& path, const nifti_image& image, SampleType type)
        : mPath(path), mType(type), mOffset(image.iname_offset), mBigEndian(image.byteorder == kMsbFirst)
    {
        dims = Coord(int(image.nx), int(image.ny), int(image.nz));
        const float slope = float(image.scl_slope);
        // NIfTI-1 §"scl_slope": a slope of 0 (or not finite) means the data are not scaled.
        if (slope != 0.0f && std::isfinite(image.scl_slope) && std::isfinite(image.scl_inter)) {
            mSlope = image.scl_slope;
            mInter = image.scl_inter;
        }
        const bool gzip = nifti_is_gzfile(path.c_str());
        mFile = znzopen(path.c_str(), "rb", gzip);
        if (znz_isnull(mFile)) throw InputError("cannot open '" + path + "'");
        const bool nativeOrder = sampleBytes(type) == 1 || mBigEndian == (__BYTE_ORDER__ == __ORDER_BIG_ENDIAN__);
        if (!gzip && isRawArrayType(type) && nativeOrder && mSlope == 1.0 && mInter == 0.0)
            mRaw = std::make_unique<RawSlabReader>(path, dims, type, std::uint64_t(mOffset));
    }
    ~NiftiSlices() override { znzclose(mFile); }
    NiftiSlices(const NiftiSlices&) = delete;
    NiftiSlices& operator=(const NiftiSlices&) = delete;

    double slope() const { return mSlope; }
    double inter() const { return mInter; }
    const RawSlabReader* rawArray() const override { return mRaw.get(); }

    void read(int z0, int count, float* out) override
    {
        const std::size_t n = std::size_t(dims.x()) * dims.y() * count, bytes = n * sampleBytes(mType);
        const std::int64_t at = mOffset + std::int64_t(z0) * dims.x() * dims.y() * std::int64_t(sampleBytes(mType));
        // znzseek returns gzseek's new offset or fseek's 0; both -1 on failure.
        if (at != mPosition && znzseek(mFile, at, SEEK_SET) < 0) fail(z0, count);
        mBuffer.resize(bytes);
        if (znzread(mBuffer.data(), 1, bytes, mFile) != bytes) fail(z0, count);
        mPosition = at + std::int64_t(bytes);
        decodeSamples(mBuffer.data(), n, mType, mBigEndian, mSlope, mInter, out);
    }

private:
    [[noreturn]] void fail(int z0, int count) const
    {
        throw InputError("'" + mPath + "' is truncated: slices " + std::to_string(z0) + ".."
            + std::to_string(z0 + count - 1) + " of " + std::to_string(dims.z()) + " cannot be read");
    }

    std::string mPath;
    SampleType mType;
    std::int64_t mOffset, mPosition = -1;
    bool mBigEndian;
    double mSlope = 1.0, mInter = 0.0;
    znzFile mFile = nullptr;
    std::vector<char> mBuffer;
    std::unique_ptr<RawSlabReader> mRaw;
};

/// 1 or 2 from the header's first bytes (nifti_image::nifti_type says 1 for both).
int niftiVersion(const std::string& path)
{
    char header[540] = {};
    znzFile file = znzopen(path.c_str(), "rb", nifti_is_gzfile(path.c_str()));
    if (znz_isnull(file)) return 1;
    const std::size_t n = znzread(header, 1, sizeof(header), file);
    znzclose(file);
    return nifti_header_version(header, n) == 2 ? 2 : 1;
}

std::array<double, 16> rowMajor(const nifti_dmat44& m)
{
    std::array<double, 16> out{};
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) out[4 * r + c] = m.m[r][c];
    return out;
}

} // namespace

DensePiece readNifti(const VolumeRequest& request, openvdb::util::NullInterrupter* /*interrupter*/, const ScanLoader& load)
{
    const std::string& path = request.input;
    const std::uint64_t size = fileSize(path);
    rejectRawFlags(request, "NIfTI", false);
    nifti_set_debug_level(0); // errors come back as one InputError, not nifticlib's stderr lines
    StderrCapture capture;
    std::unique_ptr<nifti_image, NiftiFree> image(nifti_image_read(path.c_str(), /*read_data=*/0));
    const std::string printed = capture.release();
    if (!image) {
        throw InputError("'" + path + "' is not a readable NIfTI file (bad or truncated header"
            + (printed.empty() ? std::string() : ": nifticlib says " + printed) + ")");
    }
    if (!printed.empty()) std::fprintf(stderr, "%s\n", printed.c_str()); // not an error: as nifticlib meant it
    const nifti_image& nim = *image;
    const std::optional<SampleType> type = sampleTypeOf(nim.datatype);
    if (!type) {
        throw InputError("'" + path + "' has NIfTI datatype " + nifti_datatype_string(nim.datatype) + " ("
            + std::to_string(nim.datatype) + "); isouq reads scalar volumes: uint8, int8, uint16, int16, uint32, "
              "int32, uint64, int64, float32, float64");
    }
    for (int d = 4; d <= 7; ++d) {
        if (nim.dim[0] >= d && nim.dim[d] > 1) {
            throw InputError("'" + path + "' has " + std::to_string(nim.dim[0]) + " dimensions (dim[" + std::to_string(d)
                + "] = " + std::to_string(nim.dim[d]) + "); isouq meshes one 3-D volume");
        }
    }
    const std::int64_t d[3] = {nim.nx, nim.ny, nim.nz};
    for (std::int64_t n : d) {
        if (n < 1 || std::uint64_t(n) > kMaxDim) {
            throw InputError("'" + path + "' has dimensions " + std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x"
                + std::to_string(d[2]) + ": each must be 1.." + std::to_string(kMaxDim));
        }
    }
    // Uncompressed: the data must be in the file. (gzip: a short stream fails when read.)
    const std::uint64_t bytes = std::uint64_t(d[0]) * std::uint64_t(d[1]) * std::uint64_t(d[2]) * sampleBytes(*type);
    if (!nifti_is_gzfile(path.c_str()) && (nim.iname_offset < 0 || size < std::uint64_t(nim.iname_offset)
                                              || size - std::uint64_t(nim.iname_offset) < bytes)) {
        throw InputError("'" + path + "' is truncated: " + std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x"
            + std::to_string(d[2]) + " " + toString(*type) + " needs " + std::to_string(bytes) + " bytes from offset "
            + std::to_string(nim.iname_offset) + ", the file has " + std::to_string(size));
    }

    // NIfTI-1 standard, "orientation": method 3 (sform), else 2 (qform), else 1 (pixdim).
    std::array<double, 16> affine{};
    std::string geometry;
    if (nim.sform_code > 0) {
        affine = rowMajor(nim.sto_xyz);
        geometry = "NIfTI sform (code " + std::to_string(nim.sform_code) + ")";
    } else if (nim.qform_code > 0) {
        affine = rowMajor(nim.qto_xyz);
        geometry = "NIfTI qform (code " + std::to_string(nim.qform_code) + ")";
    } else {
        affine = {nim.dx, 0, 0, 0, 0, nim.dy, 0, 0, 0, 0, nim.dz, 0, 0, 0, 0, 1};
        geometry = "NIfTI voxel sizes (no sform or qform)";
    }

    NiftiSlices source(path, nim, *type);
    std::string name = fs::path(path).filename().string();
    for (const char* ext : {".nii.gz", ".nii"})
        if (endsWith(name, ext)) name.resize(name.size() - std::string(ext).size());
    std::string what = fs::path(path).filename().string() + ": NIfTI-" + std::to_string(niftiVersion(path))
        + " " + toString(*type);
    if (source.slope() != 1.0 || source.inter() != 0.0)
        what += " scaled by " + fmt(source.slope()) + " + " + fmt(source.inter());
    return load(source, {name, affine, geometry, what});
}

} // namespace isouq::sources_internal
