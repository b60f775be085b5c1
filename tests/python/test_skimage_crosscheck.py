"""isouq's linear marching cubes against scikit-image 0.19's `marching_cubes`, an
independent implementation, on the same samples (docs/crosscheck.md has the numbers).

Claims, each on `field:tangle --resolution 64` at k = 0.1 and on Bucky at k = 50.5:
- the set of linear crossing vertices equals scikit-image's (methods 'lorensen' and
  'lewiner'), matched by grid edge, to 1e-5 voxel in index space;
- the triangle counts agree within 0.5 %, and isouq's count equals the count predicted by a
  case rule derived here from first principles (SPEC §1: a corner is inside when >= k; on an
  ambiguous face the inside corners are kept apart); every cell where scikit-image's count
  differs is ambiguous: it has an ambiguous face, or it is MC33 case 4 (ambiguous inside),
  which Lewiner's method may join by a tunnel (Bucky at k = 150.5 shows both);
- at isovalues the data hold (k = 51 on Bucky, and every other integer), isouq's mesh has no
  crack: every mesh edge is used by two triangles except on the domain boundary, where the
  open edges are exactly the marching-squares segments of the six domain faces.
  scikit-image's tie handling (its issue 8116) is measured alongside and printed.
Run with `-s` to see the measured numbers.
"""
import numpy as np
import pytest

measure = pytest.importorskip("skimage.measure")
meshio = pytest.importorskip("meshio")

VERTEX_TOL = 1e-5  # voxel; float32 rounding is ~1e-7 relative (see docs/crosscheck.md)


# --- the same samples in numpy -----------------------------------------------------------

def tangle_volume(n):
    """SPEC §5 tangle on [-1,1]^3, N^3 samples including both ends, as float32 (x, y, z)."""
    h = 2.0 / (n - 1)
    x = np.arange(n) * h - 1.0
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return (X**4 + Y**4 + Z**4 - (X * X + Y * Y + Z * Z - 0.4)).astype(np.float32)


def bucky_volume(data_dir):
    """Raw uint8, x fastest: numpy (z, y, x) after reshape, transposed to (x, y, z)."""
    raw = np.fromfile(data_dir / "bucky_32x32x32_uint8.raw", dtype=np.uint8)
    return raw.reshape(32, 32, 32).transpose(2, 1, 0).astype(np.float32)


def case_volume(name, data_dir):
    """(volume, isovalue, isouq INPUT, extra CLI args) of a named case."""
    if name == "tangle":
        return tangle_volume(64), 0.1, "field:tangle", ["--resolution", 64]
    k = float(name.split("@")[1])
    return bucky_volume(data_dir), k, data_dir / "bucky_32x32x32_uint8.raw", []


def run_isouq(isouq_mesh, data_dir, name):
    vol, k, source, args = case_volume(name, data_dir)
    ply = isouq_mesh(source, "--isovalue", repr(k), "--linear-only", *args)
    return vol, k, read_isouq_ply(ply)


# --- reading isouq's PLY (meshio for the body, the header for index_to_world) -------------

def read_isouq_ply(path):
    with open(path, "rb") as f:
        header = f.read(4096).split(b"end_header")[0].decode("ascii")
    matrix = None
    for line in header.splitlines():
        if line.startswith("comment isouq index_to_world "):
            matrix = np.array(line.split()[3:], dtype=np.float64).reshape(4, 4)
    assert matrix is not None, "isouq PLY without index_to_world"
    m = meshio.read(path)
    cols = {k: np.asarray(v) for k, v in m.point_data.items()}
    tris = np.concatenate([c.data for c in m.cells if c.type == "triangle"]).astype(np.int64)
    return {"xyz": m.points.astype(np.float64), "tris": tris, "cols": cols, "index_to_world": matrix}


def provenance_positions(mesh):
    """Index-space position edge + t_linear * axis, and the (i, j, k, axis) key per vertex."""
    c = mesh["cols"]
    edge = np.stack([c["edge_i"], c["edge_j"], c["edge_k"]], 1).astype(np.int64)
    axis = c["edge_axis"].astype(np.int64)
    pos = edge.astype(np.float64)
    pos[np.arange(len(pos)), axis] += c["t_linear"].astype(np.float64)
    return np.c_[edge, axis], pos


