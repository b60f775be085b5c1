// isouq nodes: Ranks over MPI (Distributed.h; SPEC §10 "MPI"; docs/mpi.md). Only what is
// MPI-specific lives here: the collectives on 64-bit words and the MPI-IO file; what the
// nodes do with them is in Pieces.cc, and the graph is the one-process graph.
#include "isouq/nodes/Distributed.h"

#include <isouq/Errors.h>

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>

namespace isouq::nodes {
namespace {

constexpr int kTag = 1;         // send and receive
constexpr int kExchangeTag = 2; // exchange

std::vector<Words> splitWords(const Words& all, const std::vector<int>& counts, const std::vector<int>& displs)
{
    std::vector<Words> out(counts.size());
    for (std::size_t r = 0; r < counts.size(); ++r)
        out[r].assign(all.begin() + displs[r], all.begin() + displs[r] + counts[r]);
    return out;
}

std::vector<int> displacements(const std::vector<int>& counts)
{
    std::vector<int> displs(counts.size(), 0);
    for (std::size_t r = 1; r < counts.size(); ++r) displs[r] = displs[r - 1] + counts[r - 1];
    return displs;
}

class MpiSharedFile final : public SharedFile {
public:
    explicit MpiSharedFile(MPI_File file) : mFile(file) {}
    ~MpiSharedFile() override { MPI_File_close(&mFile); }
    void writeAt(std::uint64_t offset, const char* data, std::size_t bytes, const std::string& what) override
    {
        for (std::size_t done = 0; done < bytes;) { // an int of bytes a call
            const int n = int(std::min<std::size_t>(bytes - done, std::size_t(1) << 30));
            if (MPI_File_write_at(mFile, MPI_Offset(offset + done), data + done, n, MPI_BYTE, MPI_STATUS_IGNORE) != MPI_SUCCESS)
                throw IoError("cannot write " + what + ": MPI_File_write_at failed");
            done += std::size_t(n);
        }
    }

private:
    MPI_File mFile;
};

class MpiRanks final : public Ranks {
public:
    MpiRanks(MPI_Comm comm, std::function<bool()> interrupted, bool owned = false)
        : mComm(comm), mInterrupted(std::move(interrupted)), mOwned(owned)
    {
        MPI_Comm_rank(comm, &mRank);
        MPI_Comm_size(comm, &mSize);
    }
    ~MpiRanks() override
    {
        if (mOwned) MPI_Comm_free(&mComm);
    }
    MpiRanks(const MpiRanks&) = delete;
    MpiRanks& operator=(const MpiRanks&) = delete;
    int rank() const override { return mRank; }
    int size() const override { return mSize; }
    bool interrupted() const override { return mInterrupted(); }

    std::vector<Words> allgather(const Words& words) const override
    {
        const int n = int(words.size());
        std::vector<int> counts(static_cast<std::size_t>(mSize));
        MPI_Allgather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, mComm);
        const std::vector<int> displs = displacements(counts);
        Words all(std::size_t(displs.back() + counts.back()));
        MPI_Allgatherv(words.data(), n, MPI_UINT64_T, all.data(), counts.data(), displs.data(), MPI_UINT64_T, mComm);
        return splitWords(all, counts, displs);
    }

    std::vector<Words> gather(const Words& words) const override
    {
        const int n = int(words.size());
        std::vector<int> counts(static_cast<std::size_t>(mSize));
        MPI_Gather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, 0, mComm);
        const std::vector<int> displs = displacements(counts);
        Words all(mRank == 0 ? std::size_t(displs.back() + counts.back()) : 0);
        MPI_Gatherv(words.data(), n, MPI_UINT64_T, all.data(), counts.data(), displs.data(), MPI_UINT64_T, 0, mComm);
        return mRank == 0 ? splitWords(all, counts, displs) : std::vector<Words>();
    }

    void exchangeInto(const std::vector<Words>& out, std::vector<Words>& in) const override
    {
        // The counts first, then each rank's words straight from its vector into the receiver's:
        // no packed copy of everything sent and none of everything received (a scan's blocks
        // are most of what a rank loads, RawSource.cc). Messages longer than an int's count go
        // in pieces, which arrive in order (same tag and pair).
        std::vector<std::uint64_t> sendCounts(static_cast<std::size_t>(mSize)), recvCounts(sendCounts.size());
        for (std::size_t r = 0; r < out.size(); ++r) sendCounts[r] = out[r].size();
        MPI_Alltoall(sendCounts.data(), 1, MPI_UINT64_T, recvCounts.data(), 1, MPI_UINT64_T, mComm);
        in.resize(sendCounts.size());
        std::vector<MPI_Request> pending;
        const auto post = [&](auto start, auto* data, std::uint64_t n, int peer) {
            constexpr std::uint64_t kPiece = std::uint64_t(1) << 30;
            for (std::uint64_t at = 0; at < n; at += kPiece)
                start(data + at, int(std::min(kPiece, n - at)), MPI_UINT64_T, peer, kExchangeTag, mComm,
                    &pending.emplace_back());
        };
        for (int r = 0; r < mSize; ++r) {
            if (r == mRank) continue;
            Words& words = in[std::size_t(r)];
            words.resize(std::size_t(recvCounts[std::size_t(r)]));
            post(MPI_Irecv, words.data(), words.size(), r);
        }
        for (int r = 0; r < mSize; ++r)
            if (r != mRank) post(MPI_Isend, out[std::size_t(r)].data(), out[std::size_t(r)].size(), r);
        in[std::size_t(mRank)] = out[std::size_t(mRank)];
        MPI_Waitall(int(pending.size()), pending.data(), MPI_STATUSES_IGNORE);
    }

