// isouq benchmark: isouq::extractIsosurface (linear crossings only) against OpenVDB's
// tools::volumeToMesh (adaptivity 0, same isovalue) on the same grid in one process
// (bench/README.md; DESIGN.md goals: at most 0.8x the time and at most the memory increment).
//
// Time: per case and thread count, one warm-up call of each, then repeats that take turns
// between the algorithms and the thread counts; the table gives the median wall time and the
// median process CPU time (user + system, all threads), and the thread scaling of each.
// Memory: a fresh child process (this binary re-executed) builds the same grid, trims the heap,
// resets the high-water mark (/proc/self/clear_refs "5"), makes one call and reports the rise of
// VmHWM; the median over several children is given. Triangles per second count a quad of
// volumeToMesh as two triangles.
#include "isouq/GridMetadata.h"
#include "isouq/HiddenFeatures.h"
#include "isouq/MarchingCubes.h"
#include "isouq/MeshIO.h"
#include "isouq/MeshTopology.h"
#include "isouq/VolumeSources.h"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <malloc.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

/// isouq's linear pass (positions only), its estimate pass (linear crossings with the paper's
/// e and e_b: "extraction plus estimate"), its full pass (every method, estimate and difference
/// per vertex, issue 3), its hidden-feature pass (SPEC §4: standard MC with provenance, then
/// detection, refinement and merge; positions only; with the default filter or without it), or
/// OpenVDB's volumeToMesh.
enum class Algo { Isouq, IsouqEstimate, IsouqFull, IsouqHidden, IsouqHiddenUnfiltered, VolumeToMesh };

const char* algoName(Algo a)
{
    switch (a) {
    case Algo::Isouq: return "linear";
    case Algo::IsouqEstimate: return "estimate";
    case Algo::IsouqFull: return "full";
    case Algo::IsouqHidden: return "hidden";
    case Algo::IsouqHiddenUnfiltered: return "hidden-unfiltered";
    case Algo::VolumeToMesh: break;
    }
    return "vtm";
}

Algo algoFromName(const std::string& s)
{
    for (Algo a : {Algo::Isouq, Algo::IsouqEstimate, Algo::IsouqFull, Algo::IsouqHidden, Algo::IsouqHiddenUnfiltered})
        if (s == algoName(a)) return a;
    return Algo::VolumeToMesh;
}

struct CallResult {
    std::size_t triangles = 0;   // quads count as two
    std::size_t outputBytes = 0; // positions and index arrays of the result
};

/// Issue 4's hidden-feature volumes, loaded as `isouq mesh --hidden-features` loads them
/// (KeepBlocks::CrossingOrHidden): SPEC §5's Teardrop and Tubey at 32^3 with their default
/// isovalues, and the engine and skull scans at their isovalues of docs/hidden-features.md.
std::optional<isouq::VolumeRequest> hiddenCase(const std::string& name, const std::string& dataDir)
{
    isouq::VolumeRequest request;
    request.keep = isouq::KeepBlocks::CrossingOrHidden;
    if (name == "teardrop32" || name == "tubey32") {
        request.input = "field:" + name.substr(0, name.size() - 2);
        request.resolution = 32;
    } else if (name == "engine") {
        request.input = dataDir + "/engine_256x256x128_uint8.raw";
        request.isovalue = 71.0f;
    } else if (name == "skull") {
        request.input = dataDir + "/skull_64x64x64_float32.raw";
        request.isovalue = 2.9f;
    } else {
        return std::nullopt;
    }
    return request;
}

