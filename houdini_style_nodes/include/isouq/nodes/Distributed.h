// isouq nodes: `isouq mesh` on several MPI ranks (SPEC §9, §10 "MPI"; docs/mpi.md). Every rank
// reads the grid's topology and only the leaf values of its piece of the block order and their
// halo, meshes that piece with its threads, and the ranks write one PLY together (MPI-IO at
// offsets from a prefix sum) that is byte-identical to the one-process file; the summary is
// the one-process summary (sums carried from rank to rank in order, so they are bit-equal;
// components and edges joined across the pieces' borders) plus `ranks`. Built only with MPI.
#pragma once

#include "isouq/nodes/MeshGraph.h"

#include <openvdb/util/NullInterrupter.h>

#include <mpi.h>

#include <functional>
#include <string>

namespace isouq::nodes {

/// True when a launcher started this process as one of several (or one) MPI ranks: Open MPI's
/// mpirun (OMPI_COMM_WORLD_SIZE), a PMIx or PMI launcher (PMIX_RANK, PMI_SIZE), or srun
/// (SLURM_STEP_NUM_TASKS > 1). Read from the environment, before MPI_Init.
bool launchedByMpiLauncher();

/// How a distributed run ended on this rank.
struct DistributedResult {
    int status = 0;             ///< 0, 2 (bad input on some rank), or 1 (interrupted)
    std::string error;          ///< the message of the lowest rank that failed
    bool printsError = false;   ///< this rank prints it (exactly one rank does)
    bool isRoot = false;        ///< rank 0: prints the result and the notes
    nlohmann::json summary;     ///< rank 0: the summary (as written to --summary)
    std::vector<std::string> notes; ///< rank 0: what the one-process run would warn about
};

/// Runs `isouq mesh` for @a request on the ranks of @a comm (collective). Supported: a .vdb
/// float grid (`--grid`), `--isovalue`, `--method`, `--linear-only`, a binary .ply output and
/// `--summary`; anything else is refused on every rank with one message. @a interrupted says
/// whether a signal arrived (checked between the collective steps).
DistributedResult runDistributedMesh(const MeshGraphRequest& request, MPI_Comm comm,
    openvdb::util::NullInterrupter* interrupter, const std::function<bool()>& interrupted);

} // namespace isouq::nodes
