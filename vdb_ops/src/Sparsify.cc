// isouq: dense sources made sparse, and Otsu's default isovalue (docs/inputs.md "Sparse
// conversion"; SPEC §8).
#include "SourcesInternal.h"

#include "isouq/Diagnostics.h"
#include "isouq/GridMetadata.h"
#include "isouq/Progress.h"

#include "FreshPages.h"
#include "Memory.h"
#include "isouq/Threads.h"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <deque>
#include <mutex>
#include <sstream>
#include <type_traits>
#include <vector>

namespace isouq {
namespace sources_internal {

using openvdb::FloatTree;
using LeafT = FloatTree::LeafNodeType;
using mc_internal::SlabBuffer;

std::string fmt(double v)
{
    std::ostringstream os;
    os << v;
    return os.str();
}

// ---- Otsu (SPEC §8 default for scans and fog volumes) -------------------------------------

int histogramBin(double v, double lo, double hi)
{
    if (!(hi > lo)) return 0;
    return std::clamp(int((v - lo) / (hi - lo) * 256.0), 0, 255);
}


SourceStats sourceStats(SliceSource& source, int z0, int z1, const Range* histogramRange,
    openvdb::util::NullInterrupter* interrupter)
{
    const int slab = kBlock;
    std::vector<float> buffer(std::size_t(source.dims.x()) * source.dims.y() * slab);
    // Each thread its own range and counts, joined at the end: min, max and integer sums do not
    // depend on the order.
    tbb::enumerable_thread_specific<SourceStats> parts;
    for (int z = z0; z < z1; z += slab) {
        throwIfInterrupted(interrupter); // a default isovalue reads the whole volume twice
        const int count = std::min(slab, z1 - z);
        source.read(z, count, buffer.data());
        const std::size_t n = std::size_t(source.dims.x()) * source.dims.y() * count;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, std::size_t(1) << 16), [&](const auto& r) {
            SourceStats& part = parts.local();
            const float* v = buffer.data();
            if (!histogramRange) { // NaN fails both tests; infinities fail the second of each
                constexpr float inf = std::numeric_limits<float>::infinity();
                float lo = inf, hi = -inf;
                for (std::size_t i = r.begin(); i < r.end(); ++i) {
                    if (v[i] < lo && v[i] > -inf) lo = v[i];
                    if (v[i] > hi && v[i] < inf) hi = v[i];
                }
                if (lo <= hi) part.range.add(lo), part.range.add(hi);
                return;
            }
            // A scan's samples take few distinct values (integers, scaled): each value's bin
            // is remembered, keyed by its bits, so the division runs once per value, not per sample.
            std::array<std::uint32_t, 4096> key;
            std::array<std::uint8_t, 4096> bin{};
            key.fill(0xffffffffu); // a NaN's bits: no finite sample has them
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (!std::isfinite(v[i])) continue;
                std::uint32_t bits;
                std::memcpy(&bits, &v[i], sizeof bits);
                const std::size_t h = (bits ^ (bits >> 13) ^ (bits >> 23)) & 4095u;
                if (key[h] != bits) key[h] = bits, bin[h] = std::uint8_t(histogramBin(v[i], histogramRange->min, histogramRange->max));
                ++part.histogram[bin[h]];
            }
        });
    }
    SourceStats stats;
    for (const SourceStats& part : parts) {
        stats.range.add(part.range);
        for (std::size_t b = 0; b < stats.histogram.size(); ++b) stats.histogram[b] += part.histogram[b];
    }
    return stats;
}

void checkOtsuRange(const Range& range)
{
    if (!(range.min <= range.max)) throw InputError("the data has no finite value; nothing to mesh");
    if (!(range.min < range.max))
        throw InputError("constant data (every value is " + fmt(range.min) + "): no surface and no default "
                         "isovalue; nothing to mesh");
}

/// Two streaming passes over a dense source: finite range, then a 256-bin histogram.
double otsuOfSource(SliceSource& source, openvdb::util::NullInterrupter* interrupter)
{
    const int nz = source.dims.z();
    const Range range = sourceStats(source, 0, nz, nullptr, interrupter).range;
    checkOtsuRange(range);
    return otsuThreshold(sourceStats(source, 0, nz, &range, interrupter).histogram, range.min, range.max);
}

/// Otsu over the active values of a sparse grid (tiles weigh their voxel count).
double otsuOfGrid(const openvdb::FloatGrid& grid)
{
    const ActiveValueScan scan = scanActiveValues(grid);
    return otsuOfActiveValues(grid, scan.min, scan.max, activeValueHistogram(grid, scan.min, scan.max));
}


// ---- Dense -> sparse (docs/inputs.md "Sparse conversion") ---------------------------------

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

/// Samples as the sparsifier holds them: integers as stored (exact sums, no finite checks),
/// floating point as float (a float64 scan is rounded on reading, as the float path always did).
template <typename W>
struct Samples {
    static constexpr bool kFloat = std::is_floating_point_v<W>;
    static constexpr W kHigh = kFloat ? std::numeric_limits<W>::infinity() : std::numeric_limits<W>::max();
    static constexpr W kLow = kFloat ? -std::numeric_limits<W>::infinity() : std::numeric_limits<W>::lowest();
    // 8 samples: of 8 bits fit 16 bits, of 16 bits 32 bits
    using ColumnSum = std::conditional_t<kFloat, double, std::conditional_t<sizeof(W) == 1, std::uint16_t, std::int32_t>>;
    using BlockSum = std::conditional_t<kFloat, double, std::int64_t>;
};