/// The benchmark volumes: `sphereN` is the level-set sphere of radius 0.4 centred at
/// (0.5, 0.5, 0.5) with voxel size 1/N; `smoke` is data/smoke.vdb's "density" grid; `tangle32`
/// is SPEC §5's Tangle sampled at 32^3 on [-1, 1]^3 (the paper's "less than a millisecond");
/// hiddenCase's volumes carry their isovalue as the metadata "bench_isovalue".
openvdb::FloatGrid::Ptr makeGrid(const std::string& name, const std::string& dataDir)
{
    if (const auto request = hiddenCase(name, dataDir)) {
        const isouq::LoadedVolume volume = isouq::loadVolume(*request);
        volume.grid->insertMeta("bench_isovalue", openvdb::FloatMetadata(volume.isovalue));
        return volume.grid;
    }
    if (name == "tangle32") {
        const int n = 32;
        const double h = 2.0 / (n - 1);
        auto grid = openvdb::FloatGrid::create(1.0f);
        auto acc = grid->getAccessor();
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j)
                for (int k = 0; k < n; ++k) {
                    const double x = -1 + i * h, y = -1 + j * h, z = -1 + k * h;
                    acc.setValueOn({i, j, k}, float(x * x * x * x + y * y * y * y + z * z * z * z -
                                                     (x * x + y * y + z * z) + 0.4));
                }
        grid->setTransform(openvdb::math::Transform::createLinearTransform(h));
        isouq::setDataBounds(*grid, openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(n - 1)));
        return grid;
    }
    if (name.rfind("sphere", 0) == 0) {
        const int n = std::stoi(name.substr(6));
        return openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
            0.4f, openvdb::Vec3f(0.5f), 1.0f / float(n));
    }
    if (name == "smoke") {
        openvdb::io::File file(dataDir + "/smoke.vdb");
        file.open(/*delayLoad=*/false); // load every buffer now, not on first access
        auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("density"));
        file.close();
        if (!grid) throw std::runtime_error("smoke.vdb: grid 'density' is not a float grid");
        return grid;
    }
    throw std::runtime_error("unknown case " + name +
                             " (sphereN, smoke, tangle32, teardrop32, tubey32, engine or skull)");
}

float isovalueOf(const std::string& name, const openvdb::FloatGrid& grid)
{
    if (const auto k = grid.getMetadata<openvdb::FloatMetadata>("bench_isovalue")) return k->value();
    return name == "smoke" || name == "tangle32" ? 0.1f : 0.0f;
}

/// With --reuse, isouq meshes through one IsosurfaceMesher into one Mesh for the whole case,
/// as an interactive viewer would (DESIGN.md "Memory and allocation").
struct Reuse {
    isouq::IsosurfaceMesher mesher;
    isouq::Mesh mesh;
};

CallResult runOnce(Algo algo, const openvdb::FloatGrid& grid, float isovalue, Reuse* reuse = nullptr)
{
    CallResult r;
    if (algo == Algo::IsouqHidden || algo == Algo::IsouqHiddenUnfiltered) {
        isouq::MeshSettings settings;
        settings.isovalue = isovalue;
        settings.uncertainty = false;
        isouq::HiddenFeatureSettings hidden;
        hidden.filter = algo != Algo::IsouqHiddenUnfiltered;
        const isouq::Mesh mesh = isouq::extractWithHiddenFeatures(grid, settings, hidden);
        r.triangles = mesh.triangles.size();
        r.outputBytes = mesh.positions.size() * sizeof(openvdb::Vec3s) +
                        mesh.triangles.size() * sizeof(openvdb::Vec3I);
    } else if (algo != Algo::VolumeToMesh) {
        isouq::MeshSettings settings;
        settings.isovalue = isovalue;
        settings.uncertainty = algo != Algo::Isouq;
        settings.highOrder = algo == Algo::IsouqFull;
        isouq::Mesh fresh;
        if (reuse) reuse->mesher.settings() = settings;
        isouq::Mesh& mesh = reuse ? reuse->mesh : fresh;
        if (reuse) reuse->mesher(grid, mesh);
        else fresh = isouq::extractIsosurface(grid, settings);
        r.triangles = mesh.triangles.size();
        r.outputBytes = mesh.positions.size() * sizeof(openvdb::Vec3s) +
                        mesh.triangles.size() * sizeof(openvdb::Vec3I);
    } else {
        std::vector<openvdb::Vec3s> points;
        std::vector<openvdb::Vec3I> triangles;
        std::vector<openvdb::Vec4I> quads;
        openvdb::tools::volumeToMesh(grid, points, triangles, quads, double(isovalue), 0.0);
        r.triangles = triangles.size() + 2 * quads.size();
        r.outputBytes = points.size() * sizeof(openvdb::Vec3s) +
                        triangles.size() * sizeof(openvdb::Vec3I) + quads.size() * sizeof(openvdb::Vec4I);
    }
    return r;
}

