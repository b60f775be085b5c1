# The analysis views C1..C7 against independent truths: numpy counts, brute-force box tests,
# crossings recomputed from the fixture's own grid transform, node-tree checks.

import json
import math
import os

import bpy
import numpy as np
import pytest
from mathutils import Euler, Vector

import plyfixture
from conftest import make_box, scene_delta, snapshot


@pytest.fixture
def sphere(sphere_ply):
    path, data = sphere_ply
    assert bpy.ops.isouq.import_mesh(filepath=path) == {"FINISHED"}
    return bpy.context.active_object, data


def positions(obj):
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def selected(obj):
    sel = np.empty(len(obj.data.vertices), bool)
    obj.data.vertices.foreach_get("select", sel)
    return sel


def crossing(attrs, method):
    """World crossing of `method` straight from SPEC §6: M ((i, j, k) + t e_axis, 1)."""
    m = plyfixture.index_to_world()
    out = []
    for i, j, k, a, t in zip(attrs["edge_i"], attrs["edge_j"], attrs["edge_k"],
                             attrs["edge_axis"], attrs["t_" + method]):
        p = [float(i), float(j), float(k), 1.0]
        p[a] += float(t)
        out.append((m @ p)[:3])
    return np.array(out)


# --- C1 ------------------------------------------------------------------------------------

def test_threshold_by_value_selects_the_numpy_count(sphere):
    obj, (_, _, attrs, _, _) = sphere
    s = bpy.context.scene.isouq
    s.threshold_value = float(np.median(attrs["err_est"]))
    assert bpy.ops.isouq.apply_threshold() == {"FINISHED"}
    expected = attrs["err_est"] > np.float32(s.threshold_value)
    assert selected(obj).sum() == np.count_nonzero(expected)
    assert np.array_equal(selected(obj), expected)
    tree = obj.active_material.node_tree
    assert tree.nodes["Measure"].attribute_name == "err_est"
    assert tree.nodes["Threshold"].inputs[1].default_value == pytest.approx(s.threshold_value)


@pytest.mark.parametrize("percent", [50.0, 90.0, 99.0])
def test_threshold_by_percentile(sphere, percent):
    obj, (_, _, attrs, _, _) = sphere
    s = bpy.context.scene.isouq
    s.threshold_mode, s.threshold_percentile = "PERCENTILE", percent
    assert bpy.ops.isouq.apply_threshold() == {"FINISHED"}
    values = attrs["err_est"].astype(np.float64)
    assert s.threshold_value == pytest.approx(np.percentile(values, percent), rel=1e-6)
    count = selected(obj).sum()
    assert count == np.count_nonzero(values > s.threshold_value)
    # the p-th percentile sits at rank r = (n - 1) p / 100 of the sorted values
    rank = (len(values) - 1) * percent / 100
    assert np.count_nonzero(values <= s.threshold_value) >= math.floor(rank) + 1
    assert np.count_nonzero(values < s.threshold_value) <= math.ceil(rank)


def test_cdf_plot_is_written(sphere):
    from isouq import ui
    bpy.ops.isouq.apply_threshold()
    path = ui._paths["cdf"]
    assert os.path.getsize(path) > 1000
    assert open(path, "rb").read(8) == b"\x89PNG\r\n\x1a\n"


# --- C2 and C5 -----------------------------------------------------------------------------


def brute_force_inside(points, location, rotation, scale):
    """Inside iff |(p - c) . u_k| <= s_k for the box's three rotated unit axes u_k."""
    axes = Euler(rotation).to_matrix()
    inside = []
    for p in points:
        d = Vector(p) - Vector(location)
        inside.append(all(abs(d.dot(axes.col[k])) <= scale[k] for k in range(3)))
    return np.array(inside)


@pytest.mark.parametrize("rotation", [(0, 0, 0), (0.4, -0.3, 1.1)])
def test_box_selection_equals_brute_force(sphere, rotation):
    obj, (pos, *_) = sphere
    centre = pos.mean(axis=0) + [0.1, 0.2, 0.0]
    location, scale = tuple(centre), (0.35, 0.5, 0.6)
    make_box(location, rotation, scale)
    expected = brute_force_inside(pos.astype(np.float64), location, rotation, scale)
    assert 0 < expected.sum() < len(pos)
    assert bpy.ops.isouq.select_box() == {"FINISHED"}
    assert np.array_equal(selected(obj), expected)
    bpy.ops.isouq.plot_bars()
    from isouq import ui
    assert os.path.getsize(ui._paths["bars"]) > 1000


