// isouq: volume inputs (SPEC §5, §8; design and measurements in docs/inputs.md).
#include "isouq/VolumeSources.h"

#include "isouq/MarchingCubes.h"
#include "isouq/Progress.h"

#include <openvdb/io/File.h>

#include <muParser.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <regex>
#include <sstream>

namespace isouq {
namespace sources_internal {

namespace fs = std::filesystem;
using openvdb::Coord;
using openvdb::FloatTree;
using LeafT = FloatTree::LeafNodeType;

constexpr int kBlock = 8; // VDB leaf edge
constexpr int kHalo = 3;  // widest stencil reach beyond an edge (SPEC §2)

std::string fmt(double v)
{
    std::ostringstream os;
    os << v;
    return os.str();
}

// ---- Dense sources, read as consecutive z-slices ------------------------------------------

/// A dense X*Y*Z array read slice by slice; out[x + X*(y + Y*(z - z0))].
class SliceSource {
public:
    virtual ~SliceSource() = default;
    virtual void read(int z0, int count, float* out) = 0;
    Coord dims;
};

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

/// N^3 samples of an analytic field at lo + i*h (the grid transform's exact index->world map).
/// A non-finite sample is an error naming the first one (SPEC §5 fields are finite).
class FieldSlices : public SliceSource {
public:
    FieldSlices(const AnalyticField& field, int n) : mField(field), mH(field.spacing(n))
    {
        dims = Coord(n);
    }

    double world(int i) const { return double(i) * mH + mField.lo; }

    void read(int z0, int count, float* out) override
    {
        const int nx = dims.x(), ny = dims.y();
        std::atomic<std::size_t> firstBad{std::numeric_limits<std::size_t>::max()};
        tbb::parallel_for(tbb::blocked_range<int>(0, ny * count), [&](const tbb::blocked_range<int>& r) {
            for (int row = r.begin(); row != r.end(); ++row) {
                const int y = row % ny, z = z0 + row / ny;
                float* dst = out + std::size_t(row) * nx;
                for (int x = 0; x < nx; ++x) {
                    const double v = mField(world(x), world(y), world(z));
                    dst[x] = float(v);
                    if (!std::isfinite(dst[x])) {
                        std::size_t bad = std::size_t(row) * nx + x, seen = firstBad.load();
                        while (bad < seen && !firstBad.compare_exchange_weak(seen, bad)) {}
                    }
                }
            }
        });
        if (firstBad.load() == std::numeric_limits<std::size_t>::max()) return;
        const std::size_t bad = firstBad.load();
        const int x = int(bad % nx), y = int(bad / nx % ny), z = z0 + int(bad / nx / ny);
        throw InputError(mField.name + " '" + mField.expression + "' is " + fmt(out[bad])
            + " (not finite) at x=" + fmt(world(x)) + " y=" + fmt(world(y)) + " z=" + fmt(world(z))
            + " (voxel " + std::to_string(x) + "," + std::to_string(y) + "," + std::to_string(z)
            + ") on [" + fmt(mField.lo) + ", " + fmt(mField.hi) + "]^3");
    }

private:
    const AnalyticField& mField;
    double mH;
};

// ---- Otsu (SPEC §8 default for scans and fog volumes) -------------------------------------

struct Range {
    double min = std::numeric_limits<double>::infinity();
    double max = -std::numeric_limits<double>::infinity();
    void add(double v) { min = std::min(min, v); max = std::max(max, v); }
};

int histogramBin(double v, double lo, double hi)
{
    if (!(hi > lo)) return 0;
    return std::clamp(int((v - lo) / (hi - lo) * 256.0), 0, 255);
}

/// Two streaming passes over a dense source: finite range, then a 256-bin histogram.
double otsuOfSource(SliceSource& source)
{
    const int slab = kBlock, nz = source.dims.z();
    std::vector<float> buffer(std::size_t(source.dims.x()) * source.dims.y() * slab);
    Range range;
    std::array<std::uint64_t, 256> histogram{};
    for (int pass = 0; pass < 2; ++pass) {
        for (int z0 = 0; z0 < nz; z0 += slab) {
            const int count = std::min(slab, nz - z0);
            source.read(z0, count, buffer.data());
            const std::size_t n = std::size_t(source.dims.x()) * source.dims.y() * count;
            for (std::size_t i = 0; i < n; ++i) {
                if (!std::isfinite(buffer[i])) continue;
                if (pass == 0) range.add(buffer[i]);
                else ++histogram[histogramBin(buffer[i], range.min, range.max)];
            }
        }
    }
    return otsuThreshold(histogram, range.min, range.max);
}

/// Otsu over the active values of a sparse grid (tiles weigh their voxel count).
double otsuOfGrid(const openvdb::FloatGrid& grid)
{
    Range range;
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        if (std::isfinite(*it)) range.add(*it);
    }
    std::array<std::uint64_t, 256> histogram{};
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        if (std::isfinite(*it)) histogram[histogramBin(*it, range.min, range.max)] += it.getVoxelCount();
    }
    return otsuThreshold(histogram, range.min, range.max);
}

