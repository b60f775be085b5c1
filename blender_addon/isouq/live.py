# Live mode (docs/blender.md "Live mode"): with Scene.isouq.live on, changing the isovalue or
# the method in the panel re-meshes the live object in process (the isouq module, native.py)
# and replaces its mesh data in place, like Blender's Volume to Mesh modifier; changing the
# threshold redoes its views. Changes are debounced (a timer DEBOUNCE s after the last one); the
# mesher runs on one worker thread (the module releases the GIL) while the UI goes on, and only
# the copy into Blender runs on the main thread. The volume is loaded once per input
# (isouq.load, keep=non_constant: every isovalue meshes as the full data), so one update is one
# pass of the mesher plus the copy into Blender: of the columns the views show (shown_columns),
# from the cheapest pass that gives them (_pass_for); the rest follows REST s later (complete).

import dataclasses
import json
import queue
import threading
import time

import bpy
import numpy as np

from . import attributes, native, views

DEBOUNCE = 0.03                 # s after the last change before re-meshing
VOLUME_CACHE = 2                # loaded volumes kept (input, grid, resolution)
REQUEST_KEY = "isouq_request"   # Object custom property: the request the object was meshed with
REST = 0.25                     # s after an update, with no change since, to fill the columns not shown

_volumes = {}                   # (input, grid, resolution) -> isouq_native.Volume, oldest first
_later = {}                     # what the last update left (complete): obj, data, columns, remesh
                                # (a cheaper pass ran), at (when), update (the full pass, if started)
_pending = {"remesh": False, "views": False, "since": None}
last_timing = {}                # the last update: load_ms, mesh_ms, check_ms, edges_ms (worker),
                                # edges_wait_ms, fill_ms, views_ms, depsgraph_ms, blender_ms (their
                                # sum), total_ms, since_change_ms, vertices, mesher_pass, mesh_cpu_ms
                                # and cpu_ms (CPU time of every thread of Blender's process: the
                                # mesher alone, the whole update; walls vary with the load), rest_ms,
                                # rest_columns, rest_remeshed once complete() ran


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


_running = {}   # "update": the _Update being made on the worker thread
_last_triangles = {}  # request (JSON) -> the last live mesh's triangles
_jobs = queue.Queue()
_worker = []    # the worker thread, started on first use


def _tick():
    """The timer: applies a background mesh once it is made, starts the next one, or redoes
    the views; polls every 10 ms while a mesh is being made (the UI keeps running meanwhile)."""
    context = bpy.context
    if _running:
        if not _running["update"].meshed.is_set():
            return 0.01
        _apply_update(context, _running.pop("update"))
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


class _Update:
    """One re-mesh, made on the worker thread (the module releases the GIL): first the mesh
    (then `meshed` is set and the main thread starts copying it into Blender), then its edge
    table, which the copy waits for last (attributes.fill_mesh). Blender data is only touched on
    the main thread."""

    def __init__(self, obj, request, isovalue, method, since, shown=None, mesher_pass=("full", None)):
        self.obj, self.request, self.isovalue, self.method = obj, request, isovalue, method
        self.shown = shown   # the attributes to fill at once (fill_mesh's `now`)
        self.pass_name, self.cheaper = mesher_pass  # _pass_for: arguments of a cheaper pass, or None
        self.since, self.start, self.cpu = since, time.perf_counter(), time.process_time()
        self.meshed, self.done = threading.Event(), threading.Event()
        self.mesh = self.module_mesh = self.edges = self.error = None
        self.timing = {}

    def run(self, module):
        try:
            start = time.perf_counter()
            vol = volume(module, self.request)
            loaded, cpu = time.perf_counter(), time.process_time()
            mesh = module.mesh(vol, isovalue=vol.isovalue if self.isovalue is None else self.isovalue,
                               method=self.method, summary=False, **(self.cheaper or {}))
            meshed = time.perf_counter()
            self.timing.update(load_ms=1e3 * (loaded - start), mesh_ms=1e3 * (meshed - loaded),
                               mesh_cpu_ms=1e3 * (time.process_time() - cpu))
            # The same triangles as the last mesh (a new method): fill_mesh keeps the faces and
            # edges, so no edge table is made.
            key = json.dumps(self.request, sort_keys=True)
            previous = _last_triangles.get(key)
            same = previous is not None and np.array_equal(previous, mesh.triangles)
            _last_triangles.clear()
            _last_triangles[key] = mesh.triangles
            # What fill_mesh needs, checked here rather than on Blender's thread.
            self.mesh = native.to_isouq_mesh(mesh, self.wait_edges)
            attributes.check_mesh(self.mesh)
            self.module_mesh = mesh
            checked = time.perf_counter()
            self.timing["check_ms"] = 1e3 * (checked - meshed)
            self.meshed.set()
            if same:
                self.edges = (None, None)
            else:
                self.edges = mesh.edges()
                attributes.check_edges(dataclasses.replace(self.mesh, edges=self.edges[0],
                                                           corner_edges=self.edges[1]))
            self.timing["edges_ms"] = 1e3 * (time.perf_counter() - checked)
        except Exception as e:  # InputError etc.: shown on the object
            self.error = str(e)
        finally:
            self.meshed.set()
            self.done.set()

    def wait_edges(self):
        """The edge table (fill_mesh calls this once the faces and attributes are in)."""
        waiting = time.perf_counter()
        self.done.wait()
        self.timing["edges_wait_ms"] = 1e3 * (time.perf_counter() - waiting)
        if self.error:
            raise RuntimeError(self.error)
        return self.edges