def test_box_follows_the_object_transform(sphere):
    obj, (pos, *_) = sphere
    obj.location = (0.5, 0.0, 0.0)
    bpy.context.view_layer.update()
    location = tuple(pos.mean(axis=0) + [0.5, 0, 0])
    make_box(location, (0, 0, 0), (0.4, 0.4, 2.0))
    assert bpy.ops.isouq.select_box() == {"FINISHED"}
    expected = brute_force_inside(pos.astype(np.float64) + [0.5, 0, 0], location, (0, 0, 0),
                                  (0.4, 0.4, 2.0))
    assert np.array_equal(selected(obj), expected)


def test_empty_box_is_an_error_and_changes_nothing(sphere):
    obj, _ = sphere
    make_box((100.0, 100.0, 100.0), (0, 0, 0), (0.1, 0.1, 0.1))
    before = selected(obj).copy()
    for op in (bpy.ops.isouq.select_box, bpy.ops.isouq.plot_bars):
        with pytest.raises(RuntimeError, match="box contains no vertex"):
            op()
    assert np.array_equal(selected(obj), before)
    s = bpy.context.scene.isouq
    s.selection = "BOX"
    with pytest.raises(RuntimeError, match="selection is empty"):
        bpy.ops.isouq.apply_methods()


def test_no_box_is_an_error(sphere):
    with pytest.raises(RuntimeError, match="no box"):
        bpy.ops.isouq.select_box()


# --- C3 ------------------------------------------------------------------------------------

@pytest.mark.parametrize("inside,outside", [("weno", "linear"), ("cubic", "weno")])
def test_methods_move_exactly_the_selected_vertices(sphere, inside, outside):
    obj, (pos, _, attrs, _, _) = sphere
    s = bpy.context.scene.isouq
    s.threshold_value = float(np.percentile(attrs["err_est"], 70))
    s.method_inside, s.method_outside = inside, outside
    assert bpy.ops.isouq.apply_methods() == {"FINISHED"}
    sel = attrs["err_est"] > np.float32(s.threshold_value)
    got = positions(obj)
    want = np.where(sel[:, None], crossing(attrs, inside), crossing(attrs, outside))
    assert np.abs(got - want).max() < 1e-6      # float32 positions of ~1 world unit
    assert np.array_equal(selected(obj), sel)
    if outside == "linear":
        assert np.array_equal(got[~sel], pos[~sel])       # untouched, bit for bit
        moved = np.any(got != pos, axis=1)
        assert np.array_equal(moved, sel & (attrs["t_" + inside] != attrs["t_linear"]))
    assert bpy.ops.isouq.reset_positions() == {"FINISHED"}
    assert np.array_equal(positions(obj), pos)


def test_methods_inside_the_box(sphere):
    obj, (pos, _, attrs, _, _) = sphere
    location = tuple(pos.mean(axis=0))
    make_box(location, (0, 0, 0.5), (0.5, 0.5, 0.5))
    s = bpy.context.scene.isouq
    s.selection, s.method_inside, s.method_outside = "BOX", "weno", "linear"
    assert bpy.ops.isouq.apply_methods() == {"FINISHED"}
    sel = brute_force_inside(pos.astype(np.float64), location, (0, 0, 0.5), (0.5, 0.5, 0.5))
    want = np.where(sel[:, None], crossing(attrs, "weno"), pos)
    assert np.abs(positions(obj) - want).max() < 1e-6


def test_methods_without_the_header_matrix_use_a_fitted_one(tmp_path):
    pos, faces, attrs, fattrs, comments = plyfixture.sphere_fixture(n=12, radius=4.0)
    path = str(tmp_path / "no_matrix.ply")
    plyfixture.write_ply(path, pos, faces, attrs, fattrs, comments[1:])
    assert bpy.ops.isouq.import_mesh(filepath=path) == {"FINISHED"}
    obj = bpy.context.active_object
    s = bpy.context.scene.isouq
    s.threshold_value, s.method_inside, s.method_outside = 0.0, "weno", "weno"
    assert bpy.ops.isouq.apply_methods() == {"FINISHED"}
    assert np.abs(positions(obj) - crossing(attrs, "weno")).max() < 1e-5
    assert obj.data["isouq_index_to_world_fitted"]


