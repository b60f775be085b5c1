// isouq nodes: the ranks of an MPI communicator (Ranks.h; SPEC §9, §10 "MPI"; docs/mpi.md).
// `isouq mesh` and `isouq run` under a launcher hand these to runGraph, which runs the same
// graph on every rank. Built only with MPI, into the executable only.
#pragma once

#include "isouq/nodes/Ranks.h"

#include <mpi.h>

#include <functional>
#include <memory>
#include <string>

namespace isouq::nodes {

/// True when a launcher started this process as one of several (or one) MPI ranks: Open MPI's
/// mpirun (OMPI_COMM_WORLD_SIZE), a PMIx or PMI launcher (PMIX_RANK, PMI_SIZE), or srun
/// (SLURM_STEP_NUM_TASKS > 1). Read from the environment, before MPI_Init.
bool launchedByMpiLauncher();

/// The error line when srun started this process without PMIx, as one of several tasks
/// (`--mpi=none`, Slurm's default) or with PMI-2 (`--mpi=pmi2`): Debian's Open MPI cannot start
/// then and would print a page of text instead. Empty otherwise (docs/mpi.md "Slurm").
std::string srunWithoutPmix();

/// The ranks of @a comm (the communicator is passed in, never global); @a interrupted says
/// whether a signal arrived on this rank.
std::unique_ptr<Ranks> mpiRanks(MPI_Comm comm, std::function<bool()> interrupted);

} // namespace isouq::nodes
