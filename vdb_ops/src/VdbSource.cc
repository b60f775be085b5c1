// isouq: .vdb inputs: the first float grid or --grid NAME, read after a bounded walk of the
// file layout (SPEC §8; docs/inputs.md).
#include "SourcesInternal.h"

#include <openvdb/io/DelayedLoadMetadata.h>
#include <openvdb/io/File.h>

#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>

#include <cctype>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <set>

namespace isouq {
namespace sources_internal {

namespace fs = std::filesystem;

// VDB files: OpenVDB 10 neither checks lengths nor offsets against the file size (a truncated
// header can crash it, a truncated grid reads silently as a partial one), so the header and
// grid descriptors are walked first with bounded reads and every grid's end checked.
class BoundedReader {
public:
    BoundedReader(std::ifstream& in, std::uint64_t size, const std::string& path)
        : mIn(in), mSize(size), mPath(path) {}

    template <typename T>
    T pod()
    {
        T value;
        bytes(reinterpret_cast<char*>(&value), sizeof(T));
        return value;
    }
    std::string string()
    {
        const std::uint32_t length = pod<std::uint32_t>();
        need(length);
        std::string s(length, '\0');
        bytes(s.data(), length);
        return s;
    }
    void skip(std::uint64_t n) { need(n); seek(mPos + n); }
    std::uint64_t position() const { return mPos; }
    std::uint64_t size() const { return mSize; }
    void seek(std::uint64_t pos)
    {
        mPos = pos;
        mIn.seekg(std::streamoff(pos));
    }
    void fail(const std::string& what) const
    {
        throw InputError("'" + mPath + "' is truncated or corrupt: " + what + " (file has "
            + std::to_string(mSize) + " bytes)");
    }

private:
    void need(std::uint64_t n) const { if (n > mSize - mPos) fail("header runs past the end"); }
    void bytes(char* out, std::uint64_t n)
    {
        need(n);
        mIn.read(out, std::streamsize(n));
        mPos += n;
    }
    std::ifstream& mIn;
    std::uint64_t mSize, mPos = 0;
    const std::string& mPath;
};

/// The metadata types OpenVDB reads as sizeof(T) bytes whatever the file says (TypedMetadata of
/// a number, vector or matrix). Strings and the others (__delayedload, ...) read what they announce.
bool fixedSizeMetadata(const std::string& type)
{
    using namespace openvdb;
    static const std::set<std::string> sFixed = {BoolMetadata::staticTypeName(),
        Int32Metadata::staticTypeName(), Int64Metadata::staticTypeName(), FloatMetadata::staticTypeName(),
        DoubleMetadata::staticTypeName(), Vec2IMetadata::staticTypeName(), Vec2SMetadata::staticTypeName(),
        Vec2DMetadata::staticTypeName(), Vec3IMetadata::staticTypeName(), Vec3SMetadata::staticTypeName(),
        Vec3DMetadata::staticTypeName(), Vec4IMetadata::staticTypeName(), Vec4SMetadata::staticTypeName(),
        Vec4DMetadata::staticTypeName(), Mat4SMetadata::staticTypeName(), Mat4DMetadata::staticTypeName()};
    return sFixed.count(type) != 0;
}

/// OpenVDB's delayed-load table (DelayedLoadMetadata::readValue, written into every grid by
/// OpenVDB 10): a leaf count; the per-leaf masks as a byte count and that many blosc bytes, or 0
/// and one raw byte per leaf; the per-leaf compressed sizes the same way (8 raw bytes per leaf),
/// or 0xffffffff for none; bytes after these are skipped. OpenVDB allocates the arrays, the
/// buffers and the blosc header's uncompressed size unchecked, and blosc reads as many bytes as
/// its header says (a 12 KB file asked for 4 GiB, found by fuzz_vdb). So: the parts fit the
/// announced size, each blosc part holds its 16-byte header, which says the part's own sizes
/// (or OpenVDB's padding), and the leaves fit the file (each stores at least its 64-byte value mask).
void walkDelayedLoad(BoundedReader& r, std::uint32_t bytes)
{
    const std::uint64_t end = r.position() + bytes;
    const auto fail = [&](const std::string& what) {
        r.fail("the delayed-load table (" + std::to_string(bytes) + " bytes) " + what);
    };
    const std::uint32_t leaves = r.pod<std::uint32_t>();
    if (std::uint64_t(leaves) * 64 > r.size()) fail("has " + std::to_string(leaves) + " leaves");
    for (const std::uint64_t elementBytes : {1u, 8u}) {
        const std::uint32_t n = r.pod<std::uint32_t>();
        if (elementBytes == 8 && n == 0xffffffffu) break; // no compressed sizes
        const std::uint64_t raw = leaves * elementBytes, stored = n ? n : raw;
        if (r.position() + stored > end) fail("runs past its end");
        if (n) {
            if (n < 16) fail("holds a blosc part without its header");
            r.pod<std::uint32_t>(); // versions, flags, type size
            const std::uint32_t uncompressed = r.pod<std::uint32_t>();
            r.pod<std::uint32_t>(); // block size
            const std::uint32_t compressed = r.pod<std::uint32_t>();
            // OpenVDB pads a part shorter than 128 bytes to 128 before blosc (StreamCompression.cc).
            const bool padded = raw < 128 && uncompressed == 128;
            if ((uncompressed != raw && !padded) || compressed > n) fail("holds a blosc part of other sizes than its own");
            r.skip(n - 16);
        } else {
            r.skip(raw);
        }
    }
    if (r.position() > end) fail("runs past its end");
    r.seek(end);
}

/// A transform as Transform::read reads it (file versions 219 on): the map's type name, then the
/// map's own fixed-size numbers (math/Maps.h read()); a frustum holds its bounding box, taper,
/// depth and a second (affine) map. An unknown type would make OpenVDB throw; a wrong length
/// would shift everything after it.
void walkTransform(BoundedReader& r, std::uint32_t version, bool nested = false)
{
    using namespace openvdb::math;
    static const std::map<std::string, std::uint64_t> sMapBytes = {
        {AffineMap::mapType(), 16 * 8}, {UnitaryMap::mapType(), 16 * 8},
        {ScaleMap::mapType(), 5 * 24}, {UniformScaleMap::mapType(), 5 * 24},
        {ScaleTranslateMap::mapType(), 6 * 24}, {UniformScaleTranslateMap::mapType(), 6 * 24},
        {TranslationMap::mapType(), 24}};
    const std::string type = r.string();
    if (type == NonlinearFrustumMap::mapType() && !nested) {
        r.skip(version < openvdb::OPENVDB_FILE_VERSION_FLOAT_FRUSTUM_BBOX ? 6 * 4 : 6 * 8); // bbox
        r.skip(2 * 8);                                                                       // taper, depth
        walkTransform(r, version, true);
        return;
    }
    const auto bytes = sMapBytes.find(type);
    if (bytes == sMapBytes.end()) r.fail("unknown transform '" + type.substr(0, 64) + "'");
    r.skip(bytes->second);
}

/// The start of a float or double tree (Tree::readTopology, RootNode::readTopology): its buffer
/// count, the background, then tile and child counts. OpenVDB allocates each root child (a
/// 270 KB node) before reading it, whatever is left of the file, and only warns about a buffer
/// count other than 1 and reads on (a 13 KB file took 42 s and 4.5 GB, found by fuzz_vdb). Each
/// tile takes its origin, value and active byte; each child its origin and two 4096-byte masks.
void walkRootTopology(BoundedReader& r, std::uint64_t valueBytes, std::uint64_t end, const std::string& grid)
{
    const std::int32_t buffers = r.pod<std::int32_t>();
    if (buffers != 1) r.fail("grid '" + grid + "' has " + std::to_string(buffers) + " buffers (OpenVDB reads 1)");
    r.skip(valueBytes); // background
    const std::uint64_t tiles = r.pod<std::uint32_t>(), children = r.pod<std::uint32_t>();
    const std::uint64_t least = tiles * (12 + valueBytes + 1) + children * (12 + 2 * 4096);
    if (least > end - std::min(end, r.position())) {
        r.fail("grid '" + grid + "' has " + std::to_string(tiles) + " root tiles and "
            + std::to_string(children) + " root children, more than its bytes hold");
    }
}

/// A metadata map as OpenVDB's MetaMap::readMeta reads it: an unsigned count, then name, type
/// and value size per entry. A fixed-size type must announce its own size: OpenVDB reads
/// sizeof(T) whatever the file says, and a mismatch would let it run on desynchronised.
void walkMetadata(BoundedReader& r)
{
    for (std::uint32_t i = 0, n = r.pod<std::uint32_t>(); i < n; ++i) {
        r.string();
        const std::string type = r.string();
        const std::uint32_t bytes = r.pod<std::uint32_t>();
        if (fixedSizeMetadata(type) && openvdb::Metadata::createMetadata(type)->size() != bytes) {
            r.fail("metadata of type " + type + " holds " + std::to_string(bytes) + " bytes");
        }
        if (type == openvdb::io::DelayedLoadMetadata::staticTypeName() && bytes > 0) {
            walkDelayedLoad(r, bytes);
            continue;
        }
        r.skip(bytes);
    }
}

void checkVdbLayout(const std::string& path, std::uint64_t size)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError("cannot open '" + path + "'");
    BoundedReader r(in, size, path);
    if (r.pod<std::int64_t>() != openvdb::OPENVDB_MAGIC) {
        throw InputError("'" + path + "' is not a VDB file (bad magic number)");
    }
    const std::uint32_t version = r.pod<std::uint32_t>();
    // OpenVDB only warns about a version it does not know and reads on unchecked, so the
    // versions this walk knows are the ones read (219, from 2013, up to the library's own;
    // 218's transforms were of an older kind).
    if (version < openvdb::OPENVDB_FILE_VERSION_NEW_TRANSFORM || version > openvdb::OPENVDB_FILE_VERSION) {
        throw InputError("'" + path + "' has VDB file format version " + std::to_string(version)
            + "; this build reads versions " + std::to_string(openvdb::OPENVDB_FILE_VERSION_NEW_TRANSFORM)
            + " to " + std::to_string(openvdb::OPENVDB_FILE_VERSION));
    }
    r.skip(8);                                  // library major, minor
    const bool hasOffsets = r.pod<char>() != 0;
    if (version >= openvdb::OPENVDB_FILE_VERSION_SELECTIVE_COMPRESSION
        && version < openvdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION) {
        r.skip(1);                              // compression flag of versions 220 and 221
    }
    // UUID: 36 characters that OpenVDB parses as text (`is >> uuid` skips whitespace and
    // would then read past where this walk looks), so only hex digits and dashes.
    for (int i = 0; i < 36; ++i) {
        const char c = r.pod<char>();
        const bool dash = i == 8 || i == 13 || i == 18 || i == 23;
        if (dash ? c != '-' : !std::isxdigit(static_cast<unsigned char>(c))) r.fail("bad UUID");
    }
    walkMetadata(r); // file metadata
    // Without grid offsets (io::Stream output) OpenVDB reads every grid in one pass, each
    // length unchecked, and this walk cannot find where one grid ends without reading it.
    if (!hasOffsets) {
        throw InputError("'" + path + "' was written as a VDB stream (no grid offsets), which isouq"
            " does not read; save it with openvdb::io::File (any VDB tool's file output)");
    }
    const std::int32_t grids = r.pod<std::int32_t>();
    if (grids < 0) r.fail("negative grid count");
    for (std::int32_t i = 0; i < grids; ++i) {
        const std::string name = r.string();
        const std::string type = r.string();
        const bool instance = !r.string().empty(); // an instance shares its parent's tree
        const auto gridPos = r.pod<std::int64_t>(), blockPos = r.pod<std::int64_t>(),
                   endPos = r.pod<std::int64_t>();
        if (!(0 < gridPos && gridPos <= blockPos && blockPos <= endPos)) r.fail("bad offsets of a grid");
        if (std::uint64_t(endPos) > size) {
            r.fail("grid '" + openvdb::io::GridDescriptor::nameAsString(name) + "' ends at byte "
                + std::to_string(endPos));
        }
        // The grid follows its descriptor, so the walk (and OpenVDB's) always moves on.
        if (std::uint64_t(gridPos) < r.position()) r.fail("grid '" +
            openvdb::io::GridDescriptor::nameAsString(name) + "' starts inside its descriptor");
        // The grid's start, as Archive::readGrid reads it: compression flags, its metadata, the
        // transform and the root of its tree (lengths and counts there are not checked by OpenVDB).
        r.seek(std::uint64_t(gridPos));
        if (version >= openvdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION) r.skip(4);
        walkMetadata(r);
        walkTransform(r, version);
        // Only float and double grids are read (type names as GridDescriptor writes them).
        const std::string tree = type.substr(0, type.rfind("_HalfFloat"));
        if (!instance && (tree == openvdb::FloatTree::treeType() || tree == openvdb::DoubleTree::treeType())) {
            walkRootTopology(r, tree == openvdb::FloatTree::treeType() ? 4 : 8, std::uint64_t(endPos),
                openvdb::io::GridDescriptor::nameAsString(name));
        }
        r.seek(std::uint64_t(endPos)); // the next descriptor follows this grid
    }
}

std::string describeGrids(const openvdb::GridPtrVec& grids)
{
    std::string list;
    for (const auto& grid : grids) {
        list += (list.empty() ? "" : ", ") + grid->getName() + " (" + grid->valueType() + ")";
    }
    return list.empty() ? "none" : list;
}

LoadedVolume loadVdb(const VolumeRequest& request)
{
    const std::string& path = request.input;
    checkVdbLayout(path, fileSize(path));
    LoadedVolume volume;
    try {
        openvdb::io::File file(path);
        if (request.delayLoad) file.setCopyMaxBytes(0);
        file.open(request.delayLoad);
        const openvdb::GridPtrVecPtr metas = file.readAllGridMetadata();
        std::string chosen;
        bool found = false; // a grid may be unnamed ("")
        for (const auto& meta : *metas) {
            const bool scalar = meta->isType<openvdb::FloatGrid>() || meta->isType<openvdb::DoubleGrid>();
            if (request.gridName.empty() ? scalar : meta->getName() == request.gridName) {
                if (!scalar) {
                    throw InputError("grid '" + meta->getName() + "' in '" + path + "' is "
                        + meta->valueType() + ", not a float scalar grid; grids found: "
                        + describeGrids(*metas));
                }
                chosen = meta->getName();
                found = true;
                break;
            }
        }
        if (!found && request.allowEmpty && !request.gridName.empty()) {
            file.close();
            volume.grid = openvdb::FloatGrid::create(0.0f);
            volume.grid->setName(request.gridName);
            volume.isovalue = request.isovalue.value_or(0.0f);
            volume.isovalueSource = "empty grid";
            volume.description = fs::path(path).filename().string() + ": no grid '" + request.gridName + "' (empty)";
            return volume;
        }
        if (!found) {
            throw InputError("'" + path + "' has no float grid"
                + (request.gridName.empty() ? "" : " named '" + request.gridName + "'")
                + "; grids found: " + describeGrids(*metas));
        }
        openvdb::GridBase::Ptr base = file.readGrid(chosen);
        file.close();
        if (auto doubles = openvdb::gridPtrCast<openvdb::DoubleGrid>(base)) {
            volume.grid = openvdb::FloatGrid::create(
                std::make_shared<openvdb::FloatTree>(doubles->tree()));
            volume.grid->setTransform(doubles->transform().copy());
            volume.grid->setGridClass(doubles->getGridClass());
            volume.grid->setName(doubles->getName());
        } else {
            volume.grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
        }
    } catch (const openvdb::Exception& e) {
        throw InputError("cannot read '" + path + "': " + e.what());
    }
    return sparseVolume(volume.grid, request, fs::path(path).filename().string());
}

LoadedVolume sparseVolume(openvdb::FloatGrid::Ptr grid, const VolumeRequest& request, const std::string& what)
{
    LoadedVolume volume;
    volume.grid = std::move(grid);
    const bool levelSet = volume.grid->getGridClass() == openvdb::GRID_LEVEL_SET;
    if (request.isovalue) {
        volume.isovalue = *request.isovalue;
        volume.isovalueSource = "given";
    } else if (volume.grid->empty()) {
        volume.isovalue = 0.0f;
        volume.isovalueSource = "empty grid";
    } else if (levelSet) {
        volume.isovalue = 0.0f;
        volume.isovalueSource = "level set";
    } else {
        volume.isovalue = request.delayLoad ? std::numeric_limits<float>::quiet_NaN() : float(otsuOfGrid(*volume.grid));
        volume.isovalueSource = "Otsu (starting value)";
    }
    volume.description = what + ": grid '" + volume.grid->getName()
        + "' (" + openvdb::GridBase::gridClassToString(volume.grid->getGridClass()) + "), "
        + std::to_string(volume.grid->activeVoxelCount()) + " active voxels, voxel size "
        + fmt(volume.grid->voxelSize()[0]);
    return volume;
}


} // namespace sources_internal

