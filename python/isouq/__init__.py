"""isouq: isosurfaces of sparse volumes with per-vertex uncertainty (SPEC §10 "Python").

    >>> import numpy as np, isouq
    >>> z, y, x = np.mgrid[-1:1:32j, -1:1:32j, -1:1:32j]
    >>> m = isouq.mesh((x * x + y * y + z * z).astype(np.float32), isovalue=0.5)
    >>> m.vertices.shape[1], m.columns["err_est"].dtype.name
    (3, 'float32')

`mesh()` builds the node graph that `isouq mesh` builds (houdini_style_nodes MeshGraph.h) and
runs it with the one runner, so a mesh equals the CLI's to the bit. Errors raise InputError (a
ValueError) with the CLI's one-line message; Ctrl-C cancels a long call (KeyboardInterrupt);
the GIL is released while meshing. See docs/python.md.
"""

import os

try:
    from . import _core
except ImportError as e:  # pragma: no cover - a source folder without the build
    raise ImportError(f"isouq: the native module _core is missing ({e}); build the project "
                      "and put build/python on PYTHONPATH (docs/python.md)") from e

InputError = _core.InputError
IoError = _core.IoError

__all__ = ["mesh", "load", "run", "nodes", "Mesh", "Volume", "InputError", "IoError"]


class Mesh:
    """A mesh the runner made. `vertices` (N x 3 float32), `triangles` (M x 3 uint32) and the
    arrays of `columns` (SPEC §6 vertex columns by name, from the column table of
    `nodes()["columns"]`) and `face_columns` are read-only views of the mesh's own storage (no
    copies); `summary` is the SPEC §8 summary dict (the CLI's --summary JSON), `hidden` the
    hidden-feature mesh or None."""

    def __init__(self, handle, summary=None, hidden=None):
        self._handle = handle
        self.vertices = handle.vertices
        self.triangles = handle.triangles
        self.columns = handle.columns
        self.face_columns = handle.face_columns
        self.summary = summary
        self.hidden = hidden

    @property
    def isovalue(self):
        return self._handle.isovalue

    @property
    def method(self):
        """Method that placed the vertices ("weno", "linear", ...)."""
        return self._handle.method

    @property
    def index_to_world(self):
        """The grid's index-to-world affine, 4 x 4 float64 (world = M (i, j, k, 1)): with the
        edge_* and t_* columns it places any method's crossing (SPEC §6, C3)."""
        import numpy as np
        return np.array(self._handle.info["index_to_world"], np.float64).reshape(4, 4)

    def edges(self):
        """(edges, corner_edges): the unique undirected edges, E x 2 uint32 (lower vertex
        first, sorted), and each corner's edge, 3M uint32 (corner 3t+c runs from triangles[t, c]
        to triangles[t, (c+1) % 3]), for hosts that store edges (Blender's live mode). Computed
        in C++ with the GIL released; the same for any thread count."""
        return self._handle.edges()

    def write(self, path, format="binary"):
        """Writes the mesh as the CLI does (SPEC §6 PLY, or VTK XML PolyData for a .vtp path),
        atomically: a failed write leaves no file and never clobbers an existing one.
        format: "binary" (little-endian) or "ascii", for PLY."""
        self._handle.write(os.fsdecode(path), format)

    def __repr__(self):
        return (f"<isouq.Mesh {len(self.vertices)} vertices, {len(self.triangles)} triangles, "
                f"isovalue {self.isovalue:g}, {self.method}>")


class Volume:
    """A volume loaded once (read_volume node) to mesh many times, e.g. at many isovalues
    (the Blender add-on's live mode). Dense sources are kept with keep="non_constant" by
    default, so every isovalue gives the mesh of the full data. `isovalue` is the default
    the loader chose (given, level set 0, SPEC §5, Otsu), with `isovalue_source`."""

    def __init__(self, handle, warnings):
        self._handle = handle
        self.warnings = list(warnings)

    isovalue = property(lambda self: self._handle.isovalue)
    isovalue_source = property(lambda self: self._handle.isovalue_source)
    description = property(lambda self: self._handle.description)

    def __repr__(self):
        return f"<isouq.Volume {self.description}>"