def test_missing_method_is_an_error(tmp_path):
    pos, faces, attrs, _, comments = plyfixture.sphere_fixture(n=10, radius=3.0)
    subset = {k: attrs[k] for k in ("edge_i", "edge_j", "edge_k", "edge_axis", "t_linear", "err_est")}
    path = str(tmp_path / "linear_only.ply")
    plyfixture.write_ply(path, pos, faces, subset, {}, comments)
    bpy.ops.isouq.import_mesh(filepath=path)
    with pytest.raises(RuntimeError, match="no t_weno"):
        bpy.ops.isouq.apply_methods()


# --- C4 ------------------------------------------------------------------------------------

def _upstream(socket):
    return socket.links[0].from_node if socket.is_linked else None


def test_heatmap_material_reads_the_attribute(sphere):
    obj, (_, _, attrs, _, _) = sphere
    s = bpy.context.scene.isouq
    s.measure = "d_lw"
    assert bpy.ops.isouq.show_heatmap() == {"FINISHED"}
    mat = obj.active_material
    assert mat.name == "ISOUQ_heatmap"
    nodes = mat.node_tree.nodes
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output)
    bsdf = _upstream(out.inputs["Surface"])
    ramp = _upstream(bsdf.inputs["Base Color"])
    rng = _upstream(ramp.inputs["Fac"])
    attr = _upstream(rng.inputs["Value"])
    assert (bsdf.type, ramp.type, rng.type, attr.type) == ("BSDF_PRINCIPLED", "VALTORGB",
                                                           "MAP_RANGE", "ATTRIBUTE")
    assert attr.attribute_name == "d_lw" and attr.attribute_type == "GEOMETRY"
    assert rng.inputs["From Min"].default_value == pytest.approx(attrs["d_lw"].min())
    assert rng.inputs["From Max"].default_value == pytest.approx(attrs["d_lw"].max())
    aovs = {n.name for n in nodes if n.type == "OUTPUT_AOV"}
    assert aovs == {"d_lw", "hidden"}


def test_summary_lists_counts_and_statistics(sphere, tmp_path):
    obj, (_, _, attrs, _, _) = sphere
    summary = {"vertices": len(attrs["err_est"]), "triangles": 1, "boundary_edges": 0,
               "components": 1, "isovalue": 0, "method": "linear",
               "err_est": {"min": 0.0, "max": 9.0, "mean": 1.0, "rms": 2.0},
               "hidden": {"cells_flagged": 3, "cells_total": 10, "fraction": 0.3,
                          "components_before": 2, "components_after": 1, "boundary_edges": 0}}
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(summary))
    from isouq import views
    views.load_summary(obj, str(path))
    s = bpy.context.scene.isouq
    s.threshold_value = float(np.median(attrs["err_est"]))
    rows = dict(views.summary(bpy.context, obj))
    assert rows["components"] == 1 and rows["hidden components_after"] == 1
    assert rows["err_est"].startswith("max 9 mean 1 rms 2")
    above = np.count_nonzero(attrs["err_est"] > np.float32(s.threshold_value))
    assert rows[f"err_est > {s.threshold_value:.4g}"].startswith(f"{above} (")
    d = attrs["d_lc"].astype(np.float64)                 # not in the JSON: from the attribute
    assert rows["d_lc"] == f"max {d.max():.3g} mean {d.mean():.3g} rms {math.sqrt((d * d).mean()):.3g}"


def test_menus_without_a_binary_list_the_meshes_columns(sphere_ply, tmp_path):
    """No binary: the menus hold what the scene's isouq meshes carry; the defaults still hold."""
    from isouq import props, views
    prefs = bpy.context.preferences.addons["isouq"].preferences
    prefs.binary = str(tmp_path / "no_isouq")
    try:
        s = bpy.context.scene.isouq
        assert props.measure_items(s, bpy.context) == []
        assert props.method_items(s, bpy.context) == []
        assert bpy.ops.isouq.import_mesh(filepath=sphere_ply[0]) == {"FINISHED"}
        attrs = sphere_ply[1][2]
        floats = [n for n, v in attrs.items() if v.dtype.kind == "f" and not n.startswith("t_")]
        assert [i[0] for i in props.measure_items(s, bpy.context)] == floats
        assert ([i[0] for i in props.method_items(s, bpy.context)]
                == [n[2:] for n in attrs if n.startswith("t_")])
        assert (s.measure, s.method_inside, s.method_outside) == ("err_est", "weno", "linear")
        assert bpy.context.active_object.active_material.name == "ISOUQ_heatmap"
        assert bpy.ops.isouq.apply_methods() == {"FINISHED"}
        assert "d_lc" in dict(views.summary(bpy.context, bpy.context.active_object))
    finally:
        prefs.binary = ""