double wallSeconds()
{
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double cpuSeconds()
{
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    auto sec = [](const timeval& t) { return double(t.tv_sec) + 1e-6 * double(t.tv_usec); };
    return sec(u.ru_utime) + sec(u.ru_stime);
}

/// A "Key:   123 kB" line of /proc/self/status, in KiB.
long statusKiB(const char* key)
{
    std::ifstream in("/proc/self/status");
    std::string line;
    const std::size_t n = std::strlen(key);
    while (std::getline(in, line))
        if (line.compare(0, n, key) == 0 && line[n] == ':') return std::stol(line.substr(n + 1));
    throw std::runtime_error(std::string("no ") + key + " in /proc/self/status");
}

std::string loadAverage()
{
    std::ifstream in("/proc/loadavg");
    std::string one;
    in >> one;
    return one;
}

double median(std::vector<double> v)
{
    if (v.empty()) return std::numeric_limits<double>::quiet_NaN(); // --memory-runs 0
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::unique_ptr<tbb::global_control> limitThreads(int threads)
{
    if (threads <= 0) return nullptr;
    return std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
        std::size_t(threads));
}

/// The machine's own memory scaling, measured in the same run as the mesher (bench/README.md
/// "Threads"): a streaming read of 256 MiB of resident memory by 1 thread and by all, taking
/// turns, median of 7 each. A mesher that streams its grid and output cannot scale further than
/// this: on a host whose other guests share the memory bus, 2 threads have read as little as
/// 1.07x one (bench/journal/2026-12-07.md, "14:02").
void printMemoryProbe()
{
    const int all = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
    std::vector<std::uint64_t> words(std::size_t(32) << 20, 1);
    std::vector<double> seconds[2];
    std::uint64_t sum = 0;
    for (int r = -1; r < 7; ++r)
        for (int t = 0; t < 2; ++t) {
            const auto control = limitThreads(t == 0 ? 1 : all);
            const double w0 = wallSeconds();
            sum += tbb::parallel_reduce(tbb::blocked_range<std::size_t>(0, words.size(), std::size_t(1) << 16),
                std::uint64_t(0),
                [&](const tbb::blocked_range<std::size_t>& range, std::uint64_t part) {
                    for (std::size_t i = range.begin(); i < range.end(); ++i) part += words[i];
                    return part;
                },
                std::plus<std::uint64_t>());
            if (r >= 0) seconds[t].push_back(wallSeconds() - w0);
        }
    if (sum != 16 * words.size()) throw std::runtime_error("the memory probe summed the wrong words"); // 16 reads of 1s
    const double bytes = double(words.size() * sizeof(std::uint64_t));
    const double one = bytes / median(seconds[0]) * 1e-9, many = bytes / median(seconds[1]) * 1e-9;
    std::printf("Memory in this run: a streaming read of 256 MiB, %.1f GB/s with 1 thread, %.1f GB/s with %d "
                "(%.2fx); load %s.\n\n", one, many, all, many / one, loadAverage().c_str());
}

/// Child mode: build the grid, make one call, print the VmHWM rise in KiB.
int childMemory(const std::string& caseName, Algo algo, int threads, const std::string& dataDir)
{
    const auto control = limitThreads(threads);
    openvdb::FloatGrid::Ptr grid = makeGrid(caseName, dataDir);
    // Start the worker threads now, so their stacks are in the baseline.
    tbb::parallel_for(0, 1024, [](int) {});
    malloc_trim(0);
    {
        std::ofstream clear("/proc/self/clear_refs");
        clear << "5"; // resets VmHWM to the current RSS
    }
    const long before = statusKiB("VmHWM");
    const CallResult r = runOnce(algo, *grid, isovalueOf(caseName, *grid));
    const long after = statusKiB("VmHWM");
    std::printf("%ld %zu\n", after - before, r.outputBytes);
    return 0;
}

/// Runs this binary in child mode and returns the VmHWM rise in MiB.
double memoryIncrementMiB(const std::string& caseName, Algo algo, int threads, const std::string& dataDir)
{
    int fds[2];
    if (pipe(fds) != 0) throw std::runtime_error("pipe failed");
    const pid_t pid = fork();
    if (pid < 0) throw std::runtime_error("fork failed");
    if (pid == 0) {
        dup2(fds[1], STDOUT_FILENO);
        close(fds[0]);
        close(fds[1]);
        const std::string algoName = ::algoName(algo);
        const std::string threadText = std::to_string(threads);
        execl("/proc/self/exe", "isouq_bench", "--child-memory", caseName.c_str(), algoName.c_str(),
            threadText.c_str(), dataDir.c_str(), static_cast<char*>(nullptr));
        _exit(127);
    }
    close(fds[1]);
    std::string text;
    char buffer[256];
    for (ssize_t got; (got = read(fds[0], buffer, sizeof buffer)) > 0;) text.append(buffer, std::size_t(got));
    close(fds[0]);
    int status = 0;
    waitpid(pid, &status, 0);
    long kib = -1;
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || !(std::istringstream(text) >> kib))
        throw std::runtime_error("memory child failed for " + caseName);
    return double(kib) / 1024.0;
}

