# Headless render of an isouq view to PNG (and optionally a multilayer EXR with AOVs):
#
#   blender -b --factory-startup --python-exit-code 1 -P blender_addon/scripts/render_view.py -- \
#       --mesh MESH.ply [--hidden HF.ply] [--summary S.json] \
#       --view standard|heatmap|threshold|methods|compare|hidden|combined --out OUT.png \
#       [--exr OUT.exr] [--engine eevee|cycles] [--size 800] [--measure NAME] \
#       [--threshold V | --percentile P] [--inside M --outside M] [--compare-method weno] \
#       [--cdf CDF.png] [--legend LEGEND.png] [--direction X,Y,Z] [--clip-percentile P]
#       [--figure FIG.png --title TEXT]
#
# Views (paper sec. 4.3): standard (opaque blue, any isouq mesh), heatmap C4, threshold C1
# (binary map), methods C3 (inside/outside the threshold), compare C6 (primary and
# --compare-method side by side), hidden C6 (hidden-feature surface in transparent orange over
# standard MC in blue), combined (heat map + hidden features). --figure composes the render
# with its title and key (colorbar or colour swatches; the CDF beside the threshold view) for
# documents. --measure, --inside and --outside default to the add-on's Scene.isouq defaults.
# Errors: one line, exit status 2.

import argparse
import os
import shutil
import sys

import addon_utils
import bpy
import numpy as np

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
    p.add_argument("--measure")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--threshold", type=float)
    group.add_argument("--percentile", type=float, default=90.0)
    p.add_argument("--inside")
    p.add_argument("--outside")
    p.add_argument("--compare-method", default="weno")
    p.add_argument("--cdf", help="also write the C1 CDF plot here")
    p.add_argument("--legend", help="also write the C4 legend here")
    p.add_argument("--direction", default="1,-1.2,0.8",
                   help="camera position relative to the mesh (it looks back along it)")
    p.add_argument("--clip-percentile", type=float,
                   help="heat-map range up to this percentile (above it: the top colour)")
    p.add_argument("--figure", help="also write the render with title and key here")
    p.add_argument("--title", help="figure title (default: mesh, method, view)")
    args = p.parse_args(argv[argv.index("--") + 1:] if "--" in argv else [])
    try:
        args.direction = tuple(float(v) for v in args.direction.split(","))
    except ValueError:
        args.direction = ()
    if len(args.direction) != 3 or not any(args.direction):
        p.error("--direction needs three numbers X,Y,Z, not all zero")
    return args


