# Mesh sequences (SPEC §10 "Sequences", issue 11) on fixture frames written by the independent
# numpy writer: the frame number found in a file name, the frames on disk, which frame a scene
# frame shows; after import, frame_set(k) in any order gives exactly frame k's mesh and
# attributes (ply_io on that frame's file); the cache stays bounded; the heat-map range is the
# sequence's; the views follow frames; the handler survives a file load and leaves with the
# add-on; rendering an animation shows frame k's mesh on frame k.

import json
import os
import subprocess

import addon_utils
import bpy
import numpy as np
import pytest

import plyfixture
from conftest import scene_delta, snapshot
from isouq import frames, ply_io, sequence

HERE = os.path.dirname(os.path.abspath(__file__))
INSTALL = os.path.join(HERE, "..", "install.py")
FRAMES = 12                      # frames 1..11 spheres of growing radius, frame 12 empty
EMPTY_FRAME = 12


def write_empty(path):
    """A valid isouq PLY with no vertex (what the CLI writes for a frame with an empty grid)."""
    _, _, attrs, fattrs, comments = plyfixture.sphere_fixture(n=10, radius=3.0)
    plyfixture.write_ply(path, np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32),
                         {k: v[:0] for k, v in attrs.items()}, {k: v[:0] for k, v in fattrs.items()},
                         comments)


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory):
    """ball.0001.ply .. ball.0012.ply (frame 12 empty) and, apart, the same with a summary."""
    folder = tmp_path_factory.mktemp("sequence")
    for k in range(1, FRAMES + 1):
        path = str(folder / f"ball.{k:04d}.ply")
        if k == EMPTY_FRAME:
            write_empty(path)
        else:
            plyfixture.write_sphere(path, n=16, radius=3.0 + 0.25 * k, bump=0.1 * k)
    return folder


def frame_path(folder, k):
    return str(folder / f"ball.{k:04d}.ply")


def write_summary(folder, name="ball"):
    """A sequence summary as `isouq mesh ... --summary` writes it (SPEC §10), from the files."""
    entries = []
    for k in range(1, FRAMES + 1):
        mesh = ply_io.read_ply(frame_path(folder, k))
        e = mesh.vertex_attributes["err_est"].astype(np.float64)
        entry = {"frame": k, "file": f"in.{k:04d}.vdb", "output": f"{name}.{k:04d}.ply",
                 "vertices": mesh.vertex_count, "triangles": mesh.face_count,
                 "components": 1, "boundary_edges": 0, "empty": mesh.vertex_count == 0}
        if len(e):
            entry["err_est"] = {"min": float(e.min()), "max": float(e.max()),
                                "mean": float(e.mean()), "rms": float(np.sqrt(np.mean(e * e))),
                                "count": len(e)}
        else:
            entry["err_est"] = {"min": None, "max": None, "mean": None, "rms": None, "count": 0}
        entries.append(entry)
    doc = {"frames": entries, "totals": {"frames": FRAMES}, "isovalue": 0.0,
           "isovalue_source": "given", "method": "linear",
           "sequence": {"input": "in.####.vdb", "output": f"{name}.####.ply", "first": 1,
                        "last": FRAMES, "step": 1}}
    path = folder / f"{name}.json"
    path.write_text(json.dumps(doc))
    return str(path), doc


def import_frames(folder, **kw):
    result = bpy.ops.isouq.import_sequence(filepath=frame_path(folder, 3), **kw)
    assert result == {"FINISHED"}
    return bpy.context.active_object


def blender_columns(me):
    """Positions, triangles and every PLY column of a Blender mesh as numpy arrays."""
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    tri = np.empty(3 * len(me.polygons), np.int32)
    me.polygons.foreach_get("vertices", tri)
    cols = {}
    for name in json.loads(me.get("isouq_ply_types", "{}")):
        attr = me.attributes[name]
        out = np.empty(len(attr.data), np.float32 if attr.data_type == "FLOAT" else np.int32)
        attr.data.foreach_get("value", out)
        cols[name] = out
    return co.reshape(-1, 3), tri.reshape(-1, 3), cols