    Words broadcast(const Words& words, int root) const override
    {
        std::uint64_t n = words.size();
        MPI_Bcast(&n, 1, MPI_UINT64_T, root, mComm);
        Words out = mRank == root ? words : Words(std::size_t(n));
        MPI_Bcast(out.data(), int(n), MPI_UINT64_T, root, mComm);
        return out;
    }

    void send(const Words& words, int to) const override
    {
        MPI_Send(words.data(), int(words.size()), MPI_UINT64_T, to, kTag, mComm);
    }

    Words receive(int from) const override
    {
        MPI_Status status;
        MPI_Probe(from, kTag, mComm, &status);
        int n = 0;
        MPI_Get_count(&status, MPI_UINT64_T, &n);
        Words words(static_cast<std::size_t>(n));
        MPI_Recv(words.data(), n, MPI_UINT64_T, from, kTag, mComm, MPI_STATUS_IGNORE);
        return words;
    }

    std::unique_ptr<SharedFile> openShared(const std::string& path, std::uint64_t bytes, std::string& why) const override
    {
        // Rank 0 allocates the file's blocks first: a full disk or a file size limit is then
        // one error before any row is written, in the words one process uses, rather than a
        // failed MPI_File_write_at. A file system without fallocate skips it.
        int error = 0;
        if (mRank == 0) {
            const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
            if (fd < 0 || ::fallocate(fd, 0, 0, off_t(bytes)) != 0) error = errno;
            if (fd >= 0) ::close(fd);
            if (error == EOPNOTSUPP || error == ENOSYS) error = 0;
        }
        MPI_Bcast(&error, 1, MPI_INT, 0, mComm);
        if (error != 0) {
            why = std::strerror(error);
            return nullptr;
        }
        MPI_File file = MPI_FILE_NULL;
        if (MPI_File_open(mComm, path.c_str(), MPI_MODE_WRONLY, MPI_INFO_NULL, &file) != MPI_SUCCESS) {
            why = "MPI_File_open failed";
            return nullptr;
        }
        return std::make_unique<MpiSharedFile>(file);
    }

    std::unique_ptr<Ranks> split(int color) const override
    {
        MPI_Comm group = MPI_COMM_NULL;
        MPI_Comm_split(mComm, color, mRank, &group);
        return std::make_unique<MpiRanks>(group, mInterrupted, /*owned=*/true);
    }

private:
    MPI_Comm mComm;
    std::function<bool()> mInterrupted;
    bool mOwned;
    int mRank = 0, mSize = 1;
};

} // namespace

bool launchedByMpiLauncher()
{
    for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_SIZE", "PMI_RANK"})
        if (std::getenv(name)) return true;
    const char* tasks = std::getenv("SLURM_STEP_NUM_TASKS");
    return tasks && std::atoi(tasks) > 1 && std::getenv("SLURM_PROCID");
}

std::string srunWithoutPmix()
{
    if (std::getenv("PMIX_RANK") || std::getenv("OMPI_COMM_WORLD_SIZE")) return {};
    const char* step = std::getenv("SLURM_STEP_NUM_TASKS");
    const int tasks = step ? std::atoi(step) : 0;
    // One task without PMI is a plain run; with PMI-2 (PMI_RANK) even one task fails in MPI_Init.
    if (!step || !std::getenv("SLURM_PROCID") || (tasks <= 1 && !std::getenv("PMI_RANK"))) return {};
    const char* type = std::getenv("SLURM_MPI_TYPE");
    return "srun started " + std::to_string(tasks) + (tasks == 1 ? " task" : " tasks") + " with --mpi=" +
        (type && *type ? type : "none") +
        ", which Open MPI cannot join: run srun --mpi=pmix (or set MpiDefault=pmix in slurm.conf)";
}

std::unique_ptr<Ranks> mpiRanks(MPI_Comm comm, std::function<bool()> interrupted)
{
    return std::make_unique<MpiRanks>(comm, std::move(interrupted));
}

} // namespace isouq::nodes
