# Rendering: the heat map's colour order shows in pixels, the headless script writes a PNG, a
# figure and a multilayer EXR carrying the AOV passes, and the EXR's err_est pass of the real
# teardrop demo holds the attribute's values where the surface is seen.

import os
import subprocess

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from conftest import REAL_CLI, REAL_CLI_TRIED
from isouq import attributes, render, views

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "scripts", "render_view.py")


def render_script(*args):
    cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
           "-P", SCRIPT, "--", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def test_heatmap_render_is_warmer_over_high_values(sphere_ply, tmp_path):
    assert bpy.ops.isouq.import_mesh(filepath=sphere_ply[0]) == {"FINISHED"}
    obj = bpy.context.active_object
    me = obj.data
    co = attributes.get_positions(me).astype(np.float64)
    # a smooth measure with a known pattern: err_est grows along world x
    attributes.set_attribute(me, "err_est", co[:, 0].astype(np.float32), "POINT")
    assert bpy.ops.isouq.show_heatmap() == {"FINISHED"}
    path = str(tmp_path / "heat.png")
    render.render_view(bpy.context, [obj], path, "CYCLES", size=96, samples=4)
    image = bpy.data.images.load(path)
    w, h = image.size
    px = np.array(image.pixels[:]).reshape(h, w, 4)
    cam, scene = bpy.context.scene.camera, bpy.context.scene
    view = (cam.matrix_world.to_quaternion() @ Vector((0, 0, -1)))
    normals = np.empty(3 * len(me.vertices))
    me.vertices.foreach_get("normal", normals)
    facing = normals.reshape(-1, 3) @ np.array(view) < -0.5          # seen from the front
    warmth = []
    for v in np.flatnonzero(facing):
        p = world_to_camera_view(scene, cam, obj.matrix_world @ Vector(co[v]))
        r, _, b, _ = px[min(int(p.y * h), h - 1), min(int(p.x * w), w - 1)]
        warmth.append((co[v, 0], r - b))
    warmth = np.array(sorted(warmth))
    k = max(len(warmth) // 5, 3)
    low, high = warmth[:k, 1].mean(), warmth[-k:, 1].mean()
    assert high > low + 0.2, (low, high)
    # and the order holds along the way: warmth correlates with the measure
    assert np.corrcoef(warmth[:, 0], warmth[:, 1])[0, 1] > 0.8


def test_headless_script_writes_png_figure_and_exr_with_aovs(sphere_ply, tmp_path):
    out, exr, cdf = tmp_path / "view.png", tmp_path / "view.exr", tmp_path / "cdf.png"
    fig = tmp_path / "figure.png"
    run = render_script("--mesh", sphere_ply[0], "--hidden", sphere_ply[0], "--view", "combined",
                        "--out", str(out), "--exr", str(exr), "--cdf", str(cdf),
                        "--figure", str(fig), "--clip-percentile", "95",
                        "--engine", "cycles", "--size", "64", "--samples", "2")
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    for png in (out, cdf, fig):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    figure = bpy.data.images.load(str(fig))
    assert figure.size[0] > 64 and figure.size[1] > 64             # render + title + key
    header = exr.read_bytes()[:4096]
    assert header[:4] == b"\x76\x2f\x31\x01"                       # OpenEXR magic
    for channel in (b"err_est.X", b"hidden.X", b"Combined.R"):
        assert channel in header


def test_bad_view_arguments_fail_cleanly(tmp_path):
    run = render_script("--mesh", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.png"))
    assert run.returncode == 2
    assert "isouq render: error:" in run.stderr and "missing.ply" in run.stderr
    assert not (tmp_path / "x.png").exists()


def _read_exr(path):
    """(channel name -> (H, W) array) through OpenImageIO, a reader independent of Blender."""
    oiio = pytest.importorskip("OpenImageIO", reason="python3-openimageio is not installed")
    image = oiio.ImageInput.open(path)
    assert image, oiio.geterror()
    names = list(image.spec().channelnames)
    pixels = image.read_image(oiio.FLOAT)
    image.close()
    return {name: pixels[..., c] for c, name in enumerate(names)}


def test_exr_err_est_pass_of_the_teardrop_demo_follows_the_attribute(tmp_path):
    """Render `isouq demo`'s teardrop, read the multilayer EXR back and look up every vertex
    seen by the camera (its depth equals the Depth pass within two voxels). The AOV is the
    attribute interpolated over the triangle under the pixel, so its value lies within the
    range of err_est over the vertex's 1-ring, except where anti-aliasing mixes in another
    triangle; and it ranks like the attribute."""
    if REAL_CLI is None:
        pytest.skip(f"no isouq binary (tried {REAL_CLI_TRIED})")
    demo = subprocess.run([REAL_CLI, "demo", "--dir", str(tmp_path)], capture_output=True,
                          text=True, timeout=600)
    assert demo.returncode == 0, demo.stderr[-500:]
    ply, exr, size, direction = str(tmp_path / "teardrop.ply"), str(tmp_path / "heat.exr"), 256, \
        (1.0, -1.2, 0.8)
    run = render_script("--mesh", ply, "--view", "heatmap", "--out", str(tmp_path / "heat.png"),
                        "--exr", exr, "--size", str(size), "--samples", "4",
                        "--direction", ",".join(map(str, direction)))
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    channels = _read_exr(exr)
    value, depth = channels["ViewLayer.err_est.X"], channels["ViewLayer.Depth.Z"]
    assert not channels["ViewLayer.hidden.X"].any()              # no hidden features here
    # the same camera in this process (render.frame_camera is deterministic)
    obj = views.import_ply(bpy.context, ply)
    scene = bpy.context.scene
    render.configure(scene, size=size)
    cam = render.frame_camera(scene, [obj], direction, size)
    bpy.context.view_layer.update()
    h, w = value.shape
    assert (scene.render.resolution_x, scene.render.resolution_y) == (w, h)
    err = attributes.get_attribute(obj.data, "err_est").astype(np.float64)
    seen = np.array([tuple(world_to_camera_view(scene, cam, Vector(p)))
                     for p in attributes.get_positions(obj.data)])
    col = np.clip((seen[:, 0] * w).astype(int), 0, w - 1)
    row = np.clip(((1 - seen[:, 1]) * h).astype(int), 0, h - 1)     # EXR rows run top-down
    voxel = np.array(obj.data["isouq_index_to_world"])[0]
    visible = np.abs(depth[row, col] - seen[:, 2]) < 2 * voxel
    assert visible.mean() > 0.5
    pixel = value[row, col].astype(np.float64)
    faces = np.empty(3 * len(obj.data.polygons), np.int32)
    obj.data.polygons.foreach_get("vertices", faces)
    faces = faces.reshape(-1, 3)
    lo, hi = err.copy(), err.copy()
    for a in range(3):
        for b in range(3):
            np.minimum.at(lo, faces[:, a], err[faces[:, b]])
            np.maximum.at(hi, faces[:, a], err[faces[:, b]])
    tol = 1e-3 * err.max()
    in_ring = (pixel >= lo - tol) & (pixel <= hi + tol)
    assert in_ring[visible].mean() > 0.95                          # measured 0.989
    x, y = err[visible], pixel[visible]
    rank = lambda v: np.argsort(np.argsort(v)).astype(np.float64)
    assert np.corrcoef(rank(x), rank(y))[0, 1] > 0.7                 # measured 0.79
    order, k = np.argsort(x), len(x) // 10
    assert y[order[-k:]].mean() > 3 * y[order[:k]].mean()          # measured 6x
