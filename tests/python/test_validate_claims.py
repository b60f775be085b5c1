"""`isouq validate` checked from outside: its truth columns against numpy re-implementations of
the SPEC §5 formulas (vectorised bisection, closed-form torus distance), and its tables against
the columns of the meshes it wrote (docs/validation.md)."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "scripts"))
import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402

CLI = os.environ.get("ISOUQ_CLI")

FIELDS = {  # SPEC §5, written again here (not read from AnalyticFields.h)
    "tangle": lambda x, y, z: x**4 + y**4 + z**4 - (x**2 + y**2 + z**2 - 0.4),
    "teardrop": lambda x, y, z: 0.5 * x**5 + 0.5 * x**4 - y**2 - z**2,
    "torus": lambda x, y, z: (np.sqrt(x**2 + y**2) - 0.3) ** 2 + z**2 - 0.01,
}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    if not CLI or not os.path.exists(CLI):
        pytest.skip("ISOUQ_CLI not set")
    out = tmp_path_factory.mktemp("validate")
    subprocess.run([CLI, "validate", "--quick", "--no-plots", "--out-dir", str(out),
                    "--mesh-dir", str(out / "meshes")], check=True, capture_output=True)
    with open(out / "validation.json") as f:
        return json.load(f)


def case(report, field):
    return next(c for c in report["cases"] if c["field"] == field)


def columns(path):
    """Every vertex column of a validated mesh, x, y and z included."""
    mesh = ply_io.read_ply(path, require_isouq=False)
    return dict(zip("xyz", mesh.positions.T), **mesh.vertex_attributes)


def edge_ends(v, c):
    n = c["resolution"]
    h = 2.0 / (n - 1)
    lower = np.stack([v["edge_i"], v["edge_j"], v["edge_k"]], axis=1) * h - 1.0
    step = np.zeros_like(lower)
    step[np.arange(len(lower)), v["edge_axis"]] = h
    return lower, step, h


@pytest.mark.parametrize("field", sorted(FIELDS))
def test_err_true_linear_matches_bisection(run, field):
    c = case(run, field)
    v = columns(c["mesh"])
    lower, step, h = edge_ends(v, c)
    f = FIELDS[field]
    k = np.float64(np.float32(c["isovalue"]))

    def g(t):
        p = lower + step * t[:, None]
        return f(p[:, 0], p[:, 1], p[:, 2]) - k

    lo, hi = np.zeros(len(lower)), np.ones(len(lower))
    glo = g(lo)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        same = np.sign(g(mid)) == np.sign(glo)
        lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
    exact = 0.5 * (lo + hi)
    expected = h * np.abs(v["t_linear"].astype(np.float64) - exact)
    assert np.allclose(v["err_true_linear"], expected, rtol=1e-5, atol=1e-7 * h)


def test_torus_dist_true_is_the_closed_form(run):
    c = case(run, "torus")
    v = columns(c["mesh"])
    x, y, z = (v[a].astype(np.float64) for a in "xyz")
    exact = np.abs(np.sqrt((np.sqrt(x**2 + y**2) - 0.3) ** 2 + z**2) - 0.1)
    assert np.allclose(v["dist_true"], exact, rtol=1e-5, atol=1e-9)


def test_tables_are_the_columns(run):
    for c in run["cases"]:
        v = columns(c["mesh"])
        for row in c["agreement"]:
            a, b = v[row["estimate"]].astype(np.float64), v[row["measured"]].astype(np.float64)
            ok = np.isfinite(a) & np.isfinite(b)
            ratio = np.sqrt(np.mean(a[ok] ** 2) / np.mean(b[ok] ** 2))
            assert row["rms_ratio"] == pytest.approx(ratio, rel=1e-6)


def test_paper_claim_against_edge_error(run):
    # Paper Fig. 4 / SPEC §3: e tracks the measured linear edge error, e_b overestimates it.
    for c in run["cases"]:
        ratios = {(r["estimate"], r["measured"]): r["rms_ratio"] for r in c["agreement"]}
        assert 0.5 <= ratios[("err_est", "err_true_linear")] <= 2.0, c["field"]
        assert ratios[("err_bound", "err_true_linear")] >= 3.0, c["field"]
