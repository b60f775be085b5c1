# Matplotlib figures for the side panel (C1 CDF, C4 legend, C5 bars), written as PNG files.
# No bpy: the panel loads the PNGs as previews (ui.py).

import numpy as np

from . import analysis


def _pyplot():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def cdf_plot(path, values, threshold=None, measure="err_est", size=(4.0, 3.0)):
    """C1: cumulative distribution of `values` with the threshold as a vertical line."""
    plt = _pyplot()
    x, p = analysis.cdf(np.asarray(values))
    fig, ax = plt.subplots(figsize=size, dpi=100)
    ax.plot(x, p, color="#1f4fbf", lw=1.5)
    if threshold is not None:
        frac = float(np.mean(x <= threshold)) if len(x) else 0.0
        ax.axvline(threshold, color="#e06000", lw=1.2)
        ax.set_title(f"{100 * (1 - frac):.1f}% of vertices above {threshold:.3g}", fontsize=9)
    ax.set_xlabel(measure)
    ax.set_ylabel("fraction of vertices")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def legend_plot(path, vmin, vmax, measure="err_est", colormap="plasma", size=(4.0, 0.9)):
    """C4 legend: the heat map's colormap from vmin to vmax."""
    plt = _pyplot()
    import matplotlib as mpl
    fig, ax = plt.subplots(figsize=size, dpi=100)
    norm = mpl.colors.Normalize(vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1e-12)
    fig.colorbar(mpl.cm.ScalarMappable(norm=norm, cmap=colormap), cax=ax, orientation="horizontal")
    ax.set_xlabel(f"{measure} (world units)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def bars_plot(path, columns, indices, size=(4.0, 3.0), max_bars=200):
    """C5: vertex-by-vertex bars of each column (e.g. err_est, d_lc, d_lw) for `indices`,
    sorted by the first column, at most `max_bars` (the largest)."""
    plt = _pyplot()
    names = list(columns)
    first = columns[names[0]][indices]
    order = indices[np.argsort(-first, kind="stable")][:max_bars]
    fig, ax = plt.subplots(figsize=size, dpi=100)
    width = 0.8 / max(len(names), 1)
    xs = np.arange(len(order))
    for n, name in enumerate(names):
        ax.bar(xs + n * width, columns[name][order], width=width, label=name)
    ax.set_xlabel(f"vertex in box (largest {len(order)} of {len(indices)} by {names[0]})")
    ax.set_ylabel("world units")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
