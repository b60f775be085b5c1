// isouq: NRRD scans, `.nrrd` (attached) and `.nhdr` (detached, `data file:`), through teem
// (libteem; SPEC §10 "Formats"; docs/inputs.md). Every encoding teem reads (raw, gzip, bzip2,
// ascii, hex). World coordinates from `space directions` and `space origin` in the file's own
// `space`, else from `spacings` (1 where missing) and the origin 0.
#include "SourcesInternal.h"

#include <teem/nrrd.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>

namespace isouq::sources_internal {
namespace {

namespace fs = std::filesystem;

std::optional<SampleType> sampleTypeOf(int type)
{
    switch (type) {
    case nrrdTypeChar: return SampleType::Int8;
    case nrrdTypeUChar: return SampleType::UInt8;
    case nrrdTypeShort: return SampleType::Int16;
    case nrrdTypeUShort: return SampleType::UInt16;
    case nrrdTypeInt: return SampleType::Int32;
    case nrrdTypeUInt: return SampleType::UInt32;
    case nrrdTypeLLong: return SampleType::Int64;
    case nrrdTypeULLong: return SampleType::UInt64;
    case nrrdTypeFloat: return SampleType::Float32;
    case nrrdTypeDouble: return SampleType::Float64;
    default: return std::nullopt;
    }
}

struct NrrdNuke {
    void operator()(Nrrd* n) const { nrrdNuke(n); }
};
struct IoStateNix {
    void operator()(NrrdIoState* s) const { nrrdIoStateNix(s); }
};

/// teem's error text (biff, several lines) as one line.
std::string teemError()
{
    char* text = biffGetDone(NRRD);
    std::string s = text ? text : "unknown teem error";
    std::free(text);
    // biff stacks one "[nrrd] function: message" line per call level; the innermost says most.
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    const std::size_t last = s.rfind('\n');
    if (last != std::string::npos) s = s.substr(last + 1);
    if (s.rfind("[nrrd] ", 0) == 0) s = s.substr(7);
    return s;
}

/// The decoded samples (teem reads the whole data in the file's type, native byte order).
class NrrdSlices : public SliceSource {
public:
    NrrdSlices(const Nrrd& nrrd, SampleType type) : mData(static_cast<const char*>(nrrd.data)), mType(type)
    {
        dims = Coord(int(nrrd.axis[0].size), int(nrrd.axis[1].size), int(nrrd.axis[2].size));
    }
    void read(int z0, int count, float* out) override
    {
        const std::size_t slice = std::size_t(dims.x()) * dims.y();
        decodeSamples(mData + std::size_t(z0) * slice * sampleBytes(mType), slice * count, mType,
            __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__, 1.0, 0.0, out);
    }

private:
    const char* mData;
    SampleType mType;
};

} // namespace

LoadedVolume loadNrrd(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    const std::string& path = request.input;
    fileSize(path);
    rejectRawFlags(request, "NRRD", false);
    // The header first: refuse what isouq cannot mesh before teem allocates the data.
    std::unique_ptr<Nrrd, NrrdNuke> nrrd(nrrdNew());
    std::unique_ptr<NrrdIoState, IoStateNix> io(nrrdIoStateNew());
    nrrdIoStateSet(io.get(), nrrdIoStateSkipData, AIR_TRUE);
    if (nrrdLoad(nrrd.get(), path.c_str(), io.get()))
        throw InputError("'" + path + "' is not a readable NRRD file: " + teemError());
    const Nrrd& n = *nrrd;
    const std::optional<SampleType> type = sampleTypeOf(n.type);
    if (!type) {
        throw InputError("'" + path + "' has NRRD type " + airEnumStr(nrrdType, n.type)
            + "; isouq reads scalar volumes: int8, uint8, int16, uint16, int32, uint32, int64, uint64, float, double");
    }
    if (n.dim != 3) {
        throw InputError("'" + path + "' has dimension " + std::to_string(n.dim)
            + "; isouq meshes one 3-D scalar volume");
    }
    for (unsigned a = 0; a < 3; ++a) {
        if (n.axis[a].size < 1 || n.axis[a].size > kMaxDim) {
            throw InputError("'" + path + "' has " + std::to_string(n.axis[a].size) + " samples on axis "
                + std::to_string(a) + ": each must be 1.." + std::to_string(kMaxDim));
        }
    }

    std::array<double, 16> affine{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    std::string geometry;
    if (n.spaceDim == 3) {
        for (unsigned a = 0; a < 3; ++a)
            for (int r = 0; r < 3; ++r) affine[4 * r + a] = n.axis[a].spaceDirection[r];
        for (int r = 0; r < 3; ++r) affine[4 * r + 3] = std::isnan(n.spaceOrigin[r]) ? 0.0 : n.spaceOrigin[r];
        geometry = "NRRD space directions";
        if (n.space != nrrdSpaceUnknown) geometry += std::string(" (") + airEnumStr(nrrdSpace, n.space) + ")";
    } else if (n.spaceDim != 0) {
        throw InputError("'" + path + "' has a " + std::to_string(n.spaceDim)
            + "-D space; isouq places a 3-D volume in a 3-D space");
    } else {
        for (unsigned a = 0; a < 3; ++a) affine[5 * a] = std::isnan(n.axis[a].spacing) ? 1.0 : n.axis[a].spacing;
        geometry = "NRRD spacings";
    }

    nrrd.reset(nrrdNew());
    if (nrrdLoad(nrrd.get(), path.c_str(), nullptr))
        throw InputError("cannot read the data of '" + path + "': " + teemError());
    NrrdSlices source(*nrrd, *type);
    const std::string name = fs::path(path).stem().string();
    const std::string what = fs::path(path).filename().string() + ": NRRD " + toString(*type) + " ("
        + (io->encoding ? io->encoding->name : "raw") + ")";
    return loadScan(source, request, name, affine, geometry, what, interrupter);
}

} // namespace isouq::sources_internal
