# The numbers behind the analysis views (paper sec. 4.3, SPEC §7): numpy only, no bpy.
#
# Method switching (C3): a vertex of any method sits at M * ((i, j, k) + t * e_axis, 1) with M the
# grid's index-to-world map (`comment isouq index_to_world`, SPEC §6 edge_i/j/k, edge_axis, and
# the method's t column, named by the vocabulary: pipeline.Vocabulary). Files without the comment
# get M fitted by least squares from x, y, z and the primary method's t (exact for an affine grid
# transform).

import numpy as np

EDGE_COLUMNS = ("edge_i", "edge_j", "edge_k", "edge_axis")


def has_edges(attrs):
    return all(c in attrs for c in EDGE_COLUMNS)


def index_points(attrs, column):
    """(N, 3) index-space crossing at t column `column` for every vertex (NaN where t is NaN)."""
    ijk = np.stack([attrs[c].astype(np.float64) for c in EDGE_COLUMNS[:3]], axis=1)
    axis = attrs["edge_axis"].astype(np.int64)
    if np.any((axis < 0) | (axis > 2)):
        raise ValueError("edge_axis outside 0..2")
    t = attrs[column].astype(np.float64)
    ijk[np.arange(len(axis)), axis] += t
    return ijk


def to_world(matrix, points):
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def fit_index_to_world(positions, attrs, column):
    """Least-squares affine M with positions ~ M * index_points(column); None if degenerate."""
    p = index_points(attrs, column)
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(positions), axis=1)
    if "hidden" in attrs:
        ok &= attrs["hidden"] == 0
    a = np.hstack([p[ok], np.ones((ok.sum(), 1))])
    if len(a) < 4 or np.linalg.matrix_rank(a) < 4:
        return None
    sol, *_ = np.linalg.lstsq(a, positions[ok].astype(np.float64), rcond=None)
    m = np.eye(4)
    m[:3, :] = sol.T
    return m


def guess_primary_method(positions, attrs, matrix, methods):
    """The method (of {token: t column}) whose crossings reproduce x, y, z best (used when the
    header does not say)."""
    best, best_err = None, np.inf
    for method, column in methods.items():
        w = to_world(matrix, index_points(attrs, column))
        err = np.nanmax(np.abs(w - positions)) if len(w) else 0.0
        if err < best_err:
            best, best_err = method, err
    return best


def method_positions(positions, attrs, matrix, column):
    """World positions of the crossings at t column `column`; vertices it cannot place
    (hidden-feature vertices, NaN t) keep their stored position."""
    w = to_world(matrix, index_points(attrs, column))
    keep = ~np.all(np.isfinite(w), axis=1)
    if "hidden" in attrs:
        keep |= attrs["hidden"] != 0
    w[keep] = positions[keep]
    return w.astype(np.float32)


def mixed_positions(positions, attrs, matrix, selected, inside_column, outside_column):
    """C3: the crossings at `inside_column` where `selected`, at `outside_column` elsewhere."""
    inside = method_positions(positions, attrs, matrix, inside_column)
    outside = method_positions(positions, attrs, matrix, outside_column)
    return np.where(selected[:, None], inside, outside)


def cdf(values):
    """Empirical CDF (sorted finite values, fraction of vertices <= each)."""
    v = np.sort(values[np.isfinite(values)])
    return v, np.arange(1, len(v) + 1) / max(len(v), 1)


def percentile_threshold(values, percent):
    """The value below which `percent` % of the finite values lie (linear interpolation)."""
    v = values[np.isfinite(values)]
    if len(v) == 0:
        raise ValueError("no finite values to take a percentile of")
    return float(np.percentile(v, percent))


def above(values, threshold):
    """C1 binary map: strictly above the threshold."""
    return np.asarray(values) > threshold


def box_mask(points, box_matrix_world):
    """C2: points inside the box that the unit cube [-1, 1]^3 becomes under `box_matrix_world`
    (a cube primitive or a cube empty of display size 1, moved, rotated and scaled)."""
    inv = np.linalg.inv(np.asarray(box_matrix_world, np.float64))
    local = points @ inv[:3, :3].T + inv[:3, 3]
    return np.all(np.abs(local) <= 1.0, axis=1)


def stats(values):
    """SPEC §8 summary entry {min, max, mean, rms} of the finite values."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return None
    return {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean()),
            "rms": float(np.sqrt(np.mean(v * v)))}