def world_to_index(mesh):
    m = np.linalg.inv(mesh["index_to_world"])
    return mesh["xyz"] @ m[:3, :3].T + m[:3, 3]


# --- scikit-image's vertices as grid edges ------------------------------------------------

def skimage_mesh(vol, k, method):
    verts, faces, _, _ = measure.marching_cubes(vol, k, method=method)
    return verts.astype(np.float64), faces.astype(np.int64)


def edge_keys(points):
    """(i, j, k, axis) of points lying inside a grid edge: exactly one non-integer coordinate.
    Returns the keys and a mask of such points (others sit on corners or inside cells)."""
    frac = points - np.floor(points)
    off_grid = (frac > 1e-9) & (frac < 1 - 1e-9)
    on_edge = off_grid.sum(1) == 1
    axis = np.argmax(off_grid, 1)
    lower = np.floor(points).astype(np.int64)
    return np.c_[lower, axis], on_edge


def sort_rows(keys):
    return np.lexsort(keys.T[::-1])


def exact_linear(vol, keys, k):
    """Linear crossing of each edge key in float64 from the float32 samples (SPEC §2)."""
    lo = keys[:, :3]
    hi = lo.copy()
    hi[np.arange(len(hi)), keys[:, 3]] += 1
    f0 = vol[tuple(lo.T)].astype(np.float64)
    f1 = vol[tuple(hi.T)].astype(np.float64)
    pos = lo.astype(np.float64)
    pos[np.arange(len(pos)), keys[:, 3]] += (np.float64(np.float32(k)) - f0) / (f1 - f0)
    return pos


# --- case rule from first principles -------------------------------------------------------