struct Options {
    std::vector<std::string> cases{"sphere256", "sphere512", "sphere1024", "smoke"};
    std::vector<int> threads{0, 1}; // 0: TBB's default (all cores)
    int repeats = 7;
    int memoryRuns = 3;
    std::string dataDir = ISOUQ_DATA_DIR;
    Algo isouqPass = Algo::Isouq; // --pass linear|estimate|full|hidden|hidden-unfiltered
    bool reuse = false;           // --reuse: one IsosurfaceMesher and Mesh per case
    std::vector<std::string> loads; // --load FILE,...: time isouq::loadVolume (dense scans)
    std::vector<std::string> afterMesh; // --after-mesh PLY,...: time the summary's measures and the PLY write
    bool stages = false;            // --stages: per-stage thread scaling of the mesher
    bool memoryProbe = false;       // --memory-probe: only the machine's memory scaling line
};

std::vector<std::string> splitCommas(const std::string& s)
{
    std::vector<std::string> out;
    std::stringstream in(s);
    for (std::string item; std::getline(in, item, ',');)
        if (!item.empty()) out.push_back(item);
    return out;
}

Options parseOptions(int argc, char** argv)
{
    Options o;
    for (int i = 1; i < argc; ++i) {
        const std::string arg = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) throw std::runtime_error(arg + " needs a value");
            return argv[++i];
        };
        if (arg == "--cases") o.cases = splitCommas(next());
        else if (arg == "--repeats") o.repeats = std::stoi(next());
        else if (arg == "--memory-runs") o.memoryRuns = std::stoi(next());
        else if (arg == "--data") o.dataDir = next();
        else if (arg == "--reuse") o.reuse = true;
        else if (arg == "--load") o.loads = splitCommas(next());
        else if (arg == "--after-mesh") o.afterMesh = splitCommas(next());
        else if (arg == "--stages") o.stages = true;
        else if (arg == "--memory-probe") o.memoryProbe = true;
        else if (arg == "--pass") {
            o.isouqPass = algoFromName(next());
            if (o.isouqPass == Algo::VolumeToMesh)
                throw std::runtime_error("--pass takes linear, estimate, full, hidden or hidden-unfiltered");
        }
        else if (arg == "--threads") {
            o.threads.clear();
            for (const std::string& t : splitCommas(next())) o.threads.push_back(t == "default" ? 0 : std::stoi(t));
        } else {
            throw std::runtime_error("usage: isouq_bench [--cases sphere256,sphere512,sphere1024,smoke] "
                                     "[--threads default,1] [--repeats R] [--memory-runs M] [--data DIR] "
                                     "[--pass linear|estimate|full|hidden|hidden-unfiltered] [--reuse] [--load FILE,...] "
                                     "[--after-mesh PLY,...] [--stages] [--memory-probe]");
        }
    }
    return o;
}

