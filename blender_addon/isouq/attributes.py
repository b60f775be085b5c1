# IsouqMesh (ply_io) <-> Blender mesh with named attributes (SPEC §6).
#
# Vertex columns go to the POINT domain, face columns to the FACE domain. float32 -> FLOAT,
# int32 -> INT, uint8 -> INT (edge_axis 0..2, order, hidden 0/1 keep their numbers; shaders and
# Geometry Nodes read INT directly). The PLY types are kept in mesh["isouq_ply_types"].
# Blender attribute names are unique across domains, so a face property named like a vertex one
# gets the suffix "_face": SPEC §6 `hidden` per face becomes the FACE attribute `hidden_face`.

import json

import bpy
import numpy as np

from . import analysis

_BLENDER_TYPES = {"f": "FLOAT", "i": "INT", "u": "INT", "b": "BOOLEAN"}
_NUMPY_OF = {"FLOAT": np.float32, "INT": np.int32, "BOOLEAN": np.bool_}


def _set_checked(collection, prop, values, expected):
    """foreach_set after checking the flat length, so a mismatch is an error, not garbage."""
    flat = np.ascontiguousarray(values).ravel()
    if len(flat) != expected:
        raise ValueError(f"{prop}: {len(flat)} values for {expected} slots")
    collection.foreach_set(prop, flat)


def _blender_type(array):
    kind = array.dtype.kind
    if kind not in _BLENDER_TYPES or array.dtype.itemsize > 4:
        raise ValueError(f"attribute type {array.dtype} is not supported")
    return _BLENDER_TYPES[kind]


def check_mesh(mesh):
    """Everything that could fail is checked before any Blender data is created."""
    if not np.all(np.isfinite(mesh.positions)):
        raise ValueError("vertex positions contain NaN or infinity")
    if mesh.face_count:
        ends = mesh.loop_start + mesh.loop_total
        if ends[-1] != len(mesh.corners) or np.any(mesh.loop_total < 3):
            raise ValueError("face corner table is inconsistent")
        if mesh.corners.min() < 0 or mesh.corners.max() >= mesh.vertex_count:
            raise ValueError("a face corner is not a vertex")
    if mesh.edges is not None and not callable(mesh.edges):
        check_edges(mesh)
    for domain, table, size in (("vertex", mesh.vertex_attributes, mesh.vertex_count),
                                ("face", mesh.face_attributes, mesh.face_count)):
        for name, column in table.items():
            _blender_type(column)
            if len(column) != size:
                raise ValueError(f"{domain} attribute {name}: {len(column)} values for {size}")


def check_edges(mesh):
    """The edge table given with `mesh` fits its vertices and corners."""
    edges, corner_edges = np.asarray(mesh.edges), np.asarray(mesh.corner_edges)
    if (edges.ndim != 2 or edges.shape[1] != 2 or len(corner_edges) != len(mesh.corners)
            or (len(edges) and edges.max() >= mesh.vertex_count)
            or (len(corner_edges) and corner_edges.max() >= len(edges))):
        raise ValueError("the edge table is inconsistent")
    tri = mesh.corners.reshape(-1, 3) if np.all(mesh.loop_total == 3) else None
    if tri is not None and np.any((tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2])
                                  | (tri[:, 0] == tri[:, 2])):
        raise ValueError("a triangle repeats a vertex")


def build_mesh(name, mesh):
    """A new bpy.types.Mesh holding `mesh` (an IsouqMesh) with every attribute.
    @raise ValueError before creating anything if the data is inconsistent."""
    check_mesh(mesh)
    me = bpy.data.meshes.new(name)
    try:
        fill_mesh(me, mesh, checked=True)
    except Exception:
        bpy.data.meshes.remove(me)
        raise
    return me


HEADER_KEYS = ("isouq_index_to_world", "isouq_index_to_world_fitted", "isouq_isovalue",
               "isouq_method", "isouq_ply_types")


