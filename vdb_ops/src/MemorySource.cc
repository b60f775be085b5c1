// isouq: volumes a host holds in memory, INPUT `memory:N` (VolumeSources.h MemoryVolume; the
// Python module's numpy arrays and pyopenvdb grids, SPEC §10 "Python"). A dense array goes
// through the same sparsify as a .raw scan, a grid through the same isovalue rule as a .vdb
// grid, so an array and the file holding its bytes give the same mesh.
#include "SourcesInternal.h"

#include <atomic>
#include <cmath>
#include <map>
#include <mutex>

namespace isouq {
namespace {

std::mutex sRegistryMutex;
std::map<std::string, std::shared_ptr<const MemoryVolume>> sRegistry;
std::atomic<std::uint64_t> sNextId{1};

constexpr const char* kPrefix = "memory:";

class MemorySlices : public sources_internal::SliceSource {
public:
    explicit MemorySlices(const MemoryVolume& volume) : mVolume(volume) { dims = volume.dims; }
    void read(int z0, int count, float* out) override { mVolume.readSlices(z0, count, out); }

private:
    const MemoryVolume& mVolume;
};

} // namespace

ScopedMemoryVolume::ScopedMemoryVolume(std::shared_ptr<const MemoryVolume> volume)
    : mInput(kPrefix + std::to_string(sNextId++))
{
    std::lock_guard<std::mutex> lock(sRegistryMutex);
    sRegistry[mInput] = std::move(volume);
}

ScopedMemoryVolume::~ScopedMemoryVolume()
{
    std::lock_guard<std::mutex> lock(sRegistryMutex);
    sRegistry.erase(mInput);
}

namespace sources_internal {

LoadedVolume loadMemory(const VolumeRequest& request, openvdb::util::NullInterrupter* interrupter)
{
    std::shared_ptr<const MemoryVolume> memory;
    {
        std::lock_guard<std::mutex> lock(sRegistryMutex);
        const auto it = sRegistry.find(request.input);
        if (it != sRegistry.end()) memory = it->second;
    }
    if (!memory)
        throw InputError("no in-memory volume '" + request.input + "' (a host registers one while it runs a graph)");
    if (!request.gridName.empty() || request.dims || !request.dtype.empty() || request.spacing)
        throw InputError("grid, dims, dtype and spacing are for files; an in-memory volume '" + request.input
            + "' has its own");
    if (memory->grid) return sparseVolume(memory->grid, request, memory->name);

    const Coord d = memory->dims;
    if (d.x() < 2 || d.y() < 2 || d.z() < 2)
        throw InputError(memory->name + ": " + std::to_string(d.x()) + "x" + std::to_string(d.y()) + "x"
            + std::to_string(d.z()) + " has no cell (a cell needs 2 samples along each axis): nothing to mesh");
    for (int a = 0; a < 3; ++a) {
        if (!(std::isfinite(memory->spacing[a]) && memory->spacing[a] > 0.0))
            throw InputError("spacing must be positive and finite, got " + fmt(memory->spacing[a]));
        if (!std::isfinite(memory->origin[a])) throw InputError("origin must be finite, got " + fmt(memory->origin[a]));
    }
    // As loadRaw: Otsu's starting value unless given, then the same slabs and KeepBlocks.
    MemorySlices source(*memory);
    LoadedVolume volume = loadDense(source, request, interrupter);
    volume.grid->setName(memory->name);
    auto transform = openvdb::math::Transform::createLinearTransform(1.0);
    transform->preScale(memory->spacing);
    if (memory->origin != openvdb::Vec3d(0.0)) transform->postTranslate(memory->origin);
    volume.grid->setTransform(transform);
    volume.description = memory->name + ": " + volume.description + ", spacing " + fmt(memory->spacing[0]) + ","
        + fmt(memory->spacing[1]) + "," + fmt(memory->spacing[2]);
    return volume;
}

} // namespace sources_internal
} // namespace isouq
