// isouq (internal): what the volume sources share (VolumeSources.h; docs/inputs.md). Dense
// sources (raw scans, fields, formulas, and the scans with headers: NIfTI, NRRD, TIFF stacks,
// DICOM series) are read as z-slices through a SliceSource and made sparse by sparsify(); each
// source type lives in its own file.
#pragma once

#include "isouq/VolumeSources.h"

#include <openvdb/openvdb.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace isouq::sources_internal {

using openvdb::Coord;

constexpr int kBlock = 8; // VDB leaf edge
constexpr int kHalo = 3;  // widest stencil reach beyond an edge (SPEC §2)

/// Shortest decimal text of @a v, for messages.
std::string fmt(double v);

class RawSlabReader;

/// A dense X*Y*Z array read slice by slice; out[x + X*(y + Y*(z - z0))].
class SliceSource {
public:
    virtual ~SliceSource() = default;
    virtual void read(int z0, int count, float* out) = 0;
    /// The samples as a raw scan's array in the file, where they are stored as one
    /// (uncompressed, in this machine's byte order, unscaled, a type RawSlabReader reads):
    /// then loadScan reads them as a raw scan, in parallel. Else nullptr.
    virtual const RawSlabReader* rawArray() const { return nullptr; }
    Coord dims;
};

/// The size of a regular, non-empty file. @throw InputError (missing, a directory, empty).
std::uint64_t fileSize(const std::string& path);

/// What a reader library printed (at most kPrintedChars of it) as one short line: control
/// characters as blanks, trimmed at both ends. Inline: the GDCM module (GdcmServer.cc) has its
/// own copy, as no host exports the library's internals to it.
constexpr std::size_t kPrintedChars = 400;
inline std::string printedLine(std::string_view raw)
{
    std::string text;
    for (const char c : raw.substr(0, kPrintedChars)) text += std::iscntrl(static_cast<unsigned char>(c)) ? ' ' : c;
    const std::size_t first = text.find_first_not_of(' ');
    return first == std::string::npos ? std::string() : text.substr(first, text.find_last_not_of(' ') - first + 1);
}

/// Some reader libraries print to the standard error stream whatever they are told (nifticlib's
/// "** ERROR: ...", libjpeg's messages from GDCM's trial decoders), which would make a second
/// error line (SPEC §8). While one lives, file descriptor 2 goes to a temporary file (one at a
/// time: the descriptor is the process's); release() gives back stderr and what was printed.
class StderrCapture {
public:
    StderrCapture();
    ~StderrCapture() { release(); }
    StderrCapture(const StderrCapture&) = delete;
    StderrCapture& operator=(const StderrCapture&) = delete;

    /// Stderr back; what was printed meanwhile (printedLine).
    std::string release();

private:
    void restore();
    std::unique_lock<std::mutex> mLock;
    std::FILE* mFile = nullptr;
    int mSaved = -1;
    std::string mText;
};

/// Case-insensitive suffix test (".vdb", ".RAW").
bool endsWith(const std::string& s, const std::string& suffix);

/// Finite values seen: [min, max] (empty while min > max).
struct Range {
    double min = std::numeric_limits<double>::infinity();
    double max = -std::numeric_limits<double>::infinity();
    void add(double v) { min = std::min(min, v); max = std::max(max, v); }
    void add(const Range& r) { min = std::min(min, r.min); max = std::max(max, r.max); }
};

/// Bin of @a v in Otsu's 256-bin histogram over [lo, hi].
int histogramBin(double v, double lo, double hi);

/// The data files a NRRD header names (`data file:`, patterns, LIST), relative names resolved
/// against the header's folder; none for attached data. @throw InputError on a bad pattern.
std::vector<std::string> nrrdDataFiles(const std::string& path);

/// Refuses @a source (INPUT @a input) before it is read when the memory its layers take while
/// streaming (Otsu, the sparsifier, the source's buffer) exceeds what is available (Memory.h):
/// a small header or compressed file can describe huge slices. @throw InputError.
void checkLayersFit(const SliceSource& source, const std::string& input);

