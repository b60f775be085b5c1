"""A notebook in a script: mesh a numpy array with isouq, threshold the paper's error estimate
err_est (paper sec. 4.1, SPEC §3, §6) at its 90th percentile and plot it with matplotlib (the C1
cumulative distribution and the surface coloured above/below the threshold, SPEC §7).

    PYTHONPATH=build/python /usr/bin/python3 examples/python/threshold_err_est.py err_est.png
"""
import sys

import matplotlib
matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

import isouq  # noqa: E402

# --- 1. A volume as scientists have it: a numpy array a[z, y, x] (here the Tangle field,
#        SPEC §5, sampled at 48^3 on [-2.5, 2.5]^3: bumps whose tips a linear crossing misses).
n = 48
z, y, x = np.mgrid[-2.5:2.5:n * 1j, -2.5:2.5:n * 1j, -2.5:2.5:n * 1j]
tangle = (x**4 - 5 * x**2 + y**4 - 5 * y**2 + z**4 - 5 * z**2 + 11.8).astype(np.float32)
spacing = 5.0 / (n - 1)

# --- 2. Mesh it: the same graph as `isouq mesh`, every column as a numpy view.
mesh = isouq.mesh(tangle, isovalue=0.0, method="weno", spacing=(spacing,) * 3, origin=(-2.5,) * 3)
err = mesh.columns["err_est"]
print(mesh)
print(f"err_est: max {mesh.summary['err_est']['max']:.3g}, mean {mesh.summary['err_est']['mean']:.3g} "
      f"(voxel size {spacing:.3g})")

# --- 3. Threshold (C1): the vertices whose estimated error is in the top 10 %.
threshold = float(np.nanpercentile(err, 90))
above = err > threshold
print(f"{above.sum()} of {len(err)} vertices above the 90th percentile, err_est > {threshold:.3g}")

# --- 4. Plot: the CDF with its threshold, and the surface seen from +z, above in red.
fig, (cdf, view) = plt.subplots(1, 2, figsize=(11, 4.8))
values = np.sort(err[np.isfinite(err) & (err > 0)])  # log axis: the long tail is where it matters
cdf.plot(values, np.arange(1, len(values) + 1) / len(values), color="black")
cdf.set_xscale("log")
cdf.axvline(threshold, color="tab:red", linestyle="--", label=f"90th percentile: {threshold:.3g}")
cdf.set(xlabel="err_est (world units)", ylabel="fraction of vertices", title="C1: cumulative distribution")
cdf.legend(loc="lower right")

v, t = mesh.vertices, mesh.triangles
corners = v[t]                                   # (M, 3, 3)
normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
shade = np.abs(normals[:, 2]) / np.maximum(np.linalg.norm(normals, axis=1), 1e-12)
face_above = above[t].any(axis=1)
base = np.where(face_above[:, None], [[0.85, 0.15, 0.1]], [[0.6, 0.7, 0.9]])
colors = base * (0.3 + 0.7 * shade)[:, None]
order = np.argsort(corners[:, :, 2].mean(axis=1))  # painter's order: far (low z) first
view.add_collection(PolyCollection(corners[order][:, :, :2], facecolors=colors[order], edgecolors="none"))
view.set(aspect="equal", xlim=(-2.5, 2.5), ylim=(-2.5, 2.5), xlabel="x", ylabel="y",
         title=f"Tangle from +z: {face_above.sum()} faces touch a vertex above")
fig.tight_layout()
out = sys.argv[1] if len(sys.argv) > 1 else "err_est.png"
fig.savefig(out, dpi=110)
print(f"wrote {out}")
