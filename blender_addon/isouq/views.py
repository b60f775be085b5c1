# The analysis views (paper sec. 4.3, SPEC §7 C1..C7) on Blender objects. Operators, the panel
# and the headless render script call these; the numbers come from analysis.py.

import json
import os
import tempfile

import bpy
import numpy as np

from . import analysis, attributes, materials, ply_io, plots, props

BAR_COLUMNS = ("err_est", "d_lc", "d_lw")     # C5 (paper sec. 4.3): e and two method distances


class ViewError(Exception):
    """A user-facing problem (no data, empty selection): operators report it as an error."""


# --- import --------------------------------------------------------------------------------

def prepare_mesh(context, mesh):
    """The vocabulary for `mesh` (an IsouqMesh); fills in `mesh.method` from the positions when
    the header does not say (the t column that reproduces x, y, z)."""
    columns = mesh.vertex_attributes
    vocabulary = props.vocabulary(context, {n: c.dtype.str for n, c in columns.items()})
    methods = {m: c for m, c in vocabulary.method_columns().items() if c in columns}
    if not mesh.method and methods and analysis.has_edges(columns) and mesh.vertex_count:
        matrix = mesh.index_to_world
        if matrix is None:
            matrix = analysis.fit_index_to_world(mesh.positions, columns, next(iter(methods.values())))
        if matrix is not None:
            mesh.method = analysis.guess_primary_method(mesh.positions, columns, matrix, methods)
    return vocabulary


def first_measure(vocabulary, columns):
    return next((m for m in vocabulary.measures() if m in columns), None)


def import_ply(context, path, name=None, role="MESH"):
    """Reads an isouq PLY and links a new object to the active collection.
    Nothing is created when reading or checking fails (ply_io.PlyError / ValueError)."""
    mesh = ply_io.read_ply(path)
    name = name or os.path.splitext(os.path.basename(path))[0]
    vocabulary = prepare_mesh(context, mesh)
    columns = mesh.vertex_attributes
    me = attributes.build_mesh(name, mesh)
    attributes.remember_primary_positions(me)
    obj = bpy.data.objects.new(name, me)
    context.collection.objects.link(obj)
    obj.isouq.role = role
    obj.isouq.source = path
    obj.isouq.method_shown = mesh.method or ""
    measure = first_measure(vocabulary, columns)
    if measure:
        lo, hi = value_range(columns[measure])
        materials.assign(obj, materials.heatmap_material(measure, lo, hi))
    else:
        materials.assign(obj, materials.standard_material())
    return obj


def load_summary(obj, path):
    with open(path, encoding="utf-8") as f:
        obj.isouq.summary = json.dumps(json.load(f))


# --- helpers -------------------------------------------------------------------------------

def isouq_object(context):
    """The active object if it is an isouq mesh, else the first isouq mesh in the scene."""
    obj = context.active_object
    if obj and obj.type == "MESH" and obj.isouq.role != "NONE":
        return obj
    for o in context.scene.objects:
        if o.type == "MESH" and o.isouq.role in ("MESH", "HIDDEN"):
            return o
    raise ViewError("no isouq mesh: import one with File > Import > isouq mesh (.ply)")


def measure_values(obj, measure):
    values = attributes.get_attribute(obj.data, measure)
    if values is None:
        raise ViewError(f"'{obj.name}' has no '{measure}' attribute")
    return values.astype(np.float64)


def value_range(values):
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    return (float(v.min()), float(v.max())) if len(v) else (0.0, 1.0)


def plot_path(key):
    return os.path.join(tempfile.gettempdir(), f"isouq_{key}_{os.getpid()}.png")