void benchCase(const std::string& caseName, const Options& o)
{
    const openvdb::FloatGrid::Ptr grid = makeGrid(caseName, o.dataDir);
    const float isovalue = isovalueOf(caseName, *grid);
    const double activeM = double(grid->activeVoxelCount()) * 1e-6;
    const Algo algos[2] = {o.isouqPass, Algo::VolumeToMesh};
    const std::string load = loadAverage();
    // One row per thread count; the thread counts take turns call by call, as the two
    // algorithms do, so a drift of the machine's speed shows in both rows alike.
    struct Row {
        int used = 0;
        std::size_t tris[2] = {0, 0};
        std::vector<double> wall[2], cpu[2];
        std::unique_ptr<Reuse> reuse;
    };
    std::vector<Row> rows(o.threads.size());
    for (std::size_t t = 0; t < rows.size(); ++t) {
        const auto control = limitThreads(o.threads[t]);
        Row& row = rows[t];
        row.used = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
        if (o.reuse) row.reuse = std::make_unique<Reuse>();
        for (int a = 0; a < 2; ++a) row.tris[a] = runOnce(algos[a], *grid, isovalue, row.reuse.get()).triangles; // warm-up
    }
    for (int r = 0; r < o.repeats; ++r)
        for (std::size_t t = 0; t < rows.size(); ++t) {
            const auto control = limitThreads(o.threads[t]);
            for (int a = 0; a < 2; ++a) {
                // Every call starts with the heap trimmed: what one call freed would otherwise be
                // the next call's output, already paged in, for whichever call comes next.
                malloc_trim(0);
                const double w0 = wallSeconds(), c0 = cpuSeconds();
                runOnce(algos[a], *grid, isovalue, rows[t].reuse.get());
                rows[t].wall[a].push_back(wallSeconds() - w0);
                rows[t].cpu[a].push_back(cpuSeconds() - c0);
            }
        }
    for (std::size_t t = 0; t < rows.size(); ++t) {
        const int threads = o.threads[t];
        const Row& row = rows[t];
        double mem[2];
        for (int a = 0; a < 2; ++a) {
            std::vector<double> runs;
            for (int m = 0; m < o.memoryRuns; ++m)
                runs.push_back(memoryIncrementMiB(caseName, algos[a], threads, o.dataDir));
            mem[a] = median(runs);
        }
        const double w[2] = {median(row.wall[0]), median(row.wall[1])};
        const double c[2] = {median(row.cpu[0]), median(row.cpu[1])};
        // Times under 10 ms with two decimals (the small-grid latency goal is 1 ms, issue 12).
        const char* msFormat = w[0] < 1e-2 ? "%.2f" : "%.1f";
        char ms[2][32];
        for (int a = 0; a < 2; ++a) std::snprintf(ms[a], sizeof ms[a], msFormat, 1e3 * w[a]);
        std::printf("| %s | %.2f | %s%d | %zu | %zu | %s | %s | **%.2f** | %.1f | %.1f | %.2f | %.1f | %.1f "
                    "| %.1f | %.1f | **%.2f** | %s |\n",
            caseName.c_str(), activeM, threads <= 0 ? "default " : "", row.used, row.tris[0], row.tris[1],
            ms[0], ms[1], w[0] / w[1], 1e3 * c[0], 1e3 * c[1], c[0] / c[1], 1e-6 * double(row.tris[0]) / w[0],
            1e-6 * double(row.tris[1]) / w[1], mem[0], mem[1], mem[0] / mem[1], load.c_str());
    }
    if (rows.size() == 2 && rows[0].used != rows[1].used) {
        const Row& many = rows[0].used > rows[1].used ? rows[0] : rows[1];
        const Row& few = &many == &rows[0] ? rows[1] : rows[0];
        // The ratio of each repeat's two calls too: calls next to each other share the machine's
        // state (a host that slows one vCPU for a few seconds shows in one pair, not in a median).
        std::vector<double> paired[2];
        for (int a = 0; a < 2; ++a)
            for (std::size_t r = 0; r < few.wall[a].size(); ++r) paired[a].push_back(few.wall[a][r] / many.wall[a][r]);
        std::printf("\n%s: %d threads are %.2fx as fast as %d for isouq, %.2fx for volumeToMesh (median times); "
                    "per repeat %.2fx (%.2f-%.2f) and %.2fx (%.2f-%.2f) (median, range).\n\n",
            caseName.c_str(), many.used, median(few.wall[0]) / median(many.wall[0]), few.used,
            median(few.wall[1]) / median(many.wall[1]), median(paired[0]),
            *std::min_element(paired[0].begin(), paired[0].end()), *std::max_element(paired[0].begin(), paired[0].end()),
            median(paired[1]), *std::min_element(paired[1].begin(), paired[1].end()),
            *std::max_element(paired[1].begin(), paired[1].end()));
    }
    std::fflush(stdout);
}

