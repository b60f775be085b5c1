# Live mode (docs/blender.md "Live mode"): with Scene.isouq.live on, changing the isovalue or
# the method in the panel re-meshes the live object in process (the isouq module, native.py)
# and replaces its mesh data in place, like Blender's Volume to Mesh modifier; changing the
# threshold redoes its views. Changes are debounced (a timer DEBOUNCE s after the last one); the
# mesher runs on a thread (the module releases the GIL) while the UI goes on, and only the copy
# into Blender runs on the main thread. The volume is loaded once per input (isouq.load,
# keep=non_constant: every isovalue meshes as the full data), so one update is one pass of the
# mesher plus the copy into Blender.

import json
import time

import bpy
import numpy as np

from . import attributes, native, views

DEBOUNCE = 0.03                 # s after the last change before re-meshing
VOLUME_CACHE = 2                # loaded volumes kept (input, grid, resolution)
REQUEST_KEY = "isouq_request"   # Object custom property: the request the object was meshed with

_volumes = {}                   # (input, grid, resolution) -> isouq_native.Volume, oldest first
_pending = {"remesh": False, "views": False, "since": None}
last_timing = {}                # the last update: load_ms, mesh_ms, edges_ms (thread), fill_ms, views_ms,
                                # depsgraph_ms, blender_ms (their sum), total_ms, vertices


def remember(obj, request):
    """Marks `obj` as meshed in process from `request` (pipeline.MeshRequest): live mode can
    mesh it again."""
    obj[REQUEST_KEY] = json.dumps({"input": request.input, "grid": request.grid,
                                   "resolution": request.resolution})


def target(context):
    """The object live mode updates: the active in-process isouq mesh, else the scene's first."""
    candidates = [context.view_layer.objects.active] + list(context.scene.objects)
    for obj in candidates:
        if obj is not None and obj.type == "MESH" and obj.isouq.role == "MESH" and REQUEST_KEY in obj:
            return obj
    return None


def schedule(context, remesh=True):
    """Called by the property updates (props.py): re-mesh (isovalue, method) or only redo the
    views (threshold) DEBOUNCE s after the last change."""
    if not context.scene.isouq.live:
        return
    _pending["remesh"] = _pending["remesh"] or remesh
    _pending["views"] = True
    _pending["since"] = _pending["since"] or time.perf_counter()
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=DEBOUNCE)


_running = {}   # the mesh being made off the UI thread: thread, obj, settings, result, error
_last_triangles = {}  # request (JSON) -> the last live mesh's triangles


def _tick():
    """The timer: applies a finished background mesh, starts the next one, or redoes the views;
    polls every 10 ms while a mesh is being made (the UI keeps running meanwhile)."""
    context = bpy.context
    if _running:
        if _running["thread"].is_alive():
            return 0.01
        _apply_running(context)
    if not _pending["views"]:
        return None
    obj = target(context)
    if obj is None:
        _pending.update(remesh=False, views=False, since=None)
        return None
    if not _pending["remesh"]:
        flush(context)
        return None
    since = _pending["since"]
    _pending.update(remesh=False, views=False, since=None)
    _start(context, obj, since)
    return 0.01


def _start(context, obj, since):
    """Meshes on a thread (the module releases the GIL): Blender data is only touched later,
    on the main thread, by _apply_running."""
    import threading
    module = native.load()
    if module is None:
        obj["isouq_live_error"] = f"live mode needs the isouq Python module ({native.error()})"
        return
    s = context.scene.isouq
    request = json.loads(obj[REQUEST_KEY])
    settings = (s.isovalue if s.use_isovalue else None, s.method)
    _running.update(obj=obj, since=since, start=time.perf_counter(), result=None, error=None)

    def work():
        try:
            _running["result"] = _mesh(module, request, *settings)
        except Exception as e:  # InputError etc.: shown on the object
            _running["error"] = str(e)

    _running["thread"] = threading.Thread(target=work, daemon=True)
    _running["thread"].start()


