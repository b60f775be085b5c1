// isouq Python module, native part `isouq._core` (SPEC §10 "Python"; STYLE "Python binding";
// docs/python.md). A thin layer over the node runner: the package `isouq` (python/isouq) builds
// the same mesh graph as `isouq mesh` and runs it here. In-memory volumes (numpy arrays,
// pyopenvdb grids) enter the graph as `memory:N` inputs (VolumeSources.h MemoryVolume). Every
// run happens on a worker thread with the GIL released while the calling thread polls for
// Ctrl-C, which cancels the run through its interrupter.
#include <isouq/Errors.h>
#include <isouq/MeshIO.h>
#include <isouq/Threads.h>
#include <isouq/VolumeSources.h>
#include <isouq/nodes/Graph.h>
#include <isouq/nodes/MeshGraph.h>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#ifdef ISOUQ_WITH_PYOPENVDB
#include <openvdb/python/pyopenvdb.h>
#endif

#include <openvdb/Exceptions.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <condition_variable>
#include <map>
#include <mutex>
#include <chrono>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <future>
#include <algorithm>
#include <thread>
#include <unistd.h>
#include <vector>

namespace py = pybind11;
namespace nodes = isouq::nodes;

namespace {

/// Cancels a run once the calling thread saw KeyboardInterrupt (STYLE "Interrupters").
class CancelInterrupter final : public openvdb::util::NullInterrupter {
public:
    bool wasInterrupted(int = -1) override { return mCancel.load(std::memory_order_relaxed); }
    void cancel() { mCancel = true; }

private:
    std::atomic<bool> mCancel{false};
};

/// A long-lived worker thread of one calling thread (thread_local, so calls from several
/// Python threads still run at once). It keeps TBB's arena between calls: a fresh thread or
/// arena per call cost more than meshing a 32^3 grid (bench/README.md "Python call overhead").
class Worker {
public:
    Worker() : mThread([this] { loop(); }) {}
    ~Worker()
    {
        {
            std::lock_guard<std::mutex> lock(mMutex);
            mStop = true;
        }
        mWake.notify_one();
        mThread.join();
    }
    void post(std::function<void()> job)
    {
        {
            std::lock_guard<std::mutex> lock(mMutex);
            mJob = std::move(job);
        }
        mWake.notify_one();
    }
    /// The arena of @a threads workers (0: TBB's default), made once.
    tbb::task_arena& arena(int threads)
    {
        auto& a = mArenas[threads];
        const int concurrency = threads > 0 ? threads : int(tbb::task_arena::automatic);
        if (!a) a = std::make_unique<tbb::task_arena>(concurrency);
        return *a;
    }

private:
    void loop()
    {
        for (;;) {
            std::function<void()> job;
            {
                std::unique_lock<std::mutex> lock(mMutex);
                mWake.wait(lock, [this] { return mStop || mJob; });
                if (!mJob) return;
                job = std::move(mJob);
                mJob = nullptr;
            }
            job();
        }
    }
    std::mutex mMutex;
    std::condition_variable mWake;
    std::function<void()> mJob;
    bool mStop = false;
    std::map<int, std::unique_ptr<tbb::task_arena>> mArenas; // used on the worker thread only
    std::thread mThread;
};

/// A forked child has none of the parent's threads (the Workers, TBB's): a call would wait for
/// ever on a thread that is not there. The first call of any kind records the process.
void checkNotForked()
{
    static const pid_t firstCaller = ::getpid();
    if (::getpid() != firstCaller)
        throw std::runtime_error("isouq was used before this process was forked, and its threads did not come "
            "along: use multiprocessing's 'spawn' or 'forkserver' start method, or import isouq in the child only");
}

/// A Python int of worker threads: 0 (every core) to kMaxThreads (TBB crashed setting up 10^7).
int threadsOf(const py::int_& value)
{
    int overflow = 0;
    const long long n = PyLong_AsLongLongAndOverflow(value.ptr(), &overflow);
    if (overflow != 0 || n < 0 || n > isouq::kMaxThreads)
        throw isouq::InputError("threads must be 0 (every core) or 1 to " + std::to_string(isouq::kMaxThreads) +
            ", got " + py::str(static_cast<const py::handle&>(value)).cast<std::string>());
    return int(n);
}

/// Runs @a work on the calling thread's Worker (in a TBB arena of @a threads, 0 for all cores)
/// with the GIL released; every 20 ms the caller takes the GIL back to run Python's signal
/// handlers (PyErr_CheckSignals: only the main thread has any), and a raised KeyboardInterrupt
/// cancels the work, which ends within one interrupter check. C++ errors come back as thrown.
template <typename Work>
auto runCancellable(int threads, Work work) -> decltype(work(static_cast<openvdb::util::NullInterrupter*>(nullptr)))
{
    using Result = decltype(work(static_cast<openvdb::util::NullInterrupter*>(nullptr)));
    checkNotForked();
    thread_local Worker worker;
    Worker* mine = &worker; // a thread_local named inside the job would be the worker thread's
    CancelInterrupter interrupter;
    auto task = std::make_shared<std::packaged_task<Result()>>([&, mine] {
        return mine->arena(threads).execute([&] { return work(&interrupter); });
    });
    std::future<Result> done = task->get_future();
    bool interrupted = false;
    {
        py::gil_scoped_release release;
        mine->post([task] { (*task)(); });
        while (done.wait_for(std::chrono::milliseconds(20)) != std::future_status::ready) {
            if (interrupted) continue;
            py::gil_scoped_acquire acquire;
            if (PyErr_CheckSignals() != 0) {
                interrupted = true;
                interrupter.cancel();
            }
        }
    }
    if (interrupted) {
        try {
            (void)done.get(); // the cancelled run's own error, if any, gives way to the signal
        } catch (...) {
        }
        throw py::error_already_set();
    }
    return done.get();
}

py::object toPython(const nlohmann::json& value)
{
    return py::module_::import("json").attr("loads")(value.dump());
}

/// A graph or parameters from Python: JSON values only, so NaN and infinities (which Python's
/// json writes and JSON has not) are refused with one line.
nlohmann::json fromPython(const py::handle& value)
{
    std::string text;
    try {
        text = py::module_::import("json").attr("dumps")(value, py::arg("allow_nan") = false).cast<std::string>();
    } catch (py::error_already_set& e) {
        if (!e.matches(PyExc_ValueError)) throw;
        throw isouq::InputError("a parameter is NaN or an infinity; parameters are finite numbers");
    }
    return nlohmann::json::parse(text);
}

/// A mesh a run kept: numpy views of its storage keep this object (and so the mesh) alive.
struct MeshHandle {
    std::shared_ptr<const nodes::MeshData> data;
};

/// A read-only numpy view of @a count rows of @a width values of T at @a ptr, owned by @a owner.
template <typename T>
py::array view(const T* ptr, std::size_t count, std::size_t width, py::handle owner)
{
    std::vector<py::ssize_t> shape{py::ssize_t(count)}, strides{py::ssize_t(sizeof(T) * width)};
    if (width > 1) {
        shape.push_back(py::ssize_t(width));
        strides.push_back(py::ssize_t(sizeof(T)));
    }
    py::array a(py::dtype::of<T>(), shape, strides, count ? ptr : nullptr, count ? owner : py::handle());
    py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
    return a;
}

py::dict columnsOf(const isouq::AttributeTable& table, py::handle owner)
{
    py::dict out;
    for (const isouq::Attribute& column : table.columns())
        std::visit([&](const auto& values) { out[py::str(column.name)] = view(values.data(), values.size(), 1, owner); },
            column.data);
    return out;
}

/// Scratch of edgesOf, kept per calling thread between calls: live mode builds an edge table for
/// every update, and fresh vectors of these sizes cost more in page faults than the table
/// (DESIGN.md "Memory and allocation"; docs/blender.md "Live mode").
struct EdgeScratch {
    std::vector<std::uint32_t> start, cursor, firstEdge;
    std::vector<std::uint64_t> bucket;
};

/// The mesh's unique undirected edges and each corner's edge, for hosts that store edges
/// (Blender's MEdge and MLoop.e; docs/blender.md "Live mode"). Corner 3t+c of triangle t runs
/// from vertex c to vertex (c+1)%3. Edges are ordered by (lower vertex, higher vertex), so the
/// result does not depend on the thread count: corners are bucketed by their lower vertex
/// (counting sort), each bucket is sorted by the higher vertex, and the edge ids follow the
/// buckets' prefix sums. Returns (edges E x 2 uint32, corner_edges 3M uint32).
py::tuple edgesOf(const MeshHandle& handle)
{
    checkNotForked(); // TBB runs the loops below
    const isouq::Mesh& mesh = handle.data->mesh;
    const std::size_t n = mesh.positions.size(), corners = 3 * mesh.triangles.size();
    if (corners >= std::size_t(std::numeric_limits<std::uint32_t>::max()))
        throw isouq::InputError("a mesh of " + std::to_string(corners) + " corners exceeds 32-bit edge indices");
    thread_local EdgeScratch scratch;
    EdgeScratch& s = scratch;
    py::array_t<std::uint32_t> cornerEdges{py::ssize_t(corners)};
    std::uint32_t* out = cornerEdges.mutable_data();
    const std::uint32_t* tri = corners ? mesh.triangles[0].asPointer() : nullptr;
    auto ends = [tri](std::size_t c, std::uint32_t& lo, std::uint32_t& hi) {
        const std::uint32_t a = tri[c], b = tri[c - c % 3 + (c % 3 + 1) % 3];
        lo = std::min(a, b);
        hi = std::max(a, b);
    };
    {
        py::gil_scoped_release release;
        s.start.assign(n + 1, 0);
        for (std::size_t c = 0; c < corners; ++c) {
            std::uint32_t lo, hi;
            ends(c, lo, hi);
            ++s.start[lo + 1];
        }
        for (std::size_t v = 0; v < n; ++v) s.start[v + 1] += s.start[v];
        s.bucket.resize(corners); // (higher vertex << 32) | corner
        s.cursor.assign(s.start.begin(), s.start.end() - 1);
        for (std::size_t c = 0; c < corners; ++c) {
            std::uint32_t lo, hi;
            ends(c, lo, hi);
            s.bucket[s.cursor[lo]++] = (std::uint64_t(hi) << 32) | c;
        }
        s.firstEdge.assign(n + 1, 0); // edges of lower vertex v: firstEdge[v]..
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t v = r.begin(); v < r.end(); ++v) {
                std::sort(s.bucket.begin() + s.start[v], s.bucket.begin() + s.start[v + 1]);
                std::uint32_t unique = 0;
                for (std::size_t i = s.start[v]; i < s.start[v + 1]; ++i)
                    unique += i == s.start[v] || (s.bucket[i] >> 32) != (s.bucket[i - 1] >> 32);
                s.firstEdge[v + 1] = unique;
            }
        });
        for (std::size_t v = 0; v < n; ++v) s.firstEdge[v + 1] += s.firstEdge[v];
    }
    py::array_t<std::uint32_t> edges({py::ssize_t(n ? s.firstEdge[n] : 0), py::ssize_t(2)});
    std::uint32_t* pairs = edges.mutable_data(); // lower, higher per edge
    {
        py::gil_scoped_release release;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t v = r.begin(); v < r.end(); ++v) {
                std::size_t e = s.firstEdge[v];
                for (std::size_t i = s.start[v]; i < s.start[v + 1]; ++i) {
                    if (i > s.start[v] && (s.bucket[i] >> 32) != (s.bucket[i - 1] >> 32)) ++e;
                    pairs[2 * e] = std::uint32_t(v);
                    pairs[2 * e + 1] = std::uint32_t(s.bucket[i] >> 32);
                    out[s.bucket[i] & 0xffffffffu] = std::uint32_t(e);
                }
            }
        });
    }
    return py::make_tuple(edges, cornerEdges);
}

