# Bakes a small Mantaflow smoke simulation headless, for the sequence tests (issue 11), and
# meshes every baked frame with Blender's own Volume to Mesh modifier as a comparison truth:
#
#   blender -b --factory-startup --python-exit-code 1 -P blender_addon/scripts/bake_smoke.py -- \
#       --dir OUT [--resolution 40] [--frames 24] [--threshold 0.05] [--truth truth.json]
#
# Writes OUT/cache_fluid/data/fluid_data_####.vdb (grids density, heat, velocity, ...; Blender's
# own names), OUT/smoke.blend (the simulation scene, for reference) and, with --truth, a JSON
# {"threshold", "resolution", "frames": [{"frame", "file", "vertices", "polygons", "triangles",
# "bbox_min", "bbox_max"}], "bake_s", "volume_to_mesh_s"}: what Volume to Mesh (resolution mode
# Grid, adaptivity 0, the threshold given) makes of each frame, on a Volume object that loads the
# cache as a sequence (object space = the grids' world space; the object is not moved).
#
# The emitter (a small sphere of inflow smoke) moves along x and rises over the frames, so each
# frame differs; the domain is a cube of side 2 with `--resolution` cells on its longest side.
# Errors: one line, exit status 2.

import argparse
import glob
import json
import os
import sys
import time

import bpy

DOMAIN_SIZE = 2.0
CACHE = "cache_fluid"


def parse(argv):
    p = argparse.ArgumentParser(prog="bake_smoke.py")
    p.add_argument("--dir", required=True, help="output folder (created)")
    p.add_argument("--resolution", type=int, default=40, help="domain cells on the longest side")
    p.add_argument("--frames", type=int, default=24, help="frames 1..N")
    p.add_argument("--threshold", type=float, default=0.05,
                   help="Volume to Mesh threshold for --truth")
    p.add_argument("--truth", help="write Volume to Mesh vertex counts per frame here (JSON)")
    return p.parse_args(argv[argv.index("--") + 1:] if "--" in argv else [])


def empty_scene(frames):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frames
    scene.frame_set(1)
    return scene


def make_domain(scene, folder, resolution, frames):
    bpy.ops.mesh.primitive_cube_add(size=DOMAIN_SIZE, location=(0.0, 0.0, 0.0))
    domain = bpy.context.active_object
    domain.name = "smoke_domain"
    mod = domain.modifiers.new("Fluid", "FLUID")
    mod.fluid_type = "DOMAIN"
    d = mod.domain_settings
    d.domain_type = "GAS"
    d.resolution_max = resolution
    d.cache_directory = os.path.join(folder, CACHE)
    d.cache_data_format = "OPENVDB"
    d.openvdb_data_depth = "32"        # float32 grids: isouq meshes float grids
    d.cache_frame_start, d.cache_frame_end = 1, frames
    d.use_adaptive_domain = False
    d.use_noise = False
    d.vorticity = 0.2
    d.alpha, d.beta = 0.2, 1.5          # density and heat buoyancy: the smoke rises
    d.use_dissolve_smoke = False
    return domain, d