// ---- Dense -> sparse (docs/inputs.md "Sparse conversion") ---------------------------------

struct SparseResult {
    FloatTree::Ptr tree;
    Range range; // finite values
    std::size_t blocks = 0, kept = 0;
};

/// Whether a block whose dilation by kHalo spans [lo, hi] becomes a leaf.
bool keepBlock(KeepBlocks rule, double lo, double hi, double k)
{
    if (!(std::isfinite(lo) && std::isfinite(hi))) return true; // non-finite data: keep to report
    switch (rule) {
    case KeepBlocks::Crossing: return lo < k && hi >= k;
    case KeepBlocks::CrossingOrHidden: {
        // Tricubic Lagrange on the middle cell: |p - mid| <= Lebesgue(1.25^3) * (hi - lo) / 2.
        const double mid = 0.5 * (lo + hi), reach = 1.953125 * 0.5 * (hi - lo);
        return hi > lo && mid - reach < k && k <= mid + reach;
    }
    case KeepBlocks::NonConstant: return hi > lo;
    case KeepBlocks::All: return true;
    }
    return true;
}

/// Streams @a source in layers of 8 z-slices with a kHalo halo (a rolling window of at most
/// 14 slices) and builds a tree whose leaves are the kept blocks (see KeepBlocks).
SparseResult sparsify(SliceSource& source, KeepBlocks rule, double k,
    openvdb::util::NullInterrupter* interrupter)
{
    const int nx = source.dims.x(), ny = source.dims.y(), nz = source.dims.z();
    const std::size_t slice = std::size_t(nx) * ny;
    const int bx = (nx + kBlock - 1) / kBlock, by = (ny + kBlock - 1) / kBlock,
              bz = (nz + kBlock - 1) / kBlock;
    constexpr int kWindow = kBlock + 2 * kHalo;
    std::vector<float> window(slice * kWindow);
    int winZ0 = 0, winCount = 0;

    // Per column (x, y): min/max over the layer's dilated z-range (non-finite forces a keep);
    // sum/min/max over the layer's own slices (tile values, data range).
    std::vector<float> colLo(slice), colHi(slice), ownLo(slice), ownHi(slice);
    std::vector<double> ownSum(slice);
    std::vector<LeafT*> leaves(std::size_t(bx) * by);
    std::vector<float> tileValues(leaves.size());

    SparseResult result;
    result.tree = std::make_shared<FloatTree>(0.0f);
    result.blocks = std::size_t(bx) * by * bz;
    for (int bk = 0; bk < bz; ++bk) {
        throwIfInterrupted(interrupter, int(100.0 * bk / bz));
        const int zb0 = bk * kBlock, zb1 = std::min(zb0 + kBlock, nz);
        const int needLo = std::max(zb0 - kHalo, 0), needHi = std::min(zb1 + kHalo, nz);
        if (const int drop = needLo - winZ0; drop > 0) {
            std::memmove(window.data(), window.data() + drop * slice,
                (winCount - drop) * slice * sizeof(float));
            winZ0 = needLo;
            winCount -= drop;
        }
        if (const int have = winZ0 + winCount; have < needHi) {
            source.read(have, needHi - have, window.data() + winCount * slice);
            winCount = needHi - winZ0;
        }
        const float* win = window.data();

        tbb::parallel_for(tbb::blocked_range<int>(0, ny), [&](const tbb::blocked_range<int>& r) {
            constexpr float inf = std::numeric_limits<float>::infinity();
            std::vector<float> check(nx); // v - v: 0, or NaN once a value is not finite
            for (int y = r.begin(); y != r.end(); ++y) {
                const std::size_t row = std::size_t(y) * nx;
                float *lo = &colLo[row], *hi = &colHi[row], *oLo = &ownLo[row], *oHi = &ownHi[row];
                double* sum = &ownSum[row];
                std::fill(lo, lo + nx, inf), std::fill(hi, hi + nx, -inf);
                std::fill(oLo, oLo + nx, inf), std::fill(oHi, oHi + nx, -inf);
                std::fill(sum, sum + nx, 0.0), std::fill(check.begin(), check.end(), 0.0f);
                for (int z = needLo; z < needHi; ++z) {
                    const float* v = win + (z - winZ0) * slice + row;
                    for (int x = 0; x < nx; ++x) {
                        lo[x] = std::min(lo[x], v[x]), hi[x] = std::max(hi[x], v[x]);
                        check[x] += v[x] - v[x];
                    }
                    if (z < zb0 || z >= zb1) continue;
                    for (int x = 0; x < nx; ++x) {
                        if (!std::isfinite(v[x])) continue;
                        oLo[x] = std::min(oLo[x], v[x]), oHi[x] = std::max(oHi[x], v[x]), sum[x] += v[x];
                    }
                }
                for (int x = 0; x < nx; ++x) {
                    if (check[x] != 0.0f) lo[x] = -inf, hi[x] = inf; // non-finite: always a leaf
                }
            }
        });

        tbb::parallel_for(tbb::blocked_range<int>(0, bx * by), [&](const tbb::blocked_range<int>& r) {
            for (int b = r.begin(); b != r.end(); ++b) {
                const int x0 = (b % bx) * kBlock, y0 = (b / bx) * kBlock;
                const int x1 = std::min(x0 + kBlock, nx), y1 = std::min(y0 + kBlock, ny);
                float lo = colLo[std::size_t(y0) * nx + x0], hi = colHi[std::size_t(y0) * nx + x0];
                for (int y = std::max(y0 - kHalo, 0); y < std::min(y1 + kHalo, ny); ++y) {
                    for (int x = std::max(x0 - kHalo, 0); x < std::min(x1 + kHalo, nx); ++x) {
                        lo = std::min(lo, colLo[std::size_t(y) * nx + x]);
                        hi = std::max(hi, colHi[std::size_t(y) * nx + x]);
                    }
                }
                leaves[b] = nullptr;
                if (keepBlock(rule, lo, hi, k)) {
                    auto* leaf = new LeafT(Coord(x0, y0, zb0), 0.0f, /*active=*/true);
                    float* data = leaf->buffer().data(); // offset x << 6 | y << 3 | z
                    for (int l = 0; l < kBlock; ++l) {
                        // voxels outside the data box: the nearest data value, made inactive below
                        const int z = std::min(zb0 + l, nz - 1);
                        for (int j = 0; j < kBlock; ++j) {
                            const float* row = win + (z - winZ0) * slice + std::size_t(std::min(y0 + j, ny - 1)) * nx;
                            for (int i = 0; i < kBlock; ++i) data[i << 6 | j << 3 | l] = row[std::min(x0 + i, nx - 1)];
                        }
                    }
                    if (x0 + kBlock > nx || y0 + kBlock > ny || zb0 + kBlock > nz) {
                        for (auto it = leaf->beginValueOn(); it; ++it) {
                            const Coord c = it.getCoord();
                            if (c.x() >= nx || c.y() >= ny || c.z() >= nz) it.setValueOff();
                        }
                    }
                    leaves[b] = leaf;
                    continue;
                }
                // Tile: the block mean, clamped to the block's own range, so it is on the
                // same side of k as every value of the block.
                float oLo = std::numeric_limits<float>::infinity(), oHi = -oLo;
                double sum = 0.0;
                for (int y = y0; y < y1; ++y) {
                    for (int x = x0; x < x1; ++x) {
                        const std::size_t c = std::size_t(y) * nx + x;
                        oLo = std::min(oLo, ownLo[c]), oHi = std::max(oHi, ownHi[c]), sum += ownSum[c];
                    }
                }
                const double mean = sum / (double(x1 - x0) * (y1 - y0) * (zb1 - zb0));
                tileValues[b] = std::clamp(float(mean), oLo, oHi);
            }
        });

        for (int b = 0; b < bx * by; ++b) {
            const Coord origin((b % bx) * kBlock, (b / bx) * kBlock, zb0);
            if (leaves[b]) {
                result.tree->addLeaf(leaves[b]);
                ++result.kept;
            } else {
                result.tree->addTile(/*level=*/1, origin, tileValues[b], /*active=*/false);
            }
        }
        for (std::size_t c = 0; c < slice; ++c) {
            if (ownLo[c] <= ownHi[c]) result.range.add(ownLo[c]), result.range.add(ownHi[c]);
        }
    }
    if (result.range.min <= result.range.max) {
        result.tree->root().setBackground(float(result.range.min), /*updateChildNodes=*/false);
    }
    return result;
}

