# isouq PLY reader (SPEC §6): numpy only, no bpy, so it runs and is tested outside Blender too.
#
# Blender's own PLY importer drops custom properties; this reader keeps every vertex and face
# property as a named numpy column with the file's dtype. Binary little- and big-endian, and
# ascii (isouq writes binary little-endian, or ascii with --ply-format ascii).

import os
from dataclasses import dataclass, field

import numpy as np

_SCALAR_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_MAX_HEADER_BYTES = 1 << 20


class PlyError(ValueError):
    """The file is not a readable isouq PLY; the message says why in one line."""


@dataclass
class Property:
    name: str
    dtype: str                 # numpy type code without byte order, e.g. "f4"
    count_dtype: str = ""      # list properties only: the type of the count


@dataclass
class Element:
    name: str
    count: int
    properties: list = field(default_factory=list)


@dataclass
class IsouqMesh:
    """Positions, polygons and every named property of an isouq PLY."""
    positions: np.ndarray                 # (N, 3) float32, world units
    loop_start: np.ndarray                # (F,) int32 into `corners`
    loop_total: np.ndarray                # (F,) int32, 3 for isouq's triangles
    corners: np.ndarray                   # (sum(loop_total),) int32 vertex indices
    vertex_attributes: dict               # name -> (N,) array with the file's dtype
    face_attributes: dict                 # name -> (F,) array with the file's dtype
    index_to_world: np.ndarray = None     # (4, 4) float64 from `comment isouq index_to_world`
    isovalue: float = None
    method: str = None
    comments: list = field(default_factory=list)
    edges: np.ndarray = None              # (E, 2) unique edges and (sum(loop_total),) each
    corner_edges: np.ndarray = None       # corner's edge, when known (the module's Mesh.edges());
                                          # edges may be a function giving both (attributes.fill_mesh)

    @property
    def vertex_count(self):
        return len(self.positions)

    @property
    def face_count(self):
        return len(self.loop_total)

    @property
    def triangles(self):
        """(F, 3) int32 corners. @raise PlyError unless every face is a triangle (isouq's case)."""
        if np.any(self.loop_total != 3):
            raise PlyError("not a triangle mesh: a face has more than 3 corners")
        return self.corners.reshape(-1, 3)


def parse_header(data):
    """Returns (format, elements, comments, header_length) of PLY bytes `data`."""
    if not data.startswith(b"ply\n") and not data.startswith(b"ply\r\n"):
        raise PlyError("not a PLY file (no 'ply' magic line)")
    end = data.find(b"end_header", 0, _MAX_HEADER_BYTES)
    if end < 0:
        raise PlyError("PLY header has no 'end_header' line")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise PlyError("PLY header is truncated after 'end_header'")
    text = data[:end].decode("ascii", errors="replace")
    fmt, elements, comments = None, [], []
    for line in text.splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        key = words[0]
        if key == "format":
            if len(words) < 2:
                raise PlyError("PLY format line is incomplete")
            fmt = words[1]
        elif key in ("comment", "obj_info"):
            comments.append(line.partition(" ")[2].strip())
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"bad PLY element line: {line!r}")
            elements.append(Element(words[1], int(words[2])))
        elif key == "property":
            if not elements:
                raise PlyError("PLY property before any element")
            elements[-1].properties.append(_parse_property(words, line))
        else:
            raise PlyError(f"unknown PLY header line: {line!r}")
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise PlyError(f"PLY format {fmt!r} is not supported: isouq writes binary_little_endian or ascii")
    return fmt, elements, comments, newline + 1


def _parse_property(words, line):
    if len(words) == 5 and words[1] == "list":
        if words[2] not in _SCALAR_TYPES or words[3] not in _SCALAR_TYPES:
            raise PlyError(f"unknown PLY type in: {line!r}")
        return Property(words[4], _SCALAR_TYPES[words[3]], _SCALAR_TYPES[words[2]])
    if len(words) == 3 and words[1] in _SCALAR_TYPES:
        return Property(words[2], _SCALAR_TYPES[words[1]])
    raise PlyError(f"bad PLY property line: {line!r}")


def _read_scalar_element(data, offset, element, order):
    dtype = np.dtype([(p.name, order + p.dtype) for p in element.properties])
    size = dtype.itemsize * element.count
    if offset + size > len(data):
        raise PlyError(f"PLY file is truncated inside element '{element.name}'")
    return np.frombuffer(data, dtype=dtype, count=element.count, offset=offset), offset + size


