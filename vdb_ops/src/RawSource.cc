// isouq: raw scans, `name_XxYxZ_dtype.raw` (SPEC §8; docs/inputs.md).
#include "SourcesInternal.h"
#include "isouq/Threads.h"

#include "isouq/Bricks.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <regex>
#include <unordered_map>

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

RawSlabReader::RawSlabReader(const std::string& path, const Coord& dims, SampleType type, std::uint64_t offset)
    : mPath(path), mDims(dims), mType(type), mOffset(offset), mFd(::open(path.c_str(), O_RDONLY | O_CLOEXEC))
{
    if (mFd < 0) throw InputError("cannot open '" + path + "': " + std::strerror(errno));
}

RawSlabReader::~RawSlabReader() { ::close(mFd); }

std::uint64_t RawSlabReader::sliceOffset(int z) const
{
    return mOffset + std::uint64_t(mDims.x()) * std::uint64_t(mDims.y()) * sampleBytes(mType) * std::uint64_t(z);
}

void RawSlabReader::readSlices(int z0, int z1, char* out) const
{
    std::size_t left = std::size_t(sliceOffset(z1) - sliceOffset(z0));
    off_t at = off_t(sliceOffset(z0));
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

namespace {

/// What the request and the file name say about a raw scan, checked against the file's size.
struct RawScan {
    std::string path, file, name; ///< name: the grid's
    Coord dims;
    const RawTypeInfo* type = nullptr;
    openvdb::Vec3d spacing;
};

RawScan rawScan(const VolumeRequest& request)
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
    return {path, file, named ? m[1].str() : fs::path(path).stem().string(), Coord(int(d[0]), int(d[1]), int(d[2])),
        &type, spacing};
}

/// The grid's name and transform and the description of a raw scan's volume.
void finishRaw(LoadedVolume& volume, const RawScan& scan)
{
    const openvdb::Vec3d& spacing = scan.spacing;
    volume.grid->setName(scan.name);
    auto transform = openvdb::math::Transform::createLinearTransform(1.0);
    transform->preScale(spacing);
    volume.grid->setTransform(transform);
    volume.description = scan.file + ": " + scan.type->name + " " + volume.description + ", spacing "
        + fmt(spacing[0]) + "," + fmt(spacing[1]) + "," + fmt(spacing[2]);
}

} // namespace

/// The isovalue of a raw scan and where it comes from: given, or Otsu's of the statistics
/// @a stats(histogramRange) gives (of the whole scan).
template <typename Stats>
std::pair<float, std::string> rawIsovalue(const VolumeRequest& request, SampleType type, Stats&& stats)
{
    float isovalue = request.isovalue.value_or(0.0f);
    std::string source = "given";
    if (!request.isovalue) {
        RawStats whole = stats(nullptr);
        if (type == SampleType::Float32 || type == SampleType::Float64) {
            const Range range = whole.range;
            whole.counts = stats(&range).counts;
        }
        isovalue = float(otsuOfRawStats(whole, type));
        source = "Otsu (starting value)";
    }
    if (!std::isfinite(isovalue)) throw InputError("isovalue " + fmt(isovalue) + " is not finite");
    return {isovalue, source};
}

LoadedVolume loadRawArray(const RawSlabReader& reader, const VolumeRequest& request,
    openvdb::util::NullInterrupter* interrupter)
{
    const int nz = reader.dims().z();
    checkLayersFit(reader, threadsInUse(), request.input);
    const auto [isovalue, source] = rawIsovalue(request, reader.type(),
        [&](const Range* range) { return rawStats(reader, 0, nz, range, interrupter); });
    LoadedVolume volume = denseVolume(
        sparsifyRaw(reader, 0, (nz + kBlock - 1) / kBlock, request.keep, isovalue, interrupter), reader.dims(), isovalue);
    volume.isovalueSource = source;
    return volume;
}

LoadedVolume loadRaw(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    const RawScan scan = rawScan(request);
    const RawSlabReader reader(scan.path, scan.dims, scan.type->type);
    LoadedVolume volume = loadRawArray(reader, request, interrupter);
    finishRaw(volume, scan);
    return volume;
}

// ---- By pieces (SPEC §10 "MPI"; docs/mpi.md) -----------------------------------------------

