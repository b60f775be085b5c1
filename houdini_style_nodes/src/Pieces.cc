// isouq nodes: the nodes' work on ranks (Pieces.h, Ranks.h; SPEC §9, §10 "MPI"; docs/mpi.md).
// A rank's piece is a contiguous run of the mesher's block order (BrickPlan), so its vertices
// and triangles are a contiguous run of the one-process output's: the PLY rows go to offsets
// from prefix sums of the counts, and the summary's sums are carried in rank order.
#include "Pieces.h"

#include "isouq/nodes/Summary.h"

#include <isouq/Columns.h>
#include <isouq/Diagnostics.h>
#include <isouq/Errors.h>
#include <isouq/MeshIO.h>
#include <isouq/MeshTopology.h>
#include <isouq/Threads.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <numeric>

namespace isouq::nodes {

Words wordsOfText(const std::string& text)
{
    Words words(1 + (text.size() + 7) / 8, 0);
    words[0] = text.size();
    if (!text.empty()) std::memcpy(words.data() + 1, text.data(), text.size());
    return words;
}

std::string textOfWords(const Words& words)
{
    if (words.empty()) return std::string();
    return std::string(reinterpret_cast<const char*>(words.data() + 1), std::size_t(words[0]));
}

void Ranks::step(const std::function<void()>& body, const std::string& where) const
{
    int status = 0;
    std::string message;
    try {
        body();
    } catch (const InterruptedError&) {
        status = 1;
    } catch (const std::exception& e) {
        status = interrupted() ? 1 : 2;
        message = where + e.what();
    }
    if (status == 0 && interrupted()) status = 1;
    const std::vector<Words> all = allgather({std::uint64_t(status)});
    int worst = 0, first = -1;
    for (int r = 0; r < size(); ++r) {
        worst = std::max(worst, int(all[std::size_t(r)][0]));
        if (first < 0 && all[std::size_t(r)][0] == 2) first = r;
    }
    if (worst == 0) return;
    if (worst == 1) throw InterruptedError();
    throw InputError(textOfWords(broadcast(rank() == first ? wordsOfText(message) : Words(), first)));
}

Words Ranks::carry(const Words& start, const std::function<Words(const Words&)>& add) const
{
    const Words out = add(rank() == 0 ? start : receive(rank() - 1));
    if (rank() + 1 < size()) send(out, rank() + 1);
    return broadcast(out, size() - 1);
}

namespace nodes_internal {
namespace {

Words packScan(const ActiveValueScan& s)
{
    return {s.nonFinite, s.firstLeaf, std::uint64_t(std::int64_t(s.first.x())), std::uint64_t(std::int64_t(s.first.y())),
        std::uint64_t(std::int64_t(s.first.z())), bitsOf(s.firstValue), bitsOf(s.min), bitsOf(s.max)};
}
ActiveValueScan unpackScan(const Words& w)
{
    ActiveValueScan s;
    s.nonFinite = w[0];
    s.firstLeaf = w[1];
    s.first = openvdb::Coord(int(std::int64_t(w[2])), int(std::int64_t(w[3])), int(std::int64_t(w[4])));
    s.firstValue = floatOf(w[5]);
    s.min = floatOf(w[6]);
    s.max = floatOf(w[7]);
    return s;
}

/// Union-find with the smaller index as root.
struct Sets {
    std::vector<std::uint64_t> parent;
    explicit Sets(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
    std::uint64_t find(std::uint64_t v)
    {
        while (parent[v] != v) v = parent[v] = parent[parent[v]];
        return v;
    }
    bool join(std::uint64_t a, std::uint64_t b)
    {
        a = find(a), b = find(b);
        if (a == b) return false;
        if (a < b) parent[b] = a;
        else parent[a] = b;
        return true;
    }
};

/// Rank @a rank's rows of a mesh by pieces (MeshPiece): one run per section, in section order.
struct Runs : PieceRuns {
    Runs(const std::vector<std::uint64_t>& begin, int rank, int size)
    {
        std::size_t rows = 0;
        for (std::size_t r = std::size_t(rank); r + 1 < begin.size(); r += std::size_t(size)) {
            first.push_back(begin[r]), last.push_back(begin[r + 1]), local.push_back(rows);
            rows += std::size_t(begin[r + 1] - begin[r]);
        }
    }
    /// The run holding row @a g of the whole mesh, or -1.
    int runOf(std::uint64_t g) const
    {
        for (std::size_t r = 0; r < first.size(); ++r)
            if (g - first[r] < last[r] - first[r]) return int(r); // first <= g < last, unsigned
        return -1;
    }
    std::size_t localOf(std::uint64_t g, int run) const { return local[std::size_t(run)] + std::size_t(g - first[std::size_t(run)]); }
};

/// The rank whose rows hold row @a g of the whole mesh (MeshPiece's begin).
int ownerOfRow(const std::vector<std::uint64_t>& begin, std::uint64_t g, int size)
{
    return int(std::upper_bound(begin.begin(), begin.end(), g) - begin.begin() - 1) % size;
}

} // namespace

VolumeOnRanks readVolumeOnRanks(const Ranks& ranks, VolumeRequest request, openvdb::util::NullInterrupter* interrupter)
{
    const bool dense = isDensePieceInput(request.input);
    if (!dense && pathExtension(request.input) != ".vdb") {
        std::error_code ec;
        // A missing input: one process's error line (loadVolume throws it).
        if (request.input.rfind("memory:", 0) != 0 && !std::filesystem::exists(request.input, ec)) loadVolume(request);
        throw InputError("INPUT '" + request.input + "' is not supported under MPI yet (.vdb files, scans, field: "
            "and formula: inputs are read by pieces; docs/mpi.md); run it in one process");
    }
    VolumeOnRanks out;
    auto piece = std::make_shared<VolumePiece>();
    if (dense) { // z-layers per rank, then each rank's blocks and their halo (SPEC §9)
        DensePiece layers = loadDensePiece(request, ranks, interrupter);
        out.volume = std::make_shared<LoadedVolume>(std::move(layers.volume));
        piece->plan = std::move(layers.plan);
        piece->voxelsRead = layers.voxelsRead;
    } else {
        request.delayLoad = true;
        out.volume = std::make_shared<LoadedVolume>(loadVolume(request, interrupter));
        piece->plan = std::make_shared<BrickPlan>(*out.volume->grid, ranks.size());
    }
    out.piece = piece;
    const openvdb::FloatGrid& grid = *out.volume->grid;
    const BrickPlan* plan = piece->plan.get();
    const int rank = ranks.rank();
    const auto mine = [&](const openvdb::Coord& leafOrigin) { return plan->pieceOfBlock(plan->blockOf(leafOrigin)) == rank; };

    // checkScalarVolume's scan of the active values: each rank its own leaves, rank 0 the tiles.
    ActiveValueScan scan;
    ranks.step([&] { scan = scanActiveValues(grid, mine, rank == 0); });
    const std::vector<Words> scans = ranks.allgather(packScan(scan));
    scan = ActiveValueScan();
    for (const Words& w : scans) scan.join(unpackScan(w));
    // The active box of the whole grid: the union of the ranks' (a rank holds its own leaves and
    // their halo, and every leaf is some rank's), empty where a rank holds none (more ranks than
    // blocks with a surface).
    openvdb::CoordBBox box;
    const openvdb::CoordBBox local = grid.evalActiveVoxelBoundingBox();
    const auto word = [](int v) { return std::uint64_t(std::int64_t(v)); };
    for (const Words& w : ranks.allgather({word(local.min().x()), word(local.min().y()), word(local.min().z()),
             word(local.max().x()), word(local.max().y()), word(local.max().z())})) {
        const auto at = [&](int i) { return int(std::int64_t(w[std::size_t(i)])); };
        box.expand(openvdb::CoordBBox(at(0), at(1), at(2), at(3), at(4), at(5)));
    }
    if (std::isnan(out.volume->isovalue)) { // a fog volume without an isovalue: Otsu of the whole
        std::array<std::uint64_t, 256> histogram{};
        ranks.step([&] { histogram = activeValueHistogram(grid, scan.min, scan.max, mine, rank == 0); });
        const Words whole = ranks.sum(Words(histogram.begin(), histogram.end()));
        std::copy(whole.begin(), whole.end(), histogram.begin());
        out.volume->isovalue = float(otsuOfActiveValues(grid, scan.min, scan.max, histogram));
    }
    // An empty grid with allow_empty, as one process reads it (VolumeNodes.cc): an empty mesh.
    out.empty = request.allowEmpty && box.empty();
    if (const std::string problem = out.empty ? "" : checkScalarVolume(grid, out.volume->isovalue, scan, box); !problem.empty())
        throw InputError(problem);
    if (!dense) releaseMappedPages(request.input); // the scans loaded the rank's leaves
    return out;
}

std::shared_ptr<const MeshPiece> meshOnRanks(const Ranks& ranks, const openvdb::FloatGrid& grid,
    const VolumePiece& read, const MeshSettings& settings, Mesh& mesh, openvdb::util::NullInterrupter* interrupter)
{
    const int rank = ranks.rank(), size = ranks.size();
    const std::shared_ptr<const BrickPlan>& plan = read.plan;
    BrickMesher mesher(grid, settings, *plan, rank);
    ranks.step([&] { mesher.count(interrupter); });
    const std::vector<Words> counts = ranks.allgather({mesher.vertexCount(), mesher.triangleCount()});
    auto piece = std::make_shared<MeshPiece>();
    piece->plan = plan;
    piece->vertexBegin.assign(std::size_t(size) + 1, 0);
    piece->triangleBegin.assign(std::size_t(size) + 1, 0);
    for (int r = 0; r < size; ++r) {
        piece->vertexBegin[std::size_t(r) + 1] = piece->vertexBegin[std::size_t(r)] + counts[std::size_t(r)][0];
        piece->triangleBegin[std::size_t(r) + 1] = piece->triangleBegin[std::size_t(r)] + counts[std::size_t(r)][1];
    }
    ranks.step([&] {
        mesher.setOffsets(piece->vertexBegin[std::size_t(rank)], piece->triangleBegin[std::size_t(rank)],
            piece->vertexBegin.back());
    });
    // The masks and first vertices of the + neighbours that later ranks own.
    std::vector<Words> requests(static_cast<std::size_t>(size));
    for (std::int64_t b : mesher.foreignBlocks()) requests[std::size_t(plan->pieceOfBlock(b))].push_back(std::uint64_t(b));
    const std::vector<Words> asked = ranks.exchange(requests);
    std::vector<Words> answers(static_cast<std::size_t>(size));
    ranks.step([&] {
        for (int r = 0; r < size; ++r)
            for (std::uint64_t b : asked[std::size_t(r)]) {
                Words& out = answers[std::size_t(r)];
                out.resize(out.size() + BrickMesher::kBlockWords);
                mesher.describeBlock(std::int64_t(b), out.data() + out.size() - BrickMesher::kBlockWords);
            }
    });
    const std::vector<Words> answered = ranks.exchange(answers);
    ranks.step([&] {
        for (int r = 0; r < size; ++r)
            for (std::size_t i = 0; i < requests[std::size_t(r)].size(); ++i)
                mesher.learnBlock(std::int64_t(requests[std::size_t(r)][i]),
                    answered[std::size_t(r)].data() + i * BrickMesher::kBlockWords);
        mesher.fill(mesh, interrupter);
    });
    piece->voxelsRead = read.voxelsRead ? *read.voxelsRead : loadedLeafVoxels(grid);
    return piece;
}

namespace {

/// A rank's piece in its own vertex numbering, without a copy of its triangles or positions
/// (issue 15: a rank's memory): its rows 0..nLocal-1, then the vertices of other ranks that its
/// triangles use (ghosts), whose positions it fetches.
struct LocalPiece {
    Runs runs;
    std::size_t nLocal = 0;
    std::vector<std::uint32_t> ghosts; ///< ascending, rows of the whole mesh
    std::vector<openvdb::Vec3s> ghostPositions;
    std::vector<std::uint32_t> askedRows; ///< its rows that other ranks' triangles use (local)
    /// The first run (local rows from 0), as two numbers: most corners fall in it, and the
    /// measure passes map every corner of every triangle (about 20 M at N = 1024).
    std::uint64_t firstRow = 0, firstRows = 0;

