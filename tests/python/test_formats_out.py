"""Meshes out for other programs (SPEC §10 "Formats"; docs/vtp-format.md, docs/ply-format.md):
the .vtp read by VTK's own vtkXMLPolyDataReader (ParaView 5.11's VTK, python3-paraview) has every
column of the PLY with the same name, type and bits; `--color-by` colours reach Blender's own PLY
importer and follow matplotlib's viridis; meshio 7 (Debian) reads the uint8 columns and, from an
ascii PLY, the face columns of a hidden-feature mesh. The PLYs are read with ply_io, the
project's one Python PLY reader.
"""
import json
import shutil
import subprocess
import time
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402


def run(*args):
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def teardrop(isouq_cli, tmp_path_factory):
    """The SPEC §4 teardrop, standard and hidden-feature meshes, as PLY, ascii PLY and VTP."""
    d = tmp_path_factory.mktemp("formats")
    common = ["field:teardrop", "-n", 32, "--hidden-features", "--color-by", "err_est", "-q"]
    for out, hidden, extra in (("mc.ply", "hf.ply", []), ("mc.vtp", "hf.vtp", []),
                               ("mc_ascii.ply", "hf_ascii.ply", ["--ply-format", "ascii"])):
        proc = run(isouq_cli, "mesh", *common, "-o", d / out, "--hidden-out", d / hidden,
                   "--summary", d / (out + ".json"), *extra)
        assert proc.returncode == 0, proc.stderr
    return d


def read_vtp(path):
    vtk_xml = pytest.importorskip("vtkmodules.vtkIOXML")
    from vtkmodules.util.numpy_support import vtk_to_numpy
    reader = vtk_xml.vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    assert reader.GetErrorCode() == 0
    poly = reader.GetOutput()

    def arrays(data):
        return {data.GetArrayName(i): vtk_to_numpy(data.GetArray(i)) for i in range(data.GetNumberOfArrays())}

    polys = poly.GetPolys()
    offsets = vtk_to_numpy(polys.GetOffsetsArray())
    assert np.all(np.diff(offsets) == 3), "triangles only"
    field = poly.GetFieldData()
    comments = field.GetAbstractArray("comments")
    return {"points": vtk_to_numpy(poly.GetPoints().GetData()),
            "triangles": vtk_to_numpy(polys.GetConnectivityArray()).reshape(-1, 3),
            "point_data": arrays(poly.GetPointData()), "cell_data": arrays(poly.GetCellData()),
            "active_scalars": poly.GetPointData().GetScalars().GetName(),
            "index_to_world": vtk_to_numpy(field.GetArray("index_to_world")).reshape(4, 4),
            "isovalue": vtk_to_numpy(field.GetArray("isovalue"))[0],
            "comments": [comments.GetValue(i) for i in range(comments.GetNumberOfValues())]}