/// Which slices of a layer are read and summarised: all of them (the layer's own blocks), or
/// only the kHalo at its top or bottom (the halo of the layer above or below).
enum class LayerPart { Own, Top, Bottom };

/// Makes the blocks of 8-slice layers in z order. A layer's slices are summarised once, row by
/// row, when read (columns()): per block column and row y, the min/max over the x-dilated columns
/// of the layer's own slices, of its top kHalo slices and of its bottom kHalo slices (non-finite
/// forces a keep), and per block the min/max/sum of its own finite values. The layer is made
/// (layer()) once the layer above is summarised: the min/max over its dilated box is the min/max
/// of its own part, the top of the layer below and the bottom of the layer above, over the
/// y-dilated rows. Two layers of slices are held (a ring of 16 slices; layer bk in half bk % 2).
template <typename W>
class LayerSparsifier {
public:
    using S = Samples<W>;

    LayerSparsifier(const LayerSparsifier&) = delete; // mRing points into mRingStore
    LayerSparsifier& operator=(const LayerSparsifier&) = delete;
    /// @a firstSlice: the file byte where slice 0 starts when slices are read with pread (SlabBuffer).
    LayerSparsifier(const Coord& dims, KeepBlocks rule, double k, std::uint64_t firstSlice = 0)
        : mDims(dims), mSlice(std::size_t(dims.x()) * dims.y()), mRule(rule), mK(k),
          mBx((dims.x() + kBlock - 1) / kBlock), mBy((dims.y() + kBlock - 1) / kBlock),
          mLayers((dims.z() + kBlock - 1) / kBlock), mRing(mRingStore.place(mSlice * 2 * kBlock, firstSlice)),
          mOwnLo(S::kFloat ? mSlice : 0), mOwnHi(mOwnLo.size()), mOwnSum(mSlice),
          mLeaves(std::size_t(mBx) * mBy), mTiles(mLeaves.size())
    {
        for (int p = 0; p < 3; ++p) mColLo[p].resize(mSlice), mColHi[p].resize(mSlice);
        for (Summary& summary : mSummaries) summary.resize(mLeaves.size());
    }

    int blocksPerLayer() const { return mBx * mBy; }
    int layers() const { return mLayers; }
    /// The slices of @a part of layer @a bk: [first, last).
    std::pair<int, int> slices(int bk, LayerPart part) const
    {
        const int z0 = bk * kBlock, z1 = std::min(z0 + kBlock, mDims.z());
        if (part == LayerPart::Top) return {std::max(z1 - kHalo, z0), z1};
        if (part == LayerPart::Bottom) return {z0, std::min(z0 + kHalo, z1)};
        return {z0, z1};
    }
    /// Where slice @a z of the ring goes; the slices of a layer are contiguous.
    W* slot(int z) { return mRing + std::size_t(z % (2 * kBlock)) * mSlice; }

    /// Summarises @a part of layer @a bk, whose slices are in the ring (rows in parallel when
    /// @a threaded).
    void columns(int bk, LayerPart part, bool threaded)
    {
        forRange(mDims.y(), threaded, [&](int y0, int y1) {
            std::vector<float> check(S::kFloat ? 3 * std::size_t(mDims.x()) : 0);
            for (int y = y0; y < y1; ++y) row(bk, part, y, check);
        });
        forRange(mBy, threaded, [&](int j0, int j1) {
            std::vector<W> lo(std::size_t(mDims.x())), hi(lo.size());
            for (int j = j0; j < j1; ++j) blockRow(bk, part, j, lo, hi);
        });
    }

    /// Makes layer @a bk's leaves and tiles (blocks in parallel when @a threaded), adds its own
    /// finite values to @a range, then hands the blocks to @a insert(leaves, tiles). Needs the
    /// Own summary of bk, the Top of bk - 1 and the Bottom of bk + 1 (where they exist), and
    /// bk's slices in the ring.
    template <typename Insert>
    void layer(int bk, bool threaded, Range& range, std::size_t& kept, Insert&& insert)
    {
        tbb::combinable<Range> ranges;
        forRange(mBx * mBy, threaded, [&](int b0, int b1) {
            Range& r = ranges.local();
            for (int b = b0; b < b1; ++b) block(bk, b, r);
        });
        ranges.combine_each([&](const Range& r) { range.add(r); });
        for (const auto& leaf : mLeaves) kept += leaf != nullptr;
        insert(mLeaves, mTiles);
    }

private:
    using LeafT = openvdb::FloatTree::LeafNodeType;

    /// Per block of a layer: the min/max over the x- and y-dilated box of each part (own slices,
    /// top kHalo, bottom kHalo), and the min/max/sum of its own finite values.
    struct Summary {
        std::array<std::vector<W>, 3> lo, hi;
        std::vector<W> blockLo, blockHi;
        std::vector<typename S::BlockSum> blockSum;
        void resize(std::size_t blocks)
        {
            for (int p = 0; p < 3; ++p) lo[p].resize(blocks), hi[p].resize(blocks);
            blockLo.resize(blocks), blockHi.resize(blocks), blockSum.resize(blocks);
        }
    };
    Summary& summary(int bk) { return mSummaries[std::size_t(bk % 3)]; }