    std::size_t vertexCount() const { return nLocal + ghosts.size(); }
    bool sharesVertices() const { return !ghosts.empty() || !askedRows.empty(); }
    std::uint32_t localOf(std::uint32_t g) const
    {
        if (std::uint64_t(g) - firstRow < firstRows) return std::uint32_t(g - firstRow);
        if (const int run = runs.runOf(g); run >= 0) return std::uint32_t(runs.localOf(g, run));
        return std::uint32_t(nLocal + std::size_t(std::lower_bound(ghosts.begin(), ghosts.end(), g) - ghosts.begin()));
    }
    /// The piece's triangles (rows of the whole mesh) in local indices, for measureTopology.
    TriangleChunks triangles(const Mesh& piece) const
    {
        return {vertexCount(), piece.triangles.size(), [this, &piece](std::size_t first, std::size_t count, openvdb::Vec3I* out) {
            for (std::size_t f = 0; f < count; ++f)
                for (int c = 0; c < 3; ++c) out[f][c] = localOf(std::uint32_t(piece.triangles[first + f][c]));
        }};
    }
    const openvdb::Vec3s& position(const Mesh& piece, std::uint32_t g) const
    {
        const std::uint32_t l = localOf(g);
        return l < nLocal ? piece.positions[l] : ghostPositions[l - nLocal];
    }
};

LocalPiece localPiece(const Ranks& ranks, const Mesh& piece, const MeshPiece& where)
{
    const int size = ranks.size();
    LocalPiece out{Runs(where.vertexBegin, ranks.rank(), size), piece.vertexCount(), {}, {}, {}};
    const Runs& runs = out.runs;
    if (!runs.first.empty()) out.firstRow = runs.first[0], out.firstRows = runs.last[0] - runs.first[0];
    std::vector<std::uint32_t>& ghosts = out.ghosts;
    tbb::enumerable_thread_specific<std::vector<std::uint32_t>> found; // sorted below: any order
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, piece.triangles.size()), [&](const auto& range) {
        std::vector<std::uint32_t>& mine = found.local();
        for (std::size_t f = range.begin(); f < range.end(); ++f)
            for (int c = 0; c < 3; ++c)
                if (runs.runOf(std::uint32_t(piece.triangles[f][c])) < 0) mine.push_back(piece.triangles[f][c]);
    });
    for (const std::vector<std::uint32_t>& mine : found) ghosts.insert(ghosts.end(), mine.begin(), mine.end());
    std::sort(ghosts.begin(), ghosts.end());
    ghosts.erase(std::unique(ghosts.begin(), ghosts.end()), ghosts.end());
    std::vector<Words> wanted(static_cast<std::size_t>(size));
    for (std::uint32_t g : ghosts) wanted[std::size_t(ownerOfRow(where.vertexBegin, g, size))].push_back(g);
    const std::vector<Words> wantedHere = ranks.exchange(wanted);
    std::vector<Words> positions(static_cast<std::size_t>(size));
    for (int r = 0; r < size; ++r)
        for (std::uint64_t g : wantedHere[std::size_t(r)]) {
            const std::size_t l = runs.localOf(g, runs.runOf(g));
            out.askedRows.push_back(std::uint32_t(l));
            std::uint64_t words[2] = {0, 0};
            std::memcpy(words, piece.positions[l].asPointer(), 12);
            positions[std::size_t(r)].insert(positions[std::size_t(r)].end(), words, words + 2);
        }
    const std::vector<Words> got = ranks.exchange(positions);
    out.ghostPositions.resize(ghosts.size());
    for (int r = 0; r < size; ++r)
        for (std::size_t i = 0; i < wanted[std::size_t(r)].size(); ++i) {
            const auto at = std::lower_bound(ghosts.begin(), ghosts.end(), std::uint32_t(wanted[std::size_t(r)][i]));
            std::memcpy(out.ghostPositions[std::size_t(at - ghosts.begin())].asPointer(), got[std::size_t(r)].data() + 2 * i, 12);
        }
    return out;
}

/// Sums over rows [first, last) of the whole mesh's n rows (this rank's), in the chunks of
/// kSumRows rows of the one-process order (MeshTopology.h): add(state, from, to) folds rows
/// [from, to) into state, in order. The chunks inside the rank are summed on its threads; only
/// the chunk its first row falls in continues the state carried from the rank before. Returns,
/// on rank 0, every chunk's sums in chunk order (elsewhere nothing).
std::vector<Words> chunkSumsOnRanks(const Ranks& ranks, std::uint64_t first, std::uint64_t last, std::uint64_t n,
    const Words& zero, const std::function<void(Words&, std::uint64_t, std::uint64_t)>& add)
{
    const std::uint64_t k = kSumRows;
    const auto ends = [&](std::uint64_t row) { return row % k == 0 || row == n; }; // a chunk ends before row
    const bool carried = first < last && first % k != 0;
    const std::uint64_t headEnd = carried ? std::min(last, (first / k + 1) * k) : first;
    // The chunks (or their starts) from headEnd on need nothing from other ranks.
    std::vector<std::uint64_t> cuts{headEnd};
    while (cuts.back() < last) cuts.push_back(std::min(last, (cuts.back() / k + 1) * k));
    std::vector<Words> own(cuts.size() - 1, zero);
    ranks.step([&] {
        tbb::parallel_for(std::size_t(0), own.size(), [&](std::size_t i) { add(own[i], cuts[i], cuts[i + 1]); });
    });
    Words done; // (chunk, sums...) of the chunks that end in this rank, in order
    const auto finish = [&](std::uint64_t chunk, const Words& sums) {
        done.push_back(chunk);
        done.insert(done.end(), sums.begin(), sums.end());
    };
    const bool tailOpen = !own.empty() && !ends(last);
    ranks.carry(zero, [&](const Words& in) {
        if (first == last) return in; // no rows here: the open chunk goes on
        if (carried) {
            Words head = in;
            add(head, first, headEnd);
            if (!ends(headEnd)) return head; // the rank's rows lie inside one chunk
            finish(first / k, head);
        }
        for (std::size_t i = 0; i + (tailOpen ? 1 : 0) < own.size(); ++i) finish(cuts[i] / k, own[i]);
        return tailOpen ? own.back() : zero;
    });
    std::vector<Words> chunks;
    for (const Words& w : ranks.gather(done))
        for (std::size_t i = 0; i < w.size(); i += 1 + zero.size()) chunks.emplace_back(w.begin() + std::ptrdiff_t(i) + 1, w.begin() + std::ptrdiff_t(i + 1 + zero.size()));
    return chunks;
}

/// measureTopology's edges and components of the whole mesh, on rank 0 (zeros elsewhere): each
/// rank counts its own, and rank 0 joins them over the shared vertices, those that triangles of
/// two ranks may use: a rank's ghosts, and its rows that another rank asked for as a ghost (an
/// edge of two ranks' triangles has both ends shared on both).
MeshTopologyStats topologyOnRanks(const Ranks& ranks, const Mesh& piece, const LocalPiece& local)
{
    const int rank = ranks.rank(), size = ranks.size();
    std::vector<std::uint8_t> shared(local.nLocal, 0);
    shared.resize(local.vertexCount(), 1); // the ghosts
    for (std::uint32_t l : local.askedRows) shared[l] = 1;
    MeshTopologyStats topo;
    std::vector<std::uint32_t> labels;
    ranks.step([&] { topo = measureTopology(local.triangles(piece), &labels); });
    // Edges with both ends shared: counted on rank 0 over all ranks instead of here. Both lists
    // are found in parallel and sorted later (here, or on rank 0), so their order is free.
    using Edge = std::pair<std::uint64_t, std::uint64_t>;
    tbb::enumerable_thread_specific<std::pair<std::vector<Edge>, Words>> found;
    const std::size_t scanned = local.sharesVertices() ? piece.triangles.size() : 0; // one rank: none shared
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, scanned), [&](const auto& range) {
        auto& [edges, pairs] = found.local();
        for (std::size_t f = range.begin(); f < range.end(); ++f) {
            const openvdb::Vec3I& t = piece.triangles[f]; // rows of the whole mesh
            bool isShared[3];
            for (int c = 0; c < 3; ++c) isShared[c] = shared[local.localOf(std::uint32_t(t[c]))];
            for (int c = 0; c < 3; ++c) {
                const std::uint64_t a = t[c], b = t[(c + 1) % 3];
                if (isShared[c]) pairs.insert(pairs.end(), {a, labels[f]});
                if (a != b && isShared[c] && isShared[(c + 1) % 3]) edges.emplace_back(std::min(a, b), std::max(a, b));
            }
        }
    });
    std::vector<Edge> sharedEdges;
    Words componentPairs; // (global vertex, local component) of the shared vertices used
    for (const auto& [edges, pairs] : found) {
        sharedEdges.insert(sharedEdges.end(), edges.begin(), edges.end());
        componentPairs.insert(componentPairs.end(), pairs.begin(), pairs.end());
    }
    std::sort(sharedEdges.begin(), sharedEdges.end());
    Words edgeUses; // (lo, hi, uses)
    std::size_t localBoundary = 0, localNonManifold = 0;
    for (std::size_t i = 0; i < sharedEdges.size();) {
        std::size_t j = i + 1;
        while (j < sharedEdges.size() && sharedEdges[j] == sharedEdges[i]) ++j;
        edgeUses.insert(edgeUses.end(), {sharedEdges[i].first, sharedEdges[i].second, std::uint64_t(j - i)});
        localBoundary += j - i == 1;
        localNonManifold += j - i > 2;
        i = j;
    }
    const std::vector<Words> allTallies =
        ranks.gather({topo.boundaryEdges - localBoundary, topo.nonManifoldEdges - localNonManifold, topo.components});
    const std::vector<Words> allEdges = ranks.gather(edgeUses);
    const std::vector<Words> allPairs = ranks.gather(componentPairs);
    MeshTopologyStats whole;
    if (rank != 0) return whole;

