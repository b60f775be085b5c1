// isouq: raw scans, `name_XxYxZ_dtype.raw` (SPEC §8; docs/inputs.md).
#include "SourcesInternal.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <regex>
#include <vector>

namespace isouq {
namespace sources_internal {

namespace fs = std::filesystem;

enum class RawType { Uint8, Uint16, Int16, Float32, Float64 };

struct RawTypeInfo { const char* name; RawType type; std::size_t bytes; };
constexpr RawTypeInfo kRawTypes[] = {{"uint8", RawType::Uint8, 1}, {"uint16", RawType::Uint16, 2},
    {"int16", RawType::Int16, 2}, {"float32", RawType::Float32, 4}, {"float64", RawType::Float64, 8}};

const RawTypeInfo& rawType(const std::string& name)
{
    for (const RawTypeInfo& info : kRawTypes) {
        if (name == info.name) return info;
    }
    throw InputError("unknown raw dtype '" + name + "' (use uint8, uint16, int16, float32 or float64)");
}

template <typename T>
T readLittleEndian(const char* bytes)
{
    T value;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    char swapped[sizeof(T)];
    std::reverse_copy(bytes, bytes + sizeof(T), swapped);
    std::memcpy(&value, swapped, sizeof(T));
#else
    std::memcpy(&value, bytes, sizeof(T));
#endif
    return value;
}

/// A headerless little-endian scan, x fastest (index x + X*(y + Y*z)).
class RawSlices : public SliceSource {
public:
    RawSlices(const std::string& path, Coord dimsIn, const RawTypeInfo& type)
        : mPath(path), mType(type), mFile(path, std::ios::binary)
    {
        dims = dimsIn;
        if (!mFile) throw InputError("cannot open '" + path + "'");
    }

    void read(int z0, int count, float* out) override
    {
        const std::size_t n = std::size_t(dims.x()) * dims.y() * count;
        mBytes.resize(n * mType.bytes);
        mFile.seekg(std::streamoff(std::size_t(z0) * dims.x() * dims.y() * mType.bytes));
        if (!mFile.read(mBytes.data(), std::streamsize(mBytes.size()))) {
            throw InputError("cannot read '" + mPath + "' (slices " + std::to_string(z0) + ".."
                + std::to_string(z0 + count - 1) + "): file changed or unreadable");
        }
        const char* b = mBytes.data();
        for (std::size_t i = 0; i < n; ++i, b += mType.bytes) {
            switch (mType.type) {
            case RawType::Uint8: out[i] = float(std::uint8_t(*b)); break;
            case RawType::Uint16: out[i] = float(readLittleEndian<std::uint16_t>(b)); break;
            case RawType::Int16: out[i] = float(readLittleEndian<std::int16_t>(b)); break;
            case RawType::Float32: out[i] = readLittleEndian<float>(b); break;
            case RawType::Float64: out[i] = float(readLittleEndian<double>(b)); break;
            }
        }
    }

private:
    std::string mPath;
    RawTypeInfo mType;
    std::ifstream mFile;
    std::vector<char> mBytes;
};


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
        || __builtin_mul_overflow(voxels, std::uint64_t(type.bytes), &bytes)) {
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

    RawSlices source(path, Coord(int(d[0]), int(d[1]), int(d[2])), type);
    checkLayersFit(source, request.input);
    std::string isovalueSource = "given";
    float isovalue = request.isovalue.value_or(0.0f);
    if (!request.isovalue) {
        isovalue = float(otsuOfSource(source));
        isovalueSource = "Otsu (starting value)";
    }
    LoadedVolume volume = buildDense(source, request, isovalue, interrupter);
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