/// Isovalue, sparse tree, transform and data-box metadata for a dense source.
LoadedVolume buildDense(SliceSource& source, const VolumeRequest& request, float isovalue,
    openvdb::util::NullInterrupter* interrupter)
{
    if (!std::isfinite(isovalue)) throw InputError("isovalue " + fmt(isovalue) + " is not finite");
    SparseResult sparse = sparsify(source, request.keep, isovalue, interrupter);
    const Range& range = sparse.range;
    if (!(range.min <= range.max)) throw InputError("the data has no finite value");
    if (!(range.min < isovalue && isovalue <= range.max)) {
        throw InputError("isovalue " + fmt(isovalue) + " gives no surface: the data range is ["
            + fmt(range.min) + ", " + fmt(range.max) + "] and a surface needs min < isovalue <= max");
    }
    LoadedVolume volume;
    volume.grid = openvdb::FloatGrid::create(sparse.tree);
    volume.grid->insertMeta(kDataBoundsMinMeta, openvdb::Vec3IMetadata(openvdb::Vec3i(0, 0, 0)));
    volume.grid->insertMeta(kDataBoundsMaxMeta,
        openvdb::Vec3IMetadata((source.dims - Coord(1)).asVec3i()));
    volume.isovalue = isovalue;
    volume.denseBlocks = sparse.blocks;
    volume.keptBlocks = sparse.kept;
    volume.description = std::to_string(source.dims.x()) + "x" + std::to_string(source.dims.y())
        + "x" + std::to_string(source.dims.z()) + ", range [" + fmt(range.min) + ", "
        + fmt(range.max) + "], " + std::to_string(sparse.kept) + " of "
        + std::to_string(sparse.blocks) + " 8^3 blocks kept as leaves";
    return volume;
}