    /// body(lo, hi) over [0, n): in parallel chunks, or once.
    template <typename Body>
    static void forRange(int n, bool threaded, Body&& body)
    {
        if (!threaded) return body(0, n);
        tbb::parallel_for(tbb::blocked_range<int>(0, n), [&](const tbb::blocked_range<int>& r) { body(r.begin(), r.end()); });
    }

    static bool hasPart(LayerPart part, int p)
    {
        return part == LayerPart::Own || (p == 1 && part == LayerPart::Top) || (p == 2 && part == LayerPart::Bottom);
    }

    /// Row y of the layer's slices: per column and part, the z min/max (mColLo/Hi[p]); with the
    /// own part, the min/max/sum of the finite values (mOwnLo/Hi, mOwnSum).
    void row(int bk, LayerPart part, int y, std::vector<float>& check)
    {
        const int nx = mDims.x();
        const std::size_t offset = std::size_t(y) * nx;
        const auto [z0, z1] = slices(bk, part);
        const std::pair<int, int> range[3] = {slices(bk, LayerPart::Own), slices(bk, LayerPart::Top),
            slices(bk, LayerPart::Bottom)};
        const bool own = part == LayerPart::Own;
        for (int p = 0; p < 3; ++p) {
            if (!hasPart(part, p)) continue;
            std::fill_n(&mColLo[p][offset], nx, S::kHigh), std::fill_n(&mColHi[p][offset], nx, S::kLow);
        }
        std::fill(check.begin(), check.end(), 0.0f);
        if (own) {
            if constexpr (S::kFloat) std::fill_n(&mOwnLo[offset], nx, S::kHigh), std::fill_n(&mOwnHi[offset], nx, S::kLow);
            std::fill_n(&mOwnSum[offset], nx, typename S::ColumnSum(0));
        }
        for (int z = z0; z < z1; ++z) {
            const W* v = slot(z) + offset;
            const auto in = [z](const std::pair<int, int>& r) { return z >= r.first && z < r.second; };
            for (int p = 0; p < 3; ++p) {
                if (!hasPart(part, p) || !in(range[p])) continue;
                if (p == 0 && (in(range[1]) || in(range[2]))) continue; // own = top + bottom + the rest
                W* lo = &mColLo[p][offset];
                W* hi = &mColHi[p][offset];
                for (int x = 0; x < nx; ++x) lo[x] = std::min(lo[x], v[x]), hi[x] = std::max(hi[x], v[x]);
                if constexpr (S::kFloat) {
                    float* c = check.data() + std::size_t(p) * nx;
                    for (int x = 0; x < nx; ++x) c[x] += v[x] - v[x];
                }
            }
            if (!own) continue;
            typename S::ColumnSum* sum = &mOwnSum[offset];
            if constexpr (S::kFloat) {
                W *oLo = &mOwnLo[offset], *oHi = &mOwnHi[offset];
                for (int x = 0; x < nx; ++x) {
                    if (!std::isfinite(v[x])) continue;
                    oLo[x] = std::min(oLo[x], v[x]), oHi[x] = std::max(oHi[x], v[x]), sum[x] += v[x];
                }
            } else {
                for (int x = 0; x < nx; ++x) sum[x] += v[x];
            }
        }
        if (own) {
            W *lo = &mColLo[0][offset], *hi = &mColHi[0][offset];
            for (int p = 1; p < 3; ++p) {
                const W *pLo = &mColLo[p][offset], *pHi = &mColHi[p][offset];
                for (int x = 0; x < nx; ++x) lo[x] = std::min(lo[x], pLo[x]), hi[x] = std::max(hi[x], pHi[x]);
                if constexpr (S::kFloat) {
                    for (int x = 0; x < nx; ++x) check[std::size_t(x)] += check[std::size_t(p) * nx + x];
                }
            }
        }
        if constexpr (S::kFloat) {
            for (int p = 0; p < 3; ++p) {
                if (!hasPart(part, p)) continue;
                for (int x = 0; x < nx; ++x) {
                    if (check[std::size_t(p) * nx + x] != 0.0f)
                        mColLo[p][offset + x] = S::kLow, mColHi[p][offset + x] = S::kHigh; // always a leaf
                }
            }
        }
    }