def _mesh(module, request, isovalue, method):
    start = time.perf_counter()
    vol = volume(module, request)
    loaded = time.perf_counter()
    mesh = module.mesh(vol, isovalue=vol.isovalue if isovalue is None else isovalue, method=method,
                       summary=False)
    meshed = time.perf_counter()
    # The edge table on this thread too (Blender then computes none), unless the triangles are
    # the last mesh's (a new method): attributes.fill_mesh then keeps the faces and edges.
    previous = _last_triangles.get(json.dumps(request, sort_keys=True))
    same = previous is not None and np.array_equal(previous, mesh.triangles)
    edges = (None, None) if same else mesh.edges()
    _last_triangles.clear()
    _last_triangles[json.dumps(request, sort_keys=True)] = mesh.triangles
    timing = {"load_ms": 1e3 * (loaded - start), "mesh_ms": 1e3 * (meshed - loaded),
              "edges_ms": 1e3 * (time.perf_counter() - meshed)}
    return mesh, edges, timing


def _apply_running(context):
    run = dict(_running)
    _running.clear()
    obj = run["obj"]
    try:
        obj.name  # the object may have been deleted meanwhile
    except ReferenceError:
        return
    if run["error"]:
        obj["isouq_live_error"] = run["error"]
        return
    _apply(context, obj, *run["result"], start=run["start"])
    last_timing["since_change_ms"] = 1e3 * (time.perf_counter() - run["since"])


def flush(context):
    """Runs what schedule() queued now, on this thread (the timer does it in the background;
    scripts and tests call this). Returns last_timing, or None if nothing was queued."""
    if _running:
        _running["thread"].join()
        _apply_running(context)
    if not _pending["views"]:
        return None
    remesh = _pending["remesh"]
    since = _pending["since"]
    _pending.update(remesh=False, views=False, since=None)
    obj = target(context)
    if obj is None:
        return None
    try:
        if remesh:
            update(context, obj)
        else:
            views.reapply(context, obj)
    except (ValueError, views.ViewError, RuntimeError) as e:
        obj["isouq_live_error"] = str(e)
        return None
    last_timing["since_change_ms"] = 1e3 * (time.perf_counter() - since)
    return last_timing


def volume(module, request):
    """The loaded volume of a request (dict of remember()), loaded on first use."""
    key = (request["input"], request["grid"], request["resolution"])
    if key not in _volumes:
        while len(_volumes) >= VOLUME_CACHE:
            _volumes.pop(next(iter(_volumes)))
        _volumes[key] = module.load(request["input"], grid=request["grid"] or None,
                                    resolution=request["resolution"] or None)
    return _volumes[key]


def update(context, obj):
    """Meshes `obj`'s volume at the panel's isovalue and method and puts the result in obj.data
    (geometry and every attribute, in place: materials and modifiers stay), then redoes its views."""
    module = native.load()
    if module is None:
        raise RuntimeError(f"live mode needs the isouq Python module ({native.error()})")
    s = context.scene.isouq
    start = time.perf_counter()
    result = _mesh(module, json.loads(obj[REQUEST_KEY]), s.isovalue if s.use_isovalue else None,
                   s.method)
    _apply(context, obj, *result, start=start)


def _apply(context, obj, mesh, edges, timing, start):
    """The new mesh into obj.data, its views redone, the depsgraph updated; the timings kept."""
    applying = time.perf_counter()
    attributes.fill_mesh(obj.data, native.to_isouq_mesh(mesh, edges))
    filled = time.perf_counter()
    attributes.remember_primary_positions(obj.data)
    obj.isouq.method_shown = mesh.method
    obj.isouq.summary = json.dumps({"vertices": len(mesh.vertices), "triangles": len(mesh.triangles),
                                    "isovalue": float(mesh.isovalue), "method": mesh.method, "live": True})
    if len(obj.data.vertices):
        views.reapply(context, obj)
    viewed = time.perf_counter()
    context.view_layer.update()
    done = time.perf_counter()
    last_timing.update(timing, fill_ms=1e3 * (filled - applying), views_ms=1e3 * (viewed - filled),
                       depsgraph_ms=1e3 * (done - viewed), blender_ms=1e3 * (done - applying),
                       total_ms=1e3 * (done - start), vertices=len(mesh.vertices))
    if "isouq_live_error" in obj:
        del obj["isouq_live_error"]
