// isouq nodes: `isouq mesh` on MPI ranks (Distributed.h; SPEC §9, §10 "MPI"; docs/mpi.md).
//
// Steps, each ended by an agreement (an allreduce of every rank's status), so a failure or an
// interruption on any rank stops every rank at the same step, with one message:
//   load     every rank opens the .vdb with delayed loading (topology in memory, leaf values in
//            the file until touched) and cuts the mesher's block order into pieces (BrickPlan);
//   check    each rank scans the values of its own leaves; the scans (and, for a fog volume
//            without --isovalue, the Otsu histograms) are joined, and checkScalarVolume runs;
//   mesh     count pass; prefix sums of the counts; the masks of + neighbours owned by later
//            ranks; fill pass (BrickMesher);
//   measure  topology of the piece (ghost vertices' positions from their owners), corrected by
//            the edges and components that cross pieces, joined on rank 0; area, volume and the
//            column statistics carried from rank to rank in the one-process order (bit-equal);
//   write    rank 0 creates the temporary PLY and writes the header, every rank its rows with
//            MPI-IO, rank 0 renames it and writes the summary.
#include "isouq/nodes/Distributed.h"

#include "isouq/nodes/Summary.h"

#include <isouq/Bricks.h>
#include <isouq/Columns.h>
#include <isouq/Diagnostics.h>
#include <isouq/Errors.h>
#include <isouq/MeshIO.h>
#include <isouq/MeshTopology.h>
#include <isouq/VolumeSources.h>

#include <openvdb/Exceptions.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <numeric>
#include <sstream>

namespace isouq::nodes {
namespace {

namespace fs = std::filesystem;
using Words = std::vector<std::uint64_t>;
using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start)
{
    return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

/// An agreed stop: every rank throws it at the same step.
struct Stop {
    int status;
};

class Ranks {
public:
    Ranks(MPI_Comm comm, std::function<bool()> interrupted) : mComm(comm), mInterrupted(std::move(interrupted))
    {
        MPI_Comm_rank(comm, &mRank);
        MPI_Comm_size(comm, &mSize);
    }
    int rank() const { return mRank; }
    int size() const { return mSize; }
    MPI_Comm comm() const { return mComm; }

    /// Runs @a body, then agrees with the other ranks: on a failure anywhere the lowest failing
    /// rank keeps its message (after @a where, the one-process graph's "node 'ID' (TYPE): "),
    /// and every rank throws Stop (2 for bad input, 1 interrupted).
    template <typename Body>
    void step(Body&& body, const char* where = "")
    {
        int status = 0;
        std::string message;
        try {
            body();
        } catch (const InterruptedError&) {
            status = 1;
        } catch (const std::exception& e) {
            status = mInterrupted() ? 1 : 2;
            message = where + std::string(e.what());
        }
        if (status == 0 && mInterrupted()) status = 1;
        int worst = 0;
        MPI_Allreduce(&status, &worst, 1, MPI_INT, MPI_MAX, mComm);
        if (worst == 0) return;
        if (worst == 2) {
            int mine = status == 2 ? mRank : mSize, first = mSize;
            MPI_Allreduce(&mine, &first, 1, MPI_INT, MPI_MIN, mComm);
            if (first == mRank) error = message, printsError = true;
        }
        throw Stop{worst};
    }

    /// Each rank's @a words, in rank order (collective).
    std::vector<Words> allgather(const Words& words) const
    {
        const int n = int(words.size());
        std::vector<int> counts(static_cast<std::size_t>(mSize)), displs(static_cast<std::size_t>(mSize), 0);
        MPI_Allgather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, mComm);
        for (int r = 1; r < mSize; ++r) displs[std::size_t(r)] = displs[std::size_t(r) - 1] + counts[std::size_t(r) - 1];
        Words all(std::size_t(displs.back() + counts.back()));
        MPI_Allgatherv(words.data(), n, MPI_UINT64_T, all.data(), counts.data(), displs.data(), MPI_UINT64_T, mComm);
        return split(all, counts, displs);
    }

    /// Each rank's @a words on rank 0 (collective; empty elsewhere).
    std::vector<Words> gather(const Words& words) const
    {
        const int n = int(words.size());
        std::vector<int> counts(static_cast<std::size_t>(mSize)), displs(static_cast<std::size_t>(mSize), 0);
        MPI_Gather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, 0, mComm);
        Words all;
        if (mRank == 0) {
            for (int r = 1; r < mSize; ++r) displs[std::size_t(r)] = displs[std::size_t(r) - 1] + counts[std::size_t(r) - 1];
            all.resize(std::size_t(displs.back() + counts.back()));
        }
        MPI_Gatherv(words.data(), n, MPI_UINT64_T, all.data(), counts.data(), displs.data(), MPI_UINT64_T, 0, mComm);
        return mRank == 0 ? split(all, counts, displs) : std::vector<Words>();
    }