# --- C6 ------------------------------------------------------------------------------------

def test_side_by_side_copy_shows_the_other_method(sphere):
    obj, (pos, _, attrs, _, _) = sphere
    bpy.context.scene.isouq.compare_method = "weno"
    assert bpy.ops.isouq.compare_methods() == {"FINISHED"}
    copy = bpy.data.objects[obj.name + "_weno"]
    assert copy.data is not obj.data
    assert np.abs(positions(copy) - crossing(attrs, "weno")).max() < 1e-6
    assert np.array_equal(positions(obj), pos)
    assert copy.location.x > obj.location.x


def test_hidden_views_need_a_partner(sphere):
    obj, _ = sphere
    for op in (bpy.ops.isouq.show_hidden, bpy.ops.isouq.combined_view):
        with pytest.raises(RuntimeError, match="no hidden-feature mesh"):
            op()


def test_hidden_over_standard_and_combined(sphere, sphere_ply):
    obj, _ = sphere
    assert bpy.ops.isouq.import_mesh(filepath=sphere_ply[0]) == {"FINISHED"}
    hidden = bpy.context.active_object
    hidden.isouq.role, obj.isouq.partner, hidden.isouq.partner = "HIDDEN", hidden, obj
    assert bpy.ops.isouq.show_hidden() == {"FINISHED"}
    assert obj.active_material.name == "ISOUQ_standard" and obj.active_material.blend_method == "OPAQUE"
    orange = hidden.active_material
    assert orange.name == "ISOUQ_hidden" and orange.blend_method == "BLEND"
    bsdf = next(n for n in orange.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    assert bsdf.inputs["Alpha"].default_value < 1
    assert hidden.show_in_front and not obj.show_in_front  # orange drawn over blue, no z-fight
    assert bpy.ops.isouq.combined_view() == {"FINISHED"}
    nodes = hidden.active_material.node_tree.nodes
    assert nodes["Hidden face"].attribute_name == "hidden_face"
    assert nodes["Measure"].attribute_name == "err_est"
    assert obj.hide_render and not hidden.hide_render


def test_no_isouq_mesh_is_an_error():
    before = snapshot()
    with pytest.raises(RuntimeError, match="no isouq mesh"):
        bpy.ops.isouq.apply_threshold()
    assert scene_delta(before) == (set(), set())


def test_refined_and_nan_vertices_keep_their_position(tmp_path):
    """Hidden-feature vertices (hidden = 1) lie on sub-edges, and a NaN t has no crossing:
    C3 leaves both where the file put them."""
    pos, faces, attrs, fattrs, comments = plyfixture.sphere_fixture(n=12, radius=4.0)
    attrs["hidden"][::5] = 1
    attrs["t_weno"][1::7] = np.nan
    path = str(tmp_path / "refined.ply")
    plyfixture.write_ply(path, pos, faces, attrs, fattrs, comments)
    assert bpy.ops.isouq.import_mesh(filepath=path) == {"FINISHED"}
    obj = bpy.context.active_object
    s = bpy.context.scene.isouq
    s.method_inside = s.method_outside = "weno"
    assert bpy.ops.isouq.apply_methods() == {"FINISHED"}
    keep = (attrs["hidden"] == 1) | np.isnan(attrs["t_weno"])
    got = positions(obj)
    assert np.array_equal(got[keep], pos[keep])
    assert np.abs(got[~keep] - crossing(attrs, "weno")[~keep]).max() < 1e-6


def test_empty_mesh_imports_as_an_empty_object(tmp_path):
    path = str(tmp_path / "empty.ply")
    plyfixture.write_ply(path, np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32),
                         {"t_linear": np.zeros(0, np.float32)}, {},
                         ["isouq index_to_world 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"])
    assert bpy.ops.isouq.import_mesh(filepath=path) == {"FINISHED"}
    assert len(bpy.context.active_object.data.vertices) == 0
    with pytest.raises(RuntimeError, match="no 'err_est'"):
        bpy.ops.isouq.apply_threshold()