def fill_mesh(me, mesh, checked=False, now=None):
    """Replaces the geometry and attributes of the existing mesh `me` by `mesh` (an IsouqMesh);
    materials stay. Used for each frame of a sequence (sequence.py) and by live mode. `now`: the
    Blender names of the attributes to fill (None: every one); the others are left out and
    returned, [(name, values, domain)], for fill_columns (live mode fills what the views show
    first). @raise ValueError, with `me` unchanged, if the data is inconsistent."""
    if not checked:
        check_mesh(mesh)
    for key in HEADER_KEYS:
        if key in me:
            del me[key]
    columns = [(col, face_name(col, mesh.vertex_attributes) if domain == "FACE" else col, values, domain)
               for domain, table in (("POINT", mesh.vertex_attributes), ("FACE", mesh.face_attributes))
               for col, values in table.items()]
    later = [(name, values, domain) for _, name, values, domain in columns
             if now is not None and name not in now]
    same = _same_faces(me, mesh)
    if same:  # e.g. live mode's new method: new positions and columns only
        names = {name for _, name, _, _ in columns if now is None or name in now}
        for stale in [a.name for a in me.attributes if a.name not in names and not a.name.startswith(".")]:
            me.attributes.remove(me.attributes[stale])  # as clear_geometry would
        _set_checked(me.vertices, "co", mesh.positions.astype(np.float32, copy=False), 3 * mesh.vertex_count)
    else:
        _fill_faces(me, mesh)
    types = {}
    for col, name, values, domain in columns:
        if now is None or name in now:
            set_attribute(me, name, values, domain)
        types[name] = {"ply": col, "dtype": values.dtype.str}
    if same:
        me.update()
    else:  # last, so an edge table made meanwhile on another thread (live mode) is waited for least
        _fill_edges(me, mesh, checked)
    me["isouq_ply_types"] = json.dumps(types)
    if mesh.index_to_world is not None:
        me["isouq_index_to_world"] = [float(v) for v in mesh.index_to_world.ravel()]
    if mesh.isovalue is not None:
        me["isouq_isovalue"] = mesh.isovalue
    if mesh.method:
        me["isouq_method"] = mesh.method
    return later


def fill_columns(me, later):
    """The attributes fill_mesh left out (its return value) into `me`."""
    for name, values, domain in later:
        set_attribute(me, name, values, domain)
    me.update()


def _same_faces(me, mesh):
    """Whether `me` already has `mesh`'s vertex count and faces (corners and face sizes), so
    its loops, faces and edges stay. Reading them back costs about a tenth of setting them."""
    if (len(me.vertices) != mesh.vertex_count or len(me.polygons) != mesh.face_count
            or len(me.loops) != len(mesh.corners) or not len(me.loops)):
        return False
    current = np.empty(len(me.loops), np.uint32)
    me.loops.foreach_get("vertex_index", current)
    if not np.array_equal(current, mesh.corners):
        return False
    totals = np.empty(len(me.polygons), np.uint32)
    me.polygons.foreach_get("loop_total", totals)
    return np.array_equal(totals, mesh.loop_total)


def _fill_faces(me, mesh):
    """Replaces every vertex, corner and face of `me` (its attributes and edges go too)."""
    me.clear_geometry()
    me.vertices.add(mesh.vertex_count)
    _set_checked(me.vertices, "co", mesh.positions.astype(np.float32, copy=False), 3 * mesh.vertex_count)
    # The corner, face and edge fields are unsigned in Blender's RNA: foreach_set copies a
    # buffer of exactly that type (uint32) at once and any other one element at a time (int32
    # was 17x slower on 1.3M corners; docs/blender.md "Live mode").
    corners = len(mesh.corners)
    me.loops.add(corners)
    _set_checked(me.loops, "vertex_index", mesh.corners.astype(np.uint32, copy=False), corners)
    me.polygons.add(mesh.face_count)
    _set_checked(me.polygons, "loop_start", mesh.loop_start.astype(np.uint32, copy=False), mesh.face_count)
    _set_checked(me.polygons, "loop_total", mesh.loop_total.astype(np.uint32, copy=False), mesh.face_count)