def nodes():
    """The node declarations, column and method tables (`isouq nodes --json`) as a dict."""
    import json
    return json.loads(_core.nodes_json())


def _is_pyopenvdb_grid(source):
    return type(source).__module__ == "pyopenvdb"


def _is_path(source):
    return isinstance(source, (str, bytes, os.PathLike))


def _register(source, spacing, origin):
    """A `memory:N` registration for an in-memory source (held while the graph runs), or
    None for an INPUT string."""
    if _is_path(source):
        if tuple(_vec3(origin, "origin")) != (0, 0, 0):
            raise InputError("origin is for numpy arrays; a file or field keeps its own placement")
        return None
    if isinstance(source, Volume) or _is_pyopenvdb_grid(source):
        if tuple(_vec3(spacing, "spacing")) != (1, 1, 1) or tuple(_vec3(origin, "origin")) != (0, 0, 0):
            raise InputError("spacing and origin are for numpy arrays and .raw paths; a grid or Volume keeps "
                             "its own transform")
    if isinstance(source, Volume):
        return _core.register_volume(source._handle, source)
    if _is_pyopenvdb_grid(source):
        if not _core.has_pyopenvdb:
            raise InputError("this isouq was built without pyopenvdb support (Boost.Python and "
                             "openvdb/python/pyopenvdb.h were not found)")
        return _core.register_pyopenvdb(source)
    import numpy as np
    if isinstance(source, np.ma.MaskedArray):
        raise InputError("a masked array's mask would be dropped: fill it first, e.g. a.filled(np.nan) or "
                         "a.filled(a.min())")
    array = np.asarray(source)
    if array.dtype == np.float16:
        array = array.astype(np.float32)  # exact; the reader takes float32/64 and integers
    elif array.dtype.byteorder == ">" or (array.dtype.byteorder == "<" and not _little()):
        array = array.astype(array.dtype.newbyteorder("="))
    if array.dtype.kind not in "biuf":
        raise InputError(f"arrays of {array.dtype} are not volumes (use an integer or "
                         "float32/float64 dtype)")
    return _core.register_array(array, _vec3(spacing, "spacing"), _vec3(origin, "origin"))


def _little():
    import sys
    return sys.byteorder == "little"


def _finite(value, name):
    import math
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return number


def _vec3(value, name):
    if isinstance(value, (str, bytes)):
        raise InputError(f"{name} must be three numbers, got {value!r}")
    try:
        values = [_finite(v, name) for v in value]
    except TypeError:
        raise InputError(f"{name} must be three numbers, got {value!r}") from None
    if len(values) != 3:
        raise InputError(f"{name} must be three numbers, got {len(values)}")
    return values


def _read_parms(source, registration, isovalue, grid, resolution, domain, spacing, keep=None):
    """The read_volume parameters, as `isouq mesh INPUT --isovalue ... --grid ...` sets them."""
    if registration is None:
        read = {"input": os.fsdecode(source)}
        spacing = _vec3(spacing, "spacing")
        if tuple(spacing) != (1, 1, 1):
            read["spacing"] = spacing
    else:
        read = {"input": registration.input}
        if resolution is not None or domain is not None:
            raise InputError("resolution and domain are for field: and formula: inputs, not for arrays, "
                             "grids or Volumes")
    if isovalue is not None:
        read["isovalue"] = _finite(isovalue, "isovalue")
    if grid is not None:
        read["grid"] = grid
    if resolution is not None:
        read["resolution"] = int(resolution)
    if domain is not None:
        if isinstance(domain, (str, bytes)):
            raise InputError(f"domain must be two numbers, got {domain!r}")
        read["domain"] = [_finite(v, "domain") for v in domain]
    if keep is not None:
        read["keep"] = keep
    return read