def world_points(obj):
    """World positions of the primary method's vertices (selection does not follow C3)."""
    p = attributes.stored_positions(obj.data).astype(np.float64)
    m = np.array(obj.matrix_world, np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def store_selection(obj, mask):
    """Keeps the selection as a BOOLEAN attribute and as the mesh's vertex selection."""
    attributes.set_attribute(obj.data, "isouq_selected", mask.astype(np.bool_), "POINT")
    obj.data.vertices.foreach_set("select", mask.astype(np.bool_))
    obj.data.update()


# --- C1 threshold --------------------------------------------------------------------------

def resolve_threshold(settings, values):
    """The threshold value, recomputed from the percentile in PERCENTILE mode."""
    if settings.threshold_mode == "PERCENTILE":
        settings.threshold_value = max(analysis.percentile_threshold(values,
                                                                     settings.threshold_percentile), 0.0)
    return settings.threshold_value


def apply_threshold(context, obj):
    """C1: binary colour map above/below, selection = above, CDF plot. Returns (count, path)."""
    s = context.scene.isouq
    values = measure_values(obj, s.measure)
    threshold = resolve_threshold(s, values)
    mask = analysis.above(values, threshold)
    materials.assign(obj, materials.threshold_material(s.measure, threshold, s.colour_below,
                                                       s.colour_above))
    store_selection(obj, mask)
    obj["isouq_view_selection"] = "THRESHOLD"
    path = plots.cdf_plot(plot_path("cdf"), values, threshold, s.measure)
    return int(mask.sum()), path


# --- C2 box --------------------------------------------------------------------------------

def add_box(context, obj):
    """A cube empty around the middle half of the mesh's bounding box."""
    p = world_points(obj)
    lo, hi = p.min(axis=0), p.max(axis=0)
    box = bpy.data.objects.new("ISOUQ_box", None)
    box.empty_display_type = "CUBE"
    box.empty_display_size = 1.0
    box.location = (lo + hi) / 2
    box.scale = np.maximum((hi - lo) / 4, 1e-6)
    context.collection.objects.link(box)
    context.scene.isouq.box = box
    return box


def box_selection(context, obj):
    box = context.scene.isouq.box
    if box is None:
        raise ViewError("no box: add one with 'Add Box' or pick a cube/empty")
    return analysis.box_mask(world_points(obj), np.array(box.matrix_world, np.float64))


def select_box(context, obj):
    """C2: selection = vertices inside the box. Empty -> ViewError, nothing changed."""
    mask = box_selection(context, obj)
    if not mask.any():
        raise ViewError("the box contains no vertex: move or scale it over the surface")
    store_selection(obj, mask)
    obj["isouq_view_selection"] = "BOX"
    return int(mask.sum())


# --- C3 methods ----------------------------------------------------------------------------

def selection_mask(context, obj):
    s = context.scene.isouq
    if s.selection == "BOX":
        return box_selection(context, obj)
    values = measure_values(obj, s.measure)
    return analysis.above(values, resolve_threshold(s, values))


def _method_inputs(context, obj, *methods):
    """(primary positions, attributes, M, the t column of each of `methods`)."""
    me = obj.data
    attrs = attributes.vertex_attributes(me)
    if not analysis.has_edges(attrs):
        raise ViewError(f"'{obj.name}' has no edge_i/j/k and edge_axis: cannot switch methods")
    known = props.vocabulary(context).method_columns()
    for m in methods:
        if m not in known:
            raise ViewError(f"unknown method '{m}' (known: {', '.join(known)})")
        if known[m] not in attrs:
            raise ViewError(f"'{obj.name}' has no {known[m]}: the file was written without {m}")
    primary = known.get(me.get("isouq_method")) or next(
        (c for c in known.values() if c in attrs), None)
    matrix = attributes.index_to_world(me, primary)
    if matrix is None:
        raise ViewError("no index_to_world header and too few vertices to fit one")
    return attributes.stored_positions(me), attrs, matrix, [known[m] for m in methods]


def apply_methods(context, obj, allow_empty=False):
    """C3: inside method where selected, outside method elsewhere, at once (no rerun).
    Returns the number of selected vertices. An empty selection is an error unless
    `allow_empty` (a sequence frame where nothing is above the threshold: all outside)."""
    s = context.scene.isouq
    positions, attrs, matrix, (inside, outside) = _method_inputs(context, obj, s.method_inside,
                                                                 s.method_outside)
    mask = selection_mask(context, obj)
    if s.method_inside != s.method_outside and not mask.any() and not allow_empty:
        raise ViewError("the selection is empty: lower the threshold or move the box")
    attributes.set_positions(obj.data, analysis.mixed_positions(
        positions, attrs, matrix, mask, inside, outside))
    store_selection(obj, mask)
    obj.isouq.method_shown = (s.method_inside if s.method_inside == s.method_outside
                              else f"{s.method_inside} inside, {s.method_outside} outside")
    obj["isouq_view_methods"] = True
    obj["isouq_view_selection"] = s.selection
    return int(mask.sum())


def reset_positions(obj):
    attributes.set_positions(obj.data, attributes.stored_positions(obj.data))
    obj.isouq.method_shown = obj.data.get("isouq_method", "")
    if "isouq_view_methods" in obj:
        del obj["isouq_view_methods"]


def reapply(context, obj):
    """After a new frame of a sequence is loaded into `obj` (sequence.py): the object's views on
    the new frame. A comparison copy (C6) shows its method; after C3 the scene's inside and
    outside methods are applied again (nothing selected: all outside); a C1/C2 selection is
    taken again with the scene's threshold value or box. Materials read attributes, so the heat
    map (C4) and the threshold colours (C1) follow by themselves."""
    if obj.isouq.role == "COMPARE":
        if obj.isouq.method_shown and len(obj.data.vertices):
            positions, attrs, matrix, (column,) = _method_inputs(context, obj,
                                                                 obj.isouq.method_shown)
            attributes.set_positions(obj.data, analysis.method_positions(positions, attrs,
                                                                         matrix, column))
        return
    if not len(obj.data.vertices):
        return
    if obj.get("isouq_view_methods"):
        apply_methods(context, obj, allow_empty=True)
        return
    kind = obj.get("isouq_view_selection")
    s = context.scene.isouq
    if kind == "THRESHOLD" and s.measure in obj.data.attributes:
        store_selection(obj, analysis.above(measure_values(obj, s.measure), s.threshold_value))
    elif kind == "BOX" and s.box is not None:
        store_selection(obj, box_selection(context, obj))


# --- C4 heat map, C5 bars ------------------------------------------------------------------

def heat_range(context, obj, measure):
    """The heat-map range of `measure` on `obj`: over every frame for a sequence object (unless
    the scene's range scope is FRAME), else the values shown."""
    if obj.isouq.sequence and context.scene.isouq.heat_range_scope == "SEQUENCE":
        from . import sequence
        found = sequence.measure_range(obj, measure)
        if found is not None:
            return found
    return value_range(measure_values(obj, measure))


def apply_heatmap(context, obj, reset_range=True):
    s = context.scene.isouq
    measure_values(obj, s.measure)
    if reset_range:
        s.heat_min, s.heat_max = heat_range(context, obj, s.measure)
    materials.assign(obj, materials.heatmap_material(s.measure, s.heat_min, s.heat_max))
    return plots.legend_plot(plot_path("legend"), s.heat_min, s.heat_max, s.measure,
                             materials.HEAT_COLORMAP)


def plot_bars(context, obj):
    """C5: bars of BAR_COLUMNS (those present) for the vertices in the box."""
    mask = box_selection(context, obj)
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        raise ViewError("the box contains no vertex: nothing to plot")
    cols = {n: attributes.get_attribute(obj.data, n) for n in BAR_COLUMNS}
    cols = {n: v.astype(np.float64) for n, v in cols.items() if v is not None}
    if not cols:
        raise ViewError(f"'{obj.name}' has none of {', '.join(BAR_COLUMNS)}")
    return len(idx), plots.bars_plot(plot_path("bars"), cols, idx)


# --- C6 comparisons ------------------------------------------------------------------------

def compare_methods(context, obj):
    """Side by side: a copy showing `compare_method`, shifted by 1.2 x the mesh width."""
    s = context.scene.isouq
    positions, attrs, matrix, (column,) = _method_inputs(context, obj, s.compare_method)
    name = f"{obj.name}_{s.compare_method}"
    old = bpy.data.objects.get(name)
    if old is not None and old.isouq.role == "COMPARE":
        bpy.data.objects.remove(old)
    copy = obj.copy()
    copy.data = obj.data.copy()
    copy.name = name
    attributes.set_positions(copy.data, analysis.method_positions(positions, attrs, matrix, column))
    p = world_points(obj)
    width = float(p[:, 0].max() - p[:, 0].min()) if len(p) else 1.0
    copy.location = obj.location + type(obj.location)((1.2 * width, 0, 0))
    copy.isouq.role = "COMPARE"
    copy.isouq.method_shown = s.compare_method
    for key in ("isouq_view_methods", "isouq_view_selection"):
        if key in copy:
            del copy[key]
    context.collection.objects.link(copy)
    return copy


def _hidden_pair(obj):
    partner = obj.isouq.partner
    if partner is None:
        raise ViewError("no hidden-feature mesh: run the pipeline with Hidden features on")
    return (obj, partner) if obj.isouq.role == "MESH" else (partner, obj)


def show_hidden(context, obj):
    """C6: hidden-feature surface (transparent orange) over standard MC (opaque blue)."""
    standard, hidden = _hidden_pair(obj)
    materials.assign(standard, materials.standard_material())
    materials.assign(hidden, materials.hidden_material())
    standard.hide_render = standard.hide_viewport = False
    hidden.hide_render = hidden.hide_viewport = False
    # Where the two surfaces coincide the viewport would z-fight: draw the transparent orange
    # surface in front, so it always lies over the blue one (renders blend the two layers).
    hidden.show_in_front = True
    return standard, hidden


def combined_view(context, obj):
    """Heat map of the measure on the hidden-feature mesh, green where refined."""
    standard, hidden = _hidden_pair(obj)
    s = context.scene.isouq
    lo, hi = heat_range(context, hidden, s.measure)
    s.heat_min, s.heat_max = lo, hi
    materials.assign(hidden, materials.combined_material(s.measure, lo, hi))
    standard.hide_render = standard.hide_viewport = True
    hidden.hide_render = hidden.hide_viewport = False
    return hidden


# --- C7 summary ----------------------------------------------------------------------------

def summary(context, obj):
    """C7 rows (label, value): counts above the threshold, statistics of each measure (from the
    --summary JSON when present, else from the attributes), hidden-feature components."""
    s = context.scene.isouq
    data = json.loads(obj.isouq.summary) if obj.isouq.summary else {}
    me = obj.data
    rows = [("vertices", data.get("vertices", len(me.vertices))),
            ("triangles", data.get("triangles", len(me.polygons)))]
    for key in ("boundary_edges", "components", "isovalue", "method"):
        if key in data:
            rows.append((key, data[key]))
    values = attributes.get_attribute(me, s.measure)
    if values is not None:
        n = int(analysis.above(values, s.threshold_value).sum())
        rows.append((f"{s.measure} > {s.threshold_value:.4g}", f"{n} ({100 * n / max(len(values), 1):.1f}%)"))
    for measure in props.vocabulary(context).summarised():
        st = data.get(measure)
        if st is None:
            v = attributes.get_attribute(me, measure)
            st = analysis.stats(v) if v is not None else None
        if st:
            rows.append((measure, "max {max:.3g} mean {mean:.3g} rms {rms:.3g}".format(**st)))
    hidden = data.get("hidden")
    if isinstance(hidden, dict):
        for key in ("cells_flagged", "fraction", "components_before", "components_after",
                    "boundary_edges"):
            if key in hidden:
                rows.append((f"hidden {key}", hidden[key]))
    return rows
