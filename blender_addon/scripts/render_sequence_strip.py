# Headless render of a mesh sequence as a strip of frames side by side, with the err_est heat
# map in one range for the whole sequence (so the frames compare), for documents:
#
#   blender -b --factory-startup --python-exit-code 1 -P blender_addon/scripts/render_sequence_strip.py -- \
#       --sequence out/smoke.0001.ply --frames 4,8,12,16,20,24 --out strip.png \
#       [--measure err_est] [--clip-percentile 99] [--size 300] [--samples 32] \
#       [--direction X,Y,Z] [--title TEXT]
#
# The sequence is imported like File > Import > isouq mesh sequence (its summary JSON found
# beside the files gives the range); the scene frame is set to each frame and rendered with
# Eevee under one camera that fits every frame shown; matplotlib lays the renders out with the
# frame numbers and one colorbar. --clip-percentile ends the range at that percentile of the
# values of every frame of the sequence (smoke has rare huge estimates where the density is
# flat). Errors: one line, exit status 2.

import argparse
import os
import sys
import tempfile

import addon_utils
import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def parse(argv):
    p = argparse.ArgumentParser(prog="render_sequence_strip.py")
    p.add_argument("--sequence", required=True, help="any one frame's PLY, or the #### pattern")
    p.add_argument("--frames", required=True, help="comma-separated frame numbers")
    p.add_argument("--out", required=True)
    p.add_argument("--measure", default="err_est")
    p.add_argument("--clip-percentile", type=float)
    p.add_argument("--size", type=int, default=300, help="pixels of each frame's longer side")
    p.add_argument("--samples", type=int, default=32)
    p.add_argument("--direction", default="0.35,-1,0.3")
    p.add_argument("--title")
    args = p.parse_args(argv[argv.index("--") + 1:] if "--" in argv else [])
    try:
        args.frames = [int(f) for f in args.frames.split(",") if f.strip()]
        args.direction = tuple(float(v) for v in args.direction.split(","))
    except ValueError:
        p.error("--frames needs integers and --direction three numbers")
    if not args.frames or len(args.direction) != 3:
        p.error("--frames needs at least one frame and --direction three numbers")
    return args


def all_values(obj, measure):
    """The measure's finite values over every frame of the sequence (each frame read once)."""
    from isouq import ply_io, sequence
    seq = sequence.sequence_of(obj)
    parts = []
    for f in seq.frames:
        column = ply_io.read_ply(seq.path(f)).vertex_attributes.get(measure)
        if column is not None:
            parts.append(column[np.isfinite(column)])
    return np.concatenate(parts) if parts else np.zeros(0)


def union_object(context, obj, frames):
    """A hidden point cloud of the world positions of every frame shown (to frame the camera)."""
    scene = context.scene
    points = []
    for f in frames:
        scene.frame_set(f)
        co = np.empty(3 * len(obj.data.vertices))
        obj.data.vertices.foreach_get("co", co)
        m = np.array(obj.matrix_world)
        points.append(co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3])
    points = np.concatenate(points)
    me = bpy.data.meshes.new("ISOUQ_frame_union")
    me.vertices.add(len(points))
    me.vertices.foreach_set("co", points.astype(np.float32).ravel())
    helper = bpy.data.objects.new("ISOUQ_frame_union", me)
    scene.collection.objects.link(helper)
    helper.hide_render = True
    return helper


def compose(path, renders, frames, title, bar):
    from isouq import plots
    plt = plots._pyplot()
    images = [plt.imread(p) for p in renders]
    h, w = images[0].shape[:2]
    cell = 2.0
    fig = plt.figure(figsize=(cell * len(images), cell * h / w + 1.45), dpi=110)
    total_w, total_h = fig.get_size_inches()
    for i, (image, f) in enumerate(zip(images, frames)):
        ax = fig.add_axes([i * cell / total_w, 1.0 / total_h, cell / total_w,
                           cell * h / w / total_h])
        ax.imshow(image, interpolation="lanczos")
        ax.set_axis_off()
        ax.text(0.5, -0.01, f"frame {f}", transform=ax.transAxes, ha="center", va="top",
                fontsize=9)
    fig.suptitle(title, fontsize=10, y=1 - 0.08 / total_h, va="top")
    cax = fig.add_axes([0.25, 0.42 / total_h, 0.5, 0.1 / total_h])
    plots._colorbar(fig, cax, bar["vmin"], bar["vmax"], bar["measure"], bar["colormap"],
                    bar["extend"])
    plots._save_small(fig, path, 110)
    plt.close(fig)


def main():
    args = parse(sys.argv)
    addon_utils.enable("isouq", default_set=False)
    bpy.ops.wm.read_homefile(use_empty=True)
    addon_utils.enable("isouq", default_set=False)
    from isouq import materials, render, sequence
    context = bpy.context
    s = context.scene.isouq
    obj = sequence.import_sequence(context, args.sequence)
    s.measure = args.measure
    lo, hi = sequence.measure_range(obj, args.measure) or (0.0, 1.0)
    clipped = False
    if args.clip_percentile is not None:
        top = float(np.percentile(all_values(obj, args.measure), args.clip_percentile))
        clipped, hi = top < hi, min(top, hi)
    materials.assign(obj, materials.heatmap_material(args.measure, lo, hi))
    s.heat_min, s.heat_max = lo, hi
    scene = context.scene
    helper = union_object(context, obj, args.frames)
    render.configure(scene, "BLENDER_EEVEE", args.size, args.samples)
    render.frame_camera(scene, [helper], args.direction, args.size)
    renders = []
    folder = tempfile.mkdtemp(prefix="isouq_strip_")
    for f in args.frames:
        scene.frame_set(f)
        path = os.path.join(folder, f"frame_{f:04d}.png")
        render.render_view(context, [obj], path, "BLENDER_EEVEE", args.size,
                           samples=args.samples, frame=False)
        renders.append(path)
    title = args.title or f"{obj.name}: {args.measure} over frames {args.frames[0]}-{args.frames[-1]}"
    compose(os.path.abspath(args.out), renders, args.frames, title,
            dict(vmin=lo, vmax=hi, measure=args.measure, colormap=materials.HEAT_COLORMAP,
                 extend="max" if clipped else "neither"))
    for p in renders:
        os.remove(p)
    os.rmdir(folder)
    print(f"isouq strip: {args.out} ({len(args.frames)} frames, {args.measure} in "
          f"[{lo:.3g}, {hi:.3g}])")


try:
    main()
except Exception as e:  # one line for scripts and CI, like the CLI's `isouq: error:`
    from isouq import frames, ply_io
    if not isinstance(e, (frames.SequenceError, ply_io.PlyError, ValueError, OSError)):
        raise
    print(f"isouq strip: error: {e}", file=sys.stderr)
    raise SystemExit(2)
