# The isouq Python module in process (native.py) and live mode (live.py; docs/blender.md): the
# module loads beside the add-on (both are `isouq`), "Run on a VDB" meshes without a subprocess
# or a PLY and gives the module's own arrays, and in live mode a new isovalue or method changes
# the object's mesh in place. Timings of slider change -> updated object are printed (and
# written to $ISOUQ_LIVE_TIMINGS as JSON) for docs/blender.md.

import json
import os
import subprocess
import time

import bpy
import numpy as np
import pytest

import isouq as addon
from isouq import attributes, live, native

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.environ.get("ISOUQ_DATA_DIR", os.path.join(HERE, "..", "..", "..", "shared", "data"))


@pytest.fixture
def module(monkeypatch):
    if os.environ.get(native.ENV_DIR) == "":
        pytest.skip("this build has no isouq Python module (ctest passes an empty ISOUQ_PYTHON_DIR)")
    monkeypatch.setenv(native.ENV_SWITCH, "1")
    found = native.load()
    if found is None:
        pytest.skip(f"no isouq Python module: {native.error()} (build the isouq_python target)")
    yield found
    bpy.context.scene.isouq.live = False


@pytest.fixture
def no_subprocess(monkeypatch):
    """Any subprocess the add-on would start fails the test."""
    def refuse(*args, **kwargs):
        raise AssertionError(f"a subprocess was started: {args[:1]}")
    monkeypatch.setattr(subprocess, "Popen", refuse)
    monkeypatch.setattr(subprocess, "run", refuse)


def arrays(obj):
    me = obj.data
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    tri = np.empty(3 * len(me.polygons), np.int32)
    me.polygons.foreach_get("vertices", tri)
    return co.reshape(-1, 3), tri.reshape(-1, 3)


def run_timer(function):
    """Calls a timer function as Blender would (background Blender runs no timers) until it
    stops; returns how many times it asked to be called again."""
    polls, wait = 0, function()
    while wait is not None:
        polls += 1
        time.sleep(wait)
        wait = function()
    return polls


def run_in_process(context, path, **settings):
    s = context.scene.isouq
    s.input_path = path
    for key, value in settings.items():
        setattr(s, key, value)
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    return context.view_layer.objects.active


def test_module_loads_beside_the_addon(module):
    assert module.__name__ == native.NAME and hasattr(module, "mesh")
    assert hasattr(addon, "bl_info")  # `import isouq` is still the add-on
    assert module.InputError is module._core.InputError


def test_run_in_process_equals_the_module(module, no_subprocess, empty_scene):
    obj = run_in_process(empty_scene, "field:tangle", resolution=32, method="cubic")
    assert obj.isouq.role == "MESH" and live.REQUEST_KEY in obj
    direct = module.mesh("field:tangle", resolution=32, method="cubic")
    co, tri = arrays(obj)
    assert co.tobytes() == np.ascontiguousarray(direct.vertices).tobytes()
    assert np.array_equal(tri, direct.triangles.astype(np.int32))
    for name in ("err_est", "t_cubic", "edge_axis", "err_true_cubic"):
        got = attributes.get_attribute(obj.data, name)
        assert np.array_equal(got, direct.columns[name].astype(got.dtype), equal_nan=True), name
    assert json.loads(obj.isouq.summary)["vertices"] == len(direct.vertices)
    assert obj.data["isouq_method"] == "cubic"


def test_run_in_process_reports_the_cli_error(module, no_subprocess, empty_scene):
    s = empty_scene.scene.isouq
    s.input_path = "field:nope"
    with pytest.raises(RuntimeError, match="unknown field 'nope'"):
        bpy.ops.isouq.run_pipeline()


