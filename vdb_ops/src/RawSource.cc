// isouq: raw scans, `name_XxYxZ_dtype.raw` (SPEC §8; docs/inputs.md).
#include "SourcesInternal.h"

#include <fcntl.h>
#include <unistd.h>

#include <tbb/task_arena.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <regex>

namespace isouq {
namespace sources_internal {

namespace fs = std::filesystem;

namespace {

struct RawTypeInfo { const char* name; SampleType type; };
constexpr RawTypeInfo kRawTypes[] = {{"uint8", SampleType::UInt8}, {"uint16", SampleType::UInt16},
    {"int16", SampleType::Int16}, {"float32", SampleType::Float32}, {"float64", SampleType::Float64}};

const RawTypeInfo& rawType(const std::string& name)
{
    for (const RawTypeInfo& info : kRawTypes) {
        if (name == info.name) return info;
    }
    throw InputError("unknown raw dtype '" + name + "' (use uint8, uint16, int16, float32 or float64)");
}

} // namespace

RawSlabReader::RawSlabReader(const std::string& path, const Coord& dims, SampleType type)
    : mPath(path), mDims(dims), mType(type), mFd(::open(path.c_str(), O_RDONLY | O_CLOEXEC))
{
    if (mFd < 0) throw InputError("cannot open '" + path + "': " + std::strerror(errno));
}

RawSlabReader::~RawSlabReader() { ::close(mFd); }

void RawSlabReader::readSlices(int z0, int z1, char* out) const
{
    const std::size_t slice = std::size_t(mDims.x()) * mDims.y() * sampleBytes(mType);
    std::size_t left = slice * std::size_t(z1 - z0);
    off_t at = off_t(slice * std::size_t(z0));
    while (left > 0) {
        const ssize_t got = ::pread(mFd, out, left, at);
        if (got < 0 && errno == EINTR) continue;
        if (got <= 0) {
            throw InputError("cannot read '" + mPath + "' (slices " + std::to_string(z0) + ".."
                + std::to_string(z1 - 1) + "): file changed or unreadable");
        }
        out += got, at += got, left -= std::size_t(got);
    }
}

LoadedVolume loadRaw(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    const std::string& path = request.input;
    const std::uint64_t size = fileSize(path);
    static const std::regex sName(R"(^(.*)_([0-9]+)x([0-9]+)x([0-9]+)_([a-z0-9]+)\.raw$)");
    const std::string file = fs::path(path).filename().string();
    std::smatch m;
    const bool named = std::regex_match(file, m, sName);
    if (!named && (!request.dims || request.dtype.empty())) {
        throw InputError("cannot tell the dimensions and type of '" + path
            + "': name it name_XxYxZ_dtype.raw (dtype uint8, uint16, int16, float32, float64)"
              " or give --dims and --dtype");
    }
    std::uint64_t d[3];
    for (int a = 0; a < 3; ++a) {
        if (request.dims) {
            if ((*request.dims)[a] <= 0) throw InputError("--dims must be positive");
            d[a] = std::uint64_t((*request.dims)[a]);
        } else {
            const std::string text = m[2 + a].str();
            if (text.size() > 19) throw InputError("dimension " + text + " of '" + file + "' is too large");
            d[a] = std::stoull(text);
            if (d[a] == 0) throw InputError("dimension 0 in the name of '" + file + "'");
        }
    }
    const RawTypeInfo& type = rawType(request.dtype.empty() ? m[5].str() : request.dtype);
    const std::string shape = std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x"
        + std::to_string(d[2]) + " " + type.name;
    std::uint64_t voxels = 0, bytes = 0;
    if (__builtin_mul_overflow(d[0], d[1], &voxels) || __builtin_mul_overflow(voxels, d[2], &voxels)
        || __builtin_mul_overflow(voxels, std::uint64_t(sampleBytes(type.type)), &bytes)) {
        throw InputError("'" + file + "': " + shape + " needs more than 2^64 bytes (X*Y*Z overflows)");
    }
    if (bytes != size) {
        throw InputError("'" + path + "' has " + std::to_string(size) + " bytes but " + shape
            + " needs " + std::to_string(bytes));
    }
    if (d[0] < 2 || d[1] < 2 || d[2] < 2) {
        throw InputError("'" + file + "': " + shape + " has no cell (a cell needs 2 samples along each axis): "
            "nothing to mesh");
    }
    constexpr std::uint64_t maxDim = std::numeric_limits<std::int32_t>::max() - kBlock;
    if (d[0] > maxDim || d[1] > maxDim || d[2] > maxDim) {
        throw InputError("'" + file + "': " + shape + " exceeds OpenVDB's index range");
    }
    const openvdb::Vec3d spacing = request.spacing.value_or(openvdb::Vec3d(1.0));
    for (int a = 0; a < 3; ++a) {
        if (!(std::isfinite(spacing[a]) && spacing[a] > 0.0)) {
            throw InputError("--spacing must be positive and finite, got " + fmt(spacing[a]));
        }
    }

    const RawSlabReader reader(path, Coord(int(d[0]), int(d[1]), int(d[2])), type.type);
    const int nz = int(d[2]);
    checkLayersFit(reader, tbb::this_task_arena::max_concurrency(), request.input);
    std::string isovalueSource = "given";
    float isovalue = request.isovalue.value_or(0.0f);
    if (!request.isovalue) {
        RawStats stats = rawStats(reader, 0, nz);
        if (type.type == SampleType::Float32 || type.type == SampleType::Float64) {
            const Range range = stats.range;
            stats.counts = rawStats(reader, 0, nz, &range).counts;
        }
        isovalue = float(otsuOfRawStats(stats, type.type));
        isovalueSource = "Otsu (starting value)";
    }
    if (!std::isfinite(isovalue)) throw InputError("isovalue " + fmt(isovalue) + " is not finite");
    LoadedVolume volume = denseVolume(
        sparsifyRaw(reader, 0, (nz + kBlock - 1) / kBlock, request.keep, isovalue, interrupter), reader.dims(), isovalue);
    volume.isovalueSource = isovalueSource;
    volume.grid->setName(named ? m[1].str() : fs::path(path).stem().string());
    auto transform = openvdb::math::Transform::createLinearTransform(1.0);
    transform->preScale(spacing);
    volume.grid->setTransform(transform);
    volume.description = file + ": " + type.name + " " + volume.description + ", spacing "
        + fmt(spacing[0]) + "," + fmt(spacing[1]) + "," + fmt(spacing[2]);
    return volume;
}


} // namespace sources_internal

} // namespace isouq