def mesh(source, isovalue=None, method="weno", linear_only=False, hidden_features=False,
         subdivisions=4, hidden_filter=True, threads=0, spacing=(1, 1, 1), origin=(0, 0, 0),
         grid=None, resolution=None, domain=None, summary=True, high_order=True):
    """Meshes `source` as `isouq mesh` does and returns a Mesh.

    source: a 3D numpy array a[z, y, x] of any integer or float dtype, sparsified like a
        .raw scan (any strides: views and Fortran-ordered arrays are read in place; index
        a[z, y, x] is voxel (x, y, z)); a pyopenvdb.FloatGrid, shared as is; an isouq.Volume
        (load()); or an INPUT string: FILE.vdb, NAME_XxYxZ_DTYPE.raw, a scan with a header,
        field:NAME, formula:EXPR.
    isovalue: None for the CLI's default (0 for level sets, SPEC §5's for fields, else Otsu).
    spacing, origin: world = origin + spacing * (x, y, z) for arrays (spacing also for .raw
        and TIFF paths, as --spacing).
    grid, resolution, domain: as --grid, --resolution, --domain.
    threads: worker threads, 0 for all cores.
    summary: False skips the summary node (topology and statistics; Mesh.summary is None) for
        interactive re-meshing; the mesh is the same.
    high_order: False (with method="linear") computes the linear crossings with err_est and
        err_bound only (the mesh node's high_order): the same triangles, positions and those
        columns as the full pass, in less than half its time.

        >>> m = isouq.mesh("field:tangle", resolution=32)
        >>> m.summary["method"], m.hidden is None
        ('weno', True)
    """
    if not isinstance(method, str):
        raise InputError(f"method must be a string such as 'weno' or 'linear', got {method!r}")
    registration = _register(source, spacing, origin)
    request = {
        "read": _read_parms(source, registration, isovalue, grid, resolution, domain, spacing),
        "mesh": {"method": method, "linear_only": bool(linear_only), "high_order": bool(high_order)},
        "hidden": {"subdivisions": int(subdivisions), "filter": bool(hidden_filter)},
        "hidden_features": bool(hidden_features),
    }
    graph = _core.mesh_graph(request)
    summary_node = next(n for n in graph["nodes"] if n["type"] == "summary")
    standard = summary_node["inputs"]["mesh"]
    hidden = summary_node["inputs"].get("hidden")
    keep = [standard] + ([hidden] if hidden else [])
    if not summary:  # nothing else reads it: the graph has no writers
        graph["nodes"].remove(summary_node)
    result = _core.run(graph, keep, int(threads))
    summary = result["outputs"]["summary"]["summary"] if summary else None
    hidden_mesh = None
    if hidden:
        hidden_mesh = Mesh(result["meshes"][hidden], summary.get("hidden") if summary else None)
    del registration  # the graph has run: the array or grid is no longer read
    return Mesh(result["meshes"][standard], summary, hidden_mesh)


def load(source, isovalue=None, keep="non_constant", threads=0, spacing=(1, 1, 1),
         origin=(0, 0, 0), grid=None, resolution=None, domain=None):
    """Loads `source` (as mesh() takes it) once with the read_volume node, for many mesh()
    calls: `mesh(volume, isovalue=k)` then shares the loaded grid. keep: which 8^3 blocks of
    a dense source stay ("non_constant": every isovalue meshes as the full data; "crossing":
    only near `isovalue`, smaller). field: and formula: inputs lose their exact field this
    way (no err_true_* columns); mesh the INPUT string for those."""
    registration = _register(source, spacing, origin)
    parms = _read_parms(source, registration, isovalue, grid, resolution, domain, spacing, keep)
    handle, warnings = _core.load(parms, int(threads))
    return Volume(handle, warnings)


class RunResult:
    """What run() gives: `written` files, `warnings` (one line each), `outputs` (each node's
    json outputs by node id, e.g. outputs["summary"]["summary"]) and `meshes` (Mesh by node id,
    for the ids given in keep)."""

    def __init__(self, result):
        self.written = result["written"]
        self.warnings = result["warnings"]
        self.outputs = result["outputs"]
        self.meshes = {k: Mesh(v) for k, v in result["meshes"].items()}

    def __repr__(self):
        return f"<isouq.RunResult written={self.written} meshes={sorted(self.meshes)}>"


def run(graph, keep=(), threads=0, output_dir=""):
    """Runs a node graph (a dict, or the path of a JSON file) as `isouq run GRAPH.json` does:
    every node cooks, then the files are written together (none on failure).
    keep: ids of nodes whose mesh to return in RunResult.meshes."""
    if not isinstance(graph, dict):
        graph = os.fsdecode(graph)
    return RunResult(_core.run(graph, list(keep), int(threads), os.fspath(output_dir)))
