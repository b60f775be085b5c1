# Import: every SPEC §6 attribute arrives with the file's values, on the right domain and type,
# checked against the arrays the independent numpy writer was given and against meshio.
# Bad files give an error report and create nothing.

import os

import bpy
import numpy as np
import pytest

import plyfixture
from conftest import scene_delta, snapshot

TYPES = {"f4": "FLOAT", "i4": "INT", "u1": "INT"}


def blender_values(me, name):
    attr = me.attributes[name]
    out = np.empty(len(attr.data), np.float32 if attr.data_type == "FLOAT" else np.int32)
    attr.data.foreach_get("value", out)
    return attr, out


def import_active(path):
    assert bpy.ops.isouq.import_mesh(filepath=path) == {"FINISHED"}
    return bpy.context.active_object


def test_every_attribute_equals_the_written_arrays(sphere_ply):
    path, (positions, faces, attrs, fattrs, comments) = sphere_ply
    obj = import_active(path)
    me = obj.data
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    assert np.array_equal(co.reshape(-1, 3), positions)
    corners = np.empty(3 * len(me.polygons), np.int32)
    me.polygons.foreach_get("vertices", corners)
    assert np.array_equal(corners.reshape(-1, 3), faces)
    for domain, table in (("POINT", attrs), ("FACE", fattrs)):
        for name, values in table.items():
            if domain == "FACE" and name in attrs:
                name += "_face"          # Blender names are unique across domains
            attr, got = blender_values(me, name)
            assert attr.domain == domain, name
            assert attr.data_type == TYPES[values.dtype.str[1:]], name
            assert np.array_equal(got, values.astype(got.dtype)), name
    assert np.allclose(np.array(me["isouq_index_to_world"]).reshape(4, 4),
                       plyfixture.index_to_world(), rtol=0, atol=1e-15)
    assert me["isouq_method"] == "linear" and me["isouq_isovalue"] == 0.0


def test_vertex_attributes_equal_meshio(tmp_path):
    """meshio 5 (Debian) is an independent PLY reader; it mis-reads face properties that follow
    the index list, so this file has vertex properties only."""
    meshio = pytest.importorskip("meshio")
    positions, faces, attrs, _, comments = plyfixture.sphere_fixture(n=12, radius=4.0)
    path = str(tmp_path / "vertex_only.ply")
    plyfixture.write_ply(path, positions, faces, attrs, {}, comments)
    reference = meshio.read(path)
    me = import_active(path).data
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    assert np.array_equal(co.reshape(-1, 3), reference.points.astype(np.float32))
    assert set(reference.point_data) == set(attrs)
    for name, values in reference.point_data.items():
        _, got = blender_values(me, name)
        assert np.array_equal(got, values.astype(got.dtype)), name


def test_current_cli_subset_imports(tmp_path):
    """What `isouq mesh --linear-only` writes: edge_i edge_j edge_k edge_axis t_linear only."""
    positions, faces, attrs, _, comments = plyfixture.sphere_fixture(n=10, radius=3.0)
    subset = {k: attrs[k] for k in ("edge_i", "edge_j", "edge_k", "edge_axis", "t_linear")}
    path = str(tmp_path / "subset.ply")
    plyfixture.write_ply(path, positions, faces, subset, {}, comments[:1])
    me = import_active(path).data
    assert {a.name for a in me.attributes if not a.name.startswith((".", "isouq_"))} == set(subset)
    assert me["isouq_method"] == "linear"          # guessed: only t_linear reproduces x, y, z


def test_blenders_own_ply_importer_reads_geometry(sphere_ply):
    path, (positions, faces, *_) = sphere_ply
    assert bpy.ops.import_mesh.ply(filepath=path) == {"FINISHED"}
    me = bpy.context.active_object.data
    assert len(me.polygons) == len(faces)
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    # Blender's importer may merge or reorder; the point sets must agree
    got = np.unique(np.round(co.reshape(-1, 3), 5), axis=0)
    assert np.array_equal(got, np.unique(np.round(positions, 5), axis=0))


def _bad_files(tmp_path, sphere_path):
    data = open(sphere_path, "rb").read()
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    files = {
        "truncated.ply": data[: header_end + (len(data) - header_end) // 2],
        "truncated_faces.ply": data[:-5],
        "header_only.ply": data[: header_end - 3],
        "not_ply.ply": b"solid cube\nfacet normal 0 0 1\n",
        "ascii.ply": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                     b"property float y\nproperty float z\nend_header\n0 0 0\n",
        "empty.ply": b"",
    }
    positions, faces, attrs, _, comments = plyfixture.sphere_fixture(n=8, radius=2.0)
    plain = str(tmp_path / "plain.ply")           # a PLY that is not isouq's: no comment, no edges
    plyfixture.write_ply(plain, positions, faces, {"err_est": attrs["err_est"]})
    bad_index = faces.copy()
    bad_index[0, 0] = len(positions)
    out_of_range = str(tmp_path / "out_of_range.ply")
    plyfixture.write_ply(out_of_range, positions, bad_index, attrs, {}, comments)
    paths = [plain, out_of_range]
    for name, content in files.items():
        p = tmp_path / name
        p.write_bytes(content)
        paths.append(str(p))
    return paths + [str(tmp_path / "missing.ply")]


def test_bad_files_report_an_error_and_build_nothing(tmp_path, sphere_ply):
    for path in _bad_files(tmp_path, sphere_ply[0]):
        before = snapshot()
        with pytest.raises(RuntimeError, match="Error: " + os.path.basename(path)):
            bpy.ops.isouq.import_mesh(filepath=path)
        assert scene_delta(before) == (set(), set()), path


def test_blender_exported_ply_is_refused(tmp_path):
    bpy.ops.mesh.primitive_ico_sphere_add()
    path = str(tmp_path / "blender.ply")
    bpy.ops.export_mesh.ply(filepath=path)
    before = snapshot()
    with pytest.raises(RuntimeError, match="not an isouq mesh"):
        bpy.ops.isouq.import_mesh(filepath=path)
    assert scene_delta(before) == (set(), set())