/// Cooks one node outside a graph (the context a direct cook gets, Node.h) with @a given
/// parameters over the declared defaults; @a mesh feeds its "mesh" input.
nodes::CookContext cookAlone(const std::string& type, const nlohmann::json& given,
    std::vector<nodes::PendingWrite>* writes, std::vector<std::string>* warnings, const nodes::NodeValue* mesh,
    openvdb::util::NullInterrupter* interrupter)
{
    const nodes::NodeType* t = nodes::findNodeType(type);
    nodes::CookContext ctx;
    ctx.nodeId = type;
    ctx.parms = nodes::evaluateParms(given, type, *t); // checked as a graph's are
    ctx.writes = writes;
    ctx.warnings = warnings;
    ctx.interrupter = interrupter;
    if (mesh) ctx.inputs["mesh"] = mesh;
    t->cook(ctx);
    return ctx;
}

/// The CLI's writer of a path (meshWriterType: write_ply for .ply, write_vtp for .vtp), atomic.
void writeMesh(const MeshHandle& handle, const std::string& path, const std::string& format)
{
    checkNotForked(); // the writer formats on a TBB task
    const std::string type = nodes::meshWriterType(path);
    const bool vtp = type == "write_vtp";
    const std::string normal = std::filesystem::path(path).lexically_normal().string();
    nlohmann::json parms = {{"path", normal}};
    if (!vtp) parms["format"] = format;
    nodes::NodeValue input;
    input.mesh = handle.data;
    py::gil_scoped_release release;
    isouq::checkWritable(normal);
    std::vector<nodes::PendingWrite> writes;
    cookAlone(type, parms, &writes, nullptr, &input, nullptr);
    isouq::OutputBatch batch;
    for (const nodes::PendingWrite& w : writes) w.stage(batch);
    batch.commit();
}