    // Edges and components across the pieces' borders.
    std::vector<std::uint64_t> componentBase(std::size_t(size) + 1, 0);
    for (int r = 0; r < size; ++r) {
        whole.boundaryEdges += allTallies[std::size_t(r)][0];
        whole.nonManifoldEdges += allTallies[std::size_t(r)][1];
        componentBase[std::size_t(r) + 1] = componentBase[std::size_t(r)] + allTallies[std::size_t(r)][2];
    }
    std::vector<std::array<std::uint64_t, 3>> edges;
    for (const Words& w : allEdges)
        for (std::size_t i = 0; i < w.size(); i += 3) edges.push_back({w[i], w[i + 1], w[i + 2]});
    std::sort(edges.begin(), edges.end());
    for (std::size_t i = 0; i < edges.size();) {
        std::uint64_t uses = 0;
        std::size_t j = i;
        for (; j < edges.size() && edges[j][0] == edges[i][0] && edges[j][1] == edges[i][1]; ++j) uses += edges[j][2];
        whole.boundaryEdges += uses == 1;
        whole.nonManifoldEdges += uses > 2;
        i = j;
    }
    std::vector<std::pair<std::uint64_t, std::uint64_t>> pairs; // (global vertex, component node)
    for (int r = 0; r < size; ++r)
        for (std::size_t i = 0; i < allPairs[std::size_t(r)].size(); i += 2)
            pairs.emplace_back(allPairs[std::size_t(r)][i], componentBase[std::size_t(r)] + allPairs[std::size_t(r)][i + 1]);
    std::sort(pairs.begin(), pairs.end());
    Sets sets(componentBase.back());
    whole.components = componentBase.back();
    for (std::size_t i = 1; i < pairs.size(); ++i)
        if (pairs[i].first == pairs[i - 1].first && sets.join(pairs[i].second, pairs[i - 1].second)) --whole.components;
    return whole;
}

} // namespace