def assert_shows_file(obj, path):
    """The object's mesh is the file's, exactly: positions, triangles, every column."""
    mesh = ply_io.read_ply(path)
    co, tri, cols = blender_columns(obj.data)
    assert len(co) == mesh.vertex_count
    assert np.array_equal(co, mesh.positions)
    assert np.array_equal(tri, mesh.corners.reshape(-1, 3))
    expected = dict(mesh.vertex_attributes)
    expected.update({n + "_face": v for n, v in mesh.face_attributes.items()})
    assert set(cols) == set(expected)
    for name, values in expected.items():
        assert np.array_equal(cols[name], values.astype(cols[name].dtype),
                              equal_nan=cols[name].dtype.kind == "f"), name


# --- file names and frames (no Blender data) ---------------------------------------------------

def test_detect_finds_the_frame_number_and_the_frames_on_disk(tmp_path):
    for name in ("a.0001.ply", "a.0002.ply", "a.0010.ply", "a.12.ply", "a.0003.ply.bak",
                 "b_1.ply", "b_2.ply", "b_10.ply", "b_007.ply", "c.ply", "v2_shot.0005.ply"):
        (tmp_path / name).write_bytes(b"")
    a = frames.detect(str(tmp_path / "a.0002.ply"))
    assert (a.prefix, a.width, a.suffix, a.frames) == ("a.", 4, ".ply", [1, 2, 10])
    assert a.pattern == str(tmp_path / "a.####.ply")
    assert frames.detect(str(tmp_path / "a.####.ply")).frames == [1, 2, 10]
    assert frames.detect(str(tmp_path / "a.%04d.ply")).frames == [1, 2, 10]
    b = frames.detect(str(tmp_path / "b_10.ply"))            # unpadded: b_007 is not one
    assert (b.width, b.frames) == (1, [1, 2, 10])
    assert frames.detect(str(tmp_path / "v2_shot.0005.ply")).frames == [5]   # the last digits
    with pytest.raises(frames.SequenceError, match="no frame number"):
        frames.detect(str(tmp_path / "c.ply"))
    with pytest.raises(frames.SequenceError, match="no file matches"):
        frames.detect(str(tmp_path / "z.####.ply"))
    assert frames.pattern_of("/cache/fluid_data_0001.vdb") == "/cache/fluid_data_####.vdb"
    # a frame wider than the padding is written whole (as the CLI reads it)
    assert frames.Sequence("d", "s.", ".ply", 4).name(12345) == "s.12345"


def test_scene_frame_to_file_frame_in_every_mode():
    seq = frames.Sequence("", "s.", ".ply", 4, [3, 4, 5, 7])      # frame 6 missing
    f = lambda k, mode, offset=0: seq.file_frame(k, offset, mode)
    assert [f(k, "EXTEND") for k in (1, 3, 6, 7, 9)] == [3, 3, 5, 7, 7]    # a gap holds 5
    assert [f(k, "CLIP") for k in (2, 3, 6, 7, 8)] == [None, 3, 5, 7, None]
    assert [f(k, "REPEAT") for k in (8, 9, 10, 2)] == [3, 4, 5, 7]
    assert [f(k, "PING_PONG") for k in (8, 9, 10, 11, 2)] == [5, 5, 4, 3, 4]
    assert f(1, "EXTEND", offset=3) == 4                     # file = scene + offset


# --- import and frame changes -------------------------------------------------------------------

def test_frame_set_in_any_order_gives_that_frames_mesh_exactly(frames_dir):
    obj = import_frames(frames_dir)
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (1, FRAMES)
    assert obj.isouq.sequence == str(frames_dir / "ball.####.ply")
    counts = set()
    for k in (7, 2, 11, 5, 1, 12, 9, 2, 7, 3, 12, 4):
        scene.frame_set(k)
        assert obj.isouq.sequence_frame == k
        assert_shows_file(obj, frame_path(frames_dir, k))
        counts.add(len(obj.data.vertices))
        assert ("err_est" in obj.data.attributes) and (len(obj.data.vertices) == 0) == (k == EMPTY_FRAME)
    assert len(counts) >= 8                                  # the frames really differ


