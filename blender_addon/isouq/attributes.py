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
        tri = mesh.corners.reshape(-1, 3) if np.all(mesh.loop_total == 3) else None
        if tri is not None and np.any((tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2])
                                      | (tri[:, 0] == tri[:, 2])):
            raise ValueError("a triangle repeats a vertex")
    for domain, table, size in (("vertex", mesh.vertex_attributes, mesh.vertex_count),
                                ("face", mesh.face_attributes, mesh.face_count)):
        for name, column in table.items():
            _blender_type(column)
            if len(column) != size:
                raise ValueError(f"{domain} attribute {name}: {len(column)} values for {size}")


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


def fill_mesh(me, mesh, checked=False):
    """Replaces the geometry and attributes of the existing mesh `me` by `mesh` (an IsouqMesh);
    materials stay. Used for each frame of a sequence (sequence.py).
    @raise ValueError, with `me` unchanged, if the data is inconsistent."""
    if not checked:
        check_mesh(mesh)
    me.clear_geometry()
    for key in HEADER_KEYS:
        if key in me:
            del me[key]
    me.vertices.add(mesh.vertex_count)
    _set_checked(me.vertices, "co", mesh.positions.astype(np.float32), 3 * mesh.vertex_count)
    me.loops.add(len(mesh.corners))
    _set_checked(me.loops, "vertex_index", mesh.corners.astype(np.int32), len(mesh.corners))
    me.polygons.add(mesh.face_count)
    _set_checked(me.polygons, "loop_start", mesh.loop_start.astype(np.int32), mesh.face_count)
    _set_checked(me.polygons, "loop_total", mesh.loop_total.astype(np.int32), mesh.face_count)
    me.update(calc_edges=True)
    types = {}
    for domain, table in (("POINT", mesh.vertex_attributes), ("FACE", mesh.face_attributes)):
        for col, values in table.items():
            name = face_name(col, mesh.vertex_attributes) if domain == "FACE" else col
            set_attribute(me, name, values, domain)
            types[name] = {"ply": col, "dtype": values.dtype.str}
    me["isouq_ply_types"] = json.dumps(types)
    if mesh.index_to_world is not None:
        me["isouq_index_to_world"] = [float(v) for v in mesh.index_to_world.ravel()]
    if mesh.isovalue is not None:
        me["isouq_isovalue"] = mesh.isovalue
    if mesh.method:
        me["isouq_method"] = mesh.method
    return me


def face_name(name, vertex_attributes):
    """The Blender name of face property `name` (suffix _face when a vertex has it too)."""
    return name + "_face" if name in vertex_attributes else name


def set_attribute(me, name, values, domain):
    """Creates or replaces attribute `name` on `me` and fills it (length checked)."""
    kind = _blender_type(values)
    old = me.attributes.get(name)
    if old is not None:
        me.attributes.remove(old)
    attr = me.attributes.new(name, kind, domain)
    _set_checked(attr.data, "value", values.astype(_NUMPY_OF[kind]), len(attr.data))
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


def remember_primary_positions(me):
    if me.attributes.get("isouq_primary_position") is None:
        attr = me.attributes.new("isouq_primary_position", "FLOAT_VECTOR", "POINT")
        _set_checked(attr.data, "vector", get_positions(me), 3 * len(me.vertices))


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
