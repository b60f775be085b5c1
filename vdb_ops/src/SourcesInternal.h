// isouq (internal): what the volume sources share (VolumeSources.h; docs/inputs.md). Dense
// sources (raw scans, fields, formulas) are read as z-slices through a SliceSource and made
// sparse by sparsify(); each source type lives in its own file.
#pragma once

#include "isouq/VolumeSources.h"

#include <openvdb/openvdb.h>

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

/// Otsu's threshold of a dense source (two streaming passes: range, then histogram).
double otsuOfSource(SliceSource& source);
/// Otsu over the active values of a sparse grid (tiles weigh their voxel count).
double otsuOfGrid(const openvdb::FloatGrid& grid);

/// Sparsifies @a source at @a isovalue (KeepBlocks) into a grid with its data box, the
/// isovalue and the block counts; the caller sets the name, transform and description.
/// @throw InputError if the isovalue is not finite or gives no surface.
LoadedVolume buildDense(SliceSource& source, const VolumeRequest& request, float isovalue,
    openvdb::util::NullInterrupter* interrupter);

LoadedVolume loadRaw(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter); // RawSource.cc
LoadedVolume loadVdb(const VolumeRequest& request);                                                // VdbSource.cc
/// A field: or formula: input sampled at n^3 points (FieldSource.cc).
LoadedVolume loadField(std::shared_ptr<const AnalyticField> field, int n, const VolumeRequest& request,
    const std::string& defaultSource, openvdb::util::NullInterrupter* interrupter);

} // namespace isouq::sources_internal
