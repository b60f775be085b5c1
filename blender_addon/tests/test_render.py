# Rendering: the heat map's colour order shows in pixels, and the headless script writes a PNG
# and a multilayer EXR carrying the AOV passes.

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from isouq import attributes, render

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "scripts", "render_view.py")


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


def test_headless_script_writes_png_and_exr_with_aovs(sphere_ply, tmp_path):
    out, exr, cdf = tmp_path / "view.png", tmp_path / "view.exr", tmp_path / "cdf.png"
    cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
           "-P", SCRIPT, "--", "--mesh", sphere_ply[0], "--hidden", sphere_ply[0],
           "--view", "combined", "--out", str(out), "--exr", str(exr), "--cdf", str(cdf),
           "--engine", "cycles", "--size", "64", "--samples", "2"]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert cdf.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    header = exr.read_bytes()[:4096]
    assert header[:4] == b"\x76\x2f\x31\x01"                       # OpenEXR magic
    for channel in (b"err_est.X", b"hidden.X", b"Combined.R"):
        assert channel in header


def test_bad_view_arguments_fail_cleanly(tmp_path):
    cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
           "-P", SCRIPT, "--", "--mesh", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.png")]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert run.returncode == 2
    assert "isouq render: error:" in run.stderr and "missing.ply" in run.stderr
    assert not (tmp_path / "x.png").exists()