/// What run() hands back: json outputs, files written, warnings, and the kept meshes.
py::dict resultOf(nodes::GraphResult result)
{
    py::dict out;
    out["outputs"] = toPython(result.outputs);
    out["written"] = py::cast(result.written);
    out["warnings"] = py::cast(result.warnings);
    py::dict meshes;
    for (auto& [id, mesh] : result.meshes) meshes[py::str(id)] = py::cast(MeshHandle{mesh});
    out["meshes"] = meshes;
    return out;
}

/// Runs a graph document (a dict) or file (a path) and keeps the meshes of @a keep.
py::dict run(const py::object& graph, const std::vector<std::string>& keep, const py::int_& threadCount,
    const std::string& outputDir)
{
    const int threads = threadsOf(threadCount);
    nodes::GraphOptions options;
    options.outputDir = outputDir;
    nodes::Graph parsed;
    if (py::isinstance<py::dict>(graph)) {
        parsed = nodes::parseGraph(fromPython(graph), options);
    } else {
        const std::string path = py::str(py::module_::import("os").attr("fspath")(graph));
        py::gil_scoped_release release;
        parsed = nodes::loadGraph(path, options);
    }
    for (const std::string& id : keep) {
        const auto node = std::find_if(parsed.nodes.begin(), parsed.nodes.end(), [&](const nodes::GraphNode& n) { return n.id == id; });
        if (node == parsed.nodes.end()) throw isouq::InputError("keep: the graph has no node '" + id + "'");
        if (std::none_of(node->type->outputs.begin(), node->type->outputs.end(), [](const nodes::PortSpec& p) { return p.type == "mesh"; }))
            throw isouq::InputError("keep: node '" + id + "' (" + node->type->type + ") has no mesh output");
    }
    if (!outputDir.empty()) std::filesystem::create_directories(outputDir);
    return resultOf(runCancellable(threads,
        [&](openvdb::util::NullInterrupter* interrupter) { return nodes::runGraph(parsed, interrupter, keep); }));
}