def test_live_isovalue_and_method_change_the_mesh(module, no_subprocess, empty_scene):
    context = empty_scene
    obj = run_in_process(context, "field:tangle", resolution=32, use_isovalue=True, isovalue=0.0)
    s = context.scene.isouq
    me = obj.data
    before, _ = arrays(obj)
    s.live = True
    live.flush(context)
    s.isovalue = 0.2
    assert bpy.app.timers.is_registered(live._tick)  # debounced, not meshed in the update
    bpy.app.timers.unregister(live._tick)
    # What the timer does (background Blender runs no timers): the mesher on a thread, polled
    # every 10 ms, then the copy into Blender.
    polls, wait = 0, live._tick()
    while wait is not None:
        polls += 1
        time.sleep(wait)
        wait = live._tick()
    assert polls >= 1 and live.last_timing["vertices"] > 0
    after, _ = arrays(obj)
    assert obj.data == me  # in place: the same mesh data block
    expected = module.mesh(module.load("field:tangle", resolution=32), isovalue=0.2)
    assert len(after) == len(expected.vertices) != len(before)
    assert after.tobytes() == np.ascontiguousarray(expected.vertices).tobytes()
    # The shown view's column (the heat map's err_est) at once; the others REST s later.
    assert "err_est" in live.shown_columns(context, obj) and "t_cubic" not in live.shown_columns(context, obj)
    assert np.array_equal(attributes.get_attribute(me, "err_est"), expected.columns["err_est"], equal_nan=True)
    assert me.attributes.get("t_cubic") is None
    assert bpy.app.timers.is_registered(live._complete_tick)
    bpy.app.timers.unregister(live._complete_tick)
    run_timer(live._complete_tick)  # REST s after the update
    assert live.last_timing["rest_columns"] > 10
    for name, column in expected.columns.items():
        got = attributes.get_attribute(me, name)
        assert np.array_equal(got, column.astype(got.dtype), equal_nan=True), name
    # The module's edge table (Mesh.edges): every triangle side once, each corner on its side.
    _, tri = arrays(obj)
    sides = {tuple(sorted(p)) for t in tri.tolist() for p in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    pairs = np.empty(2 * len(me.edges), np.int32)
    me.edges.foreach_get("vertices", pairs)
    assert {tuple(sorted(p)) for p in pairs.reshape(-1, 2).tolist()} == sides and len(me.edges) == len(sides)
    corner_edge = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("edge_index", corner_edge)
    sides_in_order = [tuple(sorted(p)) for t in tri.tolist() for p in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))]
    assert [tuple(sorted(p)) for p in pairs.reshape(-1, 2)[corner_edge].tolist()] == sides_in_order
    assert me.validate() is False  # nothing for Blender to fix
    s.method = "linear"
    live.flush(context)
    linear, _ = arrays(obj)
    assert obj.isouq.method_shown == "linear" and len(linear) == len(after)
    assert not np.array_equal(linear, after)
    # Same faces: the faces and edges stayed, positions and columns are the new method's.
    assert np.array_equal(arrays(obj)[1], tri) and len(me.edges) == len(sides)
    direct = module.mesh(module.load("field:tangle", resolution=32), isovalue=0.2, method="linear")
    assert linear.tobytes() == np.ascontiguousarray(direct.vertices).tobytes()
    assert attributes.stored_positions(me).tobytes() == linear.tobytes()  # C3's primary, not stale
    assert np.array_equal(attributes.get_attribute(me, "err_est"), direct.columns["err_est"], equal_nan=True)
    # The threshold redoes the views (C1 selection) without re-meshing.
    obj["isouq_view_selection"] = "THRESHOLD"
    s.measure = "err_est"
    s.threshold_value = 0.0
    live.flush(context)
    s.threshold_value = float(np.nanmedian(attributes.get_attribute(me, "err_est")))
    live.flush(context)
    selected = attributes.get_attribute(me, "isouq_selected")
    assert selected is not None and 0 < selected.sum() < len(selected)
    s.live = False
    s.isovalue = 1.0
    assert live.flush(context) is None  # off: nothing queued