namespace {

using Words = PieceComm::Words;

/// Moves into @a into the blocks this piece asked for: requests[r] from piece r (x, y, z of each
/// block), its own from @a from; @a asked[r] is what piece r asked this one for, answered from
/// @a from, whose leaves go as soon as no piece needs them. Collective over @a comm.
void gatherBlocks(openvdb::FloatTree& from, openvdb::FloatTree& into, const std::vector<Words>& requests,
    const std::vector<Words>& asked, const PieceComm& comm)
{
    using LeafT = openvdb::FloatTree::LeafNodeType;
    constexpr std::size_t kMaskWords = LeafT::NodeMaskType::WORD_COUNT;
    const int pieces = comm.size(), piece = comm.rank();
    // This piece's own requests take the leaves out of its tree, uncopied. Stolen from the root:
    // the tree's stealNode also clears its accessors' caches (none), 0.6 us a call, about 60 ms
    // for the 1 GiB scan's 90 000 leaves at -np 1.
    openvdb::tree::ValueAccessor<openvdb::FloatTree> acc(into);
    const auto steal = [&from](const Coord& o) { return from.root().stealNode<LeafT>(o, 0.0f, false); };
    const Words& own = requests[std::size_t(piece)];
    for (std::size_t i = 0; i < own.size(); i += 3) {
        const Coord o{int(own[i]), int(own[i + 1]), int(own[i + 2])};
        if (LeafT* leaf = steal(o)) acc.addLeaf(leaf);
        else acc.addTile(/*level=*/1, o, from.getValue(o), /*active=*/false);
    }
    // How many other pieces ask for each leaf left in the tree: it is freed when the last has it.
    std::unordered_map<Coord, int> askedFor;
    for (int r = 0; r < pieces; ++r)
        for (std::size_t i = 0; r != piece && i < asked[std::size_t(r)].size(); i += 3) {
            const Words& a = asked[std::size_t(r)];
            const Coord o{int(a[i]), int(a[i + 1]), int(a[i + 2])};
            if (from.probeConstLeaf(o)) ++askedFor[o];
        }
    // The other pieces' blocks go in kRounds exchanges, each a kRounds-th of every list (a leaf:
    // 1, its mask, its 512 values; a tile: 0, its value), so that what is in flight at once is a
    // small part of what moves (issue 15: a rank's memory). Both ends split a list of n blocks
    // at n i / kRounds, the sender's from what it was asked, the receiver's from its request.
    constexpr std::size_t kRounds = 16;
    const auto cut = [](std::size_t n, std::size_t i) { return n / 3 * i / kRounds * 3; };
    // The first round's buffers serve every round after it (fresh pages cost, Bricks.h): the
    // answers reserved at their largest (every block a leaf), so they never grow by doubling.
    std::vector<Words> answers(static_cast<std::size_t>(pieces)), answered;
    for (std::size_t round = 0; round < kRounds; ++round) {
        for (int r = 0; r < pieces; ++r) {
            if (r == piece) continue;
            const Words& a = asked[std::size_t(r)];
            Words& answer = answers[std::size_t(r)];
            const std::size_t first = cut(a.size(), round), last = cut(a.size(), round + 1);
            answer.clear();
            answer.reserve((last - first) / 3 * (1 + kMaskWords + LeafT::SIZE / 2));
            for (std::size_t i = first; i < last; i += 3) {
                const Coord o{int(a[i]), int(a[i + 1]), int(a[i + 2])};
                const LeafT* leaf = from.probeConstLeaf(o);
                if (!leaf) leaf = acc.probeConstLeaf(o); // one this piece also wants
                if (leaf) {
                    answer.push_back(1);
                    for (std::size_t w = 0; w < kMaskWords; ++w) answer.push_back(leaf->getValueMask().getWord<std::uint64_t>(openvdb::Index(w)));
                    const std::size_t at = answer.size();
                    answer.resize(at + LeafT::SIZE / 2);
                    std::memcpy(answer.data() + at, leaf->buffer().data(), LeafT::SIZE * sizeof(float));
                    if (const auto left = askedFor.find(o); left != askedFor.end() && --left->second == 0) {
                        delete steal(o);
                        askedFor.erase(left);
                    }
                } else {
                    answer.insert(answer.end(), {0, std::uint64_t(bitsOf(double(from.getValue(o))))});
                }
            }
        }
        comm.exchangeInto(answers, answered);
        for (int r = 0; r < pieces; ++r) {
            if (r == piece) continue;
            const Words& req = requests[std::size_t(r)];
            const Words& ans = answered[std::size_t(r)];
            std::size_t at = 0;
            for (std::size_t i = cut(req.size(), round); i < cut(req.size(), round + 1); i += 3) {
                const Coord o{int(req[i]), int(req[i + 1]), int(req[i + 2])};
                if (ans[at] == 1) {
                    auto leaf = std::make_unique<LeafT>(o, 0.0f);
                    for (std::size_t w = 0; w < kMaskWords; ++w)
                        leaf->getValueMask().getWord<std::uint64_t>(openvdb::Index(w)) = ans[at + 1 + w];
                    std::memcpy(leaf->buffer().data(), ans.data() + at + 1 + kMaskWords, LeafT::SIZE * sizeof(float));
                    acc.addLeaf(leaf.release());
                    at += 1 + kMaskWords + LeafT::SIZE / 2;
                } else {
                    acc.addTile(/*level=*/1, o, float(doubleOf(ans[at + 1])), /*active=*/false);
                    at += 2;
                }
            }
        }
    }
}

} // namespace

