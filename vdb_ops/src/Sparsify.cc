// isouq: dense sources made sparse, and Otsu's default isovalue (docs/inputs.md "Sparse
// conversion"; SPEC §8).
#include "SourcesInternal.h"

#include "isouq/GridMetadata.h"
#include "isouq/Progress.h"

#include "Memory.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <sstream>
#include <vector>

namespace isouq {
namespace sources_internal {

using openvdb::FloatTree;
using LeafT = FloatTree::LeafNodeType;

std::string fmt(double v)
{
    std::ostringstream os;
    os << v;
    return os.str();
}

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
    if (!(range.min < range.max))
        throw InputError("constant data (every value is " + fmt(range.min) + "): no surface and no default "
                         "isovalue; nothing to mesh");
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
    if (!(range.min < range.max)) {
        // One active value: the surface is where it meets the background, halfway between them.
        const float background = grid.background();
        if (std::isfinite(background) && background != range.min) return 0.5 * (range.min + double(background));
        throw InputError("constant grid '" + grid.getName() + "' (every value is " + fmt(range.min) +
                         "): no surface and no default isovalue; nothing to mesh");
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

void checkLayersFit(const SliceSource& source, const std::string& input)
{
    // sparsify's window of kBlock + 2 kHalo slices and five per-column arrays, a source's own
    // buffer of up to kBlock slices of 8-byte samples; a leaf pointer and a tile value per
    // column of blocks.
    const std::uint64_t slice = std::uint64_t(source.dims.x()) * std::uint64_t(source.dims.y());
    const std::uint64_t columns = std::uint64_t((source.dims.x() + kBlock - 1) / kBlock) * ((source.dims.y() + kBlock - 1) / kBlock);
    const std::uint64_t bytes = slice * ((kBlock + 2 * kHalo) * 4 + 4 * 4 + 8 + kBlock * 8) + columns * 12;
    memory_internal::checkFits(bytes, "'" + input + "' (" + std::to_string(source.dims.x()) + "x"
        + std::to_string(source.dims.y()) + "x" + std::to_string(source.dims.z())
        + ", read in layers of " + std::to_string(kBlock) + " slices)");
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
    setDataBounds(*volume.grid, openvdb::CoordBBox(Coord(0), source.dims - Coord(1)));
    volume.isovalue = isovalue;
    volume.denseBlocks = sparse.blocks;
    volume.keptBlocks = sparse.kept;
    volume.description = std::to_string(source.dims.x()) + "x" + std::to_string(source.dims.y())
        + "x" + std::to_string(source.dims.z()) + ", range [" + fmt(range.min) + ", "
        + fmt(range.max) + "], " + std::to_string(sparse.kept) + " of "
        + std::to_string(sparse.blocks) + " 8^3 blocks kept as leaves";
    return volume;
}


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

} // namespace isouq