// --- in-memory volumes ---------------------------------------------------------------------

/// A registered `memory:N` input and what keeps its storage alive (the numpy array).
struct MemoryHandle {
    std::unique_ptr<isouq::ScopedMemoryVolume> scope;
    py::object keepAlive;
    std::string input() const { return scope->input(); }
};

/// Slices of a 3D array a[z, y, x] of T with byte strides (any layout: views, Fortran order,
/// negative strides), converted to float as the .raw reader converts its samples.
template <typename T>
std::function<void(int, int, float*)> sliceReader(const char* base, std::array<py::ssize_t, 3> strides, openvdb::Coord dims)
{
    return [=](int z0, int count, float* out) {
        for (int z = z0; z < z0 + count; ++z)
            for (int y = 0; y < dims.y(); ++y) {
                const char* row = base + z * strides[0] + y * strides[1];
                if (strides[2] == py::ssize_t(sizeof(T))) {
                    const T* v = reinterpret_cast<const T*>(row);
                    for (int x = 0; x < dims.x(); ++x) *out++ = float(v[x]);
                } else {
                    for (int x = 0; x < dims.x(); ++x) *out++ = float(*reinterpret_cast<const T*>(row + x * strides[2]));
                }
            }
    };
}

MemoryHandle registerArray(const py::array& array, const std::array<double, 3>& spacing,
    const std::array<double, 3>& origin)
{
    if (array.ndim() != 3)
        throw isouq::InputError("a volume array has 3 dimensions a[z, y, x], got " + std::to_string(array.ndim()));
    const py::dtype dtype = array.dtype();
    const char kind = dtype.kind();
    const std::size_t size = std::size_t(dtype.itemsize());
    if (dtype.attr("byteorder").cast<std::string>() == ">")
        throw isouq::InputError("a big-endian array: convert it with a.astype(a.dtype.newbyteorder('='))");
    auto volume = std::make_shared<isouq::MemoryVolume>();
    volume->dims = openvdb::Coord(int(array.shape(2)), int(array.shape(1)), int(array.shape(0)));
    for (int a = 0; a < 3; ++a)
        if (array.shape(a) > py::ssize_t(std::numeric_limits<std::int32_t>::max() - 8))
            throw isouq::InputError("an array axis of " + std::to_string(array.shape(a)) + " samples exceeds OpenVDB's index range");
    volume->spacing = openvdb::Vec3d(spacing[0], spacing[1], spacing[2]);
    volume->origin = openvdb::Vec3d(origin[0], origin[1], origin[2]);
    const std::string typeName = py::str(dtype.attr("name"));
    volume->name = "numpy " + typeName + " array";
    const char* base = static_cast<const char*>(array.data());
    const std::array<py::ssize_t, 3> strides{array.strides(0), array.strides(1), array.strides(2)};
    const openvdb::Coord dims = volume->dims;
    auto& read = volume->readSlices;
    if (kind == 'b' || (kind == 'u' && size == 1)) read = sliceReader<std::uint8_t>(base, strides, dims);
    else if (kind == 'i' && size == 1) read = sliceReader<std::int8_t>(base, strides, dims);
    else if (kind == 'u' && size == 2) read = sliceReader<std::uint16_t>(base, strides, dims);
    else if (kind == 'i' && size == 2) read = sliceReader<std::int16_t>(base, strides, dims);
    else if (kind == 'u' && size == 4) read = sliceReader<std::uint32_t>(base, strides, dims);
    else if (kind == 'i' && size == 4) read = sliceReader<std::int32_t>(base, strides, dims);
    else if (kind == 'u' && size == 8) read = sliceReader<std::uint64_t>(base, strides, dims);
    else if (kind == 'i' && size == 8) read = sliceReader<std::int64_t>(base, strides, dims);
    else if (kind == 'f' && size == 4) read = sliceReader<float>(base, strides, dims);
    else if (kind == 'f' && size == 8) read = sliceReader<double>(base, strides, dims);
    else throw isouq::InputError("arrays of " + typeName + " are not volumes (use an integer or float32/float64 dtype)");
    return MemoryHandle{std::make_unique<isouq::ScopedMemoryVolume>(volume), array};
}