def _read_face_element(data, offset, element, order):
    """Faces: one list property `vertex_indices` (first) and scalar properties after it.
    Fast path when every face is a triangle (isouq's case); a per-face walk otherwise."""
    lists = [p for p in element.properties if p.count_dtype]
    if len(lists) != 1 or element.properties[0] is not lists[0]:
        raise PlyError("face element must start with its only list property vertex_indices")
    index = lists[0]
    if index.name not in ("vertex_indices", "vertex_index"):
        raise PlyError(f"face list property is '{index.name}', expected vertex_indices")
    scalars = [(p.name, order + p.dtype) for p in element.properties[1:]]
    count_t, index_t = np.dtype(order + index.count_dtype), np.dtype(order + index.dtype)
    tri = np.dtype([("n", count_t), ("v", index_t, (3,))] + scalars)
    n = element.count
    if n == 0:
        extra = np.zeros(0, dtype=np.dtype(scalars)) if scalars else None
        return (np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.int32), extra), offset
    if offset + tri.itemsize * n <= len(data):
        rows = np.frombuffer(data, dtype=tri, count=n, offset=offset)
        if np.all(rows["n"] == 3):
            starts = np.arange(0, 3 * n, 3, dtype=np.int32)
            extra = rows[[s[0] for s in scalars]] if scalars else None
            return (starts, np.full(n, 3, np.int32), rows["v"].astype(np.int32).ravel(),
                    extra), offset + tri.itemsize * n
    return _walk_faces(data, offset, n, count_t, index_t, np.dtype(scalars) if scalars else None)


def _walk_faces(data, offset, n, count_t, index_t, scalar_t):
    totals = np.empty(n, np.int32)
    corners, extras = [], []
    for f in range(n):
        if offset + count_t.itemsize > len(data):
            raise PlyError("PLY file is truncated inside element 'face'")
        k = int(np.frombuffer(data, count_t, 1, offset)[0])
        offset += count_t.itemsize
        if k < 3 or offset + k * index_t.itemsize > len(data):
            raise PlyError("PLY file is truncated or has a face with fewer than 3 corners")
        corners.append(np.frombuffer(data, index_t, k, offset))
        offset += k * index_t.itemsize
        totals[f] = k
        if scalar_t is not None:
            if offset + scalar_t.itemsize > len(data):
                raise PlyError("PLY file is truncated inside element 'face'")
            extras.append(np.frombuffer(data, scalar_t, 1, offset))
            offset += scalar_t.itemsize
    starts = np.zeros(n, np.int32)
    np.cumsum(totals[:-1], out=starts[1:])
    extra = np.concatenate(extras) if extras else None
    return (starts, totals, np.concatenate(corners).astype(np.int32), extra), offset


def _ascii_columns(words, element, columns):
    """(count, len(columns)) array of byte words -> structured array with the properties' dtypes."""
    rows = np.zeros(element.count, dtype=np.dtype([(p.name, p.dtype) for p in columns]))
    for c, p in enumerate(columns):
        text = words[:, c]
        try:
            if np.dtype(p.dtype).kind == "f":
                rows[p.name] = text.astype(np.float64)
            else:
                values = text.astype(np.int64)
                info = np.iinfo(p.dtype)
                if values.size and (values.min() < info.min or values.max() > info.max):
                    raise PlyError(f"PLY value of '{p.name}' out of range for {p.dtype}")
                rows[p.name] = values
        except ValueError:
            raise PlyError(f"PLY ascii value of '{p.name}' is not a number") from None
    return rows


def _ascii_words(tokens, pos, n, element):
    if pos + n > len(tokens):
        raise PlyError(f"PLY file is truncated inside element '{element.name}'")
    return np.array(tokens[pos:pos + n], dtype=bytes)


def _read_ascii_element(tokens, pos, element):
    """A scalar element from whitespace-separated words: (rows, next position)."""
    width = len(element.properties)
    words = _ascii_words(tokens, pos, element.count * width, element).reshape(element.count, width)
    return _ascii_columns(words, element, element.properties), pos + element.count * width