def test_cache_stays_bounded_and_serves_recent_frames(frames_dir, monkeypatch):
    obj = import_frames(frames_dir)
    reads = []
    real = ply_io.read_ply
    monkeypatch.setattr(ply_io, "read_ply", lambda p, *a: reads.append(p) or real(p, *a))
    sequence.CACHE.clear()
    scene = bpy.context.scene
    assert obj.isouq.sequence_frame == 1                    # shown: frame 1
    for k in [*range(2, FRAMES + 1), 1]:
        scene.frame_set(k)
        assert len(sequence.CACHE) <= sequence.CACHE_FRAMES == 8
    assert len(reads) == FRAMES and len(sequence.CACHE) == 8
    for k in (12, 9, 6, 11, 1):                            # the last 8 frames: no reading
        scene.frame_set(k)
        assert_shows_file(obj, frame_path(frames_dir, k))
    assert len(reads) == FRAMES + 5                         # (assert_shows_file reads too)
    scene.frame_set(2)                                     # evicted long ago: read again
    assert len(reads) == FRAMES + 6 and reads[-1] == frame_path(frames_dir, 2)
    assert_shows_file(obj, frame_path(frames_dir, 2))


def test_outside_the_frames_hold_or_clip_and_offset(frames_dir):
    obj = import_frames(frames_dir)
    scene = bpy.context.scene
    scene.frame_set(-3)
    assert obj.isouq.sequence_frame == 1                    # EXTEND: the nearest frame
    assert_shows_file(obj, frame_path(frames_dir, 1))
    obj.isouq.sequence_mode = "CLIP"                        # takes effect at once
    assert len(obj.data.vertices) == 0 and obj.isouq.summary == ""
    scene.frame_set(FRAMES + 5)
    assert len(obj.data.vertices) == 0
    obj.isouq.sequence_offset = -10                          # scene 17 shows file 7
    assert obj.isouq.sequence_frame == 7
    assert_shows_file(obj, frame_path(frames_dir, 7))


def test_import_with_offset_sets_the_scene_range(frames_dir):
    obj = import_frames(frames_dir, offset=-100, mode="CLIP")
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (101, 100 + FRAMES)
    assert scene.frame_current == 101 and obj.isouq.sequence_frame == 1
    scene.frame_set(104)
    assert_shows_file(obj, frame_path(frames_dir, 4))


def test_heat_range_covers_every_frame_from_a_scan_or_the_summary(frames_dir, tmp_path):
    everything = np.concatenate([ply_io.read_ply(frame_path(frames_dir, k)).vertex_attributes
                                 ["err_est"] for k in range(1, FRAMES + 1)])
    lo, hi = float(everything.min()), float(everything.max())
    obj = import_frames(frames_dir)
    assert obj["isouq_sequence_ranges_from"] == "scan" and obj.isouq.sequence_summary == ""
    rng = obj.data.materials[0].node_tree.nodes["Range"]
    assert (rng.inputs["From Min"].default_value, rng.inputs["From Max"].default_value) == \
        pytest.approx((lo, hi), rel=1e-6)
    s = bpy.context.scene.isouq
    bpy.context.scene.frame_set(2)                           # a frame with a smaller range
    frame_hi = float(ply_io.read_ply(frame_path(frames_dir, 2)).vertex_attributes["err_est"].max())
    assert frame_hi < hi
    assert bpy.ops.isouq.show_heatmap() == {"FINISHED"}
    assert (s.heat_min, s.heat_max) == pytest.approx((lo, hi), rel=1e-6)
    s.heat_range_scope = "FRAME"
    assert bpy.ops.isouq.show_heatmap() == {"FINISHED"}
    assert s.heat_max == pytest.approx(frame_hi, rel=1e-6)
    # with a summary beside the files, the range comes from it (no scan)
    copy = tmp_path / "with_summary"
    copy.mkdir()
    for k in range(1, FRAMES + 1):
        (copy / f"ball.{k:04d}.ply").write_bytes(open(frame_path(frames_dir, k), "rb").read())
    summary, doc = write_summary(copy)
    doc["frames"][4]["err_est"]["max"] = 2 * hi            # the summary is what counts
    (copy / "ball.json").write_text(json.dumps(doc))
    bpy.ops.wm.read_homefile(use_empty=True)
    obj = import_frames(copy)
    assert obj["isouq_sequence_ranges_from"] == "summary"
    assert obj.isouq.sequence_summary == summary
    assert sequence.measure_range(obj, "err_est") == pytest.approx((lo, 2 * hi), rel=1e-6)


