#!/usr/bin/python3
"""isouq sequence report: the per-frame series of a sequence summary as one PNG picture.

    sequence_report.py SEQ.json OUT.png [--title TEXT] [--measures err_bound,d_lc,...]

SEQ.json is the summary of `isouq mesh 'in.####.vdb' -o 'out.####.ply' --summary SEQ.json`
(SPEC §10 "Sequences": a `frames` list, one object per frame with `frame`, `vertices`,
`components` and each measure's {min, max, mean, rms, count}). Draws, over the frame number:
vertices and triangles; connected components (and, with hidden features, the components after
recovery); err_est RMS and max; and the RMS of every other measure present (or of --measures).
Frames with an empty mesh are shaded grey and frames missing from the run are marked. The
picture is written atomically. Needs Debian's python3-matplotlib; no isouq module.
"""
import argparse
import json
import math
import os
import sys
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

PRIMARY = "err_est"
EMPTY_SHADE = "0.88"


def fail(message):
    sys.stderr.write(f"sequence_report.py: error: {message}\n")
    sys.exit(2)


def load(path):
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"cannot read {path}: {e}")
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, list) or not frames:
        fail(f"{path} is not a sequence summary (no 'frames' list)")
    entries = [e for e in frames if isinstance(e, dict) and isinstance(e.get("frame"), int)]
    if len(entries) != len(frames):
        fail(f"{path}: every entry of 'frames' needs an integer 'frame'")
    return doc, sorted(entries, key=lambda e: e["frame"])


def number(value):
    """A finite float, or NaN (gaps in the plotted line)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok else math.nan


def measures_of(entries):
    """Per-vertex measures present, in the order they first appear: keys holding {..., rms}."""
    names = []
    for e in entries:
        for key, value in e.items():
            if isinstance(value, dict) and "rms" in value and key not in names:
                names.append(key)
    return names


def series(entries, key, stat=None):
    out = []
    for e in entries:
        value = e.get(key)
        out.append(number(value.get(stat) if isinstance(value, dict) else math.nan)
                   if stat else number(value))
    return out


def shade_empty(ax, frames, empty):
    for f, is_empty in zip(frames, empty):
        if is_empty:
            ax.axvspan(f - 0.5, f + 0.5, color=EMPTY_SHADE, lw=0, zorder=0)


def positive(values):
    return [v if v > 0 else math.nan for v in values]


def draw(doc, entries, out, title=None, measures=None):
    frames = [e["frame"] for e in entries]
    empty = [bool(e.get("empty")) or e.get("vertices") == 0 for e in entries]
    available = measures_of(entries)
    others = measures if measures is not None else [m for m in available if m != PRIMARY]
    unknown = [m for m in others if m not in available]
    if unknown:
        fail(f"no measure {', '.join(unknown)} in the summary (it has {', '.join(available)})")
    panels = 3 + bool(others)
    fig, axes = plt.subplots(panels, 1, sharex=True, figsize=(8.0, 2.1 * panels + 0.6), dpi=110)

    ax = axes[0]
    ax.plot(frames, series(entries, "vertices"), "-o", ms=3, color="#1f4fbf", label="vertices")
    ax.plot(frames, series(entries, "triangles"), "-", color="#7f9fdf", label="triangles")
    ax.set_ylabel("count")
    ax.legend(fontsize=8, loc="best")

    ax = axes[1]
    ax.step(frames, series(entries, "components"), where="mid", color="#2a7f3f",
            label="components")
    hidden = [e.get("hidden", {}).get("components_after") if isinstance(e.get("hidden"), dict)
              else None for e in entries]
    if any(h is not None for h in hidden):
        ax.step(frames, [number(h) for h in hidden], where="mid", ls="--", color="#e06000",
                label="after hidden features")
    boundary = series(entries, "boundary_edges")
    if any(b > 0 for b in boundary if not math.isnan(b)):
        ax.plot(frames, boundary, "x", color="#b00020", label="boundary edges")
    ax.set_ylabel("components")
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.legend(fontsize=8, loc="best")

    ax = axes[2]
    if PRIMARY in available:
        ax.plot(frames, positive(series(entries, PRIMARY, "max")), "-", color="#e06000",
                label=f"{PRIMARY} max")
        ax.plot(frames, positive(series(entries, PRIMARY, "rms")), "-o", ms=3, color="#7a1fa2",
                label=f"{PRIMARY} RMS")
        ax.set_yscale("log")
        ax.legend(fontsize=8, loc="best")
    else:
        ax.text(0.5, 0.5, f"no {PRIMARY} in the summary", ha="center", va="center",
                transform=ax.transAxes)
    ax.set_ylabel("world units")

    if others:
        ax = axes[3]
        for name in others:
            ax.plot(frames, positive(series(entries, name, "rms")), "-", lw=1.2,
                    label=f"{name} RMS")
        ax.set_yscale("log")
        ax.set_ylabel("world units")
        ax.legend(fontsize=7, loc="best", ncol=3)

    missing = (doc.get("totals") or {}).get("missing") or []
    for ax in axes:
        shade_empty(ax, frames, empty)
        for f in missing:
            ax.axvline(f, color="#b00020", lw=0.8, ls=":")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("frame")
    if len(frames) < 30:
        axes[-1].set_xticks(frames if len(frames) <= 12 else frames[::2])
    seq = doc.get("sequence") or {}
    k = doc.get("isovalue")
    default_title = (f"{os.path.basename(seq.get('input', '')) or 'sequence'}: "
                     f"{len(frames)} frames, isovalue {k:g}" if isinstance(k, (int, float))
                     else f"{len(frames)} frames")
    if doc.get("method"):
        default_title += f", {doc['method']}"
    notes = []
    if any(empty):
        notes.append("grey: empty frames")
    if missing:
        notes.append("dotted: missing frames")
    fig.suptitle(title or default_title, fontsize=11)
    if notes:
        fig.text(0.99, 0.005, "; ".join(notes), ha="right", va="bottom", fontsize=8, color="0.4")
    fig.tight_layout(rect=(0, 0.02, 1, 0.97))
    save(fig, out)


def save(fig, path):
    """Writes the figure next to PATH and renames it: no partial picture is ever left."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(suffix=".png", dir=folder)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)                 # as a plain open() would have made it
    try:
        fig.savefig(tmp)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.remove(tmp)


def main(argv=None):
    p = argparse.ArgumentParser(prog="sequence_report.py", description=__doc__.split("\n\n")[0])
    p.add_argument("summary", help="sequence summary JSON (isouq mesh ... --summary)")
    p.add_argument("out", help="the picture (.png)")
    p.add_argument("--title")
    p.add_argument("--measures", help="comma-separated measures for the RMS panel "
                                      "(default: every measure but err_est)")
    args = p.parse_args(argv)
    if not args.out.lower().endswith(".png"):
        fail(f"{args.out}: the picture is a .png")
    if not os.path.isdir(os.path.dirname(os.path.abspath(args.out))):
        fail(f"{args.out}: no such folder")
    doc, entries = load(args.summary)
    measures = [m for m in args.measures.split(",") if m] if args.measures else None
    draw(doc, entries, args.out, args.title, measures)
    print(f"wrote {args.out}: {len(entries)} frames")


if __name__ == "__main__":
    main()
