// isouq: turning the user's INPUT into a FloatGrid (SPEC §5, §8; docs/inputs.md).
//
// INPUT is one of `path.vdb`, `path.raw` (Open SciVis name `name_XxYxZ_dtype.raw`), a scan
// with a header (`.nii`, `.nii.gz`, `.nrrd`, `.nhdr`, a TIFF stack `.tif`/`.tiff` or a folder
// of numbered TIFF slices, a folder of one DICOM series; SPEC §10 "Formats"), `field:NAME`
// (AnalyticFields.h) or `formula:EXPR` (muParser, variables x y z). Dense sources (raw, scans,
// field, formula) are streamed in slabs of 8 z-slices and made sparse on the way: an 8^3
// block becomes an active leaf only where the surface can be (KeepBlocks), the rest inactive
// tiles, so the grid's memory follows the surface, not the bounding box. Dense grids carry the
// data box as grid metadata (GridMetadata.h). A host holding a volume in memory (the Python
// module: a numpy array or a pyopenvdb grid) registers it as INPUT `memory:N` (MemoryVolume).
#pragma once

#include "isouq/AnalyticFields.h"
#include "isouq/Errors.h"

#include <openvdb/openvdb.h>
#include <openvdb/util/NullInterrupter.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace isouq {

/// Which 8^3 blocks of a dense source become active leaves; the others become inactive
/// leaf-level tiles holding a value on the same side of the isovalue as the block.
enum class KeepBlocks {
    /// The block dilated by 3 voxels has values >= k and values < k: every crossing edge and
    /// every stencil voxel of it (SPEC §2, 3 voxels) is in a leaf, so meshes equal dense ones.
    Crossing,
    /// Crossing, or k within the tricubic interpolant's reach over the dilated block (Lebesgue
    /// bound), so hidden-feature refinement (SPEC §4) also equals the dense result.
    CrossingOrHidden,
    /// Every block whose dilation is not constant: identical meshes at every isovalue.
    NonConstant,
    /// Every block (dense; for comparisons).
    All,
};

/// What the user asked for; CLI flags map 1:1.
struct VolumeRequest {
    std::string input;                        ///< path.vdb | path.raw | scan | field:NAME | formula:EXPR
    std::string gridName;                     ///< --grid (vdb)
    std::optional<openvdb::Vec3i> dims;       ///< --dims X,Y,Z (raw)
    std::string dtype;                        ///< --dtype (raw): uint8 uint16 int16 float32 float64
    std::optional<openvdb::Vec3d> spacing;    ///< --spacing (raw and TIFF, default 1,1,1 or the TIFF's)
    std::optional<int> resolution;            ///< --resolution N (field default: the paper's; formula 64)
    std::optional<std::pair<double, double>> domain; ///< --domain LO,HI (formula, default -1,1)
    std::optional<float> isovalue;            ///< --isovalue
    KeepBlocks keep = KeepBlocks::Crossing;   ///< dense sources only
    /// .vdb: leave the leaf buffers in the file until they are touched (OpenVDB's delayed
    /// loading), and a fog volume's default isovalue to the caller (isovalue NaN): an MPI rank
    /// reads only its pieces and their halo (SPEC §10 "MPI"; docs/mpi.md). The file is mapped
    /// as it is, without OpenVDB's private copy of files under 500 MB (which made every rank
    /// copy the whole file first): it must not change while isouq reads it.
    bool delayLoad = false;
    /// .vdb: a named grid that is absent gives an empty grid instead of an error (a frame of a
    /// simulation cache where the grid is empty; SPEC §10 "Sequences").
    bool allowEmpty = false;
};

struct LoadedVolume {
    std::string input;          ///< the request's INPUT
    openvdb::FloatGrid::Ptr grid;
    float isovalue = 0.0f;      ///< the one to use: given, or the default (SPEC §8)
    std::string isovalueSource; ///< "given", "level set", "SPEC §5 default", "formula default",
                                ///< "Otsu (starting value)"
    std::string description;    ///< one line for the summary / progress
    /// Where the grid's index-to-world map comes from for scans with a header ("NIfTI sform",
    /// "NRRD space directions", "DICOM image position and orientation", ...); else empty.
    std::string geometry;
    /// The exact field for field: and formula: inputs (world coordinates), else null.
    std::shared_ptr<const AnalyticField> truth;
    /// Dense sources: 8^3 blocks covering the data, and those kept as leaves.
    std::size_t denseBlocks = 0, keptBlocks = 0;
};

/// A volume a host holds in memory, read by loadVolume through the INPUT its
/// ScopedMemoryVolume names (`memory:N`), so in-memory volumes run the same graph as files.
struct MemoryVolume {
    std::string name; ///< the grid's name and the description's start, e.g. "numpy uint8 array"
    /// A sparse grid used as is (shared, neither copied nor densified), as a .vdb grid is.
    openvdb::FloatGrid::Ptr grid;
    /// Else a dense X*Y*Z array, sparsified as a .raw scan is (same slabs, KeepBlocks, Otsu):
    /// readSlices(z0, count, out) fills out[x + X*(y + Y*(z - z0))] for z in [z0, z0 + count),
    /// called from the loading thread only; index (0,0,0) sits at @a origin, voxels are
    /// @a spacing apart (world = origin + spacing * index).
    openvdb::Coord dims;
    std::function<void(int z0, int count, float* out)> readSlices;
    openvdb::Vec3d spacing{1.0}, origin{0.0};
};