def test_views_work_on_every_frame(frames_dir, tmp_path):
    copy = tmp_path / "views"
    copy.mkdir()
    for k in range(1, FRAMES + 1):
        (copy / f"ball.{k:04d}.ply").write_bytes(open(frame_path(frames_dir, k), "rb").read())
    write_summary(copy)
    obj = import_frames(copy)
    scene, s = bpy.context.scene, bpy.context.scene.isouq
    scene.frame_set(4)
    threshold = float(np.percentile(ply_io.read_ply(frame_path(copy, 4)).vertex_attributes
                                    ["err_est"], 70))
    s.threshold_mode, s.threshold_value = "VALUE", threshold
    assert bpy.ops.isouq.apply_threshold() == {"FINISHED"}                        # C1
    s.method_inside, s.method_outside, s.selection = "weno", "linear", "THRESHOLD"
    assert bpy.ops.isouq.apply_methods() == {"FINISHED"}                          # C3
    assert bpy.ops.isouq.compare_methods() == {"FINISHED"}                        # C6 copy
    compare = bpy.data.objects[f"{obj.name}_{s.compare_method}"]
    from isouq import analysis, views
    for k in (9, 2, 12, 6):
        scene.frame_set(k)
        mesh = ply_io.read_ply(frame_path(copy, k))
        attrs = mesh.vertex_attributes
        if mesh.vertex_count == 0:
            assert len(obj.data.vertices) == len(compare.data.vertices) == 0
            continue
        mask = attrs["err_est"] > np.float32(threshold)
        want = analysis.mixed_positions(mesh.positions, attrs, mesh.index_to_world, mask,
                                        "t_weno", "t_linear")
        co, _, _ = blender_columns(obj.data)
        assert np.array_equal(co, want)                     # C3 redone on the new frame
        selected = np.empty(len(obj.data.vertices), bool)
        obj.data.vertices.foreach_get("select", selected)
        assert np.array_equal(selected, mask)               # C1 selection of this frame
        cco, _, _ = blender_columns(compare.data)
        assert np.array_equal(cco, analysis.method_positions(
            mesh.positions, attrs, mesh.index_to_world, "t_" + s.compare_method))
        rows = dict(views.summary(bpy.context, obj))       # C7: this frame's summary entry
        assert rows["vertices"] == mesh.vertex_count and rows["method"] == "linear"
        bpy.context.view_layer.objects.active = obj
        assert bpy.ops.isouq.show_heatmap() == {"FINISHED"}                       # C4
    scene.frame_set(3)
    assert bpy.ops.isouq.reset_positions() == {"FINISHED"}
    scene.frame_set(5)
    co, _, _ = blender_columns(obj.data)
    assert np.array_equal(co, ply_io.read_ply(frame_path(copy, 5)).positions)


def test_setting_the_pattern_again_finds_frames_written_since(frames_dir, tmp_path):
    copy = tmp_path / "growing"
    copy.mkdir()
    for k in range(1, 4):
        (copy / f"ball.{k:04d}.ply").write_bytes(open(frame_path(frames_dir, k), "rb").read())
    obj = import_frames(copy)
    bpy.context.scene.frame_set(6)
    assert obj.isouq.sequence_frame == 3                    # EXTEND holds the last
    for k in range(4, 7):                                   # a run still writing frames
        (copy / f"ball.{k:04d}.ply").write_bytes(open(frame_path(frames_dir, k), "rb").read())
    obj.isouq.sequence = obj.isouq.sequence
    assert obj.isouq.sequence_frame == 6
    assert_shows_file(obj, str(copy / "ball.0006.ply"))