/// --load: isouq::loadVolume of a dense scan (read, Otsu's default isovalue, dense to sparse)
/// as `isouq mesh` loads it; wall and CPU medians, the file's bytes per wall second.
void benchLoad(const std::string& path, const Options& o)
{
    std::ifstream file(path, std::ios::binary | std::ios::ate);
    const double mib = double(file.tellg()) / double(1 << 20);
    isouq::VolumeRequest request;
    request.input = path;
    for (const int threads : o.threads) {
        const std::string load = loadAverage();
        const auto control = limitThreads(threads);
        const int used = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
        isouq::LoadedVolume volume = isouq::loadVolume(request); // warm-up: the file into the page cache
        std::vector<double> wall, cpu;
        for (int r = 0; r < o.repeats; ++r) {
            volume = {};
            const double w0 = wallSeconds(), c0 = cpuSeconds();
            volume = isouq::loadVolume(request);
            wall.push_back(wallSeconds() - w0);
            cpu.push_back(cpuSeconds() - c0);
        }
        const double w = median(wall), c = median(cpu);
        std::printf("| %s | %.0f | %s%d | %.2f | %zu | %.1f | %.1f | **%.0f** | %s |\n", path.substr(path.rfind('/') + 1).c_str(),
            mib, threads <= 0 ? "default " : "", used, volume.isovalue, volume.keptBlocks, 1e3 * w, 1e3 * c,
            mib * 1.048576 / w, load.c_str());
        std::fflush(stdout);
    }
}

/// --after-mesh: what `isouq mesh` does with a mesh once it is made, on a mesh read from a PLY:
/// the summary's measureTopology (edges, components, area, volume) and writing the PLY to a new
/// file beside it (removed before each write and at the end); medians per thread count, the
/// thread counts taking turns call by call.
void benchAfterMesh(const std::string& path, const Options& o)
{
    const isouq::Mesh mesh = isouq::readPly(path);
    const std::string out = path + ".after-mesh.ply";
    const std::string load = loadAverage();
    std::vector<std::vector<std::array<double, 2>>> times(o.threads.size()); // measure, write
    std::vector<int> used(o.threads.size());
    for (int r = -1; r < o.repeats; ++r) // r = -1: warm-up
        for (std::size_t t = 0; t < o.threads.size(); ++t) {
            const auto control = limitThreads(o.threads[t]);
            used[t] = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
            const double w0 = wallSeconds();
            (void)isouq::measureTopology(mesh);
            const double w1 = wallSeconds();
            std::remove(out.c_str());
            isouq::writePly(mesh, out);
            const double w2 = wallSeconds();
            if (r >= 0) times[t].push_back({w1 - w0, w2 - w1});
        }
    std::remove(out.c_str());
    for (std::size_t t = 0; t < o.threads.size(); ++t) {
        std::vector<double> measure, write;
        for (const auto& [m, w] : times[t]) measure.push_back(m), write.push_back(w);
        std::printf("| %s | %zu | %s%d | %.1f | %.1f | %s |\n", path.substr(path.rfind('/') + 1).c_str(),
            mesh.triangleCount(), o.threads[t] <= 0 ? "default " : "", used[t], 1e3 * median(measure),
            1e3 * median(write), load.c_str());
    }
    std::fflush(stdout);
}