DensePiece loadRawArrayPiece(const RawSlabReader& reader, const VolumeRequest& request, const PieceComm& comm,
    openvdb::util::NullInterrupter* interrupter)
{
    const Coord dims = reader.dims();
    checkLayersFit(reader, threadsInUse(), request.input);
    const int pieces = comm.size(), piece = comm.rank(), layers = (dims.z() + kBlock - 1) / kBlock;
    const int l0 = firstLayerOf(layers, piece, pieces), l1 = firstLayerOf(layers, piece + 1, pieces);
    const int z0 = std::min(l0 * kBlock, dims.z()), z1 = std::min(l1 * kBlock, dims.z());

    // Otsu's statistics: each piece its slices, joined in piece order.
    const auto [isovalue, source] = rawIsovalue(request, reader.type(), [&](const Range* range) {
        RawStats part;
        comm.agree([&] { part = rawStats(reader, z0, z1, range, interrupter); });
        Words words = {bitsOf(part.range.min), bitsOf(part.range.max)};
        words.insert(words.end(), part.counts.begin(), part.counts.end());
        RawStats whole;
        for (const Words& w : comm.allgather(words)) {
            RawStats q;
            q.range.min = doubleOf(w[0]), q.range.max = doubleOf(w[1]);
            q.counts.assign(w.begin() + 2, w.end());
            whole.add(q);
        }
        return whole;
    });
    SparseResult sparse;
    const auto iso = isovalue; // a structured binding cannot be captured before C++20 (clang)
    comm.agree([&] { sparse = sparsifyRaw(reader, l0, l1, request.keep, iso, interrupter); });
    DensePiece out = spreadLayers(std::move(sparse), dims, isovalue, comm);
    out.volume.isovalueSource = source;
    return out;
}

DensePiece loadRawPiece(const VolumeRequest& request, const PieceComm& comm, openvdb::util::NullInterrupter* interrupter)
{
    const RawScan scan = rawScan(request);
    const RawSlabReader reader(scan.path, scan.dims, scan.type->type);
    DensePiece out = loadRawArrayPiece(reader, request, comm, interrupter);
    finishRaw(out.volume, scan);
    return out;
}