def same_bits(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("name", ["mc", "hf"])
def test_vtk_reads_every_ply_column_exactly(teardrop, name):
    ply = ply_io.read_ply(teardrop / f"{name}.ply")
    vtp = read_vtp(teardrop / f"{name}.vtp")
    assert same_bits(vtp["points"], ply.positions)
    assert np.array_equal(vtp["triangles"], ply.triangles)
    assert list(vtp["point_data"]) == list(ply.vertex_attributes)
    for column, values in ply.vertex_attributes.items():
        assert same_bits(vtp["point_data"][column], values), column
    assert list(vtp["cell_data"]) == list(ply.face_attributes)
    for column, values in ply.face_attributes.items():
        assert same_bits(vtp["cell_data"][column], values), column
    assert np.array_equal(vtp["index_to_world"], ply.index_to_world)
    assert vtp["isovalue"] == np.float32(ply.isovalue)
    assert vtp["comments"] == ply.comments
    assert vtp["active_scalars"] == "err_est"
    # Every SPEC §6 column the run computed is there, the hidden flags on both elements.
    for column in ("t_linear", "t_cubic", "t_weno", "edge_i", "edge_j", "edge_k", "edge_axis", "order",
                   "err_est", "err_bound", "d_lc", "d_lw", "d_cw", "max_var", "err_true_linear",
                   "red", "green", "blue", "quality"):
        assert column in vtp["point_data"], column
    if name == "hf":
        assert vtp["point_data"]["hidden"].dtype == np.uint8 and vtp["cell_data"]["hidden"].sum() > 0
        assert 255 in vtp["point_data"]["edge_axis"]


def test_vtp_summary_names_the_output(teardrop):
    summary = json.loads((teardrop / "mc.vtp.json").read_text())
    assert summary["output"].endswith("mc.vtp") and summary["hidden"]["output"].endswith("hf.vtp")
    assert summary == {**json.loads((teardrop / "mc.ply.json").read_text()),
                       "output": summary["output"], "hidden": summary["hidden"],
                       "timings_ms": summary["timings_ms"]}


def test_paraview_opens_the_vtp(teardrop):
    """ParaView's own reader (paraview.simple) sees the arrays by name."""
    simple = pytest.importorskip("paraview.simple")
    source = simple.XMLPolyDataReader(FileName=[str(teardrop / "hf.vtp")])
    source.UpdatePipeline()
    info = source.GetDataInformation()
    assert info.GetNumberOfPoints() == ply_io.read_ply(teardrop / "hf.ply").vertex_count
    names = set(source.PointData.keys())
    assert {"err_est", "edge_axis", "hidden", "red", "quality"} <= names
    assert "hidden" in source.CellData.keys()
    lo, hi = source.PointData["err_est"].GetRange()
    assert 0 <= lo < hi


def viridis_reference(t):
    matplotlib = pytest.importorskip("matplotlib")
    return matplotlib.colormaps["viridis"](np.clip(t, 0, 1))[:, :3] * 255


def test_color_by_follows_viridis_over_the_percentile_range(teardrop):
    mesh = ply_io.read_ply(teardrop / "hf.ply")
    v = mesh.vertex_attributes
    err = v["err_est"]
    assert same_bits(v["quality"], err)
    finite = np.isfinite(err)
    assert 0 < finite.sum() < len(err)  # refined vertices have no estimate
    lo, hi = np.percentile(err[finite], [2, 98])
    summary = json.loads((teardrop / "mc.ply.json").read_text())["color"]
    assert summary["measure"] == "err_est" and summary["colormap"] == "viridis"
    rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(float)
    assert v["red"].dtype == np.uint8
    expected = viridis_reference((err[finite] - lo) / (hi - lo))
    assert np.abs(rgb[finite] - expected).max() <= 6  # 17 anchors, within 6/255 (docs)
    assert np.all(rgb[~finite] == 128)


def test_color_range_and_colormap_flags(isouq_cli, tmp_path):
    out = tmp_path / "g.ply"
    proc = run(isouq_cli, "mesh", "field:sphere", "-n", 24, "-o", out, "--color-by", "err_bound",
               "--color-range", "0,1", "--colormap", "gray", "-q", "--summary", tmp_path / "s.json")
    assert proc.returncode == 0, proc.stderr
    v = ply_io.read_ply(out).vertex_attributes
    expected = np.round(255 * np.clip(v["err_bound"].astype(float), 0, 1))
    assert np.array_equal(v["red"], expected.astype(np.uint8))
    assert np.array_equal(v["red"], v["green"]) and np.array_equal(v["red"], v["blue"])
    color = json.loads((tmp_path / "s.json").read_text())["color"]
    assert color["range"] == [0, 1] and color["range_source"] == "given"


@pytest.mark.parametrize("args, words", [
    (["--color-by", "err_est", "--color-range", "1,0"], ["range", "LO must be below HI"]),
    (["--color-by", "nope"], ["--color-by", "nope"]),
    (["--colormap", "jet", "--color-by", "err_est"], ["--colormap", "jet"]),
    (["--linear-only", "--color-by", "err_est"], ["no per-vertex 'err_est'"]),
])
def test_bad_color_flags_give_one_line(isouq_cli, tmp_path, args, words):
    out = tmp_path / "x.ply"
    proc = run(isouq_cli, "mesh", "field:sphere", "-n", 16, "-o", out, *args, "-q")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("isouq: error:"), proc.stderr
    assert all(w in lines[0] for w in words), lines[0]
    assert not out.exists()


@pytest.mark.parametrize("args, words", [
    (["-o", "{d}/x.vtp", "--ply-format", "ascii"], ["--ply-format", ".vtp"]),
])
def test_ply_flags_on_a_vtp_output_are_refused(isouq_cli, tmp_path, args, words):
    proc = run(isouq_cli, "mesh", "field:sphere", "-n", 16, *[a.format(d=tmp_path) for a in args], "-q")
    assert proc.returncode == 2 and proc.stderr.startswith("isouq: error:")
    assert all(w in proc.stderr for w in words) and len(proc.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_write_nodes_refuse_other_extensions(isouq_cli, tmp_path):
    # Checked with the graph, before anything is read or meshed (the field below is 512^3).
    for writer, path, words in (("write_ply", "a.vtp", 'expected a path ending in .ply, got "a.vtp"'),
                                ("write_ply", "a.vdb", 'expected a path ending in .ply, got "a.vdb"'),
                                ("write_ply", "a", 'expected a path ending in .ply, got "a"'),
                                ("write_vtp", "a.ply", 'expected a path ending in .vtp, got "a.ply"')):
        graph = {"nodes": [{"id": "load", "type": "read_volume", "parms": {"input": "field:sphere", "resolution": 512}},
                           {"id": "mesh", "type": "mesh", "inputs": {"volume": "load"}},
                           {"id": "save", "type": writer, "inputs": {"mesh": "mesh"}, "parms": {"path": path}}]}
        (tmp_path / "g.json").write_text(json.dumps(graph))
        start = time.monotonic()
        proc = run(isouq_cli, "run", tmp_path / "g.json", "-d", tmp_path / "out", "-q")
        assert proc.returncode == 2 and words in proc.stderr and "node 'save'" in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and time.monotonic() - start < 5
        assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("out", ["x.vdb", "x.obj", "x", "x.ply.gz", "x\nb.stl"])
def test_mesh_outputs_other_than_ply_and_vtp_are_refused(isouq_cli, tmp_path, out):
    # -o picks the writer by the extension (SPEC §10): anything else would be PLY bytes under a
    # name that promises another format. The upper-case .PLY and .VTP are the same formats.
    proc = run(isouq_cli, "mesh", "field:sphere", "-n", 16, "-o", tmp_path / out, "-q")
    assert proc.returncode == 2 and proc.stderr.startswith("isouq: error: output ")
    assert "name it .ply" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert list(tmp_path.iterdir()) == []
    for good in ("x.PLY", "x.VTP"):
        assert run(isouq_cli, "mesh", "field:sphere", "-n", 16, "-o", tmp_path / good, "-q").returncode == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.PLY", "x.VTP"]


BLENDER_IMPORT = """
import bpy, json, sys
bpy.ops.import_mesh.ply(filepath=sys.argv[-2])
mesh = bpy.context.selected_objects[0].data
layers = mesh.vertex_colors
out = {"vertices": len(mesh.vertices), "layers": [l.name for l in layers],
       "corners": [p.vertices[:] for p in mesh.polygons][:200],
       "colors": [list(c.color[:3]) for c in layers[0].data][:600] if len(layers) else []}
open(sys.argv[-1], "w").write(json.dumps(out))
"""


def test_blenders_own_importer_finds_the_colours(teardrop, tmp_path):
    blender = shutil.which("blender")
    if not blender:
        pytest.skip("blender is not installed")
    ply = teardrop / "mc.ply"
    result = tmp_path / "blender.json"
    proc = run(blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python-expr", BLENDER_IMPORT,
               "--", ply, result)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(result.read_text())
    mesh = ply_io.read_ply(ply)
    v = mesh.vertex_attributes
    assert got["vertices"] == mesh.vertex_count and len(got["layers"]) == 1
    rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1) / 255.0
    corners = np.array(got["corners"]).ravel()
    colors = np.array(got["colors"])[:len(corners)]
    assert len(colors) == len(corners) > 0
    assert np.abs(colors - rgb[corners]).max() < 1.5 / 255  # byte colours, per corner
    assert np.ptp(colors[:, 0]) > 0.2  # a heat map, not one colour


def test_meshio_reads_the_uint8_columns_of_a_binary_ply(teardrop):
    meshio = pytest.importorskip("meshio")
    mesh = ply_io.read_ply(teardrop / "mc.ply")
    m = meshio.read(teardrop / "mc.ply", file_format="ply")  # no face columns: binary reads
    for column, values in mesh.vertex_attributes.items():
        assert same_bits(m.point_data[column], values), column
    assert m.point_data["edge_axis"].dtype == np.uint8 and m.point_data["red"].max() > 128


def test_meshio_reads_a_hidden_feature_mesh_from_ascii(teardrop):
    """meshio 7's binary reader takes one value per face property (docs/ply-format.md), its
    ascii reader reads them: --ply-format ascii gives meshio the face columns."""
    meshio = pytest.importorskip("meshio")
    binary = ply_io.read_ply(teardrop / "hf.ply")
    ascii_ply = ply_io.read_ply(teardrop / "hf_ascii.ply")
    m = meshio.read(teardrop / "hf_ascii.ply", file_format="ply")
    assert np.array_equal(m.points.astype(np.float32), binary.positions)
    assert np.array_equal(m.cells_dict["triangle"], binary.triangles)
    assert m.point_data["edge_axis"].dtype == np.uint8
    assert np.array_equal(m.point_data["edge_axis"], binary.vertex_attributes["edge_axis"])
    assert 255 in m.point_data["edge_axis"]  # refined vertices (SPEC §6)
    assert list(m.cell_data) == ["hidden"]
    assert np.array_equal(m.cell_data["hidden"][0], binary.face_attributes["hidden"])
    for column, values in binary.vertex_attributes.items():
        got = m.point_data[column]
        assert got.dtype == values.dtype and np.array_equal(got, values, equal_nan=values.dtype.kind == "f"), column
        assert same_bits(ascii_ply.vertex_attributes[column], values), column
    assert np.array_equal(ascii_ply.corners, binary.corners)


def test_saved_graph_reproduces_vtp_and_colours(isouq_cli, tmp_path):
    """SPEC §10 "One runner": the graph `isouq mesh` ran (write_vtp, color_map) run again gives
    the same bytes."""
    first, again = tmp_path / "first", tmp_path / "again"
    first.mkdir(), again.mkdir()
    args = ["mesh", "field:teardrop", "-n", 24, "--hidden-features", "--color-by", "d_lw", "--colormap",
            "coolwarm", "-o", "mc.vtp", "--hidden-out", "hf.ply", "--ply-format", "ascii"]
    proc = subprocess.run([isouq_cli, *map(str, args), "--save-graph", "g.json", "-q"], cwd=first,
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "--ply-format applies to .ply outputs" in proc.stderr
    args = args[:-2]
    proc = subprocess.run([isouq_cli, *map(str, args), "--save-graph", "g.json", "-q"], cwd=first,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    graph = json.loads((first / "g.json").read_text())
    types = [n["type"] for n in graph["nodes"]]
    assert types.count("color_map") == 2 and "write_vtp" in types and "write_ply" in types
    shutil.copy(first / "g.json", again / "g.json")
    proc = subprocess.run([isouq_cli, "run", "g.json", "-q"], cwd=again, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    for name in ("mc.vtp", "hf.ply"):
        assert (first / name).read_bytes() == (again / name).read_bytes(), name


def test_wrote_lines_stay_one_line_each(isouq_cli, tmp_path):
    # A newline in an output's name split its stdout line in two (hostile sweep, 7 Dec): the
    # names are escaped as error lines escape them; the files keep their real names.
    names = ["a\nb.ply", "s\x1b[31m.json", "hidden\r.ply"]
    proc = run(isouq_cli, "mesh", "field:tangle", "-n", 24, "--hidden-features", "-o", tmp_path / names[0],
               "--summary", tmp_path / names[1], "--hidden-out", tmp_path / names[2], "-q")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 3 and all(line.startswith("wrote ") for line in lines), lines
    assert "a\\nb.ply: " in lines[0] and "hidden\\r.ply: hidden features" in lines[1] and "s\\x1b[31m.json" in lines[2]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)