def make_emitter(scene, frames):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.22, location=(-0.5, 0.0, -0.6),
                                         segments=16, ring_count=8)
    emitter = bpy.context.active_object
    emitter.name = "smoke_emitter"
    mod = emitter.modifiers.new("Fluid", "FLUID")
    mod.fluid_type = "FLOW"
    f = mod.flow_settings
    f.flow_type = "SMOKE"
    f.flow_behavior = "INFLOW"
    f.flow_source = "MESH"
    f.surface_distance = 1.5
    f.density = 1.0
    f.use_initial_velocity = True
    f.velocity_coord = (0.25, 0.0, 0.9)
    # the emitter sweeps from left to right and back, so frames differ in shape
    for frame, x, z in ((1, -0.45, -0.65), (frames // 2, 0.25, -0.6), (frames, -0.1, -0.45)):
        emitter.location = (x, 0.0, z)
        emitter.keyframe_insert("location", frame=frame)
    emitter.hide_render = True
    return emitter


def bake(scene, domain):
    # Blender 3.4 (Debian, Python 3.11): a domain whose cache type is Bake All while an inflow
    # is first evaluated fails in Mantaflow ("'NoneType' object has no attribute
    # 'getDataPointer'", then an abort); evaluated as Replay first, then switched, it bakes.
    bpy.context.view_layer.update()
    domain.modifiers["Fluid"].domain_settings.cache_type = "ALL"
    bpy.context.view_layer.objects.active = domain
    domain.select_set(True)
    with bpy.context.temp_override(active_object=domain, object=domain,
                                   selected_objects=[domain], scene=scene):
        result = bpy.ops.fluid.bake_all()
    if result != {"FINISHED"}:
        raise RuntimeError(f"fluid.bake_all returned {result}")


def data_files(folder):
    return sorted(glob.glob(os.path.join(folder, CACHE, "data", "fluid_data_*.vdb")))


def volume_to_mesh_counts(scene, files, threshold, frames):
    """Volume to Mesh (Grid resolution, adaptivity 0) on a Volume object that loads the baked
    cache as a sequence: (vertices, triangles) per frame."""
    for obj in list(scene.objects):
        bpy.data.objects.remove(obj)
    volume = bpy.data.volumes.new("smoke_cache")
    volume.filepath = files[0]
    volume.is_sequence = True
    first = int(os.path.splitext(files[0])[0].rsplit("_", 1)[1])
    volume.frame_start, volume.frame_offset = 1, first - 1
    volume.frame_duration = len(files)
    volume.sequence_mode = "CLIP"
    vol_obj = bpy.data.objects.new("smoke_volume", volume)
    scene.collection.objects.link(vol_obj)
    target = bpy.data.objects.new("volume_to_mesh", bpy.data.meshes.new("volume_to_mesh"))
    scene.collection.objects.link(target)
    mod = target.modifiers.new("VolumeToMesh", "VOLUME_TO_MESH")
    mod.object = vol_obj
    mod.grid_name = "density"
    mod.resolution_mode = "GRID"
    mod.threshold = threshold
    mod.adaptivity = 0.0
    mod.use_smooth_shade = False
    out = []
    for frame in range(1, frames + 1):
        scene.frame_set(frame)
        evaluated = target.evaluated_get(bpy.context.evaluated_depsgraph_get())
        me = evaluated.to_mesh()
        tris = sum(len(p.vertices) - 2 for p in me.polygons)
        co = [v.co for v in me.vertices]
        box = ([min(c[i] for c in co) for i in range(3)], [max(c[i] for c in co) for i in range(3)]) \
            if co else (None, None)
        out.append({"frame": frame, "file": files[frame - 1],
                    "vertices": len(me.vertices), "polygons": len(me.polygons),
                    "triangles": tris, "bbox_min": box[0], "bbox_max": box[1]})
        evaluated.to_mesh_clear()
    return out


def main():
    args = parse(sys.argv)
    folder = os.path.abspath(args.dir)
    os.makedirs(folder, exist_ok=True)
    scene = empty_scene(args.frames)
    domain, _ = make_domain(scene, folder, args.resolution, args.frames)
    make_emitter(scene, args.frames)
    start = time.perf_counter()
    bake(scene, domain)
    bake_s = time.perf_counter() - start
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "smoke.blend"))
    files = data_files(folder)
    if len(files) != args.frames:
        raise RuntimeError(f"the bake wrote {len(files)} data files, expected {args.frames}")
    print(f"bake_smoke: {len(files)} frames at resolution {args.resolution} in {bake_s:.1f} s",
          flush=True)
    if args.truth:
        start = time.perf_counter()
        frames = volume_to_mesh_counts(scene, files, args.threshold, args.frames)
        v2m_s = time.perf_counter() - start
        with open(args.truth, "w", encoding="utf-8") as f:
            json.dump({"threshold": args.threshold, "resolution": args.resolution,
                       "grid": "density", "bake_s": bake_s, "volume_to_mesh_s": v2m_s,
                       "frames": frames}, f, indent=1)
        print(f"bake_smoke: Volume to Mesh on {len(frames)} frames in {v2m_s:.1f} s", flush=True)


if __name__ == "__main__":
    try:
        main()
    except (RuntimeError, OSError, ValueError) as e:
        sys.stderr.write(f"bake_smoke.py: error: {e}\n")
        sys.exit(2)