    /// Sends out[r] to rank r and returns what each rank sent here (collective).
    std::vector<Words> exchange(const std::vector<Words>& out) const
    {
        std::vector<int> sendCounts(static_cast<std::size_t>(mSize)), recvCounts(static_cast<std::size_t>(mSize));
        std::vector<int> sendDispls(static_cast<std::size_t>(mSize), 0), recvDispls(static_cast<std::size_t>(mSize), 0);
        Words send;
        for (int r = 0; r < mSize; ++r) {
            sendCounts[std::size_t(r)] = int(out[std::size_t(r)].size());
            sendDispls[std::size_t(r)] = int(send.size());
            send.insert(send.end(), out[std::size_t(r)].begin(), out[std::size_t(r)].end());
        }
        MPI_Alltoall(sendCounts.data(), 1, MPI_INT, recvCounts.data(), 1, MPI_INT, mComm);
        for (int r = 1; r < mSize; ++r)
            recvDispls[std::size_t(r)] = recvDispls[std::size_t(r) - 1] + recvCounts[std::size_t(r) - 1];
        Words recv(std::size_t(recvDispls.back() + recvCounts.back()));
        MPI_Alltoallv(send.data(), sendCounts.data(), sendDispls.data(), MPI_UINT64_T, recv.data(),
            recvCounts.data(), recvDispls.data(), MPI_UINT64_T, mComm);
        return split(recv, recvCounts, recvDispls);
    }

    std::string error;
    bool printsError = false;

private:
    static std::vector<Words> split(const Words& all, const std::vector<int>& counts, const std::vector<int>& displs)
    {
        std::vector<Words> out(counts.size());
        for (std::size_t r = 0; r < counts.size(); ++r)
            out[r].assign(all.begin() + displs[r], all.begin() + displs[r] + counts[r]);
        return out;
    }

    MPI_Comm mComm;
    std::function<bool()> mInterrupted;
    int mRank = 0, mSize = 1;
};

std::uint64_t bitsOf(double v)
{
    std::uint64_t w;
    std::memcpy(&w, &v, sizeof w);
    return w;
}
double doubleOf(std::uint64_t w)
{
    double v;
    std::memcpy(&v, &w, sizeof v);
    return v;
}
std::uint64_t bitsOf(float v)
{
    std::uint32_t w;
    std::memcpy(&w, &v, sizeof w);
    return w;
}
float floatOf(std::uint64_t w)
{
    const std::uint32_t u = std::uint32_t(w);
    float v;
    std::memcpy(&v, &u, sizeof v);
    return v;
}

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

/// The options the distributed run supports; anything else is refused by name.
void checkSupported(const MeshGraphRequest& request)
{
    const auto refuse = [](const std::string& what) {
        throw InputError(what + " is not supported under MPI yet (docs/mpi.md); run it in one process");
    };
    for (const auto& [key, value] : request.read.items())
        if (!value.is_null() && key != "input" && key != "grid" && key != "isovalue") refuse("read_volume '" + key + "'");
    for (const auto& [key, value] : request.mesh.items())
        if (!value.is_null() && key != "method" && key != "linear_only" && key != "isovalue") refuse("mesh '" + key + "'");
    for (const auto& [key, value] : request.write.items())
        if (!value.is_null() && !(key == "format" && value == "binary")) refuse("write_ply '" + key + "'");
    if (request.hiddenFeatures || !request.hiddenOutput.empty()) refuse("--hidden-features");
    if (request.color.contains("measure") && !request.color["measure"].is_null()) refuse("--color-by");
    const std::string input = request.read.value("input", std::string());
    std::string ext = fs::path(input).extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (ext != ".vdb") refuse("INPUT '" + input + "' (only .vdb files are read by pieces)");
    std::string out = fs::path(request.output).extension().string();
    for (char& c : out) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (out != ".ply") refuse("output '" + request.output + "' (only .ply is written by pieces)");
}