// ---- Inputs -------------------------------------------------------------------------------

std::uint64_t fileSize(const std::string& path)
{
    std::error_code ec;
    if (!fs::exists(path, ec)) throw InputError("cannot open '" + path + "': no such file");
    if (fs::is_directory(path, ec)) throw InputError("'" + path + "' is a directory, not a volume");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec) throw InputError("cannot open '" + path + "': " + ec.message());
    if (size == 0) throw InputError("'" + path + "' is empty");
    return size;
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
        || __builtin_mul_overflow(voxels, std::uint64_t(type.bytes), &bytes)) {
        throw InputError("'" + file + "': " + shape + " needs more than 2^64 bytes (X*Y*Z overflows)");
    }
    if (bytes != size) {
        throw InputError("'" + path + "' has " + std::to_string(size) + " bytes but " + shape
            + " needs " + std::to_string(bytes));
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

LoadedVolume loadField(std::shared_ptr<const AnalyticField> field, int n, const VolumeRequest& request,
    const std::string& defaultSource, openvdb::util::NullInterrupter* interrupter)
{
    if (n < 2) throw InputError("--resolution must be at least 2, got " + std::to_string(n));
    if (n > std::numeric_limits<std::int32_t>::max() - kBlock) throw InputError("--resolution is too large");
    FieldSlices source(*field, n);
    LoadedVolume volume = buildDense(source, request,
        request.isovalue.value_or(float(field->isovalue)), interrupter);
    volume.isovalueSource = request.isovalue ? "given" : defaultSource;
    volume.grid->setName(field->name);
    auto transform = openvdb::math::Transform::createLinearTransform(field->spacing(n));
    transform->postTranslate(openvdb::Vec3d(field->lo));
    volume.grid->setTransform(transform);
    volume.description = field->name + " " + field->expression + " on [" + fmt(field->lo) + ", "
        + fmt(field->hi) + "]^3: " + volume.description;
    volume.truth = std::move(field);
    return volume;
}

// VDB files: OpenVDB 10 neither checks lengths nor offsets against the file size (a truncated
// header can crash it, a truncated grid reads silently as a partial one), so the header and
// grid descriptors are walked first with bounded reads and every grid's end checked.
class BoundedReader {
public:
    BoundedReader(std::ifstream& in, std::uint64_t size, const std::string& path)
        : mIn(in), mSize(size), mPath(path) {}

    template <typename T>
    T pod()
    {
        T value;
        bytes(reinterpret_cast<char*>(&value), sizeof(T));
        return value;
    }
    std::string string()
    {
        const std::uint32_t length = pod<std::uint32_t>();
        need(length);
        std::string s(length, '\0');
        bytes(s.data(), length);
        return s;
    }
    void skip(std::uint64_t n) { need(n); seek(mPos + n); }
    void seek(std::uint64_t pos)
    {
        mPos = pos;
        mIn.seekg(std::streamoff(pos));
    }
    void fail(const std::string& what) const
    {
        throw InputError("'" + mPath + "' is truncated or corrupt: " + what + " (file has "
            + std::to_string(mSize) + " bytes)");
    }

private:
    void need(std::uint64_t n) const { if (n > mSize - mPos) fail("header runs past the end"); }
    void bytes(char* out, std::uint64_t n)
    {
        need(n);
        mIn.read(out, std::streamsize(n));
        mPos += n;
    }
    std::ifstream& mIn;
    std::uint64_t mSize, mPos = 0;
    const std::string& mPath;
};

void checkVdbLayout(const std::string& path, std::uint64_t size)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError("cannot open '" + path + "'");
    BoundedReader r(in, size, path);
    if (r.pod<std::int64_t>() != openvdb::OPENVDB_MAGIC) {
        throw InputError("'" + path + "' is not a VDB file (bad magic number)");
    }
    const std::uint32_t version = r.pod<std::uint32_t>();
    if (version < openvdb::OPENVDB_FILE_VERSION_BOOST_UUID || version > openvdb::OPENVDB_FILE_VERSION) {
        return; // outside what the walk below knows; OpenVDB decides
    }
    r.skip(8);                                  // library major, minor
    const bool hasOffsets = r.pod<char>() != 0;
    r.skip(36);                                 // UUID
    for (std::int32_t i = 0, n = r.pod<std::int32_t>(); i < n; ++i) { // file metadata
        r.string();
        r.string();
        r.skip(r.pod<std::uint32_t>());
    }
    if (!hasOffsets) return;
    const std::int32_t grids = r.pod<std::int32_t>();
    if (grids < 0) r.fail("negative grid count");
    for (std::int32_t i = 0; i < grids; ++i) {
        const std::string name = r.string();
        r.string();                             // type
        r.string();                             // instance parent
        const auto gridPos = r.pod<std::int64_t>(), blockPos = r.pod<std::int64_t>(),
                   endPos = r.pod<std::int64_t>();
        if (!(0 < gridPos && gridPos <= blockPos && blockPos <= endPos)) r.fail("bad offsets of a grid");
        if (std::uint64_t(endPos) > size) {
            r.fail("grid '" + openvdb::io::GridDescriptor::nameAsString(name) + "' ends at byte "
                + std::to_string(endPos));
        }
        r.seek(std::uint64_t(endPos)); // the next descriptor follows this grid
    }
}