MeshTopologyStats topologyOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where)
{
    return topologyOnRanks(ranks, piece, localPiece(ranks, piece, where));
}

nlohmann::json summarizeOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where)
{
    const std::uint64_t totalVertices = where.vertexBegin.back();
    const LocalPiece local = localPiece(ranks, piece, where);
    const std::size_t nLocal = local.nLocal;

    // Area, volume and statistics in the one-process order, about the centre of the whole mesh's
    // bounding box (as measureTopology). One section of rows (a mesh node's piece): the ranks'
    // rows follow each other in the whole mesh's order.
    if (where.triangleBegin.size() != std::size_t(ranks.size()) + 1)
        throw std::invalid_argument("input 'mesh' is not a mesh node's piece (its sums would not be in the one-process order)");
    Words box(6);
    for (int c = 0; c < 3; ++c) {
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        for (std::size_t v = 0; v < nLocal; ++v) {
            lo = std::min(lo, double(piece.positions[v][c]));
            hi = std::max(hi, double(piece.positions[v][c]));
        }
        box[std::size_t(c)] = bitsOf(lo), box[std::size_t(c) + 3] = bitsOf(hi);
    }
    std::array<double, 3> lo, hi, centre;
    lo.fill(std::numeric_limits<double>::infinity());
    hi.fill(-std::numeric_limits<double>::infinity());
    for (const Words& w : ranks.allgather(box))
        for (std::size_t c = 0; c < 3; ++c) lo[c] = std::min(lo[c], doubleOf(w[c])), hi[c] = std::max(hi[c], doubleOf(w[c + 3]));
    for (std::size_t c = 0; c < 3; ++c) centre[c] = 0.5 * (lo[c] + hi[c]);
    std::vector<const std::vector<float>*> columns;
    std::vector<std::string> names;
    for (const ColumnInfo& c : columnTable())
        if (const auto* column = c.summary ? piece.vertexAttributes.find<float>(c.name) : nullptr) {
            columns.push_back(column);
            names.emplace_back(c.name);
        }
    // Area and volume by chunks of triangle rows, the statistics by chunks of vertex rows, each
    // chunk's sums bit-equal to one process's, joined in chunk order on rank 0.
    const int rank = ranks.rank();
    const std::uint64_t v0 = where.vertexBegin[std::size_t(rank)], t0 = where.triangleBegin[std::size_t(rank)];
    const std::vector<Words> geometryChunks = chunkSumsOnRanks(ranks, t0, where.triangleBegin[std::size_t(rank) + 1],
        where.triangleBegin.back(), Words(3, 0), [&](Words& w, std::uint64_t from, std::uint64_t to) {
            GeometrySums g{doubleOf(w[0]), doubleOf(w[1]), std::size_t(w[2])};
            addTriangleGeometry([&](std::uint32_t v) -> const openvdb::Vec3s& { return local.position(piece, v); },
                piece.triangles.data() + (from - t0), piece.triangles.data() + (to - t0), centre, g);
            w = {bitsOf(g.area), bitsOf(g.signedVolume), g.degenerate};
        });
    Words empty; // an empty StatisticsSums per column
    for (std::size_t c = 0; c < columns.size(); ++c) {
        const StatisticsSums none;
        empty.insert(empty.end(), {bitsOf(none.lo), bitsOf(none.hi), 0, 0, 0});
    }
    const auto sumsOf = [](const std::uint64_t* w) {
        StatisticsSums s;
        s.lo = doubleOf(w[0]), s.hi = doubleOf(w[1]), s.sum = doubleOf(w[2]), s.sumSq = doubleOf(w[3]);
        s.count = std::size_t(w[4]);
        return s;
    };
    const std::vector<Words> columnChunks = chunkSumsOnRanks(ranks, v0, where.vertexBegin[std::size_t(rank) + 1],
        totalVertices, empty, [&](Words& w, std::uint64_t from, std::uint64_t to) {
            for (std::size_t c = 0; c < columns.size(); ++c) {
                StatisticsSums s = sumsOf(w.data() + 5 * c);
                s.add(columns[c]->data() + (from - v0), std::size_t(to - from));
                std::copy_n(Words{bitsOf(s.lo), bitsOf(s.hi), bitsOf(s.sum), bitsOf(s.sumSq), s.count}.begin(), 5,
                    w.begin() + std::ptrdiff_t(5 * c));
            }
        });
    GeometrySums geometry;
    for (const Words& w : geometryChunks) geometry.join({doubleOf(w[0]), doubleOf(w[1]), std::size_t(w[2])});
    std::vector<StatisticsSums> stats(columns.size());
    for (const Words& w : columnChunks)
        for (std::size_t c = 0; c < columns.size(); ++c) stats[c].join(sumsOf(w.data() + 5 * c));

    MeshTopologyStats topo = topologyOnRanks(ranks, piece, local);
    if (ranks.rank() != 0) return nlohmann::json::object();
    topo.degenerateTriangles = geometry.degenerate;
    topo.area = geometry.area;
    topo.enclosedVolume = std::abs(geometry.signedVolume);
    nlohmann::json s = summaryCounts(totalVertices, where.triangleBegin.back(), topo);
    for (std::size_t c = 0; c < columns.size(); ++c) s[names[c]] = stats[c].result();
    return s;
}