def _fill_edges(me, mesh, checked=False):
    """The edges of the faces _fill_faces set: the given table, else Blender's. `mesh.edges` may
    be a function that returns (edges, corner_edges) or (None, None): live mode's table, made on
    its thread while the faces and attributes were filled. Such a table is checked on arrival
    (unless `checked`: the function checked it); if it does not fit (ValueError) or the function
    raises, `me` is left empty and the error raised."""
    if callable(mesh.edges):
        try:
            mesh.edges, mesh.corner_edges = mesh.edges()
            if mesh.edges is not None and not checked:
                check_edges(mesh)
        except Exception:
            me.clear_geometry()
            raise
    if mesh.edges is None:
        me.update(calc_edges=True)  # Blender hashes the edges (0.6 s for 1.3M corners)
        return
    # The module's edge table: Blender then computes none (mesh.update keeps them).
    corners = len(mesh.corners)
    me.edges.add(len(mesh.edges))
    _set_checked(me.edges, "vertices", mesh.edges.astype(np.uint32, copy=False), 2 * len(mesh.edges))
    _set_checked(me.loops, "edge_index", mesh.corner_edges.astype(np.uint32, copy=False), corners)
    me.update()


def face_name(name, vertex_attributes):
    """The Blender name of face property `name` (suffix _face when a vertex has it too)."""
    return name + "_face" if name in vertex_attributes else name


def set_attribute(me, name, values, domain):
    """Creates or replaces attribute `name` on `me` and fills it (length checked)."""
    kind = _blender_type(values)
    attr = me.attributes.get(name)
    if attr is not None and (attr.data_type, attr.domain) != (kind, domain):
        me.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = me.attributes.new(name, kind, domain)
    _set_checked(attr.data, "value", values.astype(_NUMPY_OF[kind], copy=False), len(attr.data))
    return attr


def get_attribute(me, name):
    """The attribute as a numpy array (float32 or int32), or None if absent."""
    attr = me.attributes.get(name)
    if attr is None or attr.data_type not in _NUMPY_OF:
        return None
    out = np.empty(len(attr.data), _NUMPY_OF[attr.data_type])
    attr.data.foreach_get("value", out)
    return out


def vertex_attributes(me):
    """Every POINT-domain float/int attribute of `me` as numpy columns."""
    return {a.name: get_attribute(me, a.name) for a in me.attributes
            if a.domain == "POINT" and a.data_type in ("FLOAT", "INT") and not a.name.startswith(".")}


def get_positions(me):
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def set_positions(me, positions):
    _set_checked(me.vertices, "co", positions.astype(np.float32), 3 * len(me.vertices))
    me.update()


def stored_positions(me):
    """The primary method's positions as imported (kept so C3 can always go back)."""
    attr = me.attributes.get("isouq_primary_position")
    if attr is None:
        return get_positions(me)
    out = np.empty(3 * len(attr.data), np.float32)
    attr.data.foreach_get("vector", out)
    return out.reshape(-1, 3)


def remember_primary_positions(me, positions=None):
    """`positions`: the ones just set, when the caller has them (not read back)."""
    if me.attributes.get("isouq_primary_position") is None:
        attr = me.attributes.new("isouq_primary_position", "FLOAT_VECTOR", "POINT")
        positions = get_positions(me) if positions is None else positions.astype(np.float32, copy=False)
        _set_checked(attr.data, "vector", positions, 3 * len(me.vertices))


def index_to_world(me, primary_column):
    """M from the header, or fitted from positions and the primary method's t column
    `primary_column` (analysis module)."""
    stored = me.get("isouq_index_to_world")
    if stored is not None and len(stored) == 16:
        return np.array(stored, np.float64).reshape(4, 4)
    attrs = vertex_attributes(me)
    if not analysis.has_edges(attrs) or primary_column not in attrs:
        return None
    m = analysis.fit_index_to_world(stored_positions(me), attrs, primary_column)
    if m is not None:
        me["isouq_index_to_world"] = [float(v) for v in m.ravel()]
        me["isouq_index_to_world_fitted"] = True
    return m