    /// Block row j of the layer: per part, the min/max over the y-dilated rows (in @a lo, @a hi)
    /// then over each block's x-dilated columns; with the own part, the blocks' own min/max/sum.
    void blockRow(int bk, LayerPart part, int j, std::vector<W>& loColumns, std::vector<W>& hiColumns)
    {
        // Raw pointers: a store through W = uint8_t may alias a vector's own pointers, which
        // would keep the loops from being vectorised.
        W* lo = loColumns.data();
        W* hi = hiColumns.data();
        const int nx = mDims.x(), ny = mDims.y();
        Summary& out = summary(bk);
        const int y0 = j * kBlock, y1 = std::min(y0 + kBlock, ny);
        for (int p = 0; p < 3; ++p) {
            if (!hasPart(part, p)) continue;
            std::fill_n(lo, nx, S::kHigh), std::fill_n(hi, nx, S::kLow);
            for (int y = std::max(y0 - kHalo, 0); y < std::min(y1 + kHalo, ny); ++y) {
                const W* rowLo = &mColLo[p][std::size_t(y) * nx];
                const W* rowHi = &mColHi[p][std::size_t(y) * nx];
                for (int x = 0; x < nx; ++x) lo[x] = std::min(lo[x], rowLo[x]), hi[x] = std::max(hi[x], rowHi[x]);
            }
            W* outLo = out.lo[p].data() + std::size_t(j) * mBx;
            W* outHi = out.hi[p].data() + std::size_t(j) * mBx;
            for (int i = 0; i < mBx; ++i) {
                W l = S::kHigh, h = S::kLow;
                for (int x = std::max(i * kBlock - kHalo, 0); x < std::min((i + 1) * kBlock + kHalo, nx); ++x)
                    l = std::min(l, lo[x]), h = std::max(h, hi[x]);
                outLo[i] = l, outHi[i] = h;
            }
        }
        if (part != LayerPart::Own) return;
        // Own values: integers from the own part's min/max (all finite; sums exact in any order),
        // floating point from the finite min/max and the sums added in (y, x) order.
        if constexpr (!S::kFloat) {
            // Down the block row's 8 rows first (vectorised), then across each block's columns.
            std::vector<typename S::BlockSum> sumColumns(std::size_t(nx), 0);
            typename S::BlockSum* sums = sumColumns.data();
            std::fill_n(lo, nx, S::kHigh), std::fill_n(hi, nx, S::kLow);
            for (int y = y0; y < y1; ++y) {
                const std::size_t r = std::size_t(y) * nx;
                const W *rowLo = &mColLo[0][r], *rowHi = &mColHi[0][r];
                const typename S::ColumnSum* rowSum = &mOwnSum[r];
                for (int x = 0; x < nx; ++x)
                    lo[x] = std::min(lo[x], rowLo[x]), hi[x] = std::max(hi[x], rowHi[x]), sums[x] += rowSum[x];
            }
            for (int i = 0; i < mBx; ++i) {
                W l = S::kHigh, h = S::kLow;
                typename S::BlockSum sum = 0;
                for (int x = i * kBlock; x < std::min((i + 1) * kBlock, nx); ++x)
                    l = std::min(l, lo[x]), h = std::max(h, hi[x]), sum += sums[x];
                const std::size_t b = std::size_t(j) * mBx + i;
                out.blockLo[b] = l, out.blockHi[b] = h, out.blockSum[b] = sum;
            }
            return;
        }
        const std::vector<W>& ownLo = mOwnLo;
        const std::vector<W>& ownHi = mOwnHi;
        for (int i = 0; i < mBx; ++i) {
            W l = S::kHigh, h = S::kLow;
            typename S::BlockSum sum = 0;
            const int x0 = i * kBlock, x1 = std::min(x0 + kBlock, nx);
            for (int y = y0; y < y1; ++y) {
                const std::size_t r = std::size_t(y) * nx;
                for (int x = x0; x < x1; ++x)
                    l = std::min(l, ownLo[r + x]), h = std::max(h, ownHi[r + x]), sum += mOwnSum[r + x];
            }
            const std::size_t b = std::size_t(j) * mBx + i;
            out.blockLo[b] = l, out.blockHi[b] = h, out.blockSum[b] = sum;
        }
    }

    void block(int bk, int b, Range& range)
    {
        const int nx = mDims.x(), ny = mDims.y(), nz = mDims.z();
        const int x0 = (b % mBx) * kBlock, y0 = (b / mBx) * kBlock, zb0 = bk * kBlock;
        const int x1 = std::min(x0 + kBlock, nx), y1 = std::min(y0 + kBlock, ny), zb1 = std::min(zb0 + kBlock, nz);
        const Summary& own = summary(bk);
        const Summary* below = bk > 0 ? &summary(bk - 1) : nullptr;
        const Summary* above = bk + 1 < mLayers ? &summary(bk + 1) : nullptr;
        W lo = own.lo[0][std::size_t(b)], hi = own.hi[0][std::size_t(b)];
        if (below) lo = std::min(lo, below->lo[1][std::size_t(b)]), hi = std::max(hi, below->hi[1][std::size_t(b)]);
        if (above) lo = std::min(lo, above->lo[2][std::size_t(b)]), hi = std::max(hi, above->hi[2][std::size_t(b)]);
        const W oLo = own.blockLo[std::size_t(b)], oHi = own.blockHi[std::size_t(b)];
        if (oLo <= oHi) range.add(double(oLo)), range.add(double(oHi));
        mLeaves[std::size_t(b)].reset();
        if (keepBlock(mRule, double(lo), double(hi), mK)) {
            auto leaf = std::make_unique<LeafT>(Coord(x0, y0, zb0), 0.0f, /*active=*/true);
            float* data = leaf->buffer().data(); // offset x << 6 | y << 3 | z
            for (int l = 0; l < kBlock; ++l) {
                // voxels outside the data box: the nearest data value, made inactive below
                const W* slice = slot(std::min(zb0 + l, nz - 1));
                for (int j = 0; j < kBlock; ++j) {
                    const W* row = slice + std::size_t(std::min(y0 + j, ny - 1)) * nx;
                    for (int i = 0; i < kBlock; ++i) data[i << 6 | j << 3 | l] = float(row[std::min(x0 + i, nx - 1)]);
                }
            }
            if (x0 + kBlock > nx || y0 + kBlock > ny || zb0 + kBlock > nz) {
                for (auto it = leaf->beginValueOn(); it; ++it) {
                    const Coord c = it.getCoord();
                    if (c.x() >= nx || c.y() >= ny || c.z() >= nz) it.setValueOff();
                }
            }
            mLeaves[std::size_t(b)] = std::move(leaf);
            return;
        }
        // Tile: the block mean, clamped to the block's own range, so it is on the same side of k
        // as every value of the block.
        const double mean = double(own.blockSum[std::size_t(b)]) / (double(x1 - x0) * (y1 - y0) * (zb1 - zb0));
        mTiles[std::size_t(b)] = std::clamp(float(mean), float(oLo), float(oHi));
    }