std::string describeGrids(const openvdb::GridPtrVec& grids)
{
    std::string list;
    for (const auto& grid : grids) {
        list += (list.empty() ? "" : ", ") + grid->getName() + " (" + grid->valueType() + ")";
    }
    return list.empty() ? "none" : list;
}

LoadedVolume loadVdb(const VolumeRequest& request)
{
    const std::string& path = request.input;
    checkVdbLayout(path, fileSize(path));
    LoadedVolume volume;
    try {
        openvdb::io::File file(path);
        file.open(/*delayLoad=*/false);
        const openvdb::GridPtrVecPtr metas = file.readAllGridMetadata();
        std::string chosen;
        for (const auto& meta : *metas) {
            const bool scalar = meta->isType<openvdb::FloatGrid>() || meta->isType<openvdb::DoubleGrid>();
            if (request.gridName.empty() ? scalar : meta->getName() == request.gridName) {
                if (!scalar) {
                    throw InputError("grid '" + meta->getName() + "' in '" + path + "' is "
                        + meta->valueType() + ", not a float scalar grid; grids found: "
                        + describeGrids(*metas));
                }
                chosen = meta->getName();
                break;
            }
        }
        if (chosen.empty()) {
            throw InputError("'" + path + "' has no float grid"
                + (request.gridName.empty() ? "" : " named '" + request.gridName + "'")
                + "; grids found: " + describeGrids(*metas));
        }
        openvdb::GridBase::Ptr base = file.readGrid(chosen);
        file.close();
        if (auto doubles = openvdb::gridPtrCast<openvdb::DoubleGrid>(base)) {
            volume.grid = openvdb::FloatGrid::create(
                std::make_shared<openvdb::FloatTree>(doubles->tree()));
            volume.grid->setTransform(doubles->transform().copy());
            volume.grid->setGridClass(doubles->getGridClass());
            volume.grid->setName(doubles->getName());
        } else {
            volume.grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
        }
    } catch (const openvdb::Exception& e) {
        throw InputError("cannot read '" + path + "': " + e.what());
    }
    const bool levelSet = volume.grid->getGridClass() == openvdb::GRID_LEVEL_SET;
    if (request.isovalue) {
        volume.isovalue = *request.isovalue;
        volume.isovalueSource = "given";
    } else if (levelSet) {
        volume.isovalue = 0.0f;
        volume.isovalueSource = "level set";
    } else {
        volume.isovalue = float(otsuOfGrid(*volume.grid));
        volume.isovalueSource = "Otsu (starting value)";
    }
    volume.description = fs::path(path).filename().string() + ": grid '" + volume.grid->getName()
        + "' (" + openvdb::GridBase::gridClassToString(volume.grid->getGridClass()) + "), "
        + std::to_string(volume.grid->activeVoxelCount()) + " active voxels, voxel size "
        + fmt(volume.grid->voxelSize()[0]);
    return volume;
}

