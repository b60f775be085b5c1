# Renders the current isouq view to PNG (Eevee, or Cycles on the CPU without denoising: Debian's
# Cycles has no OpenImageDenoise), optionally also a multilayer OpenEXR with shader AOV passes
# (the measure and the hidden mask, materials.py).

import math

import bpy
import numpy as np
from mathutils import Euler, Vector

from . import materials

CAMERA, LIGHT = "ISOUQ_camera", "ISOUQ_sun"
# Lit faces reach about the material colour (sun + world + emission ~ 1), so pixels read
# against the legend; faces turned away keep about half of it.
SUN_STRENGTH, WORLD_GREY = 0.6, 0.3


def _world_vertices(objects):
    pts = []
    for obj in objects:
        co = np.empty(3 * len(obj.data.vertices))
        obj.data.vertices.foreach_get("co", co)
        m = np.array(obj.matrix_world, np.float64)
        pts.append(co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3])
    pts = np.concatenate(pts) if pts else np.empty((0, 3))
    if len(pts) == 0:
        raise ValueError("nothing visible to render")
    return pts


def frame_camera(scene, objects, direction=(1.0, -1.2, 0.8), size=800, margin=1.06):
    """An orthographic ISOUQ_camera looking along -direction that fits the objects' vertices
    tightly: the longer image side is `size` pixels, the other follows the projected extent.
    The sun shines from over the viewer's left shoulder."""
    d = Vector(direction).normalized()
    rotation = (-d).to_track_quat("-Z", "Y")
    axes = np.array(rotation.to_matrix(), np.float64)          # columns: camera x, y, z
    local = _world_vertices(objects) @ axes
    lo, hi = local.min(axis=0), local.max(axis=0)
    extent = np.maximum(hi - lo, 1e-9)
    cam = bpy.data.objects.get(CAMERA)
    if cam is None:
        cam = bpy.data.objects.new(CAMERA, bpy.data.cameras.new(CAMERA))
        scene.collection.objects.link(cam)
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = float(extent[:2].max()) * margin
    cam.data.clip_start = 0.01 * float(extent[2])
    cam.data.clip_end = 3.0 * float(extent[2])
    centre = (lo + hi) / 2
    centre[2] = hi[2] + extent[2]                               # in front of the nearest point
    cam.location = Vector(axes @ centre)
    cam.rotation_euler = rotation.to_euler()
    wide = extent[0] >= extent[1]
    short = int(round(size * min(extent[:2]) / max(extent[:2])))
    short = max(short + short % 2, size // 3)
    scene.render.resolution_x, scene.render.resolution_y = (size, short) if wide else (short, size)
    scene.camera = cam
    sun = bpy.data.objects.get(LIGHT)
    if sun is None:
        sun = bpy.data.objects.new(LIGHT, bpy.data.lights.new(LIGHT, "SUN"))
        scene.collection.objects.link(sun)
    sun.data.energy = SUN_STRENGTH
    tilt = Euler((math.radians(-30), math.radians(-35), 0.0)).to_quaternion()
    sun.rotation_euler = (rotation @ tilt).to_euler()
    return cam


def configure(scene, engine="BLENDER_EEVEE", size=800, samples=16):
    scene.render.engine = engine
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True              # figures compose on white
    if engine == "CYCLES":
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        scene.cycles.use_preview_denoising = False
    else:
        scene.eevee.taa_render_samples = samples
    if scene.world is None:
        scene.world = bpy.data.worlds.new("ISOUQ_world")
    scene.world.color = (WORLD_GREY,) * 3
    scene.view_settings.view_transform = "Standard"   # colours as in the legend


def render_view(context, objects, path, engine="BLENDER_EEVEE", size=800, exr_path=None,
                aovs=(), samples=16, direction=(1.0, -1.2, 0.8), frame=True):
    """Renders `objects` (framed, or with the current camera when not `frame`) to the PNG
    `path`; with `exr_path` also a multilayer EXR holding the combined pass and the shader AOVs
    `aovs`. Returns the paths written."""
    scene = context.scene
    resolution = scene.render.resolution_x, scene.render.resolution_y
    configure(scene, engine, size, samples)
    if frame:
        frame_camera(scene, [o for o in objects if not o.hide_render], direction, size)
    else:
        scene.render.resolution_x, scene.render.resolution_y = resolution
    if exr_path:
        materials.ensure_aovs(context.view_layer, aovs)
        context.view_layer.use_pass_z = True           # depth: which surface a pixel shows
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    written = [path]
    if exr_path:
        result = bpy.data.images["Render Result"]
        settings = scene.render.image_settings
        settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
        result.save_render(exr_path, scene=scene)
        settings.file_format = "PNG"
        written.append(exr_path)
    return written