    Coord mDims;
    std::size_t mSlice;
    KeepBlocks mRule;
    double mK;
    int mBx, mBy, mLayers;
    SlabBuffer<W> mRingStore;
    W* mRing; // in mRingStore
    std::array<std::vector<W>, 3> mColLo, mColHi; // per column and part: z min/max
    std::vector<W> mOwnLo, mOwnHi;                // floating point: finite own values only
    std::vector<typename S::ColumnSum> mOwnSum;
    std::array<Summary, 3> mSummaries; // layers bk - 1, bk, bk + 1 at bk % 3
    std::vector<std::unique_ptr<LeafT>> mLeaves;
    std::vector<float> mTiles;
};

/// Makes layer @a bk0 and the ones after it while @a more(bk) says that layer bk + 1 is this
/// run's too (asked once per layer, before that layer is read ahead), with @a layers, reading
/// slices with @a read(z0, z1, out) (out: the ring slots of z0, contiguous), inner loops in
/// parallel when @a threaded; hands each layer's blocks to @a insert(bk, leaves, tiles), polling
/// @a poll() before each.
template <typename W, typename More, typename Read, typename Insert, typename Poll>
void makeLayers(LayerSparsifier<W>& layers, int bk0, More&& more, bool threaded, Read&& read, Insert&& insert,
    Poll&& poll, Range& range, std::size_t& kept)
{
    auto summarise = [&](int bk, LayerPart part) {
        const auto [z0, z1] = layers.slices(bk, part);
        read(z0, z1, layers.slot(z0));
        layers.columns(bk, part, threaded);
    };
    if (bk0 > 0) summarise(bk0 - 1, LayerPart::Top);
    summarise(bk0, LayerPart::Own);
    for (int bk = bk0;; ++bk) {
        poll();
        mc_internal::populateHeapTop(); // the layer's leaves come from malloc
        const bool next = more(bk);
        if (bk + 1 < layers.layers()) summarise(bk + 1, next ? LayerPart::Own : LayerPart::Bottom);
        layers.layer(bk, threaded, range, kept, [&](auto& leaves, const auto& tiles) { insert(bk, leaves, tiles); });
        if (!next) return;
    }
}

/// Adds one layer's blocks (leaves or inactive tiles) to @a tree.
struct LayerInserter {
    FloatTree& tree;
    int bx;

    void operator()(int bk, std::vector<std::unique_ptr<LeafT>>& leaves, const std::vector<float>& tiles) const
    {
        openvdb::tree::ValueAccessor<FloatTree> acc(tree);
        for (std::size_t b = 0; b < leaves.size(); ++b) {
            if (leaves[b]) {
                acc.addLeaf(leaves[b].release());
            } else {
                const Coord origin(int(b % std::size_t(bx)) * kBlock, int(b / std::size_t(bx)) * kBlock, bk * kBlock);
                acc.addTile(/*level=*/1, origin, tiles[b], /*active=*/false);
            }
        }
    }
};


namespace {

/// Bytes one LayerSparsifier holds for slices of @a dims with samples of @a bytes: its ring of
/// two layers, the column min/max of three parts (and two more for floating point), the column
/// sums; per column of blocks a leaf pointer, a tile value and three summaries.
std::uint64_t sparsifierBytes(const Coord& dims, std::uint64_t bytes)
{
    const std::uint64_t slice = std::uint64_t(dims.x()) * std::uint64_t(dims.y());
    const std::uint64_t columns = std::uint64_t((dims.x() + kBlock - 1) / kBlock) * ((dims.y() + kBlock - 1) / kBlock);
    return slice * ((2 * kBlock + 8) * bytes + 8) + columns * (12 + 3 * (9 * bytes + 8));
}

void checkLayerBytes(const Coord& dims, std::uint64_t bytes, const std::string& input)
{
    memory_internal::checkFits(bytes, "'" + input + "' (" + std::to_string(dims.x()) + "x" + std::to_string(dims.y())
        + "x" + std::to_string(dims.z()) + ", read in layers of " + std::to_string(kBlock) + " slices)");
}

} // namespace

void checkLayersFit(const SliceSource& source, const std::string& input)
{
    // One float sparsifier, and the source's own buffer of up to kBlock slices of 8-byte samples.
    const std::uint64_t slice = std::uint64_t(source.dims.x()) * std::uint64_t(source.dims.y());
    checkLayerBytes(source.dims, sparsifierBytes(source.dims, 4) + slice * kBlock * 8, input);
}

void checkLayersFit(const RawSlabReader& reader, int workers, const std::string& input)
{
    // Integers are held as stored, floating point as float (Samples<W>).
    const std::uint64_t bytes = std::min<std::uint64_t>(sampleBytes(reader.type()), 4);
    checkLayerBytes(reader.dims(), std::uint64_t(std::max(workers, 1)) * sparsifierBytes(reader.dims(), bytes), input);
}