/// The finite range of the slices [z0, z1) of @a source, and with @a histogramRange their
/// 256-bin histogram over that range (histogramBin). Parts of a volume add up, so pieces can
/// join theirs (loadScanPiece).
struct SourceStats {
    Range range;
    std::array<std::uint64_t, 256> histogram{};
};
SourceStats sourceStats(SliceSource& source, int z0, int z1, const Range* histogramRange = nullptr,
    openvdb::util::NullInterrupter* interrupter = nullptr);
/// InputError when a volume's finite @a range gives no default isovalue (no finite value, constant data).
void checkOtsuRange(const Range& range);
/// Otsu's threshold of a dense source (two streaming passes: range, then histogram).
double otsuOfSource(SliceSource& source, openvdb::util::NullInterrupter* interrupter = nullptr);
/// Otsu over the active values of a sparse grid (tiles weigh their voxel count).
double otsuOfGrid(const openvdb::FloatGrid& grid);

/// Sparsifies @a source at @a isovalue (KeepBlocks) into a grid with its data box, the
/// isovalue and the block counts; the caller sets the name, transform and description.
/// @throw InputError if the isovalue is not finite or gives no surface.
LoadedVolume buildDense(SliceSource& source, const VolumeRequest& request, float isovalue,
    openvdb::util::NullInterrupter* interrupter);

/// A dense source as every slice reader loads it: checkLayersFit, the given isovalue or Otsu's
/// starting value (isovalueSource says which), then buildDense.
LoadedVolume loadDense(SliceSource& source, const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter);

/// A dense volume made sparse (docs/inputs.md "Sparse conversion"): kept blocks are active
/// leaves, the others inactive tiles; @a range spans the finite values of the blocks' own voxels.
struct SparseResult {
    openvdb::FloatTree::Ptr tree;
    Range range;
    std::size_t blocks = 0, kept = 0;
};

/// Sparsifies the block layers [layer0, layer1) of @a source (slices 8 layer0 to 8 layer1, with
/// kHalo slices read on either side; all layers when @a layer1 < 0) at @a k, as buildDense does.
SparseResult sparsify(SliceSource& source, KeepBlocks rule, double k, openvdb::util::NullInterrupter* interrupter,
    int layer0 = 0, int layer1 = -1);

/// buildDense's checks and grid for a SparseResult of a whole @a dims volume.
LoadedVolume denseVolume(SparseResult&& sparse, const Coord& dims, float isovalue);

/// Sample types of the scan formats, decoded to float by decodeSamples (ScanSource.cc).
enum class SampleType { UInt8, Int8, UInt16, Int16, UInt32, Int32, UInt64, Int64, Float32, Float64 };
std::size_t sampleBytes(SampleType type);
const char* toString(SampleType type); ///< "uint8", "int16", "float32", ...

/// out[i] = slope * v_i + inter for @a n samples at @a bytes stored in the file's byte order
/// (@a bigEndian), in double, then rounded to float (NIfTI scl_slope/scl_inter, DICOM rescale).
void decodeSamples(const char* bytes, std::size_t n, SampleType type, bool bigEndian, double slope,
    double inter, float* out);

/// A raw array (x fastest, little-endian samples) from byte @a offset of a file (a headerless
/// raw scan; the data of a NIfTI or NRRD file) read by z-slabs with positioned reads (pread):
/// no shared file position, so any thread, or any MPI rank, reads any slabs at any time
/// (RawSource.cc). Types: UInt8, UInt16, Int16, Float32, Float64 (isRawArrayType).
class RawSlabReader {
public:
    /// @throw InputError if the file cannot be opened.
    RawSlabReader(const std::string& path, const Coord& dims, SampleType type, std::uint64_t offset = 0);
    ~RawSlabReader();
    RawSlabReader(const RawSlabReader&) = delete;
    RawSlabReader& operator=(const RawSlabReader&) = delete;