ValuesOnRanks orderStatisticsOnRanks(const Ranks& ranks, const std::vector<float>& values,
    const std::vector<std::uint64_t>& ks)
{
    // Ordered bits: a float's order is its key's as an unsigned integer.
    const auto keyOf = [](float v) {
        std::uint32_t u = 0;
        v = v == 0.0f ? 0.0f : v;
        std::memcpy(&u, &v, sizeof u);
        return u & 0x80000000u ? ~u : u | 0x80000000u;
    };
    ValuesOnRanks out;
    const auto finite = std::count_if(values.begin(), values.end(), [](float v) { return std::isfinite(v); });
    const Words counts = ranks.sum({values.size(), std::uint64_t(finite)});
    out.count = counts[0], out.finite = counts[1];
    if (ks.empty()) return out; // the counts alone
    const std::size_t n = ks.size();
    std::vector<std::uint32_t> prefix(n, 0); // the key's bytes found so far
    std::vector<std::uint64_t> left = ks;     // the position sought among the keys with that prefix
    for (int shift = 24; shift >= 0; shift -= 8) {
        const std::uint32_t high = shift == 24 ? 0 : ~std::uint32_t(0) << (shift + 8);
        Words histogram(256 * n, 0);
        for (float v : values)
            if (std::isfinite(v)) {
                const std::uint32_t key = keyOf(v);
                for (std::size_t i = 0; i < n; ++i)
                    if ((key & high) == prefix[i]) ++histogram[256 * i + ((key >> shift) & 255u)];
            }
        const Words total = ranks.sum(histogram);
        for (std::size_t i = 0; i < n; ++i) {
            std::uint32_t byte = 0;
            while (left[i] >= total[256 * i + byte]) left[i] -= total[256 * i + byte++];
            prefix[i] |= byte << shift;
        }
    }
    for (std::size_t i = 0; i < n; ++i) {
        const std::uint32_t u = prefix[i] & 0x80000000u ? prefix[i] & 0x7fffffffu : ~prefix[i];
        float v = 0.0f;
        std::memcpy(&v, &u, sizeof v);
        out.kth.push_back(v);
    }
    return out;
}