/// A grid of another isouq.Volume or of pyopenvdb, shared as is (no copy, no densifying).
MemoryHandle registerGrid(openvdb::FloatGrid::Ptr grid, const std::string& name, py::object keepAlive)
{
    auto volume = std::make_shared<isouq::MemoryVolume>();
    volume->grid = std::move(grid);
    volume->name = name;
    return MemoryHandle{std::make_unique<isouq::ScopedMemoryVolume>(volume), std::move(keepAlive)};
}

/// A volume loaded once by the read_volume node and meshed many times (the add-on's live mode).
struct VolumeHandle {
    std::shared_ptr<const isouq::LoadedVolume> volume;
};

py::tuple load(const nlohmann::json& parms, const py::int_& threadCount)
{
    const int threads = threadsOf(threadCount);
    std::vector<std::string> warnings;
    auto volume = runCancellable(threads, [&](openvdb::util::NullInterrupter* interrupter) {
        nodes::CookContext ctx = cookAlone("read_volume", parms, nullptr, &warnings, nullptr, interrupter);
        return ctx.outputs.at("volume").volume;
    });
    return py::make_tuple(VolumeHandle{volume}, warnings);
}

} // namespace

PYBIND11_MODULE(_core, m)
{
    m.doc() = "Native part of the isouq package (use `import isouq`).";
    openvdb::initialize();

    static py::exception<isouq::InputError> inputError(m, "InputError", PyExc_ValueError);
    static py::exception<isouq::IoError> ioError(m, "IoError", PyExc_OSError);
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const isouq::InterruptedError&) {
            PyErr_SetString(PyExc_KeyboardInterrupt, "interrupted");
        } catch (const isouq::IoError& e) {
            ioError(isouq::oneLine(e.what()).c_str());
        } catch (const std::filesystem::filesystem_error& e) {
            ioError(isouq::oneLine(e.what()).c_str());
        } catch (const isouq::InputError& e) {
            inputError(isouq::oneLine(e.what()).c_str());
        } catch (const openvdb::Exception& e) {
            inputError(isouq::oneLine(e.what()).c_str());
        } catch (const nlohmann::json::exception& e) {
            inputError(isouq::oneLine(e.what()).c_str());
        }
    });

    py::class_<MeshHandle>(m, "MeshHandle")
        .def_property_readonly("vertices", [](py::object self) {
            const isouq::Mesh& mesh = self.cast<const MeshHandle&>().data->mesh;
            return view(mesh.positions.empty() ? nullptr : mesh.positions[0].asPointer(), mesh.positions.size(), 3, self);
        })
        .def_property_readonly("triangles", [](py::object self) {
            const isouq::Mesh& mesh = self.cast<const MeshHandle&>().data->mesh;
            return view(mesh.triangles.empty() ? nullptr : mesh.triangles[0].asPointer(), mesh.triangles.size(), 3, self);
        })
        .def_property_readonly("columns", [](py::object self) {
            return columnsOf(self.cast<const MeshHandle&>().data->mesh.vertexAttributes, self);
        })
        .def_property_readonly("face_columns", [](py::object self) {
            return columnsOf(self.cast<const MeshHandle&>().data->mesh.faceAttributes, self);
        })
        .def_property_readonly("isovalue", [](const MeshHandle& h) { return h.data->isovalue; })
        .def_property_readonly("method", [](const MeshHandle& h) { return h.data->method; })
        .def_property_readonly("info", [](const MeshHandle& h) { return toPython(h.data->info); })
        .def("edges", &edgesOf)
        .def("write", &writeMesh, py::arg("path"), py::arg("format") = "binary");

    py::class_<MemoryHandle>(m, "MemoryHandle").def_property_readonly("input", &MemoryHandle::input);
    py::class_<VolumeHandle>(m, "VolumeHandle")
        .def_property_readonly("isovalue", [](const VolumeHandle& v) { return v.volume->isovalue; })
        .def_property_readonly("isovalue_source", [](const VolumeHandle& v) { return v.volume->isovalueSource; })
        .def_property_readonly("description", [](const VolumeHandle& v) { return v.volume->description; })
        .def_property_readonly("name", [](const VolumeHandle& v) { return v.volume->grid->getName(); });

    m.def("nodes_json", [] { return nodes::nodeTypesJson().dump(); });
    m.def("mesh_graph", [](const py::dict& request) {
        const nlohmann::json r = fromPython(request);
        nodes::MeshGraphRequest req;
        req.read = r.at("read");
        req.mesh = r.at("mesh");
        req.hidden = r.at("hidden");
        req.hiddenFeatures = r.at("hidden_features").get<bool>();
        return toPython(nodes::meshGraph(req));
    }, py::arg("request"));
    m.def("run", &run, py::arg("graph"), py::arg("keep") = std::vector<std::string>(), py::arg("threads") = 0,
        py::arg("output_dir") = "");
    m.def("register_array", &registerArray, py::arg("array"), py::arg("spacing"), py::arg("origin"));
    m.def("register_volume", [](const VolumeHandle& v, py::object owner) {
        return registerGrid(v.volume->grid, v.volume->description, std::move(owner));
    });
#ifdef ISOUQ_WITH_PYOPENVDB
    m.def("register_pyopenvdb", [](py::object grid) {
        namespace bp = boost::python;
        bp::object object(bp::handle<>(bp::borrowed(grid.ptr())));
        bp::extract<openvdb::FloatGrid::Ptr> floatGrid(object);
        if (!floatGrid.check()) {
            std::string type = py::str(py::type::of(grid).attr("__name__"));
            throw isouq::InputError("a pyopenvdb." + type + " is not a float scalar grid (use a pyopenvdb.FloatGrid)");
        }
        openvdb::FloatGrid::Ptr shared = floatGrid();
        return registerGrid(shared, "pyopenvdb grid '" + shared->getName() + "'", grid);
    });
#endif
    m.attr("has_pyopenvdb") =
#ifdef ISOUQ_WITH_PYOPENVDB
        true;
#else
        false;
#endif
    m.def("load", [](const py::dict& parms, const py::int_& threads) { return load(fromPython(parms), threads); },
        py::arg("parms"), py::arg("threads") = 0);
}