    const Coord& dims() const { return mDims; }
    SampleType type() const { return mType; }
    /// The file byte where slice @a z starts (to place a SlabBuffer).
    std::uint64_t sliceOffset(int z) const;
    /// Reads the slices [z0, z1) as stored, (z1 - z0) X Y samples, into @a out (best placed by
    /// a SlabBuffer: FreshPages.h).
    /// @throw InputError on a short read (the file changed) or a read error.
    void readSlices(int z0, int z1, char* out) const;

private:
    std::string mPath;
    Coord mDims;
    SampleType mType;
    std::uint64_t mOffset;
    int mFd = -1;
};

/// Whether RawSlabReader reads samples of @a type.
inline bool isRawArrayType(SampleType type)
{
    return type == SampleType::UInt8 || type == SampleType::UInt16 || type == SampleType::Int16
        || type == SampleType::Float32 || type == SampleType::Float64;
}

/// A raw array's isovalue (given, else Otsu's starting value) and sparse volume, in parallel,
/// unnamed (loadRaw; loadScan of a SliceSource::rawArray).
LoadedVolume loadRawArray(const RawSlabReader& reader, const VolumeRequest& request,
    openvdb::util::NullInterrupter* interrupter);

/// checkLayersFit for a raw scan, which @a workers sparsifiers read at once (sparsifyRaw: one
/// per thread in use, threadsInUse(), which counts -j).
void checkLayersFit(const RawSlabReader& reader, int workers, const std::string& input);

/// What Otsu's threshold needs from the slices [z0, z1) of a raw scan; parts of a volume add up
/// (add()), so MPI ranks can reduce theirs. 8- and 16-bit samples: one pass counting each value
/// (counts[v - lowest value of the type]) gives the range and the histogram. Floating point: a
/// first call (no @a histogramRange) gives the finite range, a second one the 256-bin histogram
/// over the whole volume's range.
struct RawStats {
    Range range;
    std::vector<std::uint64_t> counts;
    void add(const RawStats& other);
};
RawStats rawStats(const RawSlabReader& reader, int z0, int z1, const Range* histogramRange = nullptr,
    openvdb::util::NullInterrupter* interrupter = nullptr);
/// Otsu's threshold from a whole volume's RawStats (with counts), as otsuOfSource.
/// @throw InputError for constant data.
double otsuOfRawStats(const RawStats& stats, SampleType type);

/// Sparsifies the block layers [layer0, layer1) of a raw scan (slices 8 layer0 to 8 layer1,
/// with kHalo slices read on either side) at @a isovalue, as buildDense does a SliceSource,
/// in parallel over runs of layers; each run streams its slices through a window of 14.
SparseResult sparsifyRaw(const RawSlabReader& reader, int layer0, int layer1, KeepBlocks rule, double isovalue,
    openvdb::util::NullInterrupter* interrupter);

/// The largest dimension a dense source may have (OpenVDB's 32-bit index space, less a leaf).
constexpr std::uint64_t kMaxDim = std::numeric_limits<std::int32_t>::max() - kBlock;

/// What a scan's header (NIfTI, NRRD, TIFF, DICOM) says besides its slices: the grid's
/// name, the index-to-world affine (row-major, column-vector convention, as
/// Mesh::indexToWorld: world = M (i, j, k, 1)), where that came from ("sform", "space
/// directions", ...) and the description's start.
struct ScanHeader {
    std::string name;
    std::array<double, 16> indexToWorld{};
    std::string geometry, what;
};

/// A scan's slices: the isovalue (given, else Otsu), the sparse grid with the header's name
/// and affine. @throw InputError if the affine is not finite or singular, or as buildDense.
LoadedVolume loadScan(SliceSource& source, const VolumeRequest& request, const ScanHeader& header,
    openvdb::util::NullInterrupter* interrupter);

/// What a scan reader hands its slices and header to: loadScan in one process (the piece is
/// the whole volume), loadScanPiece by pieces.
using ScanLoader = std::function<DensePiece(SliceSource&, const ScanHeader&)>;
/// Reads a scan's header, opens its slices and returns @a load of them (NiftiSource.cc, ...).
using ScanReader = DensePiece (*)(const VolumeRequest&, openvdb::util::NullInterrupter*, const ScanLoader&);
/// The reader of the scan with a header that @a input names (by its suffix; a folder of TIFF
/// slices or of a DICOM series), nullptr for other inputs.
ScanReader scanReaderOf(const std::string& input);

