#!/usr/bin/python3
"""isouq report: the C1, C5 and C7 views of the paper (sec. 4.3, SPEC §7) as PNG pictures.

    report.py --mesh MESH.ply --summary SUMMARY.json --out DIR [--html]

MESH.ply is written by isouq (docs/ply-format.md) after a threshold node (`above`) and a
box_select node (`in_box`); SUMMARY.json is a summary node's output. Writes
DIR/c1_cdf.png (the CDF of the thresholded measure with its threshold and the binary colour map),
DIR/c5_bars.png (err_est, d_lc, d_lw vertex by vertex in the box), DIR/c7_summary.png (the
summary table) and, with --html, DIR/index.html. Each file is written atomically. The `report`
node runs this script; it needs Debian's python3-matplotlib and reads the PLY with ply_io
(installed beside it; _isouq_path finds it).
"""
import argparse
import json
import os
import sys
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402

MAX_BARS = 48
BARS = ("err_est", "d_lc", "d_lw")  # C5 (paper sec. 4.3): e and two method distances
BELOW, ABOVE = "#3b6fb6", "#e8743b"


def save(fig, path):
    """Writes the figure next to PATH and renames it: no partial picture is ever left."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(suffix=".png", dir=folder)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.remove(tmp)


def column(mesh, name):
    return mesh.vertex_attributes.get(name)


def draw_cdf(mesh, summary, path):
    """C1: cumulative percentage of vertices against the measure, the threshold, and the
    surface coloured below/above it."""
    block = summary.get("threshold", {})
    measure = block.get("measure", "err_est")
    values = column(mesh, measure)
    above = column(mesh, "above")
    if values is None:
        raise SystemExit(f"report.py: the mesh has no '{measure}'")
    finite = np.sort(values[np.isfinite(values)].astype(np.float64))
    percent = 100.0 * np.arange(1, finite.size + 1) / max(finite.size, 1)
    fig = plt.figure(figsize=(11, 4.2))
    ax = fig.add_subplot(1, 2, 1)
    ax.plot(finite, percent, color="black", lw=1.5)
    threshold = block.get("threshold")
    title = f"C1: CDF of {measure} over {finite.size} vertices"
    if threshold is not None:
        n_above = int(np.count_nonzero(above)) if above is not None else int((finite > threshold).sum())
        ax.axvline(threshold, color=ABOVE, lw=1.2, ls="--")
        level = 100.0 * (finite.size - n_above) / max(finite.size, 1)
        ax.axhline(level, color="grey", lw=0.8, ls=":")
        ax.fill_between(finite, 0, percent, where=finite > threshold, color=ABOVE, alpha=0.25, step="post")
        label = f"threshold {threshold:.3g}"
        if "percentile" in block:
            label += f" (percentile {block['percentile']:g})"
        ax.text(threshold, 5, " " + label + f"\n {n_above} above", color=ABOVE, va="bottom")
    ax.set_xlabel(f"{measure} (world units)")
    ax.set_ylabel("cumulative % of vertices")
    ax.set_ylim(0, 100.5)
    ax.set_title(title)
    ax.grid(alpha=0.3)

    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    tris = mesh.triangles
    if tris.size and above is not None:
        hot = above[tris].max(axis=1) > 0
        colours = np.where(hot[:, None], matplotlib.colors.to_rgba_array(ABOVE),
                           matplotlib.colors.to_rgba_array(BELOW))
        ax3.add_collection3d(Poly3DCollection(mesh.positions[tris], facecolors=colours, edgecolor="none"))
        lo, hi = mesh.positions.min(axis=0), mesh.positions.max(axis=0)
        ax3.set_xlim(lo[0], hi[0]); ax3.set_ylim(lo[1], hi[1]); ax3.set_zlim(lo[2], hi[2])
        ax3.set_box_aspect(hi - lo)
        ax3.view_init(elev=20, azim=-60)
    ax3.set_title(f"binary colour map: above (orange) / below (blue)")
    ax3.set_axis_off()
    save(fig, path)


def draw_bars(mesh, summary, path):
    """C5: the BARS columns of the vertices in the box, vertex by vertex."""
    in_box = column(mesh, "in_box")
    fig, ax = plt.subplots(figsize=(11, 4))
    if in_box is None or not np.any(in_box):
        ax.text(0.5, 0.5, "no vertex in the box (or no box_select node)", ha="center", transform=ax.transAxes)
        ax.set_axis_off()
        save(fig, path)
        return
    index = np.flatnonzero(in_box)
    est = column(mesh, BARS[0])
    shown = index
    note = ""
    if index.size > MAX_BARS:
        order = np.argsort(-np.nan_to_num(est[index], nan=-1.0), kind="stable")
        shown = np.sort(index[order[:MAX_BARS]])
        note = f" (the {MAX_BARS} largest {BARS[0]} of {index.size})"
    names = [n for n in BARS if column(mesh, n) is not None]
    width = 0.8 / max(len(names), 1)
    x = np.arange(shown.size)
    for j, name in enumerate(names):
        ax.bar(x + (j - (len(names) - 1) / 2) * width, column(mesh, name)[shown], width, label=name)
    ax.set_xticks(x)
    ax.set_xticklabels([str(v) for v in shown], rotation=90, fontsize=7)
    ax.set_xlabel("vertex index")
    ax.set_ylabel("world units")
    box = summary.get("box", {})
    where = f" centre {box.get('center')} size {box.get('size')}" if box else ""
    ax.set_title(f"C5: vertex-by-vertex comparison in the box{where}{note}")
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    save(fig, path)


def fmt(v):
    return "-" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v)


def draw_summary(summary, path):
    """C7: counts, components (before and after hidden-feature recovery) and statistics."""
    counts = [("vertices", summary.get("vertices")), ("triangles", summary.get("triangles")),
              ("components", summary.get("components")), ("boundary edges", summary.get("boundary_edges")),
              ("isovalue", summary.get("isovalue")), ("method", summary.get("method"))]
    thr = summary.get("threshold")
    if thr:
        counts.append((f"{thr.get('measure')} > {fmt(thr.get('threshold'))}",
                       f"{thr.get('above')} of {thr.get('vertices')}"))
    if summary.get("box"):
        counts.append(("in box", summary["box"].get("inside")))
    hidden = summary.get("hidden")
    if hidden:
        counts += [("components before recovery", hidden.get("components_before")),
                   ("components after recovery", hidden.get("components_after")),
                   ("cells flagged", f"{hidden.get('cells_flagged')} of {hidden.get('cells_total')}")]
    stats = [(k, v) for k, v in summary.items() if isinstance(v, dict) and {"min", "max", "mean", "rms"} <= set(v)]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 0.6 + 0.32 * max(len(counts), len(stats) + 1)),
                                 gridspec_kw={"width_ratios": [1, 1.6]})
    for ax in (a1, a2):
        ax.set_axis_off()
    a1.table(cellText=[[k, fmt(v)] for k, v in counts], colLabels=["C7 summary", ""], loc="upper center",
             cellLoc="left")
    if stats:
        a2.table(cellText=[[k] + [fmt(v.get(c)) for c in ("min", "max", "mean", "rms")] for k, v in stats],
                 colLabels=["measure", "min", "max", "mean", "RMS"], loc="upper center", cellLoc="right")
    save(fig, path)


def write_html(out, summary):
    text = "<!doctype html><meta charset=utf-8><title>isouq report</title>\n"
    text += f"<h1>isouq report</h1><p>{summary.get('input', '')}</p>\n"
    for name, caption in (("c1_cdf.png", "C1: CDF and threshold"), ("c5_bars.png", "C5: vertices in the box"),
                          ("c7_summary.png", "C7: summary")):
        text += f"<h2>{caption}</h2><img src='{name}' style='max-width:100%'>\n"
    fd, tmp = tempfile.mkstemp(suffix=".html", dir=out)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, os.path.join(out, "index.html"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", required=True)
    parser.add_argument("--summary", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--html", action="store_true")
    args = parser.parse_args(argv)
    mesh = ply_io.read_ply(args.mesh, require_isouq=False)
    with open(args.summary) as f:
        summary = json.load(f)
    os.makedirs(args.out, exist_ok=True)
    draw_cdf(mesh, summary, os.path.join(args.out, "c1_cdf.png"))
    draw_bars(mesh, summary, os.path.join(args.out, "c5_bars.png"))
    draw_summary(summary, os.path.join(args.out, "c7_summary.png"))
    if args.html:
        write_html(args.out, summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