fs::path canonical(const std::string& path) { return fs::weakly_canonical(fs::absolute(path)); }

/// What the one-process graph refuses before it reads anything (SPEC §10 "Errors").
void checkOutputs(const MeshGraphRequest& request)
{
    const std::string input = request.read.value("input", std::string());
    for (const std::string& out : {request.output, request.summaryPath}) {
        if (out.empty()) continue;
        if (canonical(out) == canonical(input)) throw InputError("output " + out + " is the input; give it another path");
        checkWritable(out);
    }
    if (!request.summaryPath.empty() && canonical(request.summaryPath) == canonical(request.output))
        throw InputError("outputs " + request.output + " and " + request.summaryPath + " are the same file");
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

/// The summary columns a piece carries (SPEC §8), in the one-process order.
std::vector<const std::vector<float>*> summaryColumns(const Mesh& mesh, std::vector<std::string>& names)
{
    std::vector<const std::vector<float>*> columns;
    for (const ColumnInfo& c : columnTable())
        if (const auto* column = c.summary ? mesh.vertexAttributes.find<float>(c.name) : nullptr) {
            columns.push_back(column);
            names.emplace_back(c.name);
        }
    return columns;
}

// Where the one-process graph (MeshGraph.cc) reports a failure of the same work.
constexpr const char* kRead = "node 'load' (read_volume): ";
constexpr const char* kMesh = "node 'mesh' (mesh): ";

struct PieceTimes {
    double load = 0, check = 0, mesh = 0, measure = 0, write = 0;
};

} // namespace

bool launchedByMpiLauncher()
{
    for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_SIZE", "PMI_RANK"})
        if (std::getenv(name)) return true;
    const char* tasks = std::getenv("SLURM_STEP_NUM_TASKS");
    return tasks && std::atoi(tasks) > 1 && std::getenv("SLURM_PROCID");
}

