# Matplotlib figures for the side panel (C1 CDF, C4 legend, C5 bars), written as PNG files.
# No bpy: the panel loads the PNGs as previews (ui.py).

import numpy as np

from . import analysis


def _pyplot():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def _draw_cdf(ax, values, threshold, measure):
    x, p = analysis.cdf(np.asarray(values))
    ax.plot(x, p, color="#1f4fbf", lw=1.5)
    if threshold is not None:
        frac = float(np.mean(x <= threshold)) if len(x) else 0.0
        ax.axvline(threshold, color="#e06000", lw=1.2)
        ax.set_title(f"{100 * (1 - frac):.1f}% of vertices above {threshold:.3g}", fontsize=9)
    ax.set_xlabel(f"{measure} (world units)")
    ax.set_ylabel("fraction of vertices")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)


def cdf_plot(path, values, threshold, measure, size=(4.0, 3.0)):
    """C1: cumulative distribution of `values` with the threshold as a vertical line."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=size, dpi=100)
    _draw_cdf(ax, values, threshold, measure)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _colorbar(fig, cax, vmin, vmax, measure, colormap, extend="neither"):
    """Horizontal colorbar with few, readable ticks (scientific offset for small values)."""
    import matplotlib as mpl
    norm = mpl.colors.Normalize(vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1e-12)
    bar = fig.colorbar(mpl.cm.ScalarMappable(norm=norm, cmap=colormap), cax=cax,
                       orientation="horizontal", extend=extend)
    bar.locator = mpl.ticker.MaxNLocator(5)
    bar.formatter = mpl.ticker.ScalarFormatter(useMathText=True)
    bar.formatter.set_powerlimits((-2, 3))
    bar.update_ticks()
    above = "; top colour: this and above" if extend == "max" else ""
    cax.set_xlabel(f"{measure} (world units{above})", fontsize=9)
    return bar


def legend_plot(path, vmin, vmax, measure, colormap="plasma", size=(4.0, 0.9),
                extend="neither"):
    """C4 legend: the heat map's colormap from vmin to vmax (`extend="max"` when values above
    vmax are clamped to its colour)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=size, dpi=100)
    _colorbar(fig, ax, vmin, vmax, measure, colormap, extend)
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


def figure(path, image_path, title, colorbar=None, swatches=(), cdf=None, width=6.0, dpi=100):
    """A figure for documents: the rendered `image_path` under `title` with its key, either
    `colorbar` = dict(vmin, vmax, measure, colormap, extend) or `swatches` = [(label, sRGB,
    alpha)], and, with `cdf` = dict(values, threshold, measure), the C1 CDF beside it."""
    plt = _pyplot()
    from matplotlib.patches import Patch
    image = plt.imread(image_path)
    aspect = image.shape[0] / image.shape[1]
    width = min(width, 6.0 / aspect)                  # tall renders: at most 6 in high
    side = 0.75 * width if cdf else 0.0
    rows = 1 if width >= 5.5 else len(swatches)      # narrow figures stack the swatches
    key = (0.75 if (colorbar or swatches) else 0.0) + 0.3 * (rows if colorbar and swatches else
                                                            max(rows - 1, 0))
    fig = plt.figure(figsize=(width + side, width * aspect + key + 0.45), dpi=dpi)
    total_w, total_h = fig.get_size_inches()
    ax = fig.add_axes([0, (key) / total_h, width / total_w, width * aspect / total_h])
    ax.imshow(image, interpolation="lanczos")
    ax.set_axis_off()
    fig.suptitle(title, fontsize=11, y=1 - 0.12 / total_h, va="top", wrap=True)
    if colorbar:
        bottom = 0.42 + (0.3 * rows if swatches else 0.0)
        cax = fig.add_axes([0.12 * width / total_w, bottom / total_h, 0.76 * width / total_w,
                            0.13 / total_h])
        _colorbar(fig, cax, colorbar["vmin"], colorbar["vmax"], colorbar["measure"],
                  colorbar.get("colormap", "plasma"), colorbar.get("extend", "neither"))
    if swatches:
        handles = [Patch(facecolor=c, alpha=a, edgecolor="0.3", label=label)
                   for label, c, a in swatches]
        fig.legend(handles=handles, loc="lower center", ncol=len(handles) // rows, frameon=False,
                   fontsize=9, bbox_to_anchor=(0.5 * width / total_w, 0.0))
    if cdf:
        cax = fig.add_axes([(width + 0.12 * side) / total_w, (key + 0.5) / total_h,
                            0.8 * side / total_w, (width * aspect - 0.9) / total_h])
        _draw_cdf(cax, cdf["values"], cdf.get("threshold"), cdf["measure"])
    _save_small(fig, path, dpi)
    plt.close(fig)
    return path


def _save_small(fig, path, dpi):
    """Opaque RGB PNG (no alpha channel: a quarter fewer bytes), best compression."""
    import io
    from PIL import Image
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=dpi, format="png")
    buffer.seek(0)
    Image.open(buffer).convert("RGB").save(path, optimize=True)