void releaseMappedPages(const std::string& path)
{
#ifdef __linux__
    // The mapping is OpenVDB's (io::MappedFile shows no address): found in /proc/self/maps by
    // the file's device and inode, so a name with spaces or newlines cannot mislead the match;
    // only read-only shared mappings (OpenVDB's is r--s), which hold no pages of their own to
    // lose (a private read-only one may: relocations a loader wrote before protecting them).
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) return;
    std::FILE* maps = std::fopen("/proc/self/maps", "re");
    if (!maps) return;
    unsigned long long begin = 0, end = 0, inode = 0;
    unsigned devMajor = 0, devMinor = 0;
    char perms[5] = {}, line[4096];
    while (std::fgets(line, sizeof line, maps)) {
        const bool whole = std::strchr(line, '\n') != nullptr;
        const bool ours =
            std::sscanf(line, "%llx-%llx %4s %*s %x:%x %llu", &begin, &end, perms, &devMajor, &devMinor, &inode) == 6
            && inode == st.st_ino && devMajor == major(st.st_dev) && devMinor == minor(st.st_dev);
        if (ours && perms[1] != 'w' && perms[3] == 's')
            ::madvise(reinterpret_cast<void*>(begin), std::size_t(end - begin), MADV_DONTNEED);
        while (!whole && std::fgets(line, sizeof line, maps) && !std::strchr(line, '\n')) {} // the rest of a long name
    }
    std::fclose(maps);
#else
    (void)path;
#endif
}

} // namespace isouq