/// --stages: the mesher's stages (IsosurfaceMesher::stageTimes) with one thread and with all,
/// interleaved call by call, fresh mesher and mesh each call (as extractIsosurface); per stage
/// the median wall times, the speedup S and the serial fraction Amdahl's law gives on P threads,
/// f = (P / S - 1) / (P - 1).
void benchStages(const std::string& caseName, const Options& o)
{
    const openvdb::FloatGrid::Ptr grid = makeGrid(caseName, o.dataDir);
    isouq::MeshSettings settings;
    settings.isovalue = isovalueOf(caseName, *grid);
    settings.uncertainty = o.isouqPass != Algo::Isouq;
    settings.highOrder = o.isouqPass == Algo::IsouqFull;
    const std::string load = loadAverage();
    const int all = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
    using Stages = isouq::IsosurfaceMesher::StageTimes;
    constexpr int kStages = 7;
    auto values = [](const Stages& t, double total) {
        return std::array<double, kStages>{t.blocks, t.sides, t.count, t.offsets, t.allocate, t.fill, total};
    };
    std::vector<std::array<double, kStages>> runs[2];
    for (int r = -1; r < o.repeats; ++r)
        for (int t = 0; t < 2; ++t) {
            const auto control = limitThreads(t == 0 ? 1 : all);
            isouq::IsosurfaceMesher mesher(settings);
            isouq::Mesh mesh;
            const double w0 = wallSeconds();
            mesher(*grid, mesh);
            const double total = 1e3 * (wallSeconds() - w0);
            if (r >= 0) runs[t].push_back(values(mesher.stageTimes(), total)); // r = -1: warm-up
        }
    const char* names[kStages] = {"block set", "sides", "count", "prefix sums", "allocate output", "fill",
        "**whole call**"};
    for (int k = 0; k < kStages; ++k) {
        double m[2];
        for (int t = 0; t < 2; ++t) {
            std::vector<double> v;
            for (const auto& run : runs[t]) v.push_back(run[std::size_t(k)]);
            m[t] = median(v);
        }
        const double speedup = m[1] > 0 ? m[0] / m[1] : 0.0;
        const double serial = all > 1 && speedup > 0 ? std::clamp((all / speedup - 1.0) / (all - 1), 0.0, 1.0) : 1.0;
        std::printf("| %s | %s | %s | %.2f | %.2f | %.2f | %.2f | %s |\n", caseName.c_str(), algoName(o.isouqPass), names[k],
            m[0], m[1], speedup, serial, load.c_str());
    }
    std::fflush(stdout);
}

bool isHiddenPass(Algo a) { return a == Algo::IsouqHidden || a == Algo::IsouqHiddenUnfiltered; }

/// --pass hidden|hidden-unfiltered: the hidden-feature pass against plain marching cubes (isouq's
/// linear pass) and volumeToMesh on the same grid, interleaved; issue 4's goal is at most 3x
/// plain MC. The flagged fraction and refined cells come from one extra call with statistics.
void benchHiddenCase(const std::string& caseName, const Options& o)
{
    const openvdb::FloatGrid::Ptr grid = makeGrid(caseName, o.dataDir);
    const float isovalue = isovalueOf(caseName, *grid);
    isouq::MeshSettings settings;
    settings.isovalue = isovalue;
    settings.uncertainty = false;
    isouq::HiddenFeatureSettings hidden;
    hidden.filter = o.isouqPass != Algo::IsouqHiddenUnfiltered;
    isouq::HiddenFeatureStats stats;
    isouq::extractWithHiddenFeatures(*grid, settings, hidden, &stats);
    for (const int threads : o.threads) {
        const std::string load = loadAverage();
        const auto control = limitThreads(threads);
        const int used = int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
        const Algo algos[3] = {o.isouqPass, Algo::Isouq, Algo::VolumeToMesh};
        std::size_t tris[3];
        for (int a = 0; a < 3; ++a) tris[a] = runOnce(algos[a], *grid, isovalue).triangles; // warm-up
        std::vector<double> wall[3], cpu[3];
        for (int r = 0; r < o.repeats; ++r)
            for (int a = 0; a < 3; ++a) {
                const double w0 = wallSeconds(), c0 = cpuSeconds();
                runOnce(algos[a], *grid, isovalue);
                wall[a].push_back(wallSeconds() - w0);
                cpu[a].push_back(cpuSeconds() - c0);
            }
        double w[3], c[3];
        for (int a = 0; a < 3; ++a) {
            w[a] = median(wall[a]);
            c[a] = median(cpu[a]);
        }
        std::printf("| %s | %.1f %% | %zu | %zu | %s%d | %zu | %zu | %.2f | %.2f | %.2f | **%.2f** | %.2f | %.2f | %s |\n",
            caseName.c_str(), 100.0 * stats.fraction(), stats.cellsRefined, stats.cellsTransition,
            threads <= 0 ? "default " : "", used, tris[1], tris[0], 1e3 * w[1], 1e3 * w[0], 1e3 * w[2], w[0] / w[1],
            c[0] / c[1], w[0] / w[2], load.c_str());
        std::fflush(stdout);
    }
}

} // namespace