def test_live_linear_view_meshes_the_cheaper_pass(module, no_subprocess, empty_scene):
    """The linear method under the err_est heat map: an update runs the extraction plus
    estimate pass (high_order=False) and fills the positions and err_est, equal to the full
    pass's; REST s later the full pass fills every column, the faces kept."""
    context = empty_scene
    obj = run_in_process(context, "field:tangle", resolution=32, use_isovalue=True, isovalue=0.0,
                         method="linear")
    s = context.scene.isouq
    s.live = True
    s.isovalue = 0.2
    bpy.app.timers.unregister(live._tick)
    run_timer(live._tick)
    assert live.last_timing["mesher_pass"] == "estimate"
    me = obj.data
    full = module.mesh(module.load("field:tangle", resolution=32), isovalue=0.2, method="linear")
    co, tri = arrays(obj)
    assert co.tobytes() == np.ascontiguousarray(full.vertices).tobytes()
    assert np.array_equal(tri, full.triangles.astype(np.int32))
    assert np.array_equal(attributes.get_attribute(me, "err_est"), full.columns["err_est"], equal_nan=True)
    assert me.attributes.get("t_weno") is None
    bpy.app.timers.unregister(live._complete_tick)
    assert run_timer(live._complete_tick) >= 2  # the full pass on the worker, polled
    assert live.last_timing["rest_remeshed"]
    for name, column in full.columns.items():
        got = attributes.get_attribute(me, name)
        assert np.array_equal(got, column.astype(got.dtype), equal_nan=True), name
    assert np.array_equal(arrays(obj)[1], tri) and me.validate() is False


def live_timings(context, path, isovalues, **settings):
    obj = run_in_process(context, path, use_isovalue=True, isovalue=isovalues[0], **settings)
    s = context.scene.isouq
    s.live = True
    live.flush(context)  # loads the volume once (reported apart)
    load = dict(live.last_timing)
    rows = []
    for k in isovalues[1:] * 3:
        s.isovalue = k
        rows.append(dict(live.flush(context)))
    methods = []  # same faces: positions and columns only (attributes.fill_mesh)
    for method in ("linear", "cubic", "weno") * 3:
        s.method = method
        methods.append(dict(live.flush(context)))
    s.method = "linear"  # the heat map of err_est on linear crossings: the cheaper pass
    live.flush(context)
    linear = []
    for k in isovalues[1:] * 3:
        s.isovalue = k
        linear.append(dict(live.flush(context)))
    s.live = False
    return obj, load, rows, methods, linear


@pytest.mark.parametrize("name,grid,isovalues", [
    ("smoke.vdb", "density", [0.1, 0.12, 0.15, 0.2]),
    ("fuel_64x64x64_uint8.raw", "", [62.0, 70.0, 80.0, 90.0]),
    ("brainsmall_128x128x84_uint8.raw", "", [24.0, 28.0, 33.0, 40.0])])
def test_live_update_times(module, no_subprocess, empty_scene, name, grid, isovalues):
    path = os.path.join(DATA, name)
    if not os.path.isfile(path):
        pytest.skip(f"{path} not found")
    obj, load, rows, methods, linear = live_timings(empty_scene, path, isovalues, grid=grid)
    keys = ("mesh_ms", "edges_ms", "edges_wait_ms", "fill_ms", "views_ms", "depsgraph_ms", "blender_ms",
            "total_ms", "since_change_ms", "rest_ms", "mesh_cpu_ms", "cpu_ms")
    median = {key: float(np.median([r.get(key, 0.0) for r in rows])) for key in keys}
    report = {"input": name, "first_update_ms": load["total_ms"], "load_ms": load["load_ms"],
              "vertices": [r["vertices"] for r in rows[:len(isovalues) - 1]], **median,
              "method_change": {key: float(np.median([r.get(key, 0.0) for r in methods])) for key in keys},
              "linear_view": {key: float(np.median([r.get(key, 0.0) for r in linear])) for key in keys}}
    print(json.dumps(report))
    out = os.environ.get("ISOUQ_LIVE_TIMINGS")
    if out:
        with open(out, "a", encoding="utf-8") as f:
            f.write(json.dumps(report) + "\n")
    assert all(r["vertices"] > 0 for r in rows)
    assert len(obj.data.vertices) == linear[-1]["vertices"]
    assert {r["mesher_pass"] for r in linear} == {"estimate"} and {r["mesher_pass"] for r in rows} == {"full"}
    assert obj.data.validate() is False  # the module's edges: nothing for Blender to fix