def _read_ascii_faces(tokens, pos, element):
    """Faces from words: the list `vertex_indices` first, then scalars; triangles only."""
    lists = [p for p in element.properties if p.count_dtype]
    if len(lists) != 1 or element.properties[0] is not lists[0]:
        raise PlyError("face element must start with its only list property vertex_indices")
    scalars = element.properties[1:]
    width = 4 + len(scalars)
    words = _ascii_words(tokens, pos, element.count * width, element).reshape(element.count, width)
    if element.count and np.any(words[:, 0] != b"3"):
        raise PlyError("PLY ascii faces must be triangles")
    try:
        corners = words[:, 1:4].astype(np.int64).ravel()
    except ValueError:
        raise PlyError("PLY ascii face index is not a number") from None
    n = element.count
    extra = _ascii_columns(words[:, 4:], element, scalars) if scalars else None
    return (np.arange(0, 3 * n, 3, dtype=np.int32), np.full(n, 3, np.int32),
            corners.astype(np.int32), extra), pos + n * width


def _parse_isouq_comments(comments):
    """`comment isouq index_to_world m00 .. m33`, `comment isouq isovalue K`,
    `comment isouq method NAME` (lead's header contract)."""
    matrix, isovalue, method = None, None, None
    for c in comments:
        words = c.split()
        if len(words) < 2 or words[0] != "isouq":
            continue
        try:
            if words[1] == "index_to_world":
                if len(words) != 18:
                    raise PlyError("'comment isouq index_to_world' needs 16 numbers")
                matrix = np.array([float(w) for w in words[2:]], np.float64).reshape(4, 4)
            elif words[1] == "isovalue" and len(words) == 3:
                isovalue = float(words[2])
            elif words[1] == "method" and len(words) == 3:
                method = words[2]
        except ValueError as e:
            raise PlyError(f"bad isouq header comment {c!r}: {e}") from None
    if matrix is not None and not np.all(np.isfinite(matrix)):
        raise PlyError("'comment isouq index_to_world' has non-finite numbers")
    return matrix, isovalue, method


def read_ply_bytes(data, require_isouq=True):
    """Parses PLY bytes. With `require_isouq`, refuses files without isouq's header comment or
    edge provenance (e.g. another program's PLY), so the caller never builds a half-isouq object."""
    fmt, elements, comments, offset = parse_header(data)
    order = "<" if fmt == "binary_little_endian" else ">"
    # ascii: `offset` counts words of the body instead of bytes.
    tokens = None
    if fmt == "ascii":
        tokens, offset = data[offset:].split(), 0
    vertex_rows, faces = None, None
    for element in elements:
        if element.name == "face":
            faces, offset = (_read_ascii_faces(tokens, offset, element) if tokens is not None
                             else _read_face_element(data, offset, element, order))
        elif any(p.count_dtype for p in element.properties):
            raise PlyError(f"element '{element.name}' with list properties is not supported")
        else:
            rows, offset = (_read_ascii_element(tokens, offset, element) if tokens is not None
                            else _read_scalar_element(data, offset, element, order))
            if element.name == "vertex":
                vertex_rows = rows
    if vertex_rows is None:
        raise PlyError("PLY file has no vertex element")
    names = vertex_rows.dtype.names
    if not all(axis in names for axis in "xyz"):
        raise PlyError("PLY vertex element lacks x, y or z")
    matrix, isovalue, method = _parse_isouq_comments(comments)
    if require_isouq and matrix is None and "edge_axis" not in names:
        raise PlyError("not an isouq mesh: no 'comment isouq index_to_world' line and no "
                       "edge_axis property (use File > Import > Stanford PLY for other files)")
    if faces is None:
        faces = (np.zeros(0, np.int32),) * 3 + (None,)
    starts, totals, corners, face_rows = faces
    n = len(vertex_rows)
    if len(corners) and (corners.min() < 0 or corners.max() >= n):
        raise PlyError(f"face vertex index out of range (vertex count {n})")
    positions = np.stack([vertex_rows[a].astype(np.float32) for a in "xyz"], axis=1)
    vattrs = {k: np.ascontiguousarray(vertex_rows[k]).astype(vertex_rows.dtype[k].newbyteorder("="))
              for k in names if k not in ("x", "y", "z")}
    fattrs = {}
    if face_rows is not None:
        fattrs = {k: np.ascontiguousarray(face_rows[k]).astype(face_rows.dtype[k].newbyteorder("="))
                  for k in face_rows.dtype.names}
    return IsouqMesh(positions, starts, totals, corners, vattrs, fattrs, matrix, isovalue,
                     method, comments)


def read_ply(path, require_isouq=True):
    """Reads an isouq PLY file. @raise PlyError with a one-line reason, OSError if unreadable."""
    if os.path.getsize(path) > (1 << 34):
        raise PlyError("PLY file larger than 16 GiB")
    with open(path, "rb") as f:
        data = f.read()
    return read_ply_bytes(data, require_isouq)