int main(int argc, char** argv)
{
    try {
        openvdb::initialize();
        if (argc == 6 && std::string(argv[1]) == "--child-memory")
            return childMemory(argv[2], algoFromName(argv[3]),
                std::stoi(argv[4]), argv[5]);
        const Options o = parseOptions(argc, argv);
        if (o.memoryProbe) {
            printMemoryProbe();
            return 0;
        }
        if (!o.loads.empty()) {
            std::printf("isouq::loadVolume. Load average at start: %s; %d repeats (median).\n\n", loadAverage().c_str(),
                o.repeats);
            std::printf("| file | MiB | threads | isovalue | kept blocks | load ms | CPU ms | MB/s | load |\n");
            std::printf("|---|--:|---|--:|--:|--:|--:|--:|--:|\n");
            for (const std::string& f : o.loads) benchLoad(f, o);
            return 0;
        }
        if (!o.afterMesh.empty()) {
            std::printf("After meshing: the summary's measureTopology and writePly to a new file. Load average at "
                        "start: %s; %d repeats (median), thread counts taking turns.\n\n", loadAverage().c_str(), o.repeats);
            std::printf("| PLY | triangles | threads | measure ms | write ms | load |\n|---|--:|---|--:|--:|--:|\n");
            for (const std::string& f : o.afterMesh) benchAfterMesh(f, o);
            return 0;
        }
        if (o.stages) {
            printMemoryProbe();
            std::printf("Mesher stages, 1 thread against %d, interleaved. Load average at start: %s; %d repeats "
                        "(median).\n\n", int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)),
                loadAverage().c_str(), o.repeats);
            std::printf("| case | pass | stage | 1 thread ms | all threads ms | speedup | serial fraction | load |\n");
            std::printf("|---|---|---|--:|--:|--:|--:|--:|\n");
            for (const std::string& c : o.cases) benchStages(c, o);
            std::printf("\n");
            printMemoryProbe();
            return 0;
        }
        if (isHiddenPass(o.isouqPass)) {
            std::printf("isouq pass: %s (MC: isouq's linear pass). Load average at start: %s; %d repeats "
                        "(median).\n\n",
                algoName(o.isouqPass), loadAverage().c_str(), o.repeats);
            std::printf("| case | flagged | refined cells | transition cells | threads | MC tris | hidden tris "
                        "| MC ms | hidden ms | VtM ms | hidden / MC | CPU hidden / MC | hidden / VtM | load |\n");
            std::printf("|---|--:|--:|--:|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
            for (const std::string& c : o.cases) benchHiddenCase(c, o);
            return 0;
        }
        const bool scaling = o.threads.size() > 1;
        if (scaling) printMemoryProbe();
        std::printf("isouq pass: %s. Load average at start: %s; %d repeats (median), memory: median of %d "
                    "fresh processes.\n\n",
            (std::string(algoName(o.isouqPass)) + (o.reuse ? ", reused mesher and mesh" : "")).c_str(),
            loadAverage().c_str(), o.repeats, o.memoryRuns);
        std::printf("| case | active Mvox | threads | isouq tris | VtM tris | isouq ms | VtM ms | time ratio "
                    "| isouq CPU ms | VtM CPU ms | CPU ratio | isouq Mtri/s | VtM Mtri/s | isouq +MiB | VtM +MiB "
                    "| mem ratio | load |\n");
        std::printf("|---|--:|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
        for (const std::string& c : o.cases) benchCase(c, o);
        if (scaling) printMemoryProbe();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "isouq_bench: error: %s\n", e.what());
        return 2;
    }
    return 0;
}