/// Streams the block layers [layer0, layer1) of @a source (all of them when @a layer1 < 0) in
/// layers of 8 z-slices with a kHalo halo (a rolling window of at most 14 slices) and builds a
/// tree whose leaves are the kept blocks (see KeepBlocks).
SparseResult sparsify(SliceSource& source, KeepBlocks rule, double k,
    openvdb::util::NullInterrupter* interrupter, int layer0, int layer1)
{
    LayerSparsifier<float> layers(source.dims, rule, k);
    if (layer1 < 0) layer1 = layers.layers();
    const int count = std::max(layer1 - layer0, 0);
    SparseResult result;
    result.tree = std::make_shared<FloatTree>(0.0f);
    result.blocks = std::size_t(layers.blocksPerLayer()) * std::size_t(count);
    const LayerInserter insert{*result.tree, (source.dims.x() + kBlock - 1) / kBlock};
    int done = 0;
    if (layer0 >= layer1) return result;
    makeLayers(layers, layer0, [&](int bk) { return bk + 1 < layer1; }, /*threaded=*/true,
        [&](int z0, int z1, float* out) { source.read(z0, z1 - z0, out); }, insert,
        [&] { throwIfInterrupted(interrupter, int(100.0 * done++ / std::max(count, 1))); }, result.range, result.kept);
    if (result.range.min <= result.range.max) {
        result.tree->root().setBackground(float(result.range.min), /*updateChildNodes=*/false);
    }
    return result;
}

LoadedVolume denseVolume(SparseResult&& sparse, const Coord& dims, float isovalue)
{
    const Range& range = sparse.range;
    if (!(range.min <= range.max)) throw InputError("the data has no finite value");
    if (!(range.min < isovalue && isovalue <= range.max)) {
        throw InputError("isovalue " + fmt(isovalue) + " gives no surface: the data range is ["
            + fmt(range.min) + ", " + fmt(range.max) + "] and a surface needs min < isovalue <= max");
    }
    LoadedVolume volume;
    volume.grid = openvdb::FloatGrid::create(sparse.tree);
    setDataBounds(*volume.grid, openvdb::CoordBBox(Coord(0), dims - Coord(1)));
    volume.isovalue = isovalue;
    volume.denseBlocks = sparse.blocks;
    volume.keptBlocks = sparse.kept;
    volume.description = std::to_string(dims.x()) + "x" + std::to_string(dims.y())
        + "x" + std::to_string(dims.z()) + ", range [" + fmt(range.min) + ", "
        + fmt(range.max) + "], " + std::to_string(sparse.kept) + " of "
        + std::to_string(sparse.blocks) + " 8^3 blocks kept as leaves";
    return volume;
}

/// Isovalue, sparse tree, transform and data-box metadata for a dense source.
LoadedVolume loadDense(SliceSource& source, const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    checkLayersFit(source, request.input);
    const float isovalue = request.isovalue ? *request.isovalue : float(otsuOfSource(source, interrupter));
    LoadedVolume volume = buildDense(source, request, isovalue, interrupter);
    volume.isovalueSource = request.isovalue ? "given" : "Otsu (starting value)";
    return volume;
}

LoadedVolume buildDense(SliceSource& source, const VolumeRequest& request, float isovalue,
    openvdb::util::NullInterrupter* interrupter)
{
    if (!std::isfinite(isovalue)) throw InputError("isovalue " + fmt(isovalue) + " is not finite");
    return denseVolume(sparsify(source, request.keep, isovalue, interrupter), source.dims, isovalue);
}


// ---- Raw scans by slabs (RawSlabReader; parallel over slabs) ------------------------------

/// Calls @a f(W{}) with the sparsifier's sample type of a raw scan's @a type.
template <typename F>
decltype(auto) withRawSamples(SampleType type, F&& f)
{
    switch (type) {
    case SampleType::UInt8: return f(std::uint8_t{});
    case SampleType::UInt16: return f(std::uint16_t{});
    case SampleType::Int16: return f(std::int16_t{});
    case SampleType::Float32:
    case SampleType::Float64: return f(float{});
    default: break;
    }
    throw InputError(std::string("raw scans do not take ") + toString(type) + " samples");
}

/// Reads slices [z0, z1) of @a reader as W: in place when W is the stored type (after a byte
/// swap on a big-endian host), else through @a bytes (float64 rounded to float).
template <typename W>
void readAs(const RawSlabReader& reader, int z0, int z1, W* out, SlabBuffer<char>& bytes)
{
    const std::size_t n = std::size_t(reader.dims().x()) * reader.dims().y() * std::size_t(z1 - z0);
    if (reader.type() == SampleType::Float64) {
        char* const in = bytes.place(n * sizeof(double), reader.sliceOffset(z0));
        reader.readSlices(z0, z1, in);
        for (std::size_t i = 0; i < n; ++i) {
            char b[sizeof(double)];
            std::memcpy(b, in + i * sizeof(double), sizeof(double));
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
            std::reverse(b, b + sizeof(double));
#endif
            double v;
            std::memcpy(&v, b, sizeof(double));
            out[i] = W(v);
        }
        return;
    }
    reader.readSlices(z0, z1, reinterpret_cast<char*>(out));
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    if constexpr (sizeof(W) > 1) {
        char* p = reinterpret_cast<char*>(out);
        for (std::size_t i = 0; i < n; ++i) std::reverse(p + i * sizeof(W), p + (i + 1) * sizeof(W));
    }
#endif
}