def test_bad_files_report_and_create_nothing(tmp_path):
    (tmp_path / "plain.ply").write_bytes(b"ply\n")
    (tmp_path / "broken.0001.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    before = snapshot()
    with pytest.raises(RuntimeError, match="no frame number"):
        bpy.ops.isouq.import_sequence(filepath=str(tmp_path / "plain.ply"))
    with pytest.raises(RuntimeError, match="no vertex element"):
        bpy.ops.isouq.import_sequence(filepath=str(tmp_path / "broken.0001.ply"))
    assert scene_delta(before) == (set(), set())


def test_a_frame_broken_later_shows_nothing_and_the_others_still_play(frames_dir, tmp_path):
    copy = tmp_path / "later"
    copy.mkdir()
    for k in range(1, 4):
        (copy / f"ball.{k:04d}.ply").write_bytes(open(frame_path(frames_dir, k), "rb").read())
    obj = import_frames(copy)
    (copy / "ball.0002.ply").write_bytes(b"ply\ntruncated")
    bpy.context.scene.frame_set(2)
    assert len(obj.data.vertices) == 0
    bpy.context.scene.frame_set(1)
    assert_shows_file(obj, str(copy / "ball.0001.ply"))


# --- handlers ------------------------------------------------------------------------------------

def our_handlers():
    return {kind: [h for h in getattr(bpy.app.handlers, kind)
                   if getattr(h, "__module__", "") == "isouq.sequence"]
            for kind in ("frame_change_pre", "load_post")}


def test_handlers_registered_once_and_removed_with_the_addon(frames_dir):
    assert {k: len(v) for k, v in our_handlers().items()} == {"frame_change_pre": 1,
                                                              "load_post": 1}
    for _ in range(2):
        addon_utils.disable("isouq", default_set=True)
        assert our_handlers() == {"frame_change_pre": [], "load_post": []}
        addon_utils.enable("isouq", default_set=True)
        assert {k: len(v) for k, v in our_handlers().items()} == {"frame_change_pre": 1,
                                                                  "load_post": 1}
    # bpy.app.handlers.persistent marks a function with `_bpy_persistent` in its __dict__
    assert all("_bpy_persistent" in h.__dict__ for v in our_handlers().values() for h in v)


def test_sequence_plays_after_saving_and_opening_the_file(frames_dir, tmp_path):
    name = import_frames(frames_dir).name
    bpy.context.scene.frame_set(6)
    path = str(tmp_path / "seq.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    sequence.CACHE.clear()
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects[name]
    assert obj.isouq.sequence_frame == 6 and len(obj.data.vertices) == \
        ply_io.read_ply(frame_path(frames_dir, 6)).vertex_count
    for k in (10, 1, 8):
        bpy.context.scene.frame_set(k)
        assert_shows_file(obj, frame_path(frames_dir, k))


# --- rendering an animation ----------------------------------------------------------------------

RECORD = """
import bpy, json, os
out = os.environ["ISOUQ_RECORD"]
def record(scene, depsgraph):
    obj = bpy.data.objects["ball"].evaluated_get(depsgraph)
    with open(out, "a") as f:
        f.write(json.dumps([scene.frame_current, depsgraph.mode, len(obj.data.vertices)]) + "\\n")
bpy.app.handlers.frame_change_post.append(record)
"""


def test_rendering_the_animation_shows_frame_k_on_frame_k(frames_dir, tmp_path):
    """`blender -b file.blend -a` with the add-on installed as a user would (install.py into a
    scratch user folder): each rendered frame's evaluated mesh is that frame's file, and the
    pictures differ as the spheres grow."""
    from isouq import render
    obj = import_frames(frames_dir)
    scene = bpy.context.scene
    scene.frame_set(11)                                     # the largest sphere frames the camera
    render.configure(scene, "BLENDER_WORKBENCH", 48)
    render.frame_camera(scene, [obj], size=48, margin=1.3)
    scene.frame_start, scene.frame_end = 2, 11
    scene.frame_set(5)
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(tmp_path / "render" / "ball_####")
    blend = str(tmp_path / "anim.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    env = dict(os.environ, HOME=str(tmp_path), BLENDER_USER_CONFIG=str(tmp_path / "config"),
               BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"),
               ISOUQ_RECORD=str(tmp_path / "record.jsonl"))
    run = lambda *a: subprocess.run([bpy.app.binary_path, "-b", *a], capture_output=True,
                                    text=True, timeout=600, env=env)
    done = run("--python-exit-code", "1", "-P", INSTALL)
    assert done.returncode == 0, done.stderr[-2000:]
    done = run(blend, "--python-expr", RECORD, "-a")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    rows = [json.loads(line) for line in open(tmp_path / "record.jsonl")]
    rendered = {k: n for k, mode, n in rows if mode == "RENDER"}
    assert sorted(rendered) == list(range(2, 12))
    for k, n in rendered.items():
        assert n == ply_io.read_ply(frame_path(frames_dir, k)).vertex_count, k
    coverage = []
    for k in range(2, 12):
        image = bpy.data.images.load(str(tmp_path / "render" / f"ball_{k:04d}.png"))
        px = np.array(image.pixels[:]).reshape(image.size[1], image.size[0], 4)
        coverage.append(int((px[..., 3] > 0.5).sum()))
    assert all(b > a for a, b in zip(coverage, coverage[1:])), coverage