bool endsWith(const std::string& s, const std::string& suffix)
{
    return s.size() >= suffix.size()
        && std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
            [](char a, char b) { return std::tolower(a) == std::tolower(b); });
}

/// One muParser per thread: parsers hold pointers to their x, y, z.
struct ParserSlot {
    explicit ParserSlot(const std::string& expression)
    {
        parser.DefineVar("x", &x);
        parser.DefineVar("y", &y);
        parser.DefineVar("z", &z);
        parser.SetExpr(expression);
    }
    mu::Parser parser;
    double x = 0.0, y = 0.0, z = 0.0;
};

} // namespace sources_internal

double otsuThreshold(const std::array<std::uint64_t, 256>& histogram, double lo, double hi)
{
    // Maximise the between-class variance w0 w1 (m0 - m1)^2 over splits after bin t.
    const double width = (hi - lo) / 256.0;
    double total = 0.0, totalSum = 0.0;
    for (int b = 0; b < 256; ++b) {
        total += double(histogram[b]);
        totalSum += double(histogram[b]) * (lo + (b + 0.5) * width);
    }
    double w0 = 0.0, sum0 = 0.0, best = -1.0;
    int bestBin = 0;
    for (int t = 0; t < 255; ++t) {
        w0 += double(histogram[t]);
        sum0 += double(histogram[t]) * (lo + (t + 0.5) * width);
        const double w1 = total - w0;
        if (w0 == 0.0 || w1 == 0.0) continue;
        const double d = sum0 / w0 - (totalSum - sum0) / w1;
        const double between = w0 * w1 * d * d;
        if (between > best) best = between, bestBin = t;
    }
    return lo + (bestBin + 0.5) * width;
}