def _serve():
    while True:
        update, module = _jobs.get()
        update.run(module)


def _post(update, module):
    """Runs `update` on the one live worker thread. One thread for every update, not one each:
    the module keeps a worker, its TBB arena and the edge table's scratch per calling thread
    (python/src/module.cc), which a new thread would make again."""
    if not _worker:
        _worker.append(threading.Thread(target=_serve, name="isouq live", daemon=True))
        _worker[0].start()
    _jobs.put((update, module))


def _start(context, obj, since, whole=False):
    """Starts meshing `obj` at the panel's settings on the worker (`whole`: every column, the
    full pass); None without the module."""
    module = native.load()
    if module is None:
        obj["isouq_live_error"] = f"live mode needs the isouq Python module ({native.error()})"
        return None
    s = context.scene.isouq
    shown = None if whole else shown_columns(context, obj)
    update = _Update(obj, json.loads(obj[REQUEST_KEY]), s.isovalue if s.use_isovalue else None,
                     s.method, since, shown, ("full", None) if whole else _pass_for(module, obj, s.method, shown))
    _running["update"] = update
    _post(update, module)
    return update


def _apply_update(context, update):
    """A made mesh into its object (main thread); errors are shown on the object."""
    obj = update.obj
    try:
        obj.name  # the object may have been deleted meanwhile
    except ReferenceError:
        update.done.wait()
        return
    if update.error:
        obj["isouq_live_error"] = update.error
        return
    try:
        timing = _apply(context, obj, update)
    except (ValueError, views.ViewError, RuntimeError) as e:
        obj["isouq_live_error"] = str(e)
        return
    last_timing.clear()
    last_timing.update(timing, since_change_ms=1e3 * (time.perf_counter() - update.since))


def flush(context):
    """Runs what schedule() queued now, on this thread (the timer does it in the background;
    scripts and tests call this). Returns last_timing, or None if nothing was queued."""
    if _running:
        made = _running.pop("update")
        made.meshed.wait()
        _apply_update(context, made)
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
            last_timing.clear()
            last_timing.update(update(context, obj))
        else:
            views.reapply(context, obj)
    except (ValueError, views.ViewError, RuntimeError) as e:
        obj["isouq_live_error"] = str(e)
        return None
    last_timing["since_change_ms"] = 1e3 * (time.perf_counter() - since)
    complete(context)  # scripts get every column (timed apart: rest_ms)
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


def update(context, obj, whole=False):
    """Meshes `obj`'s volume at the panel's isovalue and method and puts the result in obj.data
    (geometry and the shown attributes, or with `whole` every one, in place: materials and
    modifiers stay), then redoes its views. Returns the timings."""
    if native.load() is None:
        raise RuntimeError(f"live mode needs the isouq Python module ({native.error()})")
    made = _start(context, obj, time.perf_counter(), whole)
    _running.pop("update")
    made.meshed.wait()
    if made.error:
        raise RuntimeError(made.error)
    return _apply(context, obj, made)