def linear_to_srgb(c):
    c = np.clip(np.asarray(c, np.float64), 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def figure_key(args, s, obj, clipped):
    """(colorbar, swatches, cdf) of the figure for this view (plots.figure)."""
    from isouq import materials, views
    bar = dict(vmin=s.heat_min, vmax=s.heat_max, measure=s.measure,
               colormap=materials.HEAT_COLORMAP, extend="max" if clipped else "neither")
    orange, blue = np.array(materials.HIDDEN_ORANGE[:3]), np.array(materials.STANDARD_BLUE[:3])

    def srgb(linear):
        return tuple(float(c) for c in linear_to_srgb(linear[:3]))

    if args.view == "threshold":
        t = s.threshold_value
        return None, [(f"{s.measure} <= {t:.3g}", srgb(np.array(s.colour_below)), 1.0),
                      (f"{s.measure} > {t:.3g}", srgb(np.array(s.colour_above)), 1.0)], \
            dict(values=views.measure_values(obj, s.measure), threshold=t, measure=s.measure)
    if args.view == "hidden":
        a = materials.HIDDEN_ALPHA          # the layers' blend (render_hidden_over_standard)
        return None, [("standard MC only", srgb(blue), 1.0),
                      ("hidden features only", srgb(a * orange + (1 - a)), 1.0),
                      ("both (orange over blue)", srgb(a * orange + (1 - a) * blue), 1.0)], None
    if args.view == "combined":
        return bar, [("refined (hidden feature)", srgb(np.array(materials.REFINED_GREEN)), 1.0)], None
    if args.view == "standard" or obj.data.attributes.get(s.measure) is None:
        return None, [], None
    return bar, [], None



def render_hidden_over_standard(context, standard, hidden, args, engine):
    """C6 as two layers under one camera: standard MC opaque blue, then the hidden-feature
    mesh alone in opaque orange, laid over it with HIDDEN_ALPHA. Where the two meshes
    coincide a single 3D render would z-fight; the layers show exactly which surface exists
    where (blue only, orange only, both). The EXR, if asked, is of the standard layer."""
    from isouq import materials, render
    render.configure(context.scene, engine, args.size, args.samples)
    render.frame_camera(context.scene, [standard, hidden], args.direction, args.size)
    materials.assign(hidden, materials.solid_material("ISOUQ_hidden_layer",
                                                      materials.HIDDEN_ORANGE))
    out = os.path.abspath(args.out)
    layer = out + ".hidden.png"
    hidden.hide_render = True
    written = render.render_view(context, [standard], out, engine, args.size,
                                 os.path.abspath(args.exr) if args.exr else None,
                                 (args.measure, "hidden"), args.samples, frame=False)
    hidden.hide_render, standard.hide_render = False, True
    render.render_view(context, [hidden], layer, engine, args.size, None, (), args.samples,
                       frame=False)
    standard.hide_render = False
    below, above = (np.array(bpy.data.images.load(p).pixels[:], np.float64) for p in (out, layer))
    os.remove(layer)
    below, above = below.reshape(-1, 4), above.reshape(-1, 4)
    a = above[:, 3:] * materials.HIDDEN_ALPHA          # blend in linear light, as 3D would
    alpha = a + below[:, 3:] * (1 - a)
    rgb = (srgb_to_linear(above[:, :3]) * a
           + srgb_to_linear(below[:, :3]) * below[:, 3:] * (1 - a)) / np.maximum(alpha, 1e-9)
    rgb = linear_to_srgb(rgb)
    image = bpy.data.images.load(out)
    image.pixels.foreach_set(np.hstack([rgb, alpha]).astype(np.float32).ravel())
    image.filepath_raw, image.file_format = out, "PNG"
    image.save()
    return written


def main():
    args = parse(sys.argv)
    addon_utils.enable("isouq", default_set=False)
    from isouq import plots, render, views

    bpy.ops.wm.read_homefile(use_empty=True)
    addon_utils.enable("isouq", default_set=False)
    context = bpy.context
    s = context.scene.isouq
    obj = views.import_ply(context, args.mesh, role="MESH")
    if args.summary:
        views.load_summary(obj, args.summary)
    if args.hidden:
        hidden = views.import_ply(context, args.hidden, obj.name + "_hidden", "HIDDEN")
        obj.isouq.partner, hidden.isouq.partner = hidden, obj
    # menus without a binary list the imported meshes' columns: set them after the import
    if args.measure:
        s.measure = args.measure
    if args.inside:
        s.method_inside = args.inside
    if args.outside:
        s.method_outside = args.outside
    if args.threshold is not None:
        s.threshold_mode, s.threshold_value = "VALUE", args.threshold
    else:
        s.threshold_mode, s.threshold_percentile = "PERCENTILE", args.percentile
    s.compare_method = args.compare_method

    has_measure = obj.data.attributes.get(s.measure) is not None
    clipped = False
    if args.view == "heatmap" or has_measure:
        legend = views.apply_heatmap(context, obj)
        if args.clip_percentile is not None:
            values = views.measure_values(obj, s.measure)
            top = float(np.nanpercentile(values, args.clip_percentile))
            clipped = top < s.heat_max
            s.heat_max = top                 # updates the material's range (props.py)
            legend = plots.legend_plot(legend, s.heat_min, s.heat_max, s.measure,
                                       extend="max" if clipped else "neither")
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
        if args.clip_percentile is not None:
            s.heat_max = float(np.nanpercentile(views.measure_values(obj.isouq.partner, s.measure),
                                                args.clip_percentile))
            clipped = True
    if args.hidden and args.view not in ("hidden", "combined"):
        hidden.hide_render = True          # the other views are of the standard mesh
    if args.cdf:
        values = views.measure_values(obj, s.measure)
        plots.cdf_plot(args.cdf, values, views.resolve_threshold(s, values), s.measure)
    if args.legend and has_measure:
        shutil.copy(legend, args.legend)

    objects = [o for o in context.scene.objects if o.type == "MESH" and not o.hide_render]
    engine = "CYCLES" if args.engine == "cycles" else "BLENDER_EEVEE"
    if args.view == "hidden":
        written = render_hidden_over_standard(context, obj, obj.isouq.partner, args, engine)
    else:
        written = render.render_view(context, objects, os.path.abspath(args.out), engine,
                                     args.size, os.path.abspath(args.exr) if args.exr else None,
                                     (s.measure, "hidden"), args.samples, args.direction)
    if args.figure:
        title = args.title or f"{obj.name} ({obj.isouq.method_shown or 'isouq'}): {args.view}"
        bar, swatches, cdf = figure_key(args, s, obj, clipped)
        written.append(plots.figure(os.path.abspath(args.figure), written[0], title, bar,
                                    swatches, cdf))
    print("isouq render:", ", ".join(written))


try:
    main()
except Exception as e:  # one line for scripts and CI, like the CLI's `isouq: error:`
    from isouq import ply_io, views
    if not isinstance(e, (views.ViewError, ply_io.PlyError, ValueError, OSError)):
        raise
    print(f"isouq render: error: {e}", file=sys.stderr)
    raise SystemExit(2)