/// Refuses the .raw-only flags for a scan that has its own header; @a spacing too unless the
/// format takes it from the command line (TIFF).
void rejectRawFlags(const VolumeRequest& request, const std::string& format, bool spacingAllowed);

LoadedVolume loadRaw(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // RawSource.cc
DensePiece readNifti(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter, const ScanLoader& load); // NiftiSource.cc
DensePiece readNrrd(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter, const ScanLoader& load); // NrrdSource.cc
DensePiece readTiff(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter, const ScanLoader& load); // TiffSource.cc
/// A folder holding .tif/.tiff files (else a folder is read as a DICOM series).
bool isTiffFolder(const std::string& path);
DensePiece readDicom(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter, const ScanLoader& load); // DicomSource.cc

LoadedVolume loadVdb(const VolumeRequest& request);                                                // VdbSource.cc
/// The isovalue (given, 0 for a level set, else Otsu) and description of a sparse @a grid
/// read from @a what (a file name, a host's name); shared by .vdb and in-memory grids.
LoadedVolume sparseVolume(openvdb::FloatGrid::Ptr grid, const VolumeRequest& request, const std::string& what);
/// A `memory:N` input (MemorySource.cc).
LoadedVolume loadMemory(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter);
/// A field: or formula: INPUT: the field, its samples per axis and where its default isovalue
/// comes from (FieldSource.cc).
struct FieldInput {
    std::shared_ptr<const AnalyticField> field;
    int n = 0;
    std::string defaultSource; ///< "SPEC §5 default", "formula default"
};
/// The field that @a request.input names, std::nullopt when it is neither field: nor formula:.
/// @throw InputError for an unknown field, a formula that does not parse, a bad resolution.
std::optional<FieldInput> fieldInput(const VolumeRequest& request);
/// @a input sampled at n^3 points.
LoadedVolume loadField(const FieldInput& input, const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter);

// ---- By pieces (SPEC §9, §10 "MPI"; docs/mpi.md; loadDensePiece) --------------------------

/// The first block layer of piece @a piece of @a pieces in a volume of @a layers layers of 8
/// z-slices: piece p reads the layers [L p / P, L (p + 1) / P).
inline int firstLayerOf(int layers, int piece, int pieces) { return int(std::int64_t(layers) * piece / pieces); }

/// The rest of loadDensePiece once each piece has sparsified its layers (firstLayerOf) into
/// @a sparse: the whole volume's range and block counts are joined, the topology of every
/// piece's leaves gives the plan, and the leaves and tiles of this piece's blocks and of the
/// blocks one block around them come from the pieces that made them (RawSource.cc). The
/// caller names the volume (name, transform, description).
/// @throw InputError as denseVolume, on every piece.
DensePiece spreadLayers(SparseResult&& sparse, const Coord& dims, float isovalue, const PieceComm& comm);

/// loadScan by pieces: Otsu's statistics of each piece's slices joined in piece order, then
/// as a raw scan (ScanSource.cc). A gzip stream cannot seek: each piece decompresses it from
/// the start to its last slice.
DensePiece loadScanPiece(SliceSource& source, const VolumeRequest& request, const ScanHeader& header,
    const PieceComm& comm, openvdb::util::NullInterrupter* interrupter);

/// loadRawArray by pieces.
DensePiece loadRawArrayPiece(const RawSlabReader& reader, const VolumeRequest& request, const PieceComm& comm,
    openvdb::util::NullInterrupter* interrupter);
/// loadRaw and loadField by pieces.
DensePiece loadRawPiece(const VolumeRequest& request, const PieceComm& comm, openvdb::util::NullInterrupter* interrupter);
DensePiece loadFieldPiece(const FieldInput& input, const VolumeRequest& request, const PieceComm& comm,
    openvdb::util::NullInterrupter* interrupter);

} // namespace isouq::sources_internal
