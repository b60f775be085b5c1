// isouq nodes (internal): what read_volume, mesh, summary, write_ply and write_vtp do on ranks (Ranks.h;
// SPEC §9, §10 "MPI"; docs/mpi.md). Each function is collective: every rank calls it.
#pragma once

#include "isouq/nodes/Node.h"

#include <isouq/Bricks.h>
#include <isouq/MeshTopology.h>
#include <isouq/VolumeSources.h>

namespace isouq::nodes::nodes_internal {

struct VolumeOnRanks {
    std::shared_ptr<LoadedVolume> volume;
    std::shared_ptr<const VolumePiece> piece;
    bool empty = false; ///< no rank holds an active voxel (VolumeRequest::allowEmpty): an empty mesh
};

/// loadVolume by pieces, the block order cut into one piece per rank: a .vdb with delayed
/// loading (topology in memory, leaf values in the file until touched), a scan (.raw, NIfTI,
/// NRRD, TIFF, DICOM), field: or formula: input by z-layers (loadDensePiece); then checkScalarVolume over the values of every
/// rank's own leaves joined (with the Otsu histograms of a fog volume without an isovalue).
/// @throw InputError as loadVolume and checkScalarVolume, on every rank.
VolumeOnRanks readVolumeOnRanks(const Ranks& ranks, VolumeRequest request, openvdb::util::NullInterrupter* interrupter);

/// This rank's piece of extractIsosurface(grid, settings) into @a mesh (BrickMesher): count
/// pass, prefix sums of the counts, the masks of + neighbours that later ranks own, fill pass.
std::shared_ptr<const MeshPiece> meshOnRanks(const Ranks& ranks, const openvdb::FloatGrid& grid,
    const VolumePiece& read, const MeshSettings& settings, Mesh& mesh, openvdb::util::NullInterrupter* interrupter);

/// Every rank's @a values together (a vertex column of a mesh by pieces): how many, how many
/// finite and, for each k of @a ks (each below that), the k-th smallest finite value (0-based)
/// as one process's sorted copy holds it: a radix select on the values' ordered bits, four
/// rounds of histograms summed over the ranks (-0 counts as 0). The colour map's percentiles.
struct ValuesOnRanks {
    std::uint64_t count = 0, finite = 0;
    std::vector<double> kth;
};
ValuesOnRanks orderStatisticsOnRanks(const Ranks& ranks, const std::vector<float>& values,
    const std::vector<std::uint64_t>& ks);

/// summarizeMesh of the whole mesh, on rank 0 (an empty object elsewhere): sums carried from
/// rank to rank in the one-process order (bit-equal), edges and components joined as
/// topologyOnRanks does.
nlohmann::json summarizeOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where);

/// measureTopology's boundary and non-manifold edges and components of the whole mesh, on rank
/// 0 (zeros elsewhere): each rank's own, joined over the vertices that triangles of two ranks
/// use (a rank's ghosts and the rows other ranks fetch from it). Any mesh by pieces (a
/// hidden-feature mesh's sections too).
MeshTopologyStats topologyOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where);

/// On rank 0, @a summary gets `ranks` (per rank: voxels_read, vertices, triangles, blocks,
/// weight and its @a timings) and `timings_ms`, the slowest rank's per entry.
void addRanksBlock(const Ranks& ranks, const MeshData& mesh, const nlohmann::json& timings, nlohmann::json& summary);

/// writePly of the whole mesh by every rank: rank 0 creates the temporary file and writes the
/// header, every rank its rows at the offsets of its piece (an ascii PLY's from the byte counts
/// of every rank's lines); rank 0's @a batch commits it.
void stagePlyOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where, const std::string& path,
    const PlyOptions& options, OutputBatch& batch);

/// writeVtp of the whole mesh by every rank, as stagePlyOnRanks: rank 0 writes the XML, the
/// blocks' byte counts and the closing tags, every rank its rows of each block.
void stageVtpOnRanks(const Ranks& ranks, const Mesh& piece, const MeshPiece& where, const std::string& path,
    const MeshFileOptions& options, OutputBatch& batch);

} // namespace isouq::nodes::nodes_internal
