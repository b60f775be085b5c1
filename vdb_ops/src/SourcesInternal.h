// isouq (internal): what the volume sources share (VolumeSources.h; docs/inputs.md). Dense
// sources (raw scans, fields, formulas, and the scans with headers: NIfTI, NRRD, TIFF stacks,
// DICOM series) are read as z-slices through a SliceSource and made sparse by sparsify(); each
// source type lives in its own file.
#pragma once

#include "isouq/VolumeSources.h"

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>

namespace isouq::sources_internal {

using openvdb::Coord;

constexpr int kBlock = 8; // VDB leaf edge
constexpr int kHalo = 3;  // widest stencil reach beyond an edge (SPEC §2)

/// Shortest decimal text of @a v, for messages.
std::string fmt(double v);

/// A dense X*Y*Z array read slice by slice; out[x + X*(y + Y*(z - z0))].
class SliceSource {
public:
    virtual ~SliceSource() = default;
    virtual void read(int z0, int count, float* out) = 0;
    Coord dims;
};

/// The size of a regular, non-empty file. @throw InputError (missing, a directory, empty).
std::uint64_t fileSize(const std::string& path);

/// Case-insensitive suffix test (".vdb", ".RAW").
bool endsWith(const std::string& s, const std::string& suffix);

/// The data files a NRRD header names (`data file:`, patterns, LIST), relative names resolved
/// against the header's folder; none for attached data. @throw InputError on a bad pattern.
std::vector<std::string> nrrdDataFiles(const std::string& path);

/// Refuses @a source (INPUT @a input) before it is read when the memory its layers take while
/// streaming (Otsu, the sparsifier, the source's buffer) exceeds what is available (Memory.h):
/// a small header or compressed file can describe huge slices. @throw InputError.
void checkLayersFit(const SliceSource& source, const std::string& input);

/// Otsu's threshold of a dense source (two streaming passes: range, then histogram).
double otsuOfSource(SliceSource& source);
/// Otsu over the active values of a sparse grid (tiles weigh their voxel count).
double otsuOfGrid(const openvdb::FloatGrid& grid);

/// Sparsifies @a source at @a isovalue (KeepBlocks) into a grid with its data box, the
/// isovalue and the block counts; the caller sets the name, transform and description.
/// @throw InputError if the isovalue is not finite or gives no surface.
LoadedVolume buildDense(SliceSource& source, const VolumeRequest& request, float isovalue,
    openvdb::util::NullInterrupter* interrupter);

/// Sample types of the scan formats, decoded to float by decodeSamples (ScanSource.cc).
enum class SampleType { UInt8, Int8, UInt16, Int16, UInt32, Int32, UInt64, Int64, Float32, Float64 };
std::size_t sampleBytes(SampleType type);
const char* toString(SampleType type); ///< "uint8", "int16", "float32", ...

/// out[i] = slope * v_i + inter for @a n samples at @a bytes stored in the file's byte order
/// (@a bigEndian), in double, then rounded to float (NIfTI scl_slope/scl_inter, DICOM rescale).
void decodeSamples(const char* bytes, std::size_t n, SampleType type, bool bigEndian, double slope,
    double inter, float* out);

/// The largest dimension a dense source may have (OpenVDB's 32-bit index space, less a leaf).
constexpr std::uint64_t kMaxDim = std::numeric_limits<std::int32_t>::max() - kBlock;

/// A scan with a header (NIfTI, NRRD, TIFF, DICOM): the isovalue (given, else Otsu), the sparse
/// grid, its name and its index-to-world affine @a indexToWorld (row-major, column-vector
/// convention, as Mesh::indexToWorld: world = M (i, j, k, 1)). @a geometry says where the affine
/// came from ("sform", "space directions", ...); @a what is the description's start.
/// @throw InputError if the affine is not finite or singular, or as buildDense.
LoadedVolume loadScan(SliceSource& source, const VolumeRequest& request, const std::string& name,
    const std::array<double, 16>& indexToWorld, const std::string& geometry, const std::string& what,
    openvdb::util::NullInterrupter* interrupter);

/// Refuses the .raw-only flags for a scan that has its own header; @a spacing too unless the
/// format takes it from the command line (TIFF).
void rejectRawFlags(const VolumeRequest& request, const std::string& format, bool spacingAllowed);

LoadedVolume loadRaw(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // RawSource.cc
LoadedVolume loadNifti(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // NiftiSource.cc
LoadedVolume loadNrrd(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // NrrdSource.cc
LoadedVolume loadTiff(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // TiffSource.cc
/// A folder holding .tif/.tiff files (else a folder is read as a DICOM series).
bool isTiffFolder(const std::string& path);
LoadedVolume loadDicom(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // DicomSource.cc

LoadedVolume loadVdb(const VolumeRequest& request);                                                // VdbSource.cc
/// A field: or formula: input sampled at n^3 points (FieldSource.cc).
LoadedVolume loadField(std::shared_ptr<const AnalyticField> field, int n, const VolumeRequest& request,
    const std::string& defaultSource, openvdb::util::NullInterrupter* interrupter);

} // namespace isouq::sources_internal