std::shared_ptr<const AnalyticField> makeFormulaField(const std::string& expression,
    double lo, double hi)
{
    using sources_internal::ParserSlot;
    if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi)) {
        throw InputError("--domain needs finite LO < HI, got " + sources_internal::fmt(lo) + ","
            + sources_internal::fmt(hi));
    }
    try {
        ParserSlot probe(expression);
        probe.parser.Eval(); // parses: syntax and unknown names fail here
    } catch (const mu::ParserError& e) {
        // muParser's message ends with its own 0-based "at position N"; say it once, 1-based.
        const std::string message = std::regex_replace(e.GetMsg(), std::regex(" at position [0-9]+\\.?$"), "");
        std::string where;
        if (e.GetPos() >= 0) {
            where = " at character " + std::to_string(std::min<std::size_t>(e.GetPos(), expression.size()) + 1)
                + (e.GetToken().empty() ? "" : " ('" + e.GetToken() + "')");
        }
        throw InputError("cannot parse formula '" + expression + "'" + where + ": " + message);
    }
    auto parsers = std::make_shared<tbb::enumerable_thread_specific<std::unique_ptr<ParserSlot>>>();
    auto field = std::make_shared<AnalyticField>();
    field->name = "formula";
    field->expression = expression;
    field->lo = lo;
    field->hi = hi;
    field->isovalue = 0.0;
    field->resolution = 64;
    field->f = [parsers, expression](double x, double y, double z) {
        std::unique_ptr<ParserSlot>& slot = parsers->local();
        if (!slot) slot = std::make_unique<ParserSlot>(expression);
        slot->x = x, slot->y = y, slot->z = z;
        return slot->parser.Eval();
    };
    return field;
}

LoadedVolume loadVolume(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    namespace si = sources_internal;
    openvdb::initialize();
    const std::string& input = request.input;
    if (interrupter) interrupter->start("Loading volume");
    struct EndGuard {
        openvdb::util::NullInterrupter* p;
        ~EndGuard() { if (p) p->end(); }
    } guard{interrupter};

    if (input.rfind("field:", 0) == 0) {
        const std::string name = input.substr(6);
        const AnalyticField* field = findAnalyticField(name);
        if (!field) {
            std::string names;
            for (const AnalyticField& f : analyticFields()) names += (names.empty() ? "" : ", ") + f.name;
            throw InputError("unknown field '" + name + "'; fields: " + names);
        }
        return si::loadField(std::make_shared<AnalyticField>(*field),
            request.resolution.value_or(field->resolution), request, "SPEC §5 default", interrupter);
    }
    if (input.rfind("formula:", 0) == 0) {
        const auto [lo, hi] = request.domain.value_or(std::make_pair(-1.0, 1.0));
        return si::loadField(makeFormulaField(input.substr(8), lo, hi),
            request.resolution.value_or(64), request, "formula default", interrupter);
    }
    if (si::endsWith(input, ".vdb")) return si::loadVdb(request);
    if (si::endsWith(input, ".raw")) return si::loadRaw(request, interrupter);
    si::fileSize(input); // a missing file says so first
    throw InputError("cannot tell what '" + input
        + "' is: expected a .vdb or .raw file, field:NAME or formula:EXPR");
}

} // namespace isouq