void addRanksBlock(const Ranks& ranks, const MeshData& mesh, const nlohmann::json& timings, nlohmann::json& summary)
{
    const MeshPiece& piece = *mesh.piece;
    const int rank = ranks.rank();
    Words mine = {piece.voxelsRead, mesh.mesh.vertexCount(), mesh.mesh.triangleCount(),
        piece.plan->end(rank) - piece.plan->begin(rank), piece.plan->weight(rank), std::uint64_t(threadsInUse())};
    const Words text = wordsOfText(timings.dump());
    mine.insert(mine.end(), text.begin(), text.end());
    const std::vector<Words> all = ranks.gather(mine);
    if (rank != 0) return;
    nlohmann::json list = nlohmann::json::array(), slowest = nlohmann::json::object();
    for (int r = 0; r < ranks.size(); ++r) {
        const Words& w = all[std::size_t(r)];
        const nlohmann::json times = nlohmann::json::parse(textOfWords(Words(w.begin() + 6, w.end())));
        list.push_back({{"rank", r}, {"voxels_read", w[0]}, {"vertices", w[1]}, {"triangles", w[2]}, {"blocks", w[3]},
            {"weight", w[4]}, {"threads", w[5]}, {"timings_ms", times}});
        for (const auto& [key, value] : times.items())
            slowest[key] = std::max(slowest.value(key, 0.0), value.get<double>());
    }
    summary["ranks"] = list;
    summary["timings_ms"] = slowest;
}