CORNERS = [(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]  # bit = x + 2y + 4z


def _edge(c0, c1):
    axis = next(a for a in range(3) if c0[a] != c1[a])
    return (min(c0, c1), axis)


def _faces():
    faces = []
    for a in range(3):
        b, c = [x for x in range(3) if x != a]
        for side in (0, 1):
            ring = []
            for db, dc in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = [0, 0, 0]
                p[a], p[b], p[c] = side, db, dc
                ring.append(tuple(p))
            faces.append(ring)
    return faces


def triangles_for_case(case):
    """Triangles of a cell whose inside corners (>= k) are the set bits of @a case, when on
    every face the surface separates the face's inside corners: the face segments join the
    cell's crossing edges into closed polygons, a polygon with n vertices is n - 2 triangles,
    so the total is (crossing edges) - 2 (polygons)."""
    inside = {c: (case >> (c[0] + 2 * c[1] + 4 * c[2])) & 1 for c in CORNERS}
    parent = {}

    def find(e):
        parent.setdefault(e, e)
        while parent[e] != e:
            e = parent[e]
        return e

    for ring in _faces():
        crossing = [i for i in range(4) if inside[ring[i]] != inside[ring[(i + 1) % 4]]]
        edges = [_edge(ring[i], ring[(i + 1) % 4]) for i in crossing]
        for e in edges:
            find(e)
        if len(edges) == 2:
            parent[find(edges[0])] = find(edges[1])
        elif len(edges) == 4:  # ambiguous face: cut off each inside corner
            for i in range(4):
                if inside[ring[i]]:
                    e1 = _edge(ring[i - 1], ring[i])
                    e2 = _edge(ring[i], ring[(i + 1) % 4])
                    parent[find(e1)] = find(e2)
    polygons = len({find(e) for e in parent})
    return len(parent) - 2 * polygons


CASE_TRIANGLES = np.array([triangles_for_case(c) for c in range(256)])


def cell_cases(vol, k):
    inside = (vol >= np.float32(k)).astype(np.int32)
    n = np.array(vol.shape) - 1
    case = np.zeros(n, np.int32)
    for (x, y, z) in CORNERS:
        case += inside[x:x + n[0], y:y + n[1], z:z + n[2]] << (x + 2 * y + 4 * z)
    return case


def ambiguous_cells(vol, k):
    """Faces whose diagonal corners agree and differ from the other diagonal (under the >= k
    rule), cells having such a face, and cells with none that are still ambiguous inside
    (MC33 case 4: two corners alone at the ends of a body diagonal, where Lewiner's interior
    test may open a tunnel). Returns (faces, face cells, interior cells) as counts/masks."""
    inside = vol >= np.float32(k)
    face_cells = np.zeros(np.array(vol.shape) - 1, bool)
    faces = 0
    for a in range(3):
        b, c = [x for x in range(3) if x != a]

        def corner(db, dc):
            idx = [slice(None)] * 3
            idx[b] = slice(db, vol.shape[b] - 1 + db)
            idx[c] = slice(dc, vol.shape[c] - 1 + dc)
            return inside[tuple(idx)]

        amb = (corner(0, 0) == corner(1, 1)) & (corner(1, 0) == corner(0, 1)) & (corner(0, 0) != corner(1, 0))
        faces += int(amb.sum())
        for lo in (0, 1):  # the cells on both sides of each face
            idx = [slice(None)] * 3
            idx[a] = slice(lo, vol.shape[a] - 1 + lo)
            face_cells |= amb[tuple(idx)]
    diagonal = [(1 << b) | (1 << (7 - b)) for b in range(4)]  # corner 7 - b is opposite b
    interior = np.isin(cell_cases(vol, k), diagonal + [255 - d for d in diagonal])
    return faces, face_cells, interior


def triangles_per_cell(points, tris, shape):
    """Cell of each triangle (floor of its centroid, in index space), counted per cell."""
    cell = np.floor(points[tris].mean(1)).astype(np.int64)
    counts = np.zeros(np.array(shape) - 1, np.int64)
    np.add.at(counts, tuple(cell.T), 1)
    return counts


# --- cracks --------------------------------------------------------------------------------

def open_edges(points, tris, shape):
    """(edges used once, of which not on the domain boundary, edges used more than twice)."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    once = uniq[count == 1].astype(np.int64)
    a, b = points[once[:, 0]], points[once[:, 1]]
    on_domain = np.zeros(len(once), bool)
    for ax in range(3):
        for plane in (0, shape[ax] - 1):
            on_domain |= (np.abs(a[:, ax] - plane) < 1e-6) & (np.abs(b[:, ax] - plane) < 1e-6)
    return len(once), int((~on_domain).sum()), int((count > 2).sum())


def domain_face_segments(vol, k):
    """Marching-squares segments on the six domain faces under the same rule: a square with
    two crossing sides has one segment, an ambiguous square (four) two."""
    inside = vol >= np.float32(k)
    total = 0
    for ax in range(3):
        for plane in (0, vol.shape[ax] - 1):
            face = np.take(inside, plane, axis=ax)
            crossings = ((face[:-1, :-1] != face[1:, :-1]).astype(int) + (face[1:, :-1] != face[1:, 1:])
                         + (face[1:, 1:] != face[:-1, 1:]) + (face[:-1, 1:] != face[:-1, :-1]))
            total += int(crossings.sum()) // 2
    return total


def welded(points, tris):
    """Merge coincident points (scikit-image emits one per edge even when several edges end
    on the same grid corner) and drop the triangles that collapse."""
    uniq, inverse = np.unique(np.round(points, 6), axis=0, return_inverse=True)
    t = inverse.reshape(-1)[tris]
    keep = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])
    return uniq, t[keep], int((~keep).sum())


# --- tests ---------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["lorensen", "lewiner"])
@pytest.mark.parametrize("name", ["tangle", "bucky@50.5"])
def test_linear_vertex_set_equals_skimage(isouq_mesh, data_dir, name, method):
    vol, k, mesh = run_isouq(isouq_mesh, data_dir, name)
    keys, pos = provenance_positions(mesh)
    # The written positions are the provenance crossings (float32 world -> index).
    assert np.abs(world_to_index(mesh) - pos).max() < VERTEX_TOL

    verts, _ = skimage_mesh(vol, k, method)
    verts = np.unique(verts, axis=0)  # duplicates per edge, if any
    sk_keys, on_edge = edge_keys(verts)
    assert on_edge.all(), f"{(~on_edge).sum()} scikit-image vertices are not inside a grid edge"
    assert len(np.unique(sk_keys, axis=0)) == len(sk_keys), "two scikit-image vertices on one edge"

    order_i, order_s = sort_rows(keys), sort_rows(sk_keys)
    assert np.array_equal(keys[order_i], sk_keys[order_s]), "the crossing-edge sets differ"
    gap = np.abs(pos[order_i] - verts[order_s]).max()
    truth = np.abs(pos - exact_linear(vol, keys, k)).max()
    print(f"\ncrosscheck {name} {method}: {len(keys)} vertices, same edges; "
          f"max |isouq - skimage| = {gap:.2e} voxel, max |isouq - float64 linear| = {truth:.2e}")
    assert gap < VERTEX_TOL
    assert truth < 1e-6  # t_linear is float32: ~6e-8 relative


@pytest.mark.parametrize("name", ["tangle", "bucky@50.5", "bucky@150.5"])
def test_triangle_counts_agree_and_differ_only_in_ambiguous_cells(isouq_mesh, data_dir, name):
    vol, k, mesh = run_isouq(isouq_mesh, data_dir, name)
    n_faces, face_cells, interior_cells = ambiguous_cells(vol, k)
    amb_cells = face_cells | interior_cells
    rule = CASE_TRIANGLES[cell_cases(vol, k)]
    ours = len(mesh["tris"])
    assert ours == rule.sum(), "isouq's triangle count differs from the face rule's"
    _, pos = provenance_positions(mesh)
    assert np.array_equal(triangles_per_cell(pos, mesh["tris"], vol.shape), rule)
    line = (f"\ncrosscheck {name}: isouq {ours} triangles; {n_faces} ambiguous faces in "
            f"{face_cells.sum()} cells, {interior_cells.sum()} cells ambiguous inside only")
    for method in ("lorensen", "lewiner"):
        verts, faces = skimage_mesh(vol, k, method)
        theirs = len(faces)
        differ = triangles_per_cell(verts, faces, vol.shape) != rule
        line += (f"; {method} {theirs} ({100 * (theirs - ours) / ours:+.2f} %), "
                 f"{differ.sum()} cells differ ({(differ & interior_cells).sum()} inside only)")
        assert abs(theirs - ours) <= 0.005 * ours
        assert not (differ & ~amb_cells).any(), "counts differ in a cell that is not ambiguous"
    print(line)


@pytest.mark.parametrize("k", [51.0, 161.0])
def test_no_crack_at_a_value_the_data_holds(isouq_mesh, data_dir, k):
    vol, k, mesh = run_isouq(isouq_mesh, data_dir, f"bucky@{k}")
    assert (vol == k).any()
    _, pos = provenance_positions(mesh)
    once, interior, over = open_edges(pos, mesh["tris"], vol.shape)
    segments = domain_face_segments(vol, k)
    collapsed = welded(pos, mesh["tris"])[2]
    line = (f"\ncrosscheck bucky k={k}: isouq {len(mesh['tris'])} triangles, {once} open edges "
            f"({interior} inside the volume), {over} used > 2 times, {collapsed} zero-area triangles; "
            f"{segments} domain-face segments")
    for method in ("lorensen", "lewiner"):
        verts, faces = skimage_mesh(vol, k, method)
        sk = open_edges(verts, faces, vol.shape)
        wv, wf, collapsed = welded(verts, faces)
        skw = open_edges(wv, wf, vol.shape)
        line += (f"; {method}: {len(faces)} triangles, {sk[0]} open edges ({sk[1]} inside), "
                 f"welded {skw[0]} ({skw[1]} inside), {collapsed} zero-area triangles")
    print(line)
    assert interior == 0 and over == 0
    assert once == segments


def test_no_crack_at_any_value_the_data_holds(isouq_mesh, data_dir):
    vol = bucky_volume(data_dir)
    values = [v for v in np.unique(vol) if vol.min() < v < vol.max()]
    cracked, sk_cracked = [], []
    for k in values:
        mesh = read_isouq_ply(isouq_mesh(data_dir / "bucky_32x32x32_uint8.raw", "--isovalue",
                                         repr(float(k)), "--linear-only"))
        _, pos = provenance_positions(mesh)
        once, interior, over = open_edges(pos, mesh["tris"], vol.shape)
        if interior or over or once != domain_face_segments(vol, k):
            cracked.append(float(k))
        verts, faces = skimage_mesh(vol, float(k), "lewiner")
        if open_edges(verts, faces, vol.shape)[1]:
            sk_cracked.append(float(k))
    print(f"\ncrosscheck bucky ties: {len(values)} isovalues; isouq cracked at {len(cracked)}, "
          f"skimage lewiner has open edges inside the volume at {len(sk_cracked)}")
    assert not cracked, f"isouq's mesh is open inside the volume at k = {cracked}"
