# Mesh sequences in Blender (SPEC §10 "Sequences"): one object whose mesh follows the scene
# frame. Its frames are isouq PLYs (name.0001.ply, ...; frames.py finds them); the frame the scene
# shows is read just in time in a frame_change_pre handler (persistent across file loads),
# through a small LRU cache of parsed frames, and replaces the object's mesh data in place, with
# every attribute (attributes.fill_mesh, ply_io). Materials read attributes, so the views follow
# by themselves; views.reapply redoes what depends on positions or selections (C3, C6 copies).
# The heat-map range is the sequence's: from the sequence summary JSON next to the files, else
# from every frame read once.

import json
import os
import types

import bpy
import numpy as np
from bpy.app.handlers import persistent

from . import attributes, frames, materials, ply_io, props, views

CACHE_FRAMES = 8                 # parsed frames kept in memory (the LRU bound)
CACHE = frames.FrameCache(CACHE_FRAMES)
FRAMES_KEY = "isouq_sequence_frames"       # Object custom property: the frame numbers on disk
RANGES_KEY = "isouq_sequence_ranges"       # Object custom property: {measure: [min, max]} JSON
_summaries = {}                  # path -> (mtime, document)
_warned = set()
_importing = False


class _Context(types.SimpleNamespace):
    """What views and props read from a context (scene, preferences, collection), for handlers,
    which run outside any operator."""


def _context(scene):
    return _Context(scene=scene, preferences=bpy.context.preferences,
                    collection=scene.collection, view_layer=None)


def _read(path):
    """A frame's IsouqMesh (ply_io), its method filled in when the header does not say."""
    mesh = ply_io.read_ply(path)
    views.prepare_mesh(bpy.context, mesh)
    return mesh


def _empty_mesh():
    z = np.zeros(0, np.int32)
    return ply_io.IsouqMesh(np.zeros((0, 3), np.float32), z, z, z, {}, {})


def is_sequence(obj):
    return obj is not None and obj.type == "MESH" and bool(obj.isouq.sequence)


def sequence_of(obj):
    """The frames.Sequence of a sequence object: its pattern and the frames found at import."""
    seq = frames.parse_pattern(bpy.path.abspath(obj.isouq.sequence))
    if seq is None:
        raise frames.SequenceError(f"'{obj.isouq.sequence}' has no frame placeholder (####)")
    seq.frames = sorted(int(f) for f in obj.get(FRAMES_KEY, ()))
    return seq


def rescan(obj):
    """Looks the frames of `obj`'s pattern up on disk again (frames added or removed since the
    import); the heat-map ranges are computed again when next asked. Returns the frames."""
    if _importing:
        return None
    seq = frames.parse_pattern(bpy.path.abspath(obj.isouq.sequence))
    if seq is None:
        return None
    try:
        seq.scan()
    except frames.SequenceError as e:
        _warn_once(obj, str(e))
        return None
    obj[FRAMES_KEY] = seq.frames
    if RANGES_KEY in obj and obj.get("isouq_sequence_ranges_from") == "scan":
        del obj[RANGES_KEY]
    return seq.frames


def summary_document(obj):
    """The sequence summary of `obj` (read once per modification of the file), or None."""
    path = bpy.path.abspath(obj.isouq.sequence_summary) if obj.isouq.sequence_summary else ""
    if not path:
        return None
    try:
        mtime = os.stat(path).st_mtime_ns
    except OSError:
        return None
    cached = _summaries.get(path)
    if cached is None or cached[0] != mtime:
        cached = (mtime, frames.read_summary(path))
        _summaries[path] = cached
    return cached[1]


def _warn_once(obj, message):
    key = (obj.name, message)
    if key not in _warned:
        _warned.add(key)
        print(f"isouq: {obj.name}: {message}")


# --- loading a frame --------------------------------------------------------------------------

def update_object(scene, obj, force=False):
    """Shows in `obj` the file frame that `scene`'s current frame maps to (or nothing).
    Returns True when the mesh changed. A frame that cannot be read shows empty (one warning)."""
    if _importing or not is_sequence(obj):
        return False
    s = obj.isouq
    try:
        seq = sequence_of(obj)
    except frames.SequenceError as e:
        _warn_once(obj, str(e))
        return False
    frame = seq.file_frame(scene.frame_current, s.sequence_offset, s.sequence_mode)
    shown = frame if frame is not None else props.NO_FRAME
    if shown == s.sequence_frame and not force:
        return False
    mesh = _empty_mesh()
    if frame is not None:
        try:
            mesh = CACHE.get(seq.path(frame), _read)
        except (OSError, ValueError) as e:          # ply_io.PlyError is a ValueError
            _warn_once(obj, f"frame {frame}: {e}; showing nothing")
            shown = props.NO_FRAME
    try:
        attributes.fill_mesh(obj.data, mesh)
    except ValueError as e:
        _warn_once(obj, f"frame {frame}: {e}; showing nothing")
        attributes.fill_mesh(obj.data, _empty_mesh())
        shown = props.NO_FRAME
    attributes.remember_primary_positions(obj.data)
    s.sequence_frame = shown
    if s.role != "COMPARE":
        s.method_shown = mesh.method or ""
    doc = summary_document(obj)
    entry = frames.frame_summary(doc, frame) if doc is not None and frame is not None else None
    s.summary = json.dumps(entry) if entry is not None else ""
    try:
        views.reapply(_context(scene), obj)
    except (views.ViewError, ValueError) as e:
        _warn_once(obj, f"frame {frame}: {e}")
    return True


