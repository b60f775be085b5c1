"""The Python module `isouq` (SPEC §10 "Python"; docs/python.md) against the CLI: a numpy array
meshes to exactly the CLI's PLY of the same .raw bytes (every column, bit for bit), a pyopenvdb
grid to the mesh of its .vdb path; bad input raises InputError with the CLI's one-line message;
the GIL is released during a call and Ctrl-C cancels it within a second.
"""
import json
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


def module_dir():
    """build/python (ctest sets ISOUQ_PYTHON_DIR), holding the package isouq and its _core."""
    return Path(os.environ.get("ISOUQ_PYTHON_DIR", REPO / "build" / "python"))


@pytest.fixture(scope="module")
def isouq():
    if os.environ.get("ISOUQ_PYTHON_DIR") == "":
        pytest.skip("this build has no isouq Python module (ctest passes an empty ISOUQ_PYTHON_DIR)")
    folder = module_dir()
    if not (folder / "isouq" / "__init__.py").is_file():
        pytest.skip(f"no isouq Python module in {folder} (build the isouq_python target)")
    sys.path.insert(0, str(folder))
    import isouq as module
    assert Path(module.__file__).resolve().parent == (folder / "isouq").resolve()
    return module


def bits(a):
    """The bytes of an array in C order: equal bytes are equal floats, NaNs included."""
    return np.ascontiguousarray(a).tobytes()


def assert_same_mesh(m, ply):
    """m (isouq.Mesh) equals the PLY the CLI wrote, bit for bit: positions, triangles, every
    vertex and face column with its type."""
    assert bits(m.vertices) == bits(ply.positions)
    assert m.triangles.shape == (ply.face_count, 3)
    assert np.array_equal(m.triangles.astype(np.int64), ply.triangles.astype(np.int64))
    assert list(m.columns) == list(ply.vertex_attributes)
    for name, values in ply.vertex_attributes.items():
        assert m.columns[name].dtype == values.dtype, name
        assert bits(m.columns[name]) == bits(values), name
    assert sorted(m.face_columns) == sorted(ply.face_attributes)
    for name, values in ply.face_attributes.items():
        assert bits(m.face_columns[name]) == bits(values), name


