# Headless render of an isouq view to PNG (and optionally a multilayer EXR with AOVs):
#
#   blender -b --factory-startup --python-exit-code 1 -P blender_addon/scripts/render_view.py -- \
#       --mesh MESH.ply [--hidden HF.ply] [--summary S.json] \
#       --view standard|heatmap|threshold|methods|compare|hidden|combined --out OUT.png \
#       [--exr OUT.exr] [--engine eevee|cycles] [--size 800] [--measure err_est] \
#       [--threshold V | --percentile P] [--inside weno --outside linear] [--compare-method weno] \
#       [--cdf CDF.png] [--legend LEGEND.png]
#
# Views (paper sec. 4.3): standard (opaque blue, any isouq mesh), heatmap C4, threshold C1
# (binary map), methods C3 (inside/outside the threshold), compare C6 (primary and
# --compare-method side by side), hidden C6 (hidden-feature surface in transparent orange over
# standard MC in blue), combined (heat map + hidden features). Errors: one line, exit status 2.

import argparse
import os
import shutil
import sys

import addon_utils
import bpy

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def parse(argv):
    p = argparse.ArgumentParser(prog="render_view.py")
    p.add_argument("--mesh", required=True)
    p.add_argument("--hidden")
    p.add_argument("--summary")
    p.add_argument("--view", default="heatmap",
                   choices=["standard", "heatmap", "threshold", "methods", "compare", "hidden",
                            "combined"])
    p.add_argument("--out", required=True)
    p.add_argument("--exr")
    p.add_argument("--engine", default="eevee", choices=["eevee", "cycles"])
    p.add_argument("--size", type=int, default=800)
    p.add_argument("--samples", type=int, default=16)
    p.add_argument("--measure", default="err_est")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--threshold", type=float)
    group.add_argument("--percentile", type=float, default=90.0)
    p.add_argument("--inside", default="weno")
    p.add_argument("--outside", default="linear")
    p.add_argument("--compare-method", default="weno")
    p.add_argument("--cdf", help="also write the C1 CDF plot here")
    p.add_argument("--legend", help="also write the C4 legend here")
    return p.parse_args(argv[argv.index("--") + 1:] if "--" in argv else [])


def main():
    args = parse(sys.argv)
    addon_utils.enable("isouq", default_set=False)
    from isouq import render, views

    bpy.ops.wm.read_homefile(use_empty=True)
    addon_utils.enable("isouq", default_set=False)
    context = bpy.context
    s = context.scene.isouq
    s.measure = args.measure
    if args.threshold is not None:
        s.threshold_mode, s.threshold_value = "VALUE", args.threshold
    else:
        s.threshold_mode, s.threshold_percentile = "PERCENTILE", args.percentile
    s.method_inside, s.method_outside = args.inside, args.outside
    s.compare_method = args.compare_method

    obj = views.import_ply(context, args.mesh, role="MESH")
    if args.summary:
        views.load_summary(obj, args.summary)
    if args.hidden:
        hidden = views.import_ply(context, args.hidden, obj.name + "_hidden", "HIDDEN")
        obj.isouq.partner, hidden.isouq.partner = hidden, obj

    has_measure = obj.data.attributes.get(s.measure) is not None
    if args.view == "heatmap" or has_measure:
        legend = views.apply_heatmap(context, obj)
    if args.view == "standard":
        from isouq import materials
        materials.assign(obj, materials.standard_material())
    elif args.view == "threshold":
        views.apply_threshold(context, obj)
    elif args.view == "methods":
        views.apply_methods(context, obj)
    elif args.view == "compare":
        views.compare_methods(context, obj)
    elif args.view == "hidden":
        views.show_hidden(context, obj)
    elif args.view == "combined":
        views.combined_view(context, obj)
    if args.cdf:
        values = views.measure_values(obj, s.measure)
        from isouq import plots
        plots.cdf_plot(args.cdf, values, views.resolve_threshold(s, values), s.measure)
    if args.legend and has_measure:
        shutil.copy(legend, args.legend)

    objects = [o for o in context.scene.objects if o.type == "MESH" and not o.hide_render]
    engine = "CYCLES" if args.engine == "cycles" else "BLENDER_EEVEE"
    written = render.render_view(context, objects, os.path.abspath(args.out), engine, args.size,
                                 os.path.abspath(args.exr) if args.exr else None,
                                 (s.measure, "hidden"), args.samples)
    print("isouq render:", ", ".join(written))


try:
    main()
except Exception as e:  # one line for scripts and CI, like the CLI's `isouq: error:`
    from isouq import ply_io, views
    if not isinstance(e, (views.ViewError, ply_io.PlyError, ValueError, OSError)):
        raise
    print(f"isouq render: error: {e}", file=sys.stderr)
    raise SystemExit(2)
