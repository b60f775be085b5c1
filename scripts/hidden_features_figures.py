#!/usr/bin/python3
"""Figures of docs/hidden-features.md from isouq PLY files (docs/ply-format.md).

Usage:
  ISOUQ_HIDDEN_PLY_DIR=/tmp/hf build/tests/test_HiddenFeatures "[.figures]"
  /usr/bin/python3 scripts/hidden_features_figures.py /tmp/hf docs/hidden-features

Writes teardrop.png (standard MC | hidden features, by triangle kind), teardrop_neck.png (the
interface between refined, transition and standard cells, with mesh edges) and bucky.png (the
hidden-feature surface in transparent orange over standard MC in opaque blue, SPEC §7 C6).
"""
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

import _isouq_path  # noqa: F401  (puts ply_io on sys.path)
import ply_io

BLUE, ORANGE, GREEN = (0.30, 0.50, 0.85), (1.00, 0.55, 0.10), (0.20, 0.70, 0.30)


def load(path):
    """Positions, triangles, vertex columns and face columns of an isouq binary PLY."""
    mesh = ply_io.read_ply(path, require_isouq=False)
    return mesh.positions, mesh.triangles, mesh.vertex_attributes, mesh.face_attributes


def draw(ax, positions, triangles, colours, alpha=1.0, edges=False):
    mesh = Poly3DCollection(positions[triangles], facecolors=colours, alpha=alpha,
                            edgecolors=(0, 0, 0, 0.35) if edges else "none", linewidths=0.2 if edges else 0)
    ax.add_collection3d(mesh)


def frame(ax, lo, hi, title):
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    ax.set_title(title, fontsize=9)
    ax.set_axis_off()


def kinds(vertices, faces, triangles):
    """Per face: 0 standard, 1 refined (subcell MC), 2 transition (fan to a centre)."""
    kind = faces["hidden"].astype(int)
    centre = vertices["edge_axis"] == 255
    kind[(kind == 1) & centre[triangles].any(axis=1)] = 2
    return kind


def shade(base, positions, triangles, light=(0.4, -0.5, 0.8)):
    """Flat Lambert shading so the surfaces read as 3D."""
    p = positions[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    lam = 0.35 + 0.65 * np.abs(n @ (np.array(light) / np.linalg.norm(light)))
    return np.clip(np.asarray(base)[..., :3] * lam[:, None], 0, 1)


def teardrop(folder, out):
    ps, ts, _, _ = load(folder / "teardrop_standard.ply")
    ph, th, vh, fh = load(folder / "teardrop_hidden.ply")
    kind = kinds(vh, fh, th)
    palette = np.array([BLUE, ORANGE, GREEN])
    lo, hi = np.array([-1.0, -0.6, -0.6]), np.array([1.0, 0.6, 0.6])
    fig = plt.figure(figsize=(11, 4.2))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    draw(ax, ps, ts, shade(np.tile(BLUE, (len(ts), 1)), ps, ts))
    frame(ax, lo, hi, "standard MC, 32^3, k = -0.001: 2 pieces")
    ax.view_init(18, -62)
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    draw(ax, ph, th, shade(palette[kind], ph, th))
    frame(ax, lo, hi, "with hidden features: 1 piece\n(blue standard, orange refined, green transition fans)")
    ax.view_init(18, -62)
    fig.tight_layout()
    fig.savefig(out / "teardrop.png", dpi=130)
    plt.close(fig)

    # The neck: refined cells (orange), transition fans (green), untouched MC (blue), with edges.
    centre = np.array([0.3, 0.0, 0.0])
    half = np.array([0.25, 0.3, 0.3])
    inside = np.all(np.abs(ph[th].mean(axis=1) - centre) < half, axis=1)
    fig = plt.figure(figsize=(9, 5))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    sel = th[inside]
    draw(ax, ph, sel, shade(palette[kind[inside]], ph, sel), edges=True)
    frame(ax, centre - half, centre + half, "Teardrop, where the neck meets the bulb: refined subcells (orange) meet standard MC (blue) "
          "through transition cells\nwhose face segments are fanned to a centre (green); no edge is open")
    ax.view_init(24, -70)
    fig.tight_layout()
    fig.savefig(out / "teardrop_neck.png", dpi=130)
    plt.close(fig)


def overlay(folder, out, name, title):
    ps, ts, _, _ = load(folder / f"{name}_standard.ply")
    ph, th, _, _ = load(folder / f"{name}_hidden.ply")
    lo, hi = np.minimum(ps.min(0), ph.min(0)), np.maximum(ps.max(0), ph.max(0))
    fig = plt.figure(figsize=(11, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    draw(ax, ps, ts, shade(np.tile(BLUE, (len(ts), 1)), ps, ts))
    frame(ax, lo, hi, f"{title}: standard MC")
    ax.view_init(22, -55)
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    draw(ax, ps, ts, shade(np.tile(BLUE, (len(ts), 1)), ps, ts))
    draw(ax, ph, th, np.tile((*ORANGE, 0.35), (len(th), 1)), alpha=0.35)
    frame(ax, lo, hi, f"{title}: hidden features (orange, transparent) over standard MC (blue)")
    ax.view_init(22, -55)
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=130)
    plt.close(fig)


def main():
    folder, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    teardrop(folder, out)
    overlay(folder, out, "bucky", "bucky 32^3, k = 51")


if __name__ == "__main__":
    main()
