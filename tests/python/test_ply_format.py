"""isouq's PLY files (docs/ply-format.md, SPEC §6) through two readers: ply_io, the one reader
of the add-on and the scripts, and meshio (Debian's python3-meshio), an outside reader for the
values it reads correctly (meshio 7 reads binary PLY `uchar` as int8, so isouq writes `uint8`,
and it takes one value per binary face property, so it fails on files with face columns). The C++ test test_MeshIO runs this file as `python3 test_ply_format.py --dump
FILE` on files written by isouq::writePly and compares the JSON it prints with the mesh it wrote.
Under pytest the readers are checked against bytes assembled here with struct, and against the
isouq CLI's output when $ISOUQ_CLI exists.
"""
import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402


def read(path):
    """The file through ply_io after the checks a lenient reader leaves out: the exact format
    line, elements vertex then face, triangles only, no byte missing or left over. Returns
    (IsouqMesh, the vertex property names in file order)."""
    data = Path(path).read_bytes()
    assert data.startswith(b"ply\nformat binary_little_endian 1.0\n")
    _, elements, _, offset = ply_io.parse_header(data)
    assert [e.name for e in elements] == ["vertex", "face"]
    mesh = ply_io.read_ply_bytes(data)
    assert np.all(mesh.loop_total == 3)
    size = lambda t: np.dtype(t).itemsize  # noqa: E731
    vertex, face = elements
    vertex_row = sum(size(p.dtype) for p in vertex.properties)
    face_row = sum(size(p.count_dtype) + 3 * size(p.dtype) if p.count_dtype else size(p.dtype)
                   for p in face.properties)
    assert offset + vertex.count * vertex_row + face.count * face_row == len(data), \
        "trailing or missing bytes"
    return mesh, [p.name for p in vertex.properties]


def _exact(array):
    """Values as JSON integers: float32 by their bit pattern, so NaN and -0 compare exactly."""
    if array.dtype.kind == "f":
        return array.astype("<f4").view("<u4").tolist()
    return array.astype(np.int64).tolist()


def dump(path):
    mesh, names = read(path)
    vertex = dict(zip("xyz", mesh.positions.T), **mesh.vertex_attributes)
    out = {"comments": mesh.comments,
           "vertex": {n: {"type": vertex[n].dtype.str, "values": _exact(vertex[n])} for n in names},
           "faces": mesh.triangles.ravel().tolist(),
           "face": {n: {"type": v.dtype.str, "values": _exact(v)}
                    for n, v in mesh.face_attributes.items()}}
    try:
        import meshio
    except ImportError:
        return out
    if mesh.face_attributes:  # meshio 7 reads one value per binary face property and fails
        return out
    m = meshio.read(path, file_format="ply")
    out["meshio"] = {"points": _exact(m.points.astype(np.float32).ravel()),
                     "point_data": {n: _exact(v) for n, v in m.point_data.items()},
                     "triangles": m.cells_dict["triangle"].ravel().tolist()}
    return out


def _hand_built(path, face_hidden):
    """Two triangles written with struct from docs/ply-format.md."""
    header = ["ply", "format binary_little_endian 1.0",
              "comment isouq index_to_world 0.5 0 0 1 0 0.5 0 2 0 0 0.5 3 0 0 0 1",
              "element vertex 4", "property float x", "property float y", "property float z",
              "property float err_est", "property int edge_i", "property uchar edge_axis",
              "element face 2", "property list uchar int vertex_indices"]
    if face_hidden:
        header.append("property uchar hidden")
    body = b""
    for i, (x, y, z) in enumerate([(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)]):
        body += struct.pack("<ffffiB", x, y, z, 0.25 * i, -i, i % 3)
    for tri, hidden in (((0, 1, 2), 1), ((2, 1, 3), 0)):
        body += struct.pack("<B3i", 3, *tri) + (struct.pack("<B", hidden) if face_hidden else b"")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\nend_header\n").encode("ascii") + body)


def test_ply_io_reads_hand_built_bytes(tmp_path):
    path = str(tmp_path / "two.ply")
    _hand_built(path, face_hidden=True)
    mesh, _ = read(path)
    vertex, face = mesh.vertex_attributes, mesh.face_attributes
    assert mesh.comments[0].split()[:2] == ["isouq", "index_to_world"]
    assert mesh.positions[:, 0].tolist() == [0, 1, 0, 1] and vertex["err_est"].tolist() == [0, 0.25, 0.5, 0.75]
    assert vertex["edge_i"].tolist() == [0, -1, -2, -3] and vertex["edge_axis"].tolist() == [0, 1, 2, 0]
    assert mesh.triangles.tolist() == [[0, 1, 2], [2, 1, 3]] and face["hidden"].tolist() == [1, 0]


def test_meshio_agrees_with_ply_io(tmp_path):
    meshio = pytest.importorskip("meshio")
    path = str(tmp_path / "two.ply")
    _hand_built(path, face_hidden=False)
    mesh, _ = read(path)
    vertex = mesh.vertex_attributes
    m = meshio.read(path, file_format="ply")
    assert np.array_equal(m.points[:, 0], mesh.positions[:, 0])
    assert np.array_equal(m.points[:, 2], mesh.positions[:, 2])
    assert np.array_equal(m.point_data["err_est"], vertex["err_est"])
    assert np.array_equal(m.point_data["edge_i"], vertex["edge_i"])
    assert np.array_equal(m.point_data["edge_axis"].astype(np.uint8), vertex["edge_axis"])
    assert np.array_equal(m.cells_dict["triangle"], mesh.triangles)


def test_cli_mesh_parses_and_is_closed(tmp_path):
    cli = os.environ.get("ISOUQ_CLI", "")
    if not os.path.isfile(cli):
        pytest.skip("ISOUQ_CLI is not built")
    out, summary = str(tmp_path / "sphere.ply"), str(tmp_path / "s.json")
    subprocess.run([cli, "mesh", "field:sphere", "--resolution", "24", "-o", out,
                    "--summary", summary], check=True, capture_output=True)
    mesh, names = read(out)
    matrix = [c for c in mesh.comments if c.startswith("isouq index_to_world ")]
    assert len(matrix) == 1 and len(matrix[0].split()) == 18
    assert tuple(names[:3]) == ("x", "y", "z")
    faces = mesh.triangles
    assert faces.min() >= 0 and faces.max() < mesh.vertex_count
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert np.all(uses == 2), "a closed sphere has every edge in exactly two triangles"
    with open(summary) as f:
        s = json.load(f)
    assert s["vertices"] == mesh.vertex_count and s["triangles"] == len(faces)
    assert s["boundary_edges"] == 0 and s["components"] == 1


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--dump":
        json.dump(dump(sys.argv[2]), sys.stdout)
    else:
        sys.exit("usage: test_ply_format.py --dump FILE.ply")