DensePiece spreadLayers(SparseResult&& sparse, const Coord& dims, float isovalue, const PieceComm& comm)
{
    using LeafT = openvdb::FloatTree::LeafNodeType;
    const int pieces = comm.size(), piece = comm.rank(), layers = (dims.z() + kBlock - 1) / kBlock;
    const int z0 = std::min(firstLayerOf(layers, piece, pieces) * kBlock, dims.z());
    const int z1 = std::min(firstLayerOf(layers, piece + 1, pieces) * kBlock, dims.z());
    DensePiece out;
    // The sparsifiers read kHalo slices on either side of the layers (the stencils' reach).
    if (z0 < z1)
        out.voxelsRead = std::uint64_t(dims.x()) * std::uint64_t(dims.y()) *
            std::uint64_t(std::min(z1 + kHalo, dims.z()) - std::max(z0 - kHalo, 0));

    // The whole volume's range and block counts, and the topology of every piece's leaves.
    SparseResult whole;
    for (const Words& w : comm.allgather({bitsOf(sparse.range.min), bitsOf(sparse.range.max), sparse.blocks, sparse.kept})) {
        Range r;
        r.min = doubleOf(w[0]), r.max = doubleOf(w[1]);
        whole.range.add(r);
        whole.blocks += std::size_t(w[2]), whole.kept += std::size_t(w[3]);
    }
    constexpr std::size_t kMaskWords = LeafT::NodeMaskType::WORD_COUNT;
    std::shared_ptr<BrickPlan> plan;
    {
        Words leaves;
        for (auto leaf = sparse.tree->cbeginLeaf(); leaf; ++leaf) {
            const Coord o = leaf->origin();
            leaves.insert(leaves.end(), {std::uint64_t(o.x()), std::uint64_t(o.y()), std::uint64_t(o.z())});
            for (std::size_t w = 0; w < kMaskWords; ++w) leaves.push_back(leaf->getValueMask().getWord<std::uint64_t>(openvdb::Index(w)));
        }
        openvdb::MaskTree topology;
        for (const Words& w : comm.allgather(leaves))
            for (std::size_t i = 0; i < w.size(); i += 3 + kMaskWords) {
                auto* leaf = topology.touchLeaf(Coord(int(w[i]), int(w[i + 1]), int(w[i + 2])));
                for (std::size_t k = 0; k < kMaskWords; ++k) leaf->getValueMask().getWord<std::uint64_t>(openvdb::Index(k)) = w[i + 3 + k];
            }
        plan = std::make_shared<BrickPlan>(topology, pieces);
    }
    out.plan = plan;

    // The blocks this piece's stencils reach: its own and those one block around them, inside
    // the data, marked in a bit per block and requested in Coord order (x, then y, then z) from
    // the piece whose layers hold each.
    const Coord blockCount((dims.x() + kBlock - 1) / kBlock, (dims.y() + kBlock - 1) / kBlock, layers);
    const auto bitOf = [&](int bx, int by, int bz) {
        return (std::size_t(bx) * std::size_t(blockCount.y()) + std::size_t(by)) * std::size_t(blockCount.z()) + std::size_t(bz);
    };
    std::vector<bool> wanted(std::size_t(blockCount.x()) * std::size_t(blockCount.y()) * std::size_t(blockCount.z()));
    for (std::size_t b = plan->begin(piece); b < plan->end(piece); ++b) {
        const Coord& o = plan->origin(b);
        const Coord c(o.x() / kBlock, o.y() / kBlock, o.z() / kBlock);
        for (int dx = std::max(c.x() - 1, 0); dx <= std::min(c.x() + 1, blockCount.x() - 1); ++dx)
            for (int dy = std::max(c.y() - 1, 0); dy <= std::min(c.y() + 1, blockCount.y() - 1); ++dy)
                for (int dz = std::max(c.z() - 1, 0); dz <= std::min(c.z() + 1, blockCount.z() - 1); ++dz)
                    wanted[bitOf(dx, dy, dz)] = true;
    }
    std::vector<int> ownerOfLayer(std::size_t(layers), 0);
    for (int owner = 1; owner < pieces; ++owner)
        for (int l = firstLayerOf(layers, owner, pieces); l < layers; ++l) ownerOfLayer[std::size_t(l)] = owner;
    std::vector<Words> requests(static_cast<std::size_t>(pieces));
    for (int bx = 0; bx < blockCount.x(); ++bx)
        for (int by = 0; by < blockCount.y(); ++by)
            for (int bz = 0; bz < blockCount.z(); ++bz)
                if (wanted[bitOf(bx, by, bz)])
                    requests[std::size_t(ownerOfLayer[std::size_t(bz)])].insert(
                        requests[std::size_t(ownerOfLayer[std::size_t(bz)])].end(),
                        {std::uint64_t(kBlock * bx), std::uint64_t(kBlock * by), std::uint64_t(kBlock * bz)});
    std::vector<bool>().swap(wanted);
    const std::vector<Words> asked = comm.exchange(requests);

    whole.tree = std::make_shared<openvdb::FloatTree>(0.0f);
    gatherBlocks(*sparse.tree, *whole.tree, requests, asked, comm);
    sparse.tree.reset();
    if (whole.range.min <= whole.range.max) whole.tree->root().setBackground(float(whole.range.min), false);
    out.volume = denseVolume(std::move(whole), dims, isovalue);
    return out;
}

} // namespace sources_internal
} // namespace isouq