def cli_summary(isouq_cli, tmp_path, *args):
    out, summary = tmp_path / "cli.ply", tmp_path / "cli.json"
    cmd = [isouq_cli, "mesh", *map(str, args), "-o", str(out), "--summary", str(summary), "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return ply_io.read_ply(out), json.loads(summary.read_text()), out


def comparable(summary):
    """A summary without what names the run (input, grid, output, description) or times it."""
    return {k: v for k, v in summary.items() if k not in ("timings_ms", "input", "grid", "output", "description")}


@pytest.mark.parametrize("name,isovalue", [("bucky_32x32x32_uint8.raw", 51), ("fuel_64x64x64_uint8.raw", None)])
def test_numpy_uint8_equals_cli_ply(isouq, isouq_cli, data_dir, tmp_path, name, isovalue):
    path = data_dir / name
    dims = [int(v) for v in name.split("_")[1].split("x")]
    array = np.fromfile(path, np.uint8).reshape(dims[2], dims[1], dims[0])  # a[z, y, x] as the file
    args = [path] + (["--isovalue", isovalue] if isovalue is not None else [])
    ply, summary, cli_ply = cli_summary(isouq_cli, tmp_path, *args)
    m = isouq.mesh(array, isovalue=isovalue)
    assert len(m.vertices) > 1000 and m.vertices.dtype == np.float32 and m.vertices.shape[1] == 3
    assert_same_mesh(m, ply)
    assert comparable(m.summary) == comparable(summary)
    # The CLI's writer: the same bytes as the CLI's file.
    m.write(tmp_path / "py.ply")
    assert (tmp_path / "py.ply").read_bytes() == cli_ply.read_bytes()
    # Any layout is read in place as a[z, y, x]: a Fortran-ordered copy, a reversed view.
    assert bits(isouq.mesh(np.asfortranarray(array), isovalue=isovalue).vertices) == bits(m.vertices)
    reversed_z = array[::-1].copy()[::-1]  # negative z stride
    wide = np.zeros(array.shape[:2] + (2 * array.shape[2],), np.uint8)
    wide[:, :, ::2] = array  # x stride of 2 bytes
    for view in (reversed_z, wide[:, :, ::2]):
        assert not view.flags.c_contiguous
        assert bits(isouq.mesh(view, isovalue=isovalue).columns["err_est"]) == bits(m.columns["err_est"])


def test_numpy_float_with_spacing_and_hidden(isouq, isouq_cli, data_dir, tmp_path):
    """float32 skull with its spacing (SPEC §8 --spacing) and hidden features: both meshes."""
    path = data_dir / "skull_64x64x64_float32.raw"
    spacing = (3.94305, 3.94305, 3.65079)
    array = np.fromfile(path, "<f4").reshape(64, 64, 64)
    hidden_ply = tmp_path / "hidden.ply"
    ply, summary, _ = cli_summary(isouq_cli, tmp_path, path, "--isovalue", 2.9, "--spacing",
                                  ",".join(map(str, spacing)), "--hidden-features", "--hidden-out", hidden_ply)
    m = isouq.mesh(array.astype(np.float64), isovalue=2.9, spacing=spacing, hidden_features=True)
    assert_same_mesh(m, ply)
    assert_same_mesh(m.hidden, ply_io.read_ply(hidden_ply))
    assert m.hidden.summary == {k: v for k, v in summary["hidden"].items() if k != "output"}
    assert comparable(m.summary) == comparable(summary) | {"hidden": m.hidden.summary}


def test_origin_moves_vertices(isouq):
    z, y, x = np.mgrid[-1:1:24j, -1:1:24j, -1:1:24j]
    ball = (x * x + y * y + z * z).astype(np.float32)
    base = isouq.mesh(ball, isovalue=0.5, method="cubic")
    moved = isouq.mesh(ball, isovalue=0.5, method="cubic", origin=(10, 20, 30), spacing=(2, 2, 2))
    assert np.allclose(moved.vertices, base.vertices * 2 + np.array([10, 20, 30], np.float32), atol=1e-4)
    assert bits(moved.columns["t_cubic"]) == bits(base.columns["t_cubic"])


def test_pyopenvdb_grid_equals_path(isouq, data_dir, tmp_path):
    pyopenvdb = pytest.importorskip("pyopenvdb")
    if not isouq._core.has_pyopenvdb:
        pytest.skip("isouq built without Boost.Python / pyopenvdb.h")
    path = str(data_dir / "smoke.vdb")
    grid = pyopenvdb.read(path, "density")
    before = grid.activeVoxelCount()
    from_grid = isouq.mesh(grid, isovalue=0.1)
    from_path = isouq.mesh(path, isovalue=0.1, grid="density")
    assert len(from_grid.vertices) > 1000
    for a, b in [(from_grid.vertices, from_path.vertices), (from_grid.triangles, from_path.triangles)]:
        assert bits(a) == bits(b)
    assert list(from_grid.columns) == list(from_path.columns)
    for name in from_path.columns:
        assert bits(from_grid.columns[name]) == bits(from_path.columns[name]), name
    assert comparable(from_grid.summary) == comparable(from_path.summary)
    assert grid.activeVoxelCount() == before  # shared, not changed
    with pytest.raises(isouq.InputError, match="not a float scalar grid"):
        isouq.mesh(pyopenvdb.Vec3SGrid())


def test_loaded_volume_meshes_every_isovalue(isouq, data_dir):
    """load() once (keep=non_constant), mesh at another isovalue: the mesh of the file there."""
    path = str(data_dir / "fuel_64x64x64_uint8.raw")
    volume = isouq.load(path)
    assert volume.isovalue_source.startswith("Otsu")
    for k in (40.0, 90.0):
        a, b = isouq.mesh(volume, isovalue=k), isouq.mesh(path, isovalue=k)
        assert bits(a.vertices) == bits(b.vertices) and bits(a.triangles) == bits(b.triangles)
        assert bits(a.columns["err_est"]) == bits(b.columns["err_est"])


def cli_error(isouq_cli, *args):
    done = subprocess.run([isouq_cli, *map(str, args)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    line = done.stderr.strip()
    assert line.startswith("isouq: error: ")
    return line[len("isouq: error: "):]


def test_bad_input_raises_one_line(isouq, isouq_cli, tmp_path):
    missing = tmp_path / "nothing_8x8x8_uint8.raw"
    cases = {
        "2D array": (lambda: isouq.mesh(np.zeros((4, 4), np.float32)), "3 dimensions"),
        "missing file": (lambda: isouq.mesh(str(missing)), "no such file"),
        "all NaN": (lambda: isouq.mesh(np.full((9, 9, 9), np.nan, np.float32)), "finite"),
        "all NaN, isovalue given": (lambda: isouq.mesh(np.full((9, 9, 9), np.nan, np.float32), isovalue=0), "finite"),
        "unknown method": (lambda: isouq.mesh("field:tangle", resolution=16, method="spline"), "method"),
        "complex array": (lambda: isouq.mesh(np.zeros((4, 4, 4), np.complex64)), "not volumes"),
        "unknown field": (lambda: isouq.mesh("field:nope"), "unknown field"),
    }
    for what, (call, words) in cases.items():
        with pytest.raises(isouq.InputError) as e:
            call()
        assert isinstance(e.value, ValueError)
        message = str(e.value)
        assert "\n" not in message and words in message, f"{what}: {message}"
    # The CLI's own line for the same input.
    with pytest.raises(isouq.InputError) as e:
        isouq.mesh(str(missing))
    assert str(e.value) == cli_error(isouq_cli, "mesh", missing, "-o", tmp_path / "x.ply")
    with pytest.raises(isouq.InputError) as e:
        isouq.mesh("field:nope")
    assert str(e.value) == cli_error(isouq_cli, "mesh", "field:nope", "-o", tmp_path / "x.ply")
    nan = tmp_path / "nan_9x9x9_float32.raw"
    np.full((9, 9, 9), np.nan, "<f4").tofile(nan)
    with pytest.raises(isouq.InputError) as e:
        isouq.mesh(np.fromfile(nan, "<f4").reshape(9, 9, 9))
    assert str(e.value) == cli_error(isouq_cli, "mesh", nan, "-o", tmp_path / "x.ply")
    # write(): an unwritable folder is an IoError (an OSError) and leaves nothing.
    m = isouq.mesh("field:tangle", resolution=16)
    with pytest.raises(isouq.IoError):
        m.write(tmp_path / "no" / "such" / "folder.ply")


def test_arguments_that_would_be_ignored_or_misread_raise(isouq, data_dir, tmp_path):
    """Found by a hostile sweep (docs/hardening.md, 7 Dec): each of these was a crash, a JSON
    parser's message, a silent no-op or a silently wrong reading."""
    ball = np.zeros((12, 12, 12), np.float32)
    ball[4:8, 4:8, 4:8] = 1
    bucky = str(data_dir / "bucky_32x32x32_uint8.raw")
    grid_like = isouq.load(ball, isovalue=0.5)
    cases = {
        "threads huge (TBB crashed)": (lambda: isouq.mesh(ball, isovalue=0.5, threads=10**7), "threads must be"),
        "threads negative": (lambda: isouq.mesh(ball, isovalue=0.5, threads=-2), "threads must be"),
        "threads beyond 64 bits (was pybind11's TypeError)": (lambda: isouq.load(ball, threads=10**30), "got 1000000000000000000000000000000"),
        "a masked array (its mask was dropped)": (lambda: isouq.mesh(np.ma.masked_less(ball, 0.5), isovalue=0.5), "mask"),
        "NaN isovalue": (lambda: isouq.mesh(ball, isovalue=float("nan")), "isovalue must be a finite number"),
        "infinite spacing": (lambda: isouq.mesh(bucky, spacing=(float("inf"), 1, 1)), "spacing must be"),
        "NaN domain": (lambda: isouq.mesh("formula:x", domain=(float("nan"), 1)), "domain must be"),
        "NaN in a graph": (lambda: isouq.run({"nodes": [{"id": "r", "type": "read_volume",
                                                          "parms": {"input": "field:sphere", "isovalue": float("nan")}}]}),
                           "NaN or an infinity"),
        "method None": (lambda: isouq.mesh(ball, isovalue=0.5, method=None), "method must be a string"),
        "spacing a string (read as 1, 2, 3)": (lambda: isouq.mesh(bucky, spacing="123"), "three numbers"),
        "origin of a file": (lambda: isouq.mesh(bucky, origin=(100, 0, 0)), "origin is for numpy arrays"),
        "spacing of a Volume": (lambda: isouq.mesh(grid_like, spacing=(2, 2, 2)), "keeps its own transform"),
        "resolution of an array": (lambda: isouq.mesh(ball, isovalue=0.5, resolution=16), "field: and formula:"),
        "unknown keep of load": (lambda: isouq.load(ball, keep="bogus"), "not one of"),
        "keep of a node not there": (lambda: isouq.run({"nodes": [{"id": "r", "type": "read_volume",
                                                                   "parms": {"input": "field:sphere"}}]}, keep=["nope"]),
                                     "no node 'nope'"),
    }
    for what, (call, words) in cases.items():
        with pytest.raises(isouq.InputError) as e:
            call()
        assert words in str(e.value) and "json.exception" not in str(e.value), f"{what}: {e.value}"
    m = isouq.mesh(ball, isovalue=0.5)
    with pytest.raises(isouq.InputError, match="not one of"):
        m.write(tmp_path / "f.ply", format="bogus")
    with pytest.raises(isouq.InputError, match="NUL"):  # was written to tmp_path / "x"
        m.write(str(tmp_path / "x\0y.ply"))
    with pytest.raises(isouq.InputError, match="not a mesh format isouq writes"):  # was PLY bytes named .obj
        m.write(tmp_path / "x.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    # A bytes path is a path, as os.fsdecode reads it.
    assert len(isouq.mesh(os.fsencode(bucky), isovalue=51).vertices) == len(isouq.mesh(bucky, isovalue=51).vertices)


def test_a_forked_child_raises_rather_than_hangs(isouq):
    isouq.mesh("field:tangle", resolution=16)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: the parent's worker thread did not come along
        os.close(read)
        try:  # another entry point than the parent's first: each is checked
            isouq.load("field:tangle", resolution=16)
            message = b"no error"
        except RuntimeError as e:
            message = str(e).encode()
        os.write(write, message)
        os._exit(0)
    os.close(write)
    deadline, ended = time.time() + 60, (0, 0)
    while time.time() < deadline and ended == (0, 0):
        time.sleep(0.05)
        ended = os.waitpid(pid, os.WNOHANG)
    if ended == (0, 0):
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's call hung")
    with os.fdopen(read, "rb") as r:
        assert b"spawn" in r.read()


def test_other_thread_runs_during_a_long_call(isouq):
    ticks, stop = [], threading.Event()

    def count():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.005)

    t = threading.Thread(target=count)
    t.start()
    try:
        start = time.perf_counter()
        m = isouq.mesh("field:tangle", resolution=256)  # long enough (> 0.3 s) on a quiet machine
        elapsed = time.perf_counter() - start
    finally:
        stop.set()
        t.join()
    during = [x for x in ticks if start < x < start + elapsed]
    assert elapsed > 0.3 and len(m.vertices) > 0
    # The counter ran all along: at least half the ticks a free 5 ms loop would make.
    assert len(during) > 0.5 * elapsed / 0.0055, (len(during), elapsed)


@pytest.mark.parametrize("call", [
    'isouq.mesh("field:tangle", resolution=600)',  # about 5-20 s on 2 cores
    # No isovalue: Otsu's two passes over 10^11 samples (a view: no memory) come first.
    'isouq.mesh(np.broadcast_to(np.float32(1), (100_000, 1000, 1000)))',
])
def test_keyboard_interrupt_cancels_within_a_second(isouq, tmp_path, call):
    script = textwrap.dedent(f"""
        import os, signal, sys, threading, time
        import numpy as np
        sys.path.insert(0, {str(module_dir())!r})
        import isouq
        sent = []
        def interrupt():
            sent.append(time.perf_counter())
            os.kill(os.getpid(), signal.SIGINT)
        threading.Timer(0.5, interrupt).start()
        start = time.perf_counter()
        try:
            {call}
        except KeyboardInterrupt:
            print(f"cancelled {{time.perf_counter() - sent[0]:.3f}}")
            sys.exit(0)
        print(f"finished after {{time.perf_counter() - start:.1f}} s: no cancellation")
        sys.exit(1)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    latency = float(done.stdout.split()[1])
    assert latency < 1.0 * float(os.environ.get("ISOUQ_TEST_TIME_SCALE", "1")), done.stdout  # sanitize.sh: 3


def test_nodes_and_run(isouq, tmp_path):
    doc = isouq.nodes()
    assert {"read_volume", "mesh", "summary"} <= {n["type"] for n in doc["nodes"]}
    assert "err_est" in {c["name"] for c in doc["columns"]}
    graph = {"nodes": [
        {"id": "read", "type": "read_volume", "parms": {"input": "field:teardrop", "resolution": 32}},
        {"id": "mesh", "type": "mesh", "inputs": {"volume": "read"}},
        {"id": "sum", "type": "summary", "inputs": {"mesh": "mesh"}},
        {"id": "save", "type": "write_ply", "parms": {"path": "t.ply"}, "inputs": {"mesh": "mesh"}}]}
    result = isouq.run(graph, keep=["mesh"], output_dir=tmp_path)
    assert result.written == [str(tmp_path / "t.ply")]
    assert result.outputs["sum"]["summary"]["vertices"] == len(result.meshes["mesh"].vertices)
    path = tmp_path / "g.json"
    path.write_text(json.dumps(graph))
    again = isouq.run(path, output_dir=tmp_path / "again")
    assert (tmp_path / "again" / "t.ply").read_bytes() == (tmp_path / "t.ply").read_bytes()
    assert again.meshes == {}
    with pytest.raises(isouq.InputError, match="unknown node type"):
        isouq.run({"nodes": [{"id": "x", "type": "nope"}]})


def test_arrays_are_views(isouq):
    m = isouq.mesh("field:tangle", resolution=24)
    a = m.columns["err_est"]
    assert not a.flags.writeable and not a.flags.owndata
    del m  # the arrays keep the mesh alive
    assert np.isfinite(a).any()


@pytest.mark.parametrize("source,kwargs", [("field:tangle", {"resolution": 24}),
                                           ("fuel_64x64x64_uint8.raw", {"isovalue": 80.0})])
def test_edges_equal_a_brute_force_count(isouq, data_dir, source, kwargs):
    """Mesh.edges() (Blender's live mode gives them to the mesh): every triangle side once,
    sorted by (lower, higher) vertex, each corner naming its side (against a Python set of
    the sides); the same result on a second call."""
    if source.endswith(".raw"):
        source = str(data_dir / source)
    m = isouq.mesh(source, summary=False, **kwargs)
    edges, corner_edges = m.edges()
    assert edges.dtype == np.uint32 and corner_edges.dtype == np.uint32
    tri = m.triangles.astype(np.int64)
    sides = [(min(a, b), max(a, b)) for t in tri.tolist() for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))]
    assert [tuple(e) for e in edges.tolist()] == sorted(set(sides))
    assert len(corner_edges) == len(sides)
    assert [tuple(e) for e in edges[corner_edges].tolist()] == sides
    isouq.mesh("field:tangle", resolution=40, summary=False).edges()  # the scratch of a bigger mesh
    again = m.edges()
    assert bits(again[0]) == bits(edges) and bits(again[1]) == bits(corner_edges)


def test_high_order_off_is_the_full_pass_linear_part(isouq, data_dir):
    """high_order=False (the estimate pass; Blender's live mode while only linear columns are
    shown): the full pass's triangles, positions, provenance, err_est and err_bound bit for bit,
    no high-order column; the linear-only pass has the same positions; refused for weno."""
    path = str(data_dir / "fuel_64x64x64_uint8.raw")
    full = isouq.mesh(path, isovalue=80.0, method="linear", summary=False)
    fast = isouq.mesh(path, isovalue=80.0, method="linear", summary=False, high_order=False)
    assert bits(fast.vertices) == bits(full.vertices) and bits(fast.triangles) == bits(full.triangles)
    assert set(fast.columns) == {"edge_i", "edge_j", "edge_k", "edge_axis", "t_linear", "err_est", "err_bound"}
    for name, column in fast.columns.items():
        assert bits(column) == bits(full.columns[name]), name
    linear = isouq.mesh(path, isovalue=80.0, linear_only=True, summary=False)
    assert bits(linear.vertices) == bits(full.vertices) and bits(linear.triangles) == bits(full.triangles)
    with pytest.raises(ValueError, match="high_order"):
        isouq.mesh(path, isovalue=80.0, high_order=False)


def test_example_notebook(isouq, tmp_path):
    """examples/python/threshold_err_est.py meshes an array, thresholds err_est, writes a PNG."""
    env = dict(os.environ, PYTHONPATH=str(module_dir()), MPLBACKEND="Agg")
    png = tmp_path / "err_est.png"
    done = subprocess.run([sys.executable, str(REPO / "examples" / "python" / "threshold_err_est.py"), str(png)],
                          capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20000
    assert "above the 90th percentile" in done.stdout


def test_dicom_loads_gdcm_on_first_use_and_meshes_as_the_cli(isouq, isouq_cli, tmp_path):
    """GDCM is a module of its own (libisouq_gdcm.so, beside _core): `import isouq` does not load
    it (its dictionary costs about 50 ms), the first DICOM series does, and the series meshes in
    process to the CLI's PLY, bit for bit."""
    pytest.importorskip("pydicom")
    from test_formats_in import ISOVALUE, write_series
    write_series(tmp_path / "series")
    cli_summary(isouq_cli, tmp_path, tmp_path / "series", "--isovalue", ISOVALUE)
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(module_dir())!r})
        maps = lambda: open("/proc/self/maps").read()
        import isouq
        print("gdcm after import:", "libgdcm" in maps())
        m = isouq.mesh({str(tmp_path / "series")!r}, isovalue={ISOVALUE!r})
        print("gdcm after the series:", "libisouq_gdcm.so" in maps() and "libgdcm" in maps())
        m.write({str(tmp_path / "module.ply")!r})
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines() == ["gdcm after import: False", "gdcm after the series: True"]
    assert (tmp_path / "module.ply").read_bytes() == (tmp_path / "cli.ply").read_bytes()