/// Runs @a body(z0, z1) over slabs of the slices [z0, z1) in parallel.
template <typename Body>
void forSlabs(int z0, int z1, Body&& body)
{
    tbb::parallel_for(tbb::blocked_range<int>(z0, z1, kBlock),
        [&](const tbb::blocked_range<int>& r) { body(r.begin(), r.end()); });
}

void RawStats::add(const RawStats& other)
{
    range.add(other.range);
    if (counts.size() < other.counts.size()) counts.resize(other.counts.size(), 0);
    for (std::size_t i = 0; i < other.counts.size(); ++i) counts[i] += other.counts[i];
}

RawStats rawStats(const RawSlabReader& reader, int z0, int z1, const Range* histogramRange,
    openvdb::util::NullInterrupter* interrupter)
{
    return withRawSamples(reader.type(), [&](auto sample) {
        using W = decltype(sample);
        tbb::enumerable_thread_specific<std::pair<SlabBuffer<W>, SlabBuffer<char>>> buffers;
        tbb::enumerable_thread_specific<RawStats> parts;
        forSlabs(z0, z1, [&](int a, int b) {
            throwIfInterrupted(interrupter); // a default isovalue reads the whole scan twice
            auto& [slab, bytes] = buffers.local();
            const std::size_t n = std::size_t(reader.dims().x()) * reader.dims().y() * std::size_t(b - a);
            W* const values = slab.place(n, reader.sliceOffset(a));
            readAs(reader, a, b, values, bytes);
            RawStats& part = parts.local();
            if constexpr (Samples<W>::kFloat) {
                if (!histogramRange) {
                    for (std::size_t i = 0; i < n; ++i)
                        if (std::isfinite(values[i])) part.range.add(values[i]);
                    return;
                }
                part.counts.resize(256, 0);
                for (std::size_t i = 0; i < n; ++i)
                    if (std::isfinite(values[i]))
                        ++part.counts[histogramBin(values[i], histogramRange->min, histogramRange->max)];
            } else {
                constexpr std::size_t kValues = std::size_t(1) << (8 * sizeof(W));
                part.counts.resize(kValues, 0);
                // Four 32-bit tallies (a slab has fewer than 2^32 samples) break the chain of
                // increments of one counter when neighbouring samples are equal.
                constexpr int kWays = sizeof(W) == 1 ? 4 : 1;
                std::vector<std::uint32_t> tally(kWays * kValues, 0);
                const std::size_t lowest = std::size_t(-std::ptrdiff_t(std::numeric_limits<W>::lowest()));
                std::size_t i = 0;
                for (; i + kWays <= n; i += kWays)
                    for (int w = 0; w < kWays; ++w) ++tally[w * kValues + std::size_t(values[i + w] + lowest)];
                for (; i < n; ++i) ++tally[std::size_t(values[i] + lowest)];
                for (int w = 0; w < kWays; ++w)
                    for (std::size_t v = 0; v < kValues; ++v) part.counts[v] += tally[w * kValues + v];
            }
        });
        RawStats stats;
        for (const RawStats& part : parts) stats.add(part);
        if constexpr (!Samples<W>::kFloat) {
            // The range from the counted values (every integer value is finite).
            for (std::size_t i = 0; i < stats.counts.size(); ++i)
                if (stats.counts[i]) stats.range.add(double(std::numeric_limits<W>::lowest()) + double(i));
        }
        return stats;
    });
}

double otsuOfRawStats(const RawStats& stats, SampleType type)
{
    const Range& range = stats.range;
    if (!(range.min <= range.max)) throw InputError("the data has no finite value; nothing to mesh");
    if (!(range.min < range.max))
        throw InputError("constant data (every value is " + fmt(range.min) + "): no surface and no default "
                         "isovalue; nothing to mesh");
    std::array<std::uint64_t, 256> histogram{};
    if (type == SampleType::Float32 || type == SampleType::Float64) {
        std::copy(stats.counts.begin(), stats.counts.end(), histogram.begin());
    } else {
        const double lowest = type == SampleType::Int16 ? -32768.0 : 0.0;
        for (std::size_t i = 0; i < stats.counts.size(); ++i)
            if (stats.counts[i]) histogram[histogramBin(lowest + double(i), range.min, range.max)] += stats.counts[i];
    }
    return otsuThreshold(histogram, range.min, range.max);
}

namespace {

/// The layers [layer0, layer1) as one run per thread, each made in order by its thread; a
/// thread done with its own run splits off the upper half of what is left of the largest other
/// (kMinSplit layers or more left), so no core waits long at the end, while the kHalo slices
/// either side of a run are read again only at the few splits. (Fixed runs of 1/(2 threads) of
/// what was left, down to 2 layers, read 78 slices twice on the 1 GiB raw scan: 25-40 ms of a
/// -j 0 load, bench/journal/2026-12-05.md; 8 equal runs left a core idle 40-100 ms.)
class LayerRuns {
public:
    struct Run {
        Run(int first, int end) : first(first), next(first + 1), end(end) {}
        std::mutex mutex;
        const int first; ///< made by the run's thread, never split off
        int next, end;   ///< [next, end): left to split; the layers before next are committed
    };

