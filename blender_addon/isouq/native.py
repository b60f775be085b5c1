# The isouq Python module inside Blender (SPEC §10 "Python"; docs/python.md, docs/blender.md),
# without bpy. The add-on package is itself called `isouq`, so inside Blender `import isouq`
# is the add-on; the module (package isouq with its native isouq._core) is loaded from its file
# under the name `isouq_native` instead. Found next to the isouq binary (an install's
# PREFIX/lib/python3/dist-packages, a build's build/python), in $ISOUQ_PYTHON_DIR, or in the
# repo's build*/python. $ISOUQ_NATIVE=0 turns it off (the add-on then runs the CLI).

import importlib.util
import os
import sys

import numpy as np

from . import ply_io

NAME = "isouq_native"
ENV_DIR = "ISOUQ_PYTHON_DIR"
ENV_SWITCH = "ISOUQ_NATIVE"

_loaded = {}   # "module" / "error"


def candidate_dirs(binary=None):
    """Folders that may hold the package folder isouq/ (with __init__.py and _core*.so)."""
    dirs = []
    if os.environ.get(ENV_DIR):
        dirs.append(os.environ[ENV_DIR])
    if binary:
        here = os.path.dirname(os.path.realpath(binary))
        dirs += [os.path.join(here, "..", "python"),                               # build tree
                 os.path.join(here, "..", "lib", "python3", "dist-packages")]       # install
    from . import pipeline
    dirs += [os.path.join(os.path.dirname(os.path.dirname(b)), "python") for b in pipeline.repo_binaries()]
    dirs += ["/usr/local/lib/python3/dist-packages", "/usr/lib/python3/dist-packages"]
    return [os.path.normpath(d) for d in dirs]


def _is_module_dir(folder):
    package = os.path.join(folder, "isouq")
    if not os.path.isfile(os.path.join(package, "__init__.py")):
        return False
    return any(f.startswith("_core") and f.endswith(".so") for f in os.listdir(package))


def load(binary=None):
    """The module (isouq_native), or None when it is off, not found or does not import; then
    error() says why. Loaded once per Blender session."""
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return None
    if "module" in _loaded or "error" in _loaded:
        return _loaded.get("module")
    tried = []
    for folder in candidate_dirs(binary):
        if folder in tried or not _is_module_dir(folder):
            tried.append(folder)
            continue
        package = os.path.join(folder, "isouq")
        spec = importlib.util.spec_from_file_location(
            NAME, os.path.join(package, "__init__.py"), submodule_search_locations=[package])
        module = importlib.util.module_from_spec(spec)
        sys.modules[NAME] = module
        try:
            spec.loader.exec_module(module)
        except ImportError as e:
            del sys.modules[NAME]
            _loaded["error"] = f"{package}: {e}"
            return None
        _loaded["module"] = module
        return module
    _loaded["error"] = "no isouq Python module in " + ", ".join(dict.fromkeys(tried))
    return None


def vocabulary():
    """The column and method tables (pipeline.Vocabulary) of the loaded module's nodes(), the
    same tables `isouq nodes --json` prints, read without a subprocess; None without a module."""
    module = load()
    if module is None:
        return None
    if "vocabulary" not in _loaded:
        from . import pipeline
        doc = module.nodes()
        _loaded["vocabulary"] = pipeline.Vocabulary(tuple(doc["columns"]), tuple(doc["methods"]))
        _loaded["methods"] = next(p["menu"] for n in doc["nodes"] if n["type"] == "mesh"
                                  for p in n["parms"] if p["token"] == "method")
    return _loaded["vocabulary"]


def method_menu():
    """The mesh node's method tokens, or None without a module."""
    return _loaded["methods"] if vocabulary() is not None else None


def error():
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return f"${ENV_SWITCH}=0"
    return _loaded.get("error", "")


def to_isouq_mesh(mesh, edges=None):
    """A module Mesh as the ply_io.IsouqMesh the add-on builds objects from (views.import_mesh,
    attributes.fill_mesh): the same arrays the PLY of that mesh holds, without the file, and
    the edge table (`mesh.edges()`, or `edges` when the caller made it already; (None, None):
    none, Blender computes them if it needs to; a function: it gives them when fill_mesh needs
    them, live mode's table made meanwhile on its thread) so Blender computes none. Indices stay
    uint32, the type Blender copies at once (attributes.fill_mesh)."""
    triangles = np.asarray(mesh.triangles)
    count = len(triangles)
    if callable(edges):
        edge_table, corner_edges = edges, None
    else:
        edge_table, corner_edges = mesh.edges() if edges is None else edges
    return ply_io.IsouqMesh(
        positions=mesh.vertices,
        loop_start=np.arange(0, 3 * count, 3, dtype=np.uint32),
        loop_total=np.full(count, 3, np.uint32),
        corners=triangles.reshape(-1),
        vertex_attributes=dict(mesh.columns),
        face_attributes=dict(mesh.face_columns),
        index_to_world=mesh.index_to_world,
        isovalue=float(mesh.isovalue),
        method=mesh.method,
        edges=edge_table,
        corner_edges=corner_edges)
