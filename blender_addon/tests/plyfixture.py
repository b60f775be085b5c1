# Test fixtures: isouq-style PLYs written with numpy exactly as SPEC §6 and the lead's header
# contract say, from an analytic sphere meshed by scikit-image (an independent mesher). No add-on
# code is used here, so the add-on's reader is checked against an independent writer.

from collections import OrderedDict

import numpy as np

PLY_TYPES = {"f4": "float", "i4": "int", "u1": "uchar"}


def write_ply(path, positions, triangles, vertex_attrs, face_attrs=None, comments=()):
    """Binary little-endian PLY: x y z then `vertex_attrs` in their order; faces as
    `list uchar int vertex_indices` then `face_attrs`."""
    face_attrs = face_attrs or {}
    n, m = len(positions), len(triangles)
    vdt = [(a, "<f4") for a in "xyz"] + [(k, "<" + v.dtype.str[1:]) for k, v in vertex_attrs.items()]
    vrows = np.zeros(n, dtype=vdt)
    for a, col in zip("xyz", np.asarray(positions, np.float32).T):
        vrows[a] = col
    for k, v in vertex_attrs.items():
        vrows[k] = v
    fdt = [("n", "u1"), ("v", "<i4", (3,))] + [(k, "<" + v.dtype.str[1:]) for k, v in face_attrs.items()]
    frows = np.zeros(m, dtype=fdt)
    frows["n"] = 3
    frows["v"] = triangles
    for k, v in face_attrs.items():
        frows[k] = v
    lines = ["ply", "format binary_little_endian 1.0"] + [f"comment {c}" for c in comments]
    lines.append(f"element vertex {n}")
    lines += [f"property float {a}" for a in "xyz"]
    lines += [f"property {PLY_TYPES[v.dtype.str[1:]]} {k}" for k, v in vertex_attrs.items()]
    lines += [f"element face {m}", "property list uchar int vertex_indices"]
    lines += [f"property {PLY_TYPES[v.dtype.str[1:]]} {k}" for k, v in face_attrs.items()]
    lines.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(lines) + "\n").encode("ascii"))
        f.write(vrows.tobytes())
        f.write(frows.tobytes())


def index_to_world():
    """An anisotropic, rotated, translated grid transform (world = M (i, j, k, 1))."""
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rot @ np.diag([0.1, 0.12, 0.09])
    m[:3, 3] = [-1.0, 0.5, 0.25]
    return m


def sphere_fixture(n=14, radius=5.0, bump=0.0):
    """A sphere (optionally with a bump, which varies err_est) sampled on an n^3 index grid and
    meshed by skimage: every vertex is on a grid edge, so its edge and t_linear follow from its
    index-space position. t_weno is the exact crossing on the edge, t_cubic their mean, and the
    estimate follows SPEC §3 from the samples."""
    from skimage.measure import marching_cubes

    centre = np.full(3, (n - 1) / 2.0)

    def field(p):
        d = p - centre
        return np.linalg.norm(d, axis=-1) - radius - bump * np.exp(-np.sum((d - [0, 0, radius]) ** 2, axis=-1) / 4.0)

    g = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), axis=-1).astype(np.float64)
    f = field(g)
    verts, faces, _, _ = marching_cubes(f, 0.0, allow_degenerate=False)
    verts = verts.astype(np.float64)
    base = np.floor(verts + 1e-9)
    frac = verts - base
    axis = np.argmax(frac, axis=1)
    rows = np.arange(len(verts))
    t_lin = frac[rows, axis]
    e = np.eye(3)[axis]
    # exact crossing on the edge by bisection of the analytic field
    lo, hi = np.zeros(len(verts)), np.ones(len(verts))
    f0 = field(base)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        fm = field(base + mid[:, None] * e)
        same = np.sign(fm) == np.sign(f0)
        lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
    t_weno = 0.5 * (lo + hi)
    t_cub = 0.5 * (t_lin + t_weno)
    m = index_to_world()
    h = np.linalg.norm(m[:3, :3] @ e.T, axis=0)                      # world edge length
    world = lambda t: (base + t[:, None] * e) @ m[:3, :3].T + m[:3, 3]
    # SPEC §3 estimate from the samples along the edge (clamped stencil at the border)
    def sample(k):
        p = np.clip(base + k * e, 0, n - 1).astype(int)
        return f[p[:, 0], p[:, 1], p[:, 2]]
    fm1, f0s, f1, f2 = sample(-1), sample(0), sample(1), sample(2)
    u01 = (f1 - f0s) / h
    u_m = ((f1 - f0s) / h - (f0s - fm1) / h) / (2 * h)
    u_p = ((f2 - f1) / h - (f1 - f0s) / h) / (2 * h)
    ratio = np.maximum(np.abs(u_m), np.abs(u_p)) / np.abs(u01)
    x = t_lin * h
    err_est = ratio * np.abs(x * (x - h))
    err_bound = ratio * h * h
    wl, wc, ww = world(t_lin), world(t_cub), world(t_weno)
    d = lambda a, b: np.linalg.norm(a - b, axis=1)
    d_lc, d_lw, d_cw = d(wl, wc), d(wl, ww), d(wc, ww)
    attrs = OrderedDict()
    attrs["edge_i"], attrs["edge_j"], attrs["edge_k"] = (base[:, c].astype(np.int32) for c in range(3))
    attrs["edge_axis"] = axis.astype(np.uint8)
    attrs["t_linear"] = t_lin.astype(np.float32)
    attrs["t_cubic"] = t_cub.astype(np.float32)
    attrs["t_weno"] = t_weno.astype(np.float32)
    attrs["order"] = np.full(len(verts), 6, np.uint8)
    attrs["err_est"] = err_est.astype(np.float32)
    attrs["err_bound"] = err_bound.astype(np.float32)
    attrs["d_lc"], attrs["d_lw"], attrs["d_cw"] = (a.astype(np.float32) for a in (d_lc, d_lw, d_cw))
    attrs["max_var"] = np.maximum(np.maximum(d_lc, d_lw), d_cw).astype(np.float32)
    attrs["hidden"] = np.zeros(len(verts), np.uint8)
    fattrs = OrderedDict(hidden=(np.arange(len(faces)) % 7 == 0).astype(np.uint8))
    comments = ["isouq index_to_world " + " ".join(repr(float(v)) for v in m.ravel()),
                "isouq isovalue 0", "isouq method linear"]
    return wl.astype(np.float32), faces.astype(np.int32), attrs, fattrs, comments


def write_sphere(path, **kw):
    positions, faces, attrs, fattrs, comments = sphere_fixture(**kw)
    write_ply(path, positions, faces, attrs, fattrs, comments)
    return positions, faces, attrs, fattrs, comments