    LayerRuns(int layer0, int layer1, int threads)
    {
        const std::int64_t n = std::max(layer1 - layer0, 0);
        for (int t = 0; t < threads; ++t)
            mRuns.emplace_back(layer0 + int(n * t / threads), layer0 + int(n * (t + 1) / threads));
    }
    /// Thread @a t's own run, or nullptr when it is empty.
    Run* own(int t)
    {
        Run& run = mRuns[std::size_t(t)];
        return run.first < run.end ? &run : nullptr;
    }
    /// Whether layer @a bk + 1 is still @a run's, which commits it to the run.
    static bool more(Run& run, int bk)
    {
        const std::lock_guard<std::mutex> lock(run.mutex);
        if (bk + 1 >= run.end) return false;
        run.next = bk + 2;
        return true;
    }
    /// A new run split off the largest run left, or nullptr when none has kMinSplit layers left.
    Run* split()
    {
        const std::lock_guard<std::mutex> list(mListMutex); // one thief at a time; owners never take it
        for (;;) {
            Run* victim = nullptr;
            int most = 0;
            for (Run& run : mRuns) {
                const std::lock_guard<std::mutex> lock(run.mutex);
                if (run.end - run.next > most) most = run.end - run.next, victim = &run;
            }
            if (most < kMinSplit) return nullptr;
            const std::lock_guard<std::mutex> lock(victim->mutex);
            const int left = victim->end - victim->next; // its thread may have gone on meanwhile
            if (left < kMinSplit) continue;
            const int mid = victim->end - left / 2;
            Run& mine = mRuns.emplace_back(mid, victim->end);
            victim->end = mid;
            return &mine;
        }
    }

private:
    static constexpr int kMinSplit = 3;
    std::mutex mListMutex;
    std::deque<Run> mRuns; // references stay valid as runs are added
};

} // namespace

SparseResult sparsifyRaw(const RawSlabReader& reader, int layer0, int layer1, KeepBlocks rule, double isovalue,
    openvdb::util::NullInterrupter* interrupter)
{
    const Coord dims = reader.dims();
    const int bx = (dims.x() + kBlock - 1) / kBlock, by = (dims.y() + kBlock - 1) / kBlock;
    SparseResult result;
    result.tree = std::make_shared<FloatTree>(0.0f);
    result.blocks = std::size_t(bx) * by * std::size_t(std::max(layer1 - layer0, 0));
    const LayerInserter insert{*result.tree, bx};
    std::mutex treeMutex;
    std::atomic<int> layersDone{0};
    const int threads = threadsInUse();
    LayerRuns runs(layer0, layer1, threads);
    withRawSamples(reader.type(), [&](auto sample) {
        using W = decltype(sample);
        tbb::enumerable_thread_specific<LayerSparsifier<W>> sparsifiers(dims, rule, isovalue, reader.sliceOffset(0));
        tbb::enumerable_thread_specific<SlabBuffer<char>> bytes;
        tbb::enumerable_thread_specific<std::pair<Range, std::size_t>> totals;
        tbb::parallel_for(0, threads, [&](int t) {
            auto& [range, kept] = totals.local();
            for (LayerRuns::Run* run = runs.own(t); run; run = runs.split())
                makeLayers(sparsifiers.local(), run->first, [run](int bk) { return LayerRuns::more(*run, bk); },
                    /*threaded=*/false,
                    [&](int z0, int z1, W* out) { readAs(reader, z0, z1, out, bytes.local()); },
                    [&](int bk, auto& leaves, const auto& tiles) {
                        const std::lock_guard<std::mutex> lock(treeMutex);
                        insert(bk, leaves, tiles);
                    },
                    [&] { throwIfInterrupted(interrupter, int(100.0 * layersDone++ / std::max(layer1 - layer0, 1))); },
                    range, kept);
        });
        for (const auto& [range, kept] : totals) result.range.add(range), result.kept += kept;
    });
    if (result.range.min <= result.range.max) {
        result.tree->root().setBackground(float(result.range.min), /*updateChildNodes=*/false);
    }
    return result;
}

} // namespace sources_internal

std::array<std::uint64_t, 256> activeValueHistogram(const openvdb::FloatGrid& grid, double lo, double hi,
    const std::function<bool(const openvdb::Coord&)>& leaves, bool tiles)
{
    std::array<std::uint64_t, 256> histogram{};
    for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
        if (leaves && !leaves(leaf->origin())) continue;
        for (auto it = leaf->cbeginValueOn(); it; ++it)
            if (std::isfinite(*it)) ++histogram[sources_internal::histogramBin(*it, lo, hi)];
    }
    if (!tiles) return histogram;
    auto tile = grid.tree().cbeginValueOn();
    tile.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tile; ++tile)
        if (std::isfinite(*tile)) histogram[sources_internal::histogramBin(*tile, lo, hi)] += tile.getVoxelCount();
    return histogram;
}

double otsuOfActiveValues(const openvdb::FloatGrid& grid, double lo, double hi,
    const std::array<std::uint64_t, 256>& histogram)
{
    if (!(lo < hi)) {
        // One active value: the surface is where it meets the background, halfway between them.
        const float background = grid.background();
        if (std::isfinite(background) && background != lo) return 0.5 * (lo + double(background));
        throw InputError("constant grid '" + grid.getName() + "' (every value is " + sources_internal::fmt(lo) +
                         "): no surface and no default isovalue; nothing to mesh");
    }
    return otsuThreshold(histogram, lo, hi);
}


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