def update_scene(scene, force=False):
    changed = 0
    for obj in scene.objects:
        if is_sequence(obj):
            changed += update_object(scene, obj, force)
    return changed


@persistent
def on_frame_change(scene, depsgraph=None):
    update_scene(scene)


@persistent
def on_load_post(*_args):
    for scene in bpy.data.scenes:
        update_scene(scene)


_HANDLERS = (("frame_change_pre", on_frame_change), ("load_post", on_load_post))


def _ours(handler, name):
    return getattr(handler, "__module__", None) == __name__ and \
        getattr(handler, "__name__", None) == name


def register_handlers():
    unregister_handlers()
    for kind, handler in _HANDLERS:
        getattr(bpy.app.handlers, kind).append(handler)


def unregister_handlers():
    """Removes this module's handlers (also those of an earlier load of the module)."""
    for kind, handler in _HANDLERS:
        hooks = getattr(bpy.app.handlers, kind)
        for h in [h for h in hooks if _ours(h, handler.__name__)]:
            hooks.remove(h)
    CACHE.clear()
    _summaries.clear()
    _warned.clear()


def handlers_registered():
    return [kind for kind, handler in _HANDLERS
            if any(_ours(h, handler.__name__) for h in getattr(bpy.app.handlers, kind))]


# --- the heat-map range of a whole sequence ---------------------------------------------------

def measure_range(obj, measure):
    """(min, max) of `measure` over every frame of the sequence object `obj`: from its stored
    ranges (the summary's, or a scan at import), else the frames read once now."""
    ranges = json.loads(obj.get(RANGES_KEY, "{}"))
    if measure not in ranges:
        seq = sequence_of(obj)
        found = frames.scan_ranges([seq.path(f) for f in seq.frames], ply_io.read_ply)
        for name, lo_hi in found.items():
            ranges.setdefault(name, list(lo_hi))
        obj[RANGES_KEY] = json.dumps(ranges)
    lo_hi = ranges.get(measure)
    return (float(lo_hi[0]), float(lo_hi[1])) if lo_hi else None


def sequence_ranges(seq, doc):
    """{measure: [min, max]}: from the summary when there is one, else every frame read once."""
    if doc is not None:
        found = frames.summary_ranges(doc)
        if found:
            return {k: list(v) for k, v in found.items()}, "summary"
    found = frames.scan_ranges([seq.path(f) for f in seq.frames], ply_io.read_ply)
    return {k: list(v) for k, v in found.items()}, "scan"


# --- import -----------------------------------------------------------------------------------

def import_sequence(context, path, name=None, role="MESH", summary=None, mode="EXTEND",
                    offset=0, set_frame_range=True):
    """One object whose mesh follows the scene frame, from any one file of a numbered set (or a
    pattern with ####). `summary`: the sequence summary JSON, else one found beside the files.
    Scene frame f shows file frame f + `offset`; `mode` says what shows outside the frames
    (props.SEQUENCE_MODES). With `set_frame_range` the scene's range becomes the sequence's.
    @raise frames.SequenceError, ply_io.PlyError or OSError; nothing is created then."""
    global _importing
    seq = frames.detect(path)
    doc = None
    if summary:
        doc = frames.read_summary(summary)
        if doc is None:
            raise frames.SequenceError(f"{summary!r} is not a sequence summary (no 'frames')")
    else:
        summary, doc = frames.find_summary(seq)
    shown = seq.file_frame(context.scene.frame_current if not set_frame_range else
                           _in_range(context.scene.frame_current, seq, offset), offset, mode)
    mesh = CACHE.get(seq.path(shown if shown is not None else seq.first), _read)
    # the summary's statistics are the standard mesh's: a hidden-feature sequence scans its own
    ranges, ranges_from = sequence_ranges(seq, doc if role != "HIDDEN" else None)
    vocabulary = views.prepare_mesh(context, mesh)
    name = name or frames.object_name(seq)
    me = attributes.build_mesh(name, mesh if shown is not None else _empty_mesh())
    obj = bpy.data.objects.new(name, me)
    context.collection.objects.link(obj)
    _importing = True
    try:
        s = obj.isouq
        s.role = role
        s.source = seq.pattern
        obj[FRAMES_KEY] = seq.frames
        obj[RANGES_KEY] = json.dumps(ranges)
        obj["isouq_sequence_ranges_from"] = ranges_from
        s.sequence_summary = summary or ""
        s.sequence_offset, s.sequence_mode = offset, mode
        s.sequence = seq.pattern
    finally:
        _importing = False
    if set_frame_range:
        scene = context.scene
        scene.frame_start, scene.frame_end = seq.first - offset, seq.last - offset
        if not scene.frame_start <= scene.frame_current <= scene.frame_end:
            scene.frame_current = scene.frame_start
    # Replacing mesh data from a frame handler while rendering needs the interface locked
    # (Blender's advice for such handlers); background renders are unaffected.
    context.scene.render.use_lock_interface = True
    measure = views.first_measure(vocabulary, mesh.vertex_attributes)
    if measure:
        lo, hi = ranges.get(measure, views.value_range(mesh.vertex_attributes[measure]))
        materials.assign(obj, materials.heatmap_material(measure, lo, hi))
        if context.scene.isouq.measure == measure:
            context.scene.isouq.heat_min, context.scene.isouq.heat_max = lo, hi
    else:
        materials.assign(obj, materials.standard_material())
    update_object(context.scene, obj, force=True)
    return obj


def _in_range(frame, seq, offset):
    """The scene frame the import will leave current (inside the new frame range)."""
    lo, hi = seq.first - offset, seq.last - offset
    return frame if lo <= frame <= hi else lo
