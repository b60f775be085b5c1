#!/usr/bin/python3
"""Plots of `isouq validate` (paper Figs. 3 and 4; docs/validation.md).

Usage: /usr/bin/python3 scripts/plot_validation.py OUT_DIR/validation.json

Reads the JSON that `isouq validate` writes and the validated meshes it names (PLY with every
per-vertex column), and writes next to the JSON:
  fig3_<field>.png     the surface coloured by the measured linear error and by e (Fig. 3)
  fig4_errors.png      max / mean / RMS of measured error, e and e_b per field (Fig. 4)
  scatter_errors.png   e, e_b and err_best against the measured edge error, per vertex
  convergence.png      RMS edge-crossing error against h per method (observed orders)
"""
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402


def stat(case, column, key="rms"):
    s = case.get("stats", {}).get(column)
    return s[key] if s else float("nan")


def fig4(cases, out):
    """Paper Fig. 4: measured (green), e (blue), e_b (light blue); max, mean, RMS per field."""
    fig, axes = plt.subplots(1, len(cases), figsize=(3.2 * len(cases), 3.4))
    series = [("err_true_linear", "measured (edge)", "#2ca02c"),
              ("dist_true_linear", "measured (surface)", "#98df8a"),
              ("err_est", "e (estimate)", "#1f77b4"),
              ("err_bound", "e_b (standard)", "#9ecae1")]
    for ax, case in zip(np.atleast_1d(axes), cases):
        x = np.arange(3)
        for s, (column, label, color) in enumerate(series):
            values = [stat(case, column, key) for key in ("max", "mean", "rms")]
            ax.bar(x + (s - 1.5) * 0.2, values, 0.2, label=label, color=color)
        ax.set_xticks(x)
        ax.set_xticklabels(["max", "mean", "RMS"])
        ax.set_yscale("log")
        ax.set_title(f"{case['field']} {case['resolution']}$^3$")
    np.atleast_1d(axes)[0].set_ylabel("world units")
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.suptitle("Linear MC: measured error, estimate e and standard bound e_b (paper Fig. 4)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "fig4_errors.png"), dpi=110)
    plt.close(fig)


def fig3(case, mesh, out):
    """Paper Fig. 3: the surface coloured by measured linear error and by e, one colour scale."""
    pts, tris, vertices = mesh.positions, mesh.triangles, mesh.vertex_attributes
    panels = [("err_true_linear", "measured edge error |x_lin - x*|"),
              ("dist_true_linear", "measured surface distance"),
              ("err_est", "estimate e")]
    vmax = np.nanpercentile(np.concatenate([vertices[c] for c, _ in panels]), 99)
    fig = plt.figure(figsize=(13, 4.6))
    for p, (column, title) in enumerate(panels):
        ax = fig.add_subplot(1, 3, p + 1, projection="3d")
        face_value = vertices[column][tris].mean(axis=1)
        poly = Poly3DCollection(pts[tris], linewidths=0, antialiased=False)
        poly.set_array(face_value)
        poly.set_cmap("inferno")
        poly.set_clim(0, vmax)
        ax.add_collection3d(poly)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centre, half = (lo + hi) / 2, (hi - lo).max() / 2
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
            setter(c - half, c + half)
        ax.set_axis_off()
        # Marschner-Lobb is a rippled sheet: look at it from above.
        ax.view_init(elev=60 if case["field"] == "marschner-lobb" else 25, azim=35)
        ax.set_title(title, fontsize=10)
        fig.colorbar(poly, ax=ax, shrink=0.6, pad=0.02)
    fig.suptitle(f"{case['field']} {case['resolution']}$^3$, k = {case['isovalue']:g} (paper Fig. 3)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, f"fig3_{case['field']}.png"), dpi=100)
    plt.close(fig)


def scatter(cases, meshes, out):
    """Per vertex: e, e_b and err_best against the measured linear edge error."""
    fig, axes = plt.subplots(1, len(cases), figsize=(3.2 * len(cases), 3.4))
    for ax, case in zip(np.atleast_1d(axes), cases):
        v = meshes.get(case["field"])
        if v is None:
            continue
        measured = v["err_true_linear"]
        ok = measured > 0
        for column, label, color in (("err_bound", "e_b", "#9ecae1"), ("err_est", "e", "#1f77b4"),
                                     ("err_best", "err_best", "#d62728")):
            ax.scatter(measured[ok], v[column][ok], s=1, alpha=0.4, color=color, label=label,
                       rasterized=True)
        lo, hi = np.nanmin(measured[ok]), np.nanmax(measured[ok])
        ax.plot([lo, hi], [lo, hi], "k--", linewidth=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(lo, hi)
        ax.set_xlabel("measured edge error")
        ax.set_title(f"{case['field']} {case['resolution']}$^3$")
    np.atleast_1d(axes)[0].set_ylabel("estimate")
    np.atleast_1d(axes)[0].legend(fontsize=7, markerscale=6)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "scatter_errors.png"), dpi=110)
    plt.close(fig)


def convergence(report, out):
    rows = report["convergence"]["rows"]
    fields = list(dict.fromkeys(r["field"] for r in rows))
    methods = [("linear", "#2ca02c"), ("cubic", "#ff7f0e"), ("weno", "#1f77b4"),
               ("weno_paper", "#9467bd")]
    cols = 4
    nrows = (len(fields) + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(3.4 * cols, 3.2 * nrows), squeeze=False)
    fitted = report["convergence"]["fitted"]
    for ax, field in zip(axes.flat, fields):
        sub = [r for r in rows if r["field"] == field]
        h = [r["spacing"] for r in sub]
        for method, color in methods:
            exact = [r["exact"][method]["rms"] for r in sub]
            mesher = [r["mesher"][method]["rms"] for r in sub]
            order = fitted[field]["exact"][method]
            ax.plot(h, exact, "o-", color=color, label=f"{method} ({order:.2f})")
            ax.plot(h, mesher, "x--", color=color, alpha=0.6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(field)
        ax.set_xlabel("h")
        ax.legend(fontsize=6)
    for ax in axes.flat[len(fields):]:
        ax.set_axis_off()
    axes[0][0].set_ylabel("RMS edge-crossing error")
    fig.suptitle("Convergence on interior edges: exact samples (solid, fitted order) and mesher (dashed, float32)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "convergence.png"), dpi=110)
    plt.close(fig)


def main(argv):
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    path = argv[1]
    out = os.path.dirname(os.path.abspath(path))
    with open(path) as f:
        report = json.load(f)
    cases = report["cases"]
    meshes = {}
    for case in cases:
        mesh = case.get("mesh")
        if mesh and os.path.exists(mesh):
            read = ply_io.read_ply(mesh, require_isouq=False)
            meshes[case["field"]] = read.vertex_attributes
            fig3(case, read, out)
    fig4(cases, out)
    scatter(cases, meshes, out)
    convergence(report, out)
    print(f"wrote plots in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