/// Registers a MemoryVolume for as long as this object lives; input() is its INPUT.
class ScopedMemoryVolume {
public:
    explicit ScopedMemoryVolume(std::shared_ptr<const MemoryVolume> volume);
    ~ScopedMemoryVolume();
    ScopedMemoryVolume(const ScopedMemoryVolume&) = delete;
    ScopedMemoryVolume& operator=(const ScopedMemoryVolume&) = delete;
    const std::string& input() const { return mInput; }

private:
    std::string mInput;
};

/// Loads @a request.input as a FloatGrid and decides the isovalue before sparsifying.
/// @throw InputError with one line (missing/empty/truncated file, wrong grid type, raw size
///        mismatch, unknown field, bad or non-finite formula, isovalue giving no surface).
/// @throw InterruptedError when @a interrupter asks to stop.
LoadedVolume loadVolume(const VolumeRequest& request,
    openvdb::util::NullInterrupter* interrupter = nullptr);

/// Drops this process's resident pages of its read-only shared mappings of @a path, such as the
/// one delayed loading makes (VolumeRequest::delayLoad): the leaves loaded so far hold copies
/// of their values, so a rank's memory is its leaves, not also the file's pages it read them
/// from. A leaf loaded later faults its pages in again (from the page cache); nothing else
/// changes. Linux; elsewhere nothing.
void releaseMappedPages(const std::string& path);

class BrickPlan;  // Bricks.h
class PieceComm; // Bricks.h

/// This piece's share of a dense source read by several processes (SPEC §9, §10 "MPI";
/// docs/mpi.md), the same as loadVolume's grid where this piece meshes.
struct DensePiece {
    /// The grid this piece meshes: the leaves and tiles of its blocks of the plan and of the
    /// blocks around them (the stencils' halo), as loadVolume makes them; elsewhere empty.
    LoadedVolume volume;
    std::shared_ptr<const BrickPlan> plan; ///< the whole volume's blocks cut into the pieces
    std::uint64_t voxelsRead = 0;          ///< samples this piece read from the file or computed
};

/// loadVolume of a dense source read by z-layers, a scan (.raw, NIfTI, NRRD, TIFF, DICOM) or a
/// field: or formula: input, by pieces (collective over @a comm): piece p reads (a raw scan,
/// with positioned reads) or samples (a field) its z-layers of 8 slices, [L p / P, L (p + 1) / P)
/// of the L layers, and the 3 slices around them, and sparsifies them; a scan's Otsu statistics, the ranges and
/// the block counts are joined, the topology of every piece's leaves gives the plan, and the
/// leaves and tiles around this piece's blocks come from the pieces that made them.
/// @throw InputError as loadVolume, on every piece, and for an INPUT isDensePieceInput refuses.
DensePiece loadDensePiece(const VolumeRequest& request, const PieceComm& comm,
    openvdb::util::NullInterrupter* interrupter = nullptr);

/// Whether loadDensePiece reads @a input: a scan, field:NAME or formula:EXPR.
bool isDensePieceInput(const std::string& input);

/// A muParser field f(x, y, z) on [lo, hi]^3, default isovalue 0; thread safe (one parser per
/// thread). @throw InputError naming the position of a parse error.
std::shared_ptr<const AnalyticField> makeFormulaField(const std::string& expression,
    double lo, double hi);

/// The files that loadVolume(@a input) reads besides @a input itself, so that no output may
/// replace one (SPEC §10 "Errors"): a NRRD header's data files (`data file:`, its patterns and
/// LIST), every regular file of a folder input (TIFF slices, a DICOM series). Best effort: an
/// unreadable input gives what could be found, never an error.
std::vector<std::string> volumeInputFiles(const std::string& input);

/// Otsu's threshold of a 256-bin histogram over [lo, hi] (bin b covers
/// [lo + b w, lo + (b+1) w), w = (hi - lo) / 256): the centre of the last bin of the lower
/// class, as scikit-image's threshold_otsu. A starting value, not a documented isovalue.
double otsuThreshold(const std::array<std::uint64_t, 256>& histogram, double lo, double hi);

/// The 256-bin histogram over [lo, hi] of the finite active values of @a grid's leaves whose
/// origin @a leaves accepts (all when empty), and of its active tiles (weighing their voxel
/// count) when @a tiles is true. Histograms of disjoint parts add up to the whole's.
std::array<std::uint64_t, 256> activeValueHistogram(const openvdb::FloatGrid& grid, double lo, double hi,
    const std::function<bool(const openvdb::Coord&)>& leaves = {}, bool tiles = true);

/// A sparse grid's default isovalue (SPEC §8) from the finite range [lo, hi] of its active
/// values and their activeValueHistogram: Otsu's threshold, or halfway to the background when
/// every active value is the same. @throw InputError for a constant grid.
double otsuOfActiveValues(const openvdb::FloatGrid& grid, double lo, double hi,
    const std::array<std::uint64_t, 256>& histogram);

} // namespace isouq