DistributedResult runDistributedMesh(const MeshGraphRequest& request, MPI_Comm comm,
    openvdb::util::NullInterrupter* interrupter, const std::function<bool()>& interrupted)
{
    Ranks ranks(comm, interrupted);
    const int rank = ranks.rank(), size = ranks.size();
    DistributedResult result;
    result.isRoot = rank == 0;
    PieceTimes times;
    try {
        // ---- load ----------------------------------------------------------------------------
        auto start = Clock::now();
        LoadedVolume volume;
        std::unique_ptr<BrickPlan> plan;
        std::string method = request.mesh.value("method", std::string("weno"));
        const bool linearOnly = request.mesh.value("linear_only", false);
        ranks.step([&] {
            checkSupported(request);
            if (rank == 0) checkOutputs(request);
        });
        ranks.step([&] {
            VolumeRequest read;
            read.input = request.read.value("input", std::string());
            if (request.read.contains("grid") && !request.read["grid"].is_null()) read.gridName = request.read["grid"].get<std::string>();
            if (request.read.contains("isovalue") && !request.read["isovalue"].is_null())
                read.isovalue = request.read["isovalue"].get<float>();
            read.delayLoad = true;
            volume = loadVolume(read, interrupter);
            plan = std::make_unique<BrickPlan>(*volume.grid, size);
        }, kRead);
        const openvdb::FloatGrid& grid = *volume.grid;
        const auto mine = [&](const openvdb::Coord& leafOrigin) { return plan->pieceOfBlock(plan->blockOf(leafOrigin)) == rank; };
        times.load = msSince(start);

        // ---- check ---------------------------------------------------------------------------
        start = Clock::now();
        ActiveValueScan scan;
        ranks.step([&] { scan = scanActiveValues(grid, mine, rank == 0); }, kRead);
        const std::vector<Words> scans = ranks.allgather(packScan(scan));
        scan = ActiveValueScan();
        for (const Words& w : scans) scan.join(unpackScan(w));
        if (std::isnan(volume.isovalue)) { // a fog volume without --isovalue: Otsu of the whole
            std::array<std::uint64_t, 256> histogram{}, total{};
            ranks.step([&] { histogram = activeValueHistogram(grid, scan.min, scan.max, mine, rank == 0); }, kRead);
            MPI_Allreduce(histogram.data(), total.data(), 256, MPI_UINT64_T, MPI_SUM, comm);
            ranks.step([&] { volume.isovalue = float(otsuOfActiveValues(grid, scan.min, scan.max, total)); }, kRead);
        }
        ranks.step([&] {
            const std::string problem = checkScalarVolume(grid, volume.isovalue, scan);
            if (!problem.empty()) throw InputError(problem);
        }, kRead);
        MeshSettings settings;
        settings.isovalue = request.mesh.contains("isovalue") && !request.mesh["isovalue"].is_null()
            ? request.mesh["isovalue"].get<float>() : volume.isovalue;
        settings.uncertainty = !linearOnly;
        settings.provenance = true;
        ranks.step([&] {
            const auto m = edgeMethodFromString(method);
            if (!m) throw InputError("unknown method '" + method + "'");
            settings.method = *m;
        }, kMesh);
        times.check = msSince(start);

        // ---- mesh ----------------------------------------------------------------------------
        start = Clock::now();
        BrickMesher mesher(grid, settings, *plan, rank);
        ranks.step([&] { mesher.count(interrupter); }, kMesh);
        const std::vector<Words> counts = ranks.allgather({mesher.vertexCount(), mesher.triangleCount()});
        std::vector<std::uint64_t> vertexBegin(std::size_t(size) + 1, 0), triangleBegin(std::size_t(size) + 1, 0);
        for (int r = 0; r < size; ++r) {
            vertexBegin[std::size_t(r) + 1] = vertexBegin[std::size_t(r)] + counts[std::size_t(r)][0];
            triangleBegin[std::size_t(r) + 1] = triangleBegin[std::size_t(r)] + counts[std::size_t(r)][1];
        }
        const std::uint64_t totalVertices = vertexBegin.back(), totalTriangles = triangleBegin.back();
        ranks.step([&] { mesher.setOffsets(vertexBegin[std::size_t(rank)], triangleBegin[std::size_t(rank)], totalVertices); }, kMesh);
        // The masks of the + neighbours that later ranks own.
        const std::vector<std::int64_t> foreign = mesher.foreignBlocks();
        std::vector<Words> requests(static_cast<std::size_t>(size));
        for (std::int64_t b : foreign) requests[std::size_t(plan->pieceOfBlock(b))].push_back(std::uint64_t(b));
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
        Mesh piece;
        ranks.step([&] {
            for (int r = 0; r < size; ++r)
                for (std::size_t i = 0; i < requests[std::size_t(r)].size(); ++i)
                    mesher.learnBlock(std::int64_t(requests[std::size_t(r)][i]),
                        answered[std::size_t(r)].data() + i * BrickMesher::kBlockWords);
            mesher.fill(piece, interrupter);
        }, kMesh);
        // The values are meshed: what this rank read, then the grid goes (as in the one-process
        // graph, which frees the volume after its last reader).
        const std::uint64_t voxelsRead = loadedLeafVoxels(grid);
        volume.grid.reset();
        times.mesh = msSince(start);

        // ---- write: the rows now, the file appears with the summary -------------------------
        start = Clock::now();
        PlyOptions options;
        options.version = ISOUQ_VERSION_STRING;
        options.isovalue = settings.isovalue;
        options.method = linearOnly ? std::string("linear") : method;
        if (!volume.geometry.empty()) options.comments.push_back("isouq geometry " + volume.geometry);
        const std::pair<std::size_t, std::size_t> strides = plyRowBytes(piece);
        const std::size_t vStride = strides.first, fStride = strides.second;
        std::unique_ptr<SharedPlyFile> file;
        std::string header;
        ranks.step([&] {
            if (rank != 0) return;
            file = std::make_unique<SharedPlyFile>(request.output);
            header = file->header(piece, totalVertices, totalTriangles, options);
        });
        std::string temp = rank == 0 ? file->temporaryPath() : std::string();
        std::uint64_t lengths[2] = {temp.size(), header.size()};
        MPI_Bcast(lengths, 2, MPI_UINT64_T, 0, comm);
        temp.resize(lengths[0]);
        MPI_Bcast(temp.data(), int(lengths[0]), MPI_CHAR, 0, comm);
        const std::uint64_t headerBytes = lengths[1];
        MPI_File fh = MPI_FILE_NULL;
        struct CloseGuard { // collective: every rank unwinds through it
            MPI_File& f;
            ~CloseGuard() { if (f != MPI_FILE_NULL) MPI_File_close(&f); }
        } closeGuard{fh};
        const int opened = MPI_File_open(comm, temp.c_str(), MPI_MODE_WRONLY, MPI_INFO_NULL, &fh);
        ranks.step([&] {
            if (opened != MPI_SUCCESS) throw IoError("cannot write " + request.output + ": MPI_File_open failed");
            const auto put = [&](std::uint64_t offset, const char* data, std::size_t bytes) {
                if (MPI_File_write_at(fh, MPI_Offset(offset), data, int(bytes), MPI_BYTE, MPI_STATUS_IGNORE) != MPI_SUCCESS)
                    throw IoError("cannot write " + request.output + ": MPI_File_write_at failed");
            };
            if (rank == 0) put(0, header.data(), header.size());
            std::uint64_t vertexAt = headerBytes + vertexBegin[std::size_t(rank)] * vStride;
            std::uint64_t faceAt = headerBytes + totalVertices * vStride + triangleBegin[std::size_t(rank)] * fStride;
            plyPieceRows(piece, totalVertices, [&](bool faces, const char* data, std::size_t bytes) {
                std::uint64_t& at = faces ? faceAt : vertexAt;
                put(at, data, bytes);
                at += bytes;
            });
        });
        MPI_File_close(&fh);
        times.write = msSince(start);

        // ---- measure -------------------------------------------------------------------------
        start = Clock::now();
        const std::uint64_t v0 = mesher.firstVertex();
        const std::size_t nLocal = piece.vertexCount();
        // Ghosts: vertices of other ranks that this rank's triangles use; their positions.
        std::vector<std::uint32_t> ghosts;
        for (const openvdb::Vec3I& t : piece.triangles)
            for (int c = 0; c < 3; ++c)
                if (t[c] < v0 || t[c] >= v0 + nLocal) ghosts.push_back(t[c]);
        std::sort(ghosts.begin(), ghosts.end());
        ghosts.erase(std::unique(ghosts.begin(), ghosts.end()), ghosts.end());
        const auto ownerOf = [&](std::uint64_t g) {
            return int(std::upper_bound(vertexBegin.begin(), vertexBegin.end(), g) - vertexBegin.begin()) - 1;
        };
        std::vector<Words> wanted(static_cast<std::size_t>(size));
        for (std::uint32_t g : ghosts) wanted[std::size_t(ownerOf(g))].push_back(g);
        const std::vector<Words> wantedHere = ranks.exchange(wanted);
        std::vector<Words> positions(static_cast<std::size_t>(size));
        for (int r = 0; r < size; ++r)
            for (std::uint64_t g : wantedHere[std::size_t(r)]) {
                std::uint64_t words[2] = {0, 0};
                std::memcpy(words, piece.positions[std::size_t(g - v0)].asPointer(), 12);
                positions[std::size_t(r)].insert(positions[std::size_t(r)].end(), words, words + 2);
            }
        const std::vector<Words> got = ranks.exchange(positions);
        // The piece becomes its own small mesh: ghosts appended, triangles in local indices.
        Mesh& local = piece;
        local.positions.resize(nLocal + ghosts.size());
        for (int r = 0; r < size; ++r)
            for (std::size_t i = 0; i < wanted[std::size_t(r)].size(); ++i) {
                const auto at = std::lower_bound(ghosts.begin(), ghosts.end(), std::uint32_t(wanted[std::size_t(r)][i]));
                std::memcpy(local.positions[nLocal + std::size_t(at - ghosts.begin())].asPointer(),
                    got[std::size_t(r)].data() + 2 * i, 12);
            }
        const auto localIndex = [&](std::uint32_t g) -> std::uint32_t {
            if (g >= v0 && g < v0 + nLocal) return std::uint32_t(g - v0);
            return std::uint32_t(nLocal + std::size_t(std::lower_bound(ghosts.begin(), ghosts.end(), g) - ghosts.begin()));
        };
        for (openvdb::Vec3I& t : local.triangles)
            for (int c = 0; c < 3; ++c) t[c] = localIndex(t[c]);
        const auto globalIndex = [&](std::uint32_t l) -> std::uint64_t {
            return l < nLocal ? v0 + l : ghosts[l - nLocal];
        };

        // Shared vertices: those that triangles of another rank may use (an edge of a cell that
        // another rank meshes). Only they can join components or edges across ranks.
        std::vector<std::uint8_t> shared(local.positions.size(), 1);
        {
            const auto* ei = piece.vertexAttributes.find<std::int32_t>(col::kEdgeI);
            const auto* ej = piece.vertexAttributes.find<std::int32_t>(col::kEdgeJ);
            const auto* ek = piece.vertexAttributes.find<std::int32_t>(col::kEdgeK);
            const auto* ax = piece.vertexAttributes.find<std::uint8_t>(col::kEdgeAxis);
            for (std::size_t v = 0; v < nLocal; ++v) {
                const openvdb::Coord e((*ei)[v], (*ej)[v], (*ek)[v]);
                const int a = (*ax)[v], a1 = (a + 1) % 3, a2 = (a + 2) % 3;
                bool other = false;
                if ((e[a1] & 7) == 0 || (e[a2] & 7) == 0) // else its four cells are in its block
                    for (int d = 0; d < 4 && !other; ++d) {
                        openvdb::Coord c = e;
                        c[a1] -= d & 1;
                        c[a2] -= d >> 1;
                        const int p = plan->pieceOfCell(c);
                        other = p >= 0 && p != rank;
                    }
                shared[v] = other;
            }
        }
        // Area, volume and statistics, carried from rank to rank in the one-process order.
        std::array<double, 3> lo, hi, centre;
        lo.fill(std::numeric_limits<double>::infinity());
        hi.fill(-std::numeric_limits<double>::infinity());
        for (std::size_t v = 0; v < nLocal; ++v)
            for (int c = 0; c < 3; ++c) {
                lo[std::size_t(c)] = std::min(lo[std::size_t(c)], double(piece.positions[v][c]));
                hi[std::size_t(c)] = std::max(hi[std::size_t(c)], double(piece.positions[v][c]));
            }
        MPI_Allreduce(MPI_IN_PLACE, lo.data(), 3, MPI_DOUBLE, MPI_MIN, comm);
        MPI_Allreduce(MPI_IN_PLACE, hi.data(), 3, MPI_DOUBLE, MPI_MAX, comm);
        for (int c = 0; c < 3; ++c) centre[std::size_t(c)] = 0.5 * (lo[std::size_t(c)] + hi[std::size_t(c)]);
        std::vector<std::string> names;
        const std::vector<const std::vector<float>*> columns = summaryColumns(piece, names);
        GeometrySums geometry;
        std::vector<StatisticsSums> stats(columns.size());
        const int carryWords = int(3 + 5 * columns.size());
        Words carry(std::size_t(carryWords), 0);
        if (rank > 0) {
            MPI_Recv(carry.data(), carryWords, MPI_UINT64_T, rank - 1, 1, comm, MPI_STATUS_IGNORE);
            geometry.area = doubleOf(carry[0]);
            geometry.signedVolume = doubleOf(carry[1]);
            geometry.degenerate = std::size_t(carry[2]);
            for (std::size_t c = 0; c < columns.size(); ++c) {
                const std::uint64_t* w = carry.data() + 3 + 5 * c;
                stats[c].lo = doubleOf(w[0]), stats[c].hi = doubleOf(w[1]);
                stats[c].sum = doubleOf(w[2]), stats[c].sumSq = doubleOf(w[3]), stats[c].count = std::size_t(w[4]);
            }
        }
        if (totalVertices > 0)
            addTriangleGeometry(local.positions, local.triangles.data(), local.triangles.data() + local.triangles.size(),
                centre, geometry);
        for (std::size_t c = 0; c < columns.size(); ++c) stats[c].add(columns[c]->data(), columns[c]->size());
        carry[0] = bitsOf(geometry.area);
        carry[1] = bitsOf(geometry.signedVolume);
        carry[2] = geometry.degenerate;
        for (std::size_t c = 0; c < columns.size(); ++c) {
            std::uint64_t* w = carry.data() + 3 + 5 * c;
            w[0] = bitsOf(stats[c].lo), w[1] = bitsOf(stats[c].hi), w[2] = bitsOf(stats[c].sum);
            w[3] = bitsOf(stats[c].sumSq), w[4] = stats[c].count;
        }
        if (rank + 1 < size) MPI_Send(carry.data(), carryWords, MPI_UINT64_T, rank + 1, 1, comm);
        if (size > 1 && rank == size - 1) MPI_Send(carry.data(), carryWords, MPI_UINT64_T, 0, 2, comm);
        if (size > 1 && rank == 0) MPI_Recv(carry.data(), carryWords, MPI_UINT64_T, size - 1, 2, comm, MPI_STATUS_IGNORE);
        // The columns are summed: only positions and triangles are left to measure.
        const std::size_t summaryColumnCount = columns.size();
        piece.vertexAttributes.clear();

        MeshTopologyStats topo;
        std::vector<std::uint32_t> labels;
        ranks.step([&] {
            topo = measureTopology(local, &labels, /*geometry=*/false);
        });
        // Edges with both ends shared: counted on rank 0 over all ranks instead of here.
        std::vector<std::pair<std::uint64_t, std::uint64_t>> sharedEdges;
        Words componentPairs; // (global vertex, local component) of the shared vertices used
        for (std::size_t f = 0; f < local.triangles.size(); ++f) {
            const openvdb::Vec3I& t = local.triangles[f];
            for (int c = 0; c < 3; ++c) {
                const std::uint32_t a = t[c], b = t[(c + 1) % 3];
                if (shared[a]) componentPairs.insert(componentPairs.end(), {globalIndex(a), labels[f]});
                if (a != b && shared[a] && shared[b])
                    sharedEdges.emplace_back(std::min(globalIndex(a), globalIndex(b)), std::max(globalIndex(a), globalIndex(b)));
            }
        }
        std::sort(sharedEdges.begin(), sharedEdges.end());
        Words edgeUses; // (lo, hi, uses)
        std::size_t localEdges = 0, localBoundary = 0, localNonManifold = 0;
        for (std::size_t i = 0; i < sharedEdges.size();) {
            std::size_t j = i + 1;
            while (j < sharedEdges.size() && sharedEdges[j] == sharedEdges[i]) ++j;
            edgeUses.insert(edgeUses.end(), {sharedEdges[i].first, sharedEdges[i].second, std::uint64_t(j - i)});
            ++localEdges;
            localBoundary += j - i == 1;
            localNonManifold += j - i > 2;
            i = j;
        }
        const Words tallies = {topo.boundaryEdges - localBoundary, topo.nonManifoldEdges - localNonManifold, topo.components};
        const std::vector<Words> allTallies = ranks.gather(tallies);
        const std::vector<Words> allEdges = ranks.gather(edgeUses);
        const std::vector<Words> allPairs = ranks.gather(componentPairs);

        times.measure = msSince(start);

        nlohmann::json summary;
        if (rank == 0) {
            // Edges and components across the pieces' borders.
            std::size_t boundary = 0, nonManifold = 0, components = 0;
            std::vector<std::uint64_t> componentBase(std::size_t(size) + 1, 0);
            for (int r = 0; r < size; ++r) {
                boundary += allTallies[std::size_t(r)][0];
                nonManifold += allTallies[std::size_t(r)][1];
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
                boundary += uses == 1;
                nonManifold += uses > 2;
                i = j;
            }
            std::vector<std::pair<std::uint64_t, std::uint64_t>> pairs; // (global vertex, component node)
            for (int r = 0; r < size; ++r)
                for (std::size_t i = 0; i < allPairs[std::size_t(r)].size(); i += 2)
                    pairs.emplace_back(allPairs[std::size_t(r)][i], componentBase[std::size_t(r)] + allPairs[std::size_t(r)][i + 1]);
            std::sort(pairs.begin(), pairs.end());
            Sets sets(componentBase.back());
            components = componentBase.back();
            for (std::size_t i = 1; i < pairs.size(); ++i)
                if (pairs[i].first == pairs[i - 1].first && sets.join(pairs[i].second, pairs[i - 1].second)) --components;

            GeometrySums total;
            total.area = doubleOf(carry[0]);
            total.signedVolume = doubleOf(carry[1]);
            total.degenerate = std::size_t(carry[2]);
            summary["vertices"] = totalVertices;
            summary["triangles"] = totalTriangles;
            summary["boundary_edges"] = boundary;
            summary["non_manifold_edges"] = nonManifold;
            summary["components"] = components;
            summary["degenerate_triangles"] = total.degenerate;
            summary["area"] = total.area;
            summary["enclosed_volume"] = std::abs(total.signedVolume);
            for (std::size_t c = 0; c < summaryColumnCount; ++c) {
                StatisticsSums s;
                const std::uint64_t* w = carry.data() + 3 + 5 * c;
                s.lo = doubleOf(w[0]), s.hi = doubleOf(w[1]), s.sum = doubleOf(w[2]), s.sumSq = doubleOf(w[3]);
                s.count = std::size_t(w[4]);
                summary[names[c]] = s.result();
            }
            // As the mesh and summary nodes of the one-process graph (VolumeNodes.cc, AnalysisNodes.cc).
            summary["isovalue"] = settings.isovalue;
            summary["method"] = linearOnly ? std::string("linear") : method;
            summary["input"] = volume.input;
            summary["description"] = volume.description;
            summary["isovalue_source"] = settings.isovalue == volume.isovalue ? volume.isovalueSource : "given";
            summary["index_to_world"] = piece.indexToWorld;
            if (!volume.geometry.empty()) summary["geometry"] = volume.geometry;
            summary["output"] = request.output;
            if (volume.isovalueSource != "given") {
                std::ostringstream line;
                line << "isovalue " << volume.isovalue << " (" << volume.isovalueSource
                     << "; set it with the isovalue parameter, --isovalue)";
                result.notes.push_back(line.str());
            }
        }


        // The ranks block (SPEC §10), then the files appear together on rank 0.
        const Words mineWords = {voxelsRead, mesher.vertexCount(), mesher.triangleCount(),
            plan->end(rank) - plan->begin(rank), plan->weight(rank), bitsOf(times.load), bitsOf(times.check),
            bitsOf(times.mesh), bitsOf(times.measure), bitsOf(times.write)};
        const std::vector<Words> perRank = ranks.gather(mineWords);
        ranks.step([&] {
            if (rank != 0) return;
            nlohmann::json list = nlohmann::json::array();
            double load = 0, mesh = 0, measure = 0;
            for (int r = 0; r < size; ++r) {
                const Words& w = perRank[std::size_t(r)];
                list.push_back({{"rank", r}, {"voxels_read", w[0]}, {"vertices", w[1]}, {"triangles", w[2]},
                    {"blocks", w[3]}, {"weight", w[4]},
                    {"timings_ms", {{"load", doubleOf(w[5])}, {"check", doubleOf(w[6])}, {"mesh", doubleOf(w[7])},
                                       {"measure", doubleOf(w[8])}, {"write", doubleOf(w[9])}}}});
                load = std::max(load, doubleOf(w[5]) + doubleOf(w[6]));
                mesh = std::max(mesh, doubleOf(w[7]));
                measure = std::max(measure, doubleOf(w[8]));
            }
            summary["ranks"] = list;
            summary["timings_ms"] = {{"load", load}, {"mesh", mesh}, {"measure", measure}};
            OutputBatch batch;
            if (!request.summaryPath.empty()) batch.addText(request.summaryPath, summary.dump(2) + "\n");
            file->commit();
            batch.commit();
            result.summary = summary;
        });
    } catch (const Stop& stop) {
        result.status = stop.status;
        result.error = ranks.error;
        result.printsError = ranks.printsError;
        result.notes.clear();
    }
    return result;
}

} // namespace isouq::nodes

