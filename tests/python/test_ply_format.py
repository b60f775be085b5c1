"""Independent readers of isouq's PLY files (docs/ply-format.md, SPEC §6).

`read_ply` is a numpy reader written from the format description only; meshio (Debian's
python3-meshio) is a second, third-party reader. The C++ test test_MeshIO runs this file as
`python3 test_ply_format.py --dump FILE` on files written by isouq::writePly and compares the
JSON it prints with the mesh it wrote. Under pytest the readers are checked against bytes
assembled here with struct, and against the isouq CLI's output when $ISOUQ_CLI exists.
"""
import json
import os
import struct
import subprocess
import sys

import numpy as np
import pytest

PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
             "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
             "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4",
             "float32": "f4", "float64": "f8"}


def read_ply(path):
    """Binary little-endian PLY with a `vertex` element of scalars and a `face` element whose
    lists all hold 3 indices. Returns (comments, vertex structured array, faces (M,3) int64,
    face structured array of the scalar face properties)."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0"
    comments, elements = [], []
    for line in lines[2:-1]:
        words = line.split()
        if words[0] == "comment":
            comments.append(line[len("comment "):])
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and words[1] == "list":
            elements[-1][2].append((words[4], ("<" + PLY_TYPES[words[2]], "<" + PLY_TYPES[words[3]])))
        else:
            assert words[0] == "property", line
            elements[-1][2].append((words[2], "<" + PLY_TYPES[words[1]]))
    assert [e[0] for e in elements] == ["vertex", "face"]
    offset = end
    (_, nv, vprops), (_, nf, fprops) = elements
    vdtype = np.dtype(vprops)
    vertex = np.frombuffer(data, vdtype, nv, offset)
    offset += nv * vdtype.itemsize
    fields = []
    for name, t in fprops:
        if isinstance(t, tuple):  # the index list: a count and 3 indices in every row
            fields += [("_count", t[0]), (name, t[1], (3,))]
        else:
            fields.append((name, t))
    fdtype = np.dtype(fields)
    face = np.frombuffer(data, fdtype, nf, offset)
    assert offset + nf * fdtype.itemsize == len(data), "trailing or missing bytes"
    assert np.all(face["_count"] == 3)
    faces = face["vertex_indices"].astype(np.int64)
    scalars = [n for n, t in fprops if not isinstance(t, tuple)]
    return comments, vertex, faces, face[scalars] if scalars else None


def _exact(array):
    """Values as JSON integers: float32 by their bit pattern, so NaN and -0 compare exactly."""
    if array.dtype.kind == "f":
        return array.astype("<f4").view("<u4").tolist()
    return array.astype(np.int64).tolist()


def dump(path):
    comments, vertex, faces, face = read_ply(path)
    out = {"comments": comments,
           "vertex": {n: {"type": vertex.dtype[n].str, "values": _exact(vertex[n])}
                      for n in vertex.dtype.names},
           "faces": faces.ravel().tolist(),
           "face": {} if face is None else
           {n: {"type": face.dtype[n].str, "values": _exact(face[n])} for n in face.dtype.names}}
    try:
        import meshio
    except ImportError:
        return out
    if face is not None:  # meshio 5.0 looks for face scalars after all the index lists
        return out
    m = meshio.read(path, file_format="ply")
    out["meshio"] = {"points": _exact(m.points.astype(np.float32).ravel()),
                     "point_data": {n: _exact(v.astype(vertex.dtype[n]))
                                    for n, v in m.point_data.items()},
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


def test_numpy_reader_on_hand_built_bytes(tmp_path):
    path = str(tmp_path / "two.ply")
    _hand_built(path, face_hidden=True)
    comments, vertex, faces, face = read_ply(path)
    assert comments[0].split()[:2] == ["isouq", "index_to_world"]
    assert vertex["x"].tolist() == [0, 1, 0, 1] and vertex["err_est"].tolist() == [0, 0.25, 0.5, 0.75]
    assert vertex["edge_i"].tolist() == [0, -1, -2, -3] and vertex["edge_axis"].tolist() == [0, 1, 2, 0]
    assert faces.tolist() == [[0, 1, 2], [2, 1, 3]] and face["hidden"].tolist() == [1, 0]


def test_meshio_agrees_with_numpy_reader(tmp_path):
    meshio = pytest.importorskip("meshio")
    path = str(tmp_path / "two.ply")
    _hand_built(path, face_hidden=False)
    _, vertex, faces, _ = read_ply(path)
    m = meshio.read(path, file_format="ply")
    assert np.array_equal(m.points[:, 0], vertex["x"]) and np.array_equal(m.points[:, 2], vertex["z"])
    assert np.array_equal(m.point_data["err_est"], vertex["err_est"])
    assert np.array_equal(m.point_data["edge_i"], vertex["edge_i"])
    assert np.array_equal(m.cells_dict["triangle"], faces)


def test_cli_mesh_parses_and_is_closed(tmp_path):
    cli = os.environ.get("ISOUQ_CLI", "")
    if not os.path.isfile(cli):
        pytest.skip("ISOUQ_CLI is not built")
    out, summary = str(tmp_path / "sphere.ply"), str(tmp_path / "s.json")
    subprocess.run([cli, "mesh", "field:sphere", "--resolution", "24", "-o", out,
                    "--summary", summary], check=True, capture_output=True)
    comments, vertex, faces, _ = read_ply(out)
    matrix = [c for c in comments if c.startswith("isouq index_to_world ")]
    assert len(matrix) == 1 and len(matrix[0].split()) == 18
    assert vertex.dtype.names[:3] == ("x", "y", "z")
    assert faces.min() >= 0 and faces.max() < len(vertex)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert np.all(uses == 2), "a closed sphere has every edge in exactly two triangles"
    with open(summary) as f:
        s = json.load(f)
    assert s["vertices"] == len(vertex) and s["triangles"] == len(faces)
    assert s["boundary_edges"] == 0 and s["components"] == 1


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--dump":
        json.dump(dump(sys.argv[2]), sys.stdout)
    else:
        sys.exit("usage: test_ply_format.py --dump FILE.ply")
