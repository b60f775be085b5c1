# Renders the current isouq view to PNG (Eevee, or Cycles on the CPU without denoising: Debian's
# Cycles has no OpenImageDenoise), optionally also a multilayer OpenEXR with shader AOV passes
# (the measure and the hidden mask, materials.py).

import math

import bpy
import numpy as np
from mathutils import Vector

from . import materials

CAMERA, LIGHT = "ISOUQ_camera", "ISOUQ_sun"


def _bounds(objects):
    pts = [obj.matrix_world @ Vector(c) for obj in objects for c in obj.bound_box]
    if not pts:
        raise ValueError("nothing visible to render")
    a = np.array([tuple(p) for p in pts])
    return a.min(axis=0), a.max(axis=0)


def frame_camera(scene, objects, direction=(1.0, -1.2, 0.8), margin=1.1):
    """An orthographic ISOUQ_camera looking at the objects' bounds along -direction, and a sun."""
    lo, hi = _bounds(objects)
    centre, diag = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0
    cam = bpy.data.objects.get(CAMERA)
    if cam is None:
        cam = bpy.data.objects.new(CAMERA, bpy.data.cameras.new(CAMERA))
        scene.collection.objects.link(cam)
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = diag * margin
    cam.data.clip_end = diag * 10
    d = Vector(direction).normalized()
    cam.location = Vector(centre) + d * diag * 2
    cam.rotation_euler = (-d).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam
    sun = bpy.data.objects.get(LIGHT)
    if sun is None:
        sun = bpy.data.objects.new(LIGHT, bpy.data.lights.new(LIGHT, "SUN"))
        scene.collection.objects.link(sun)
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(40), math.radians(10), math.radians(30))
    return cam


def configure(scene, engine="BLENDER_EEVEE", size=800, samples=16):
    scene.render.engine = engine
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    if engine == "CYCLES":
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        scene.cycles.use_preview_denoising = False
    else:
        scene.eevee.taa_render_samples = samples
    if scene.world is None:
        scene.world = bpy.data.worlds.new("ISOUQ_world")
    scene.world.color = (0.8, 0.8, 0.8)
    scene.view_settings.view_transform = "Standard"   # colours as in the legend


def render_view(context, objects, path, engine="BLENDER_EEVEE", size=800, exr_path=None,
                aovs=("err_est", "hidden"), samples=16):
    """Renders `objects` (framed) to the PNG `path`; with `exr_path` also a multilayer EXR
    holding the combined pass and the shader AOVs `aovs`. Returns the paths written."""
    scene = context.scene
    configure(scene, engine, size, samples)
    frame_camera(scene, [o for o in objects if not o.hide_render])
    if exr_path:
        materials.ensure_aovs(context.view_layer, aovs)
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