def _apply(context, obj, update):
    """The new mesh into obj.data, its views redone, the depsgraph updated; the timings kept."""
    mesh = update.module_mesh
    applying = time.perf_counter()
    _later.clear()  # the last update's columns, if still left out, are replaced now
    later = attributes.fill_mesh(obj.data, update.mesh, checked=True, now=update.shown)
    filled = time.perf_counter()
    update.done.wait()  # same faces: fill_mesh asked for no edges, the worker is finishing
    attributes.remember_primary_positions(obj.data, update.mesh.positions)
    obj.isouq.method_shown = mesh.method
    obj.isouq.summary = json.dumps({"vertices": len(mesh.vertices), "triangles": len(mesh.triangles),
                                    "isovalue": float(mesh.isovalue), "method": mesh.method, "live": True})
    if len(obj.data.vertices):
        views.reapply(context, obj)
    viewed = time.perf_counter()
    context.view_layer.update()
    done = time.perf_counter()
    timing = dict({"edges_wait_ms": 0.0, **update.timing}, fill_ms=1e3 * (filled - applying),
                  views_ms=1e3 * (viewed - filled), depsgraph_ms=1e3 * (done - viewed),
                  blender_ms=1e3 * (done - applying), total_ms=1e3 * (done - update.start),
                  cpu_ms=1e3 * (time.process_time() - update.cpu),
                  vertices=len(mesh.vertices), mesher_pass=update.pass_name)
    if "isouq_live_error" in obj:
        del obj["isouq_live_error"]
    if later or update.cheaper:  # a cheaper pass: the whole mesh later is a full pass again
        _later.update(obj=obj, data=obj.data, columns=later, remesh=bool(update.cheaper),
                      at=time.perf_counter())
        if not bpy.app.timers.is_registered(_complete_tick):
            bpy.app.timers.register(_complete_tick, first_interval=REST)
    return timing


def shown_columns(context, obj):
    """The attributes the object's views read now, which an update fills at once: those its
    materials read (the heat map's measure, C1's, C6's hidden flags) and C1's measure; None
    (every one) under C3 methods or on a comparison copy, which read the t and edge columns."""
    if obj.get("isouq_view_methods") or obj.isouq.role == "COMPARE":
        return None
    names = {context.scene.isouq.measure}
    for mat in obj.data.materials:
        if mat is not None and mat.node_tree is not None:
            names.update(n.attribute_name for n in mat.node_tree.nodes if n.type == "ATTRIBUTE")
    return names


# Passes cheaper than the full one, cheapest first: name, mesh() arguments.
CHEAPER_PASSES = (("linear", {"linear_only": True}), ("estimate", {"high_order": False}))
_pass_columns = {}  # pass name -> the vertex columns it gives


def _pass_for(module, obj, method, shown):
    """(name, mesh() arguments) of the cheapest pass that gives every shown column `obj` has
    (("full", None): the full pass). With the linear method and no high-order column shown:
    the linear-only pass or the paper's extraction plus estimate (high_order=False; err_est,
    err_bound), under half the full pass's time, the same triangles, positions and columns
    (tests/python/test_python_module.py)."""
    if method == "linear" and shown is not None:
        needed = shown & _columns_of(module, "full", {})  # a material may read what no pass gives
        for name, arguments in CHEAPER_PASSES:
            if needed <= _columns_of(module, name, arguments):
                return name, arguments
    return "full", None


def _columns_of(module, name, arguments):
    """The vertex columns of a pass, asked of the module once (no column list kept here)."""
    if name not in _pass_columns:
        _pass_columns[name] = set(module.mesh("field:tangle", resolution=8, method="linear",
                                              summary=False, **arguments).columns)
    return _pass_columns[name]


def complete(context=None):
    """Fills the columns the last update left out (shown_columns), if any, and updates the
    depsgraph; operators call it before they read the object (operators._ObjectOperator)."""
    if not _later:
        return None
    obj, data, columns, remesh = (_later[k] for k in ("obj", "data", "columns", "remesh"))
    made = _later.get("update")
    _later.clear()
    try:
        same = obj.data == data
    except ReferenceError:  # deleted meanwhile
        return None
    if not same:
        return None
    context = context or bpy.context
    start = time.perf_counter()
    if remesh and made is None:
        update(context, obj, whole=True)
    elif remesh:
        made.meshed.wait()
        if made.error:
            raise RuntimeError(made.error)
        _apply(context, obj, made)
    else:
        attributes.fill_columns(data, columns)
        context.view_layer.update()
    last_timing.update(rest_ms=1e3 * (time.perf_counter() - start), rest_columns=len(columns),
                       rest_remeshed=remesh)
    return last_timing


def _complete_tick():
    """The timer that completes an update REST s after it, once no other change is waiting; the
    full pass a cheaper one leaves is made on the worker, like any update (polled every 10 ms)."""
    if not _later:
        return None
    if _running or _pending["views"]:
        return REST
    wait = _later["at"] + REST - time.perf_counter()
    if wait > 0:
        return wait
    if _later["remesh"] and "update" not in _later:
        try:
            _later["obj"].name
        except ReferenceError:  # deleted meanwhile
            _later.clear()
            return None
        made = _start(bpy.context, _later["obj"], time.perf_counter(), whole=True)
        if made is None:
            _later.clear()
            return None
        _later["update"] = _running.pop("update")  # applied here, not by _tick
        return 0.01
    if "update" in _later and not _later["update"].meshed.is_set():
        return 0.01
    obj = _later["obj"]
    try:
        complete()
    except (ValueError, views.ViewError, RuntimeError) as e:
        obj["isouq_live_error"] = str(e)
    return None