namespace {

/// Rows a rank formats at a time for an ascii PLY.
constexpr std::size_t kAsciiRows = std::size_t(1) << 15;

/// A file every rank writes into: rank 0 creates it under its temporary name and makes its
/// head (@a head); every rank opens it, sized by @a bytes of the head's size, and @a rows writes
/// its part (rank 0 the head too) in one step; rank 0's @a batch commits it.
void stageSharedFile(const Ranks& ranks, const std::string& path, const std::function<std::string(SharedMeshFile&)>& head,
    const std::function<std::uint64_t(std::uint64_t)>& bytes,
    const std::function<void(SharedFile&, std::uint64_t)>& rows, OutputBatch& batch)
{
    const int rank = ranks.rank();
    std::unique_ptr<SharedMeshFile> file;
    std::string text;
    ranks.step([&] {
        if (rank != 0) return;
        file = std::make_unique<SharedMeshFile>(path);
        text = head(*file);
    });
    const std::string temp = textOfWords(ranks.broadcast(rank == 0 ? wordsOfText(file->temporaryPath()) : Words(), 0));
    const std::uint64_t headBytes = ranks.broadcast({text.size()}, 0)[0];
    {
        std::string why;
        const std::unique_ptr<SharedFile> shared = ranks.openShared(temp, bytes(headBytes), why);
        ranks.step([&] {
            if (!shared) throw IoError("cannot write " + path + ": " + why);
            if (rank == 0) shared->writeAt(0, text.data(), text.size(), path);
            rows(*shared, headBytes);
        });
    }
    if (file) batch.addShared(std::move(file));
}

/// An ascii PLY by every rank (stagePlyOnRanks). A line's length depends on its values: each
/// rank formats its runs' lines twice, first to count their bytes (every rank's runs in file
/// order give the offsets), then to write them there.
void stageAsciiPly(const Ranks& ranks, const Mesh& piece, const MeshPiece& where, const std::string& path,
    const PlyOptions& options, OutputBatch& batch)
{
    const std::uint64_t vertices = where.vertexBegin.back(), triangles = where.triangleBegin.back();
    const Runs vertexRuns(where.vertexBegin, ranks.rank(), ranks.size()),
        faceRuns(where.triangleBegin, ranks.rank(), ranks.size());
    const std::size_t runs = vertexRuns.first.size() + faceRuns.first.size();
    const auto eachChunk = [&](std::size_t k, const std::function<void(const std::string&)>& sink) {
        const bool faces = k >= vertexRuns.first.size();
        const Runs& r = faces ? faceRuns : vertexRuns;
        const std::size_t j = faces ? k - vertexRuns.first.size() : k, end = r.local[j] + (r.last[j] - r.first[j]);
        std::string text;
        for (std::size_t begin = r.local[j]; begin < end; begin += kAsciiRows, text.clear()) {
            plyAsciiRows(piece, faces, begin, std::min(end, begin + kAsciiRows), vertices, text);
            sink(text);
        }
    };
    Words bytes(runs, 0);
    ranks.step([&] {
        for (std::size_t k = 0; k < runs; ++k) eachChunk(k, [&](const std::string& text) { bytes[k] += text.size(); });
    });
    // Runs in file order: the vertex sections, then the face sections, each rank by rank.
    const std::vector<Words> all = ranks.allgather(bytes);
    Words at(runs);
    std::uint64_t total = 0;
    for (std::size_t k = 0; k < runs; ++k)
        for (int r = 0; r < ranks.size(); ++r) {
            if (r == ranks.rank()) at[k] = total;
            total += all[std::size_t(r)][k];
        }
    stageSharedFile(ranks, path,
        [&](SharedMeshFile& file) { return file.plyHeader(piece, vertices, triangles, options); },
        [&](std::uint64_t headBytes) { return headBytes + total; },
        [&](SharedFile& shared, std::uint64_t headBytes) {
            for (std::size_t k = 0; k < runs; ++k)
                eachChunk(k, [&](const std::string& text) {
                    shared.writeAt(headBytes + at[k], text.data(), text.size(), path);
                    at[k] += text.size();
                });
        },
        batch);
}

} // namespace

void stagePlyOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where, const std::string& path,
    const PlyOptions& options, OutputBatch& batch)
{
    const std::uint64_t vertices = where.vertexBegin.back(), triangles = where.triangleBegin.back();
    if (options.encoding == PlyEncoding::Ascii) return stageAsciiPly(ranks, piece, where, path, options, batch);
    const std::pair<std::size_t, std::size_t> strides = plyRowBytes(piece);
    const std::size_t vStride = strides.first, fStride = strides.second; // captured below (C++17)
    stageSharedFile(ranks, path,
        [&](SharedMeshFile& file) { return file.plyHeader(piece, vertices, triangles, options); },
        [&](std::uint64_t headBytes) { return headBytes + vertices * vStride + triangles * fStride; },
        [&](SharedFile& shared, std::uint64_t headBytes) {
            // Rows go to the runs of the rank's sections in order (MeshPiece), whole rows a chunk.
            const Runs vertexRuns(where.vertexBegin, ranks.rank(), ranks.size()),
                faceRuns(where.triangleBegin, ranks.rank(), ranks.size());
            std::size_t vertexRow = 0, faceRow = 0;
            plyPieceRows(piece, vertices, [&](bool faces, const char* data, std::size_t bytes) {
                const Runs& runs = faces ? faceRuns : vertexRuns;
                std::size_t& row = faces ? faceRow : vertexRow;
                const std::size_t stride = faces ? fStride : vStride;
                const std::uint64_t base = headBytes + (faces ? vertices * vStride : 0);
                while (bytes > 0) {
                    std::size_t run = runs.first.size() - 1;
                    while (runs.local[run] > row || runs.first[run] == runs.last[run]) --run;
                    const std::size_t rows = std::min<std::size_t>(bytes / stride,
                        std::size_t(runs.last[run] - runs.first[run]) - (row - runs.local[run]));
                    shared.writeAt(base + runs.globalOf(row) * stride, data, rows * stride, path);
                    data += rows * stride, bytes -= rows * stride, row += rows;
                }
            });
        },
        batch);
}

void stageVtpOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where, const std::string& path,
    const MeshFileOptions& options, OutputBatch& batch)
{
    const std::uint64_t vertices = where.vertexBegin.back(), triangles = where.triangleBegin.back();
    std::optional<VtpPieceLayout> layout;
    stageSharedFile(ranks, path,
        [&](SharedMeshFile& file) { return file.vtpHead(piece, vertices, triangles, options); },
        // The layout's offsets count from the end of the head, whose size this call learns.
        [&](std::uint64_t headBytes) { return layout.emplace(piece, vertices, triangles, headBytes).fileBytes(); },
        [&](SharedFile& shared, std::uint64_t) {
            const auto write = [&](std::uint64_t at, const char* data, std::size_t bytes) { shared.writeAt(at, data, bytes, path); };
            if (ranks.rank() == 0) layout->frame(write);
            layout->rows(piece, Runs(where.vertexBegin, ranks.rank(), ranks.size()),
                Runs(where.triangleBegin, ranks.rank(), ranks.size()), write);
        },
        batch);
}

} // namespace nodes_internal
} // namespace isouq::nodes
