"""Helpers for the node-layer tests: read the vertex element of an isouq PLY (binary little
endian, docs/ply-format.md) with numpy, and its index-to-world map. (meshio cannot read faces
with a `hidden` property, so this reads only what the tests need.)"""
import numpy as np

TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "int": "<i4", "int32": "<i4",
         "uchar": "u1", "uint8": "u1", "uint": "<u4", "short": "<i2", "ushort": "<u2", "char": "i1"}


def read_ply(path):
    """Returns (points float64 Nx3, {name: 1-D array} of the other vertex properties, 4x4 M)."""
    with open(path, "rb") as f:
        lines = []
        while True:
            line = f.readline().decode("ascii").strip()
            lines.append(line)
            if line == "end_header":
                break
        assert "format binary_little_endian 1.0" in lines
        matrix, count, props, element = np.eye(4), 0, [], None
        for line in lines:
            words = line.split()
            if line.startswith("comment isouq index_to_world"):
                matrix = np.array([float(x) for x in words[3:]]).reshape(4, 4)
            elif words[:1] == ["element"]:
                element = words[1]
                if element == "vertex":
                    count = int(words[2])
            elif words[:1] == ["property"] and element == "vertex":
                props.append((words[2], TYPES[words[1]]))
        vertices = np.frombuffer(f.read(count * np.dtype(props).itemsize), dtype=np.dtype(props), count=count)
    points = np.stack([vertices[c] for c in "xyz"], axis=1).astype(np.float64)
    data = {name: vertices[name] for name, _ in props if name not in "xyz"}
    return points, data, matrix


def crossing(data, matrix, method):
    """World position of every vertex at method's crossing: M (edge + t e_axis, 1)."""
    t = data["t_" + method.replace("-", "_")].astype(np.float64)
    idx = np.stack([data["edge_i"], data["edge_j"], data["edge_k"]], axis=1).astype(np.float64)
    idx[np.arange(len(t)), data["edge_axis"].astype(int)] += t
    return idx @ matrix[:3, :3].T + matrix[:3, 3]
