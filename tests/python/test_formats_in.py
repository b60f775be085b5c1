"""Scans with headers in (SPEC §10 "Formats"; docs/inputs.md "Scans with headers"): each format,
written here by an independent library (nibabel for NIfTI, pydicom for DICOM, tifffile for TIFF,
the NRRD text header by hand) or taken from a Debian package, meshes to the mesh of the same
voxels written as a float32 .raw, each vertex moved by the file's affine; bad files give one
`isouq: error:` line and exit 2 with nothing written.
"""
import gzip
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import _isouq_path  # noqa: E402,F401  (puts ply_io on sys.path)
import ply_io  # noqa: E402

SHAPE = (23, 17, 29)  # x, y, z: odd sizes, several leaves, a partial last one
ISOVALUE = 60.0
# A rotation about z by 30 degrees, anisotropic spacing and an origin, as a scanner writes.
C, S = np.cos(np.pi / 6), np.sin(np.pi / 6)
AFFINE = np.array([[0.9 * C, -1.1 * S, 0.0, -12.5],
                   [0.9 * S, 1.1 * C, 0.0, 40.25],
                   [0.0, 0.0, 2.5, 7.0],
                   [0.0, 0.0, 0.0, 1.0]])


def run(*args):
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=600)


def blobs(shape=SHAPE):
    """Two overlapping Gaussian blobs in [0, 120] on the grid, x fastest when written as a[z, y, x]."""
    x, y, z = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in shape), indexing="ij")
    f = 120 * np.exp(-((x - 9) ** 2 + (y - 8) ** 2 + (z - 12) ** 2) / 40.0)
    f += 90 * np.exp(-((x - 15) ** 2 + (y - 9) ** 2 + (z - 19) ** 2) / 25.0)
    return np.round(f)  # integer values: every dtype holds them exactly


def write_raw(folder, values_xyz, name="ref"):
    """The voxels as float32 .raw (SPEC §8 name), x fastest."""
    nx, ny, nz = values_xyz.shape
    path = folder / f"{name}_{nx}x{ny}x{nz}_float32.raw"
    np.ascontiguousarray(values_xyz.transpose(2, 1, 0), dtype="<f4").tofile(path)
    return path


def mesh(cli, folder, source, name, *args):
    out = folder / f"{name}.ply"
    summary = folder / f"{name}.json"
    proc = run(cli, "mesh", source, "-o", out, "--summary", summary, "-q", *args)
    assert proc.returncode == 0, proc.stderr
    return ply_io.read_ply(out), json.loads(summary.read_text())


def assert_moved_by(scan, reference, affine):
    """The scan's mesh is the reference (identity transform) mesh with every vertex moved by
    `affine`: same triangles, edges and crossings; errors in world units scale with the edge."""
    assert scan.vertex_count == reference.vertex_count > 100
    assert np.array_equal(scan.triangles, reference.triangles)
    s, r = scan.vertex_attributes, reference.vertex_attributes
    for column in ("edge_i", "edge_j", "edge_k", "edge_axis", "order", "t_linear", "t_cubic", "t_weno"):
        assert np.array_equal(s[column], r[column]), column
    moved = reference.positions.astype(np.float64) @ affine[:3, :3].T + affine[:3, 3]
    scale = np.abs(moved).max()
    assert np.abs(scan.positions - moved).max() <= 2e-6 * scale
    assert np.allclose(scan.index_to_world, affine, rtol=0, atol=1e-12)
    # SPEC §3: e and e_b are lengths along the edge: the edge's world length times the index one.
    edge_length = np.linalg.norm(affine[:3, :3], axis=0)[r["edge_axis"]]
    for column in ("err_est", "err_bound"):
        assert np.allclose(s[column], r[column] * edge_length, rtol=1e-5, atol=0), column


@pytest.fixture(scope="module")
def reference(isouq_cli, tmp_path_factory):
    folder = tmp_path_factory.mktemp("reference")
    ply, _ = mesh(isouq_cli, folder, write_raw(folder, blobs()), "raw", "--isovalue", ISOVALUE)
    return ply


# ---- NIfTI ------------------------------------------------------------------------------

nib = pytest.importorskip("nibabel")


@pytest.mark.parametrize("kind, suffix, dtype", [
    ("nifti1", ".nii", np.uint8), ("nifti1", ".nii.gz", np.int16), ("nifti2", ".nii", np.float32),
    ("nifti2", ".nii.gz", np.float64), ("nifti1", ".nii", np.int8), ("nifti1", ".nii.gz", np.uint16),
    ("nifti1", ".nii", np.int32), ("nifti1", ".nii", np.uint32), ("nifti2", ".nii", np.int64),
])
@pytest.mark.parametrize("form", ["sform", "qform"])
def test_nifti_is_the_raw_mesh_moved_by_its_affine(isouq_cli, tmp_path, reference, kind, suffix, dtype, form):
    cls = nib.Nifti1Image if kind == "nifti1" else nib.Nifti2Image
    image = cls(blobs().astype(dtype), None, dtype=dtype)
    if form == "sform":
        image.set_sform(AFFINE, code=2)
        image.set_qform(np.diag([3.0, 3.0, 3.0, 1.0]), code=1)  # ignored: the sform wins
    else:
        image.set_qform(AFFINE, code=1)  # a rotation and spacings: a qform holds it exactly
        image.set_sform(None, code=0)
    image.header.set_data_dtype(dtype)
    image.header["scl_slope"], image.header["scl_inter"] = 1.0, 0.0
    path = tmp_path / f"scan{suffix}"
    nib.save(image, path)
    ply, summary = mesh(isouq_cli, tmp_path, path, "nii", "--isovalue", ISOVALUE)
    affine = nib.load(path).affine  # the qform through nibabel's quaternion, as stored
    assert_moved_by(ply, reference, affine)
    assert summary["geometry"].startswith(f"NIfTI {form}")
    assert np.allclose(np.array(summary["index_to_world"]).reshape(4, 4), affine, atol=1e-12)
    assert summary["description"].startswith(f"scan{suffix}: NIfTI-{kind[-1]} {np.dtype(dtype).name}")


def test_nifti_scaling_is_applied(isouq_cli, tmp_path, reference):
    """Stored = 2 (value + 100) as int16 with scl_slope 0.5, scl_inter -100: isouq meshes the value."""
    stored = (2 * (blobs() + 100)).astype(np.int16)
    assert np.array_equal(0.5 * stored - 100, blobs())
    nib.save(nib.Nifti1Image(stored, AFFINE, dtype=np.int16), tmp_path / "scaled.nii")
    data = bytearray((tmp_path / "scaled.nii").read_bytes())
    data[112:120] = np.array([0.5, -100.0], "<f4").tobytes()  # scl_slope, scl_inter (NIfTI-1 offsets)
    with gzip.open(tmp_path / "scaled.nii.gz", "wb") as f:
        f.write(bytes(data))
    image = nib.load(tmp_path / "scaled.nii.gz")
    assert (image.dataobj.slope, image.dataobj.inter) == (0.5, -100.0)  # nibabel moves them there
    assert np.array_equal(np.asarray(image.dataobj), blobs())  # nibabel scales the same way
    ply, summary = mesh(isouq_cli, tmp_path, tmp_path / "scaled.nii.gz", "scaled", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, nib.load(tmp_path / "scaled.nii.gz").affine)
    assert "scaled by 0.5 + -100" in summary["description"]


def test_nifti_from_debian_nibabel_data(isouq_cli, tmp_path):
    """anatomical.nii of python3-nibabel's test data: a real MRI, big-endian int16, LAS sform."""
    path = Path(nib.__file__).parent / "tests" / "data" / "anatomical.nii"
    if not path.exists():
        pytest.skip(f"{path} is not installed")
    image = nib.load(path)
    assert image.header.endianness == ">"
    values = np.asarray(image.dataobj, dtype=np.float64)  # nibabel applies any scaling
    ply, summary = mesh(isouq_cli, tmp_path, path, "anat", "--isovalue", 7500)
    ref, _ = mesh(isouq_cli, tmp_path, write_raw(tmp_path, values, "anat"), "anat_raw", "--isovalue", 7500)
    assert_moved_by(ply, ref, image.affine)
    assert np.linalg.det(image.affine[:3, :3]) < 0  # x flipped (radiological): kept as stored
    assert summary["geometry"] == "NIfTI sform (code 2)"


def test_nifti_without_orientation_uses_the_voxel_sizes(isouq_cli, tmp_path, reference):
    nib.save(nib.Nifti1Image(blobs().astype(np.float32), np.diag([0.5, 0.75, 2.0, 1.0])), tmp_path / "plain.nii")
    data = bytearray((tmp_path / "plain.nii").read_bytes())
    data[252:256] = np.array([0, 0], "<i2").tobytes()  # qform_code, sform_code (NIfTI-1 offsets)
    (tmp_path / "plain.nii").write_bytes(bytes(data))
    header = nib.load(tmp_path / "plain.nii").header
    assert header["qform_code"] == header["sform_code"] == 0
    ply, summary = mesh(isouq_cli, tmp_path, tmp_path / "plain.nii", "plain", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, np.diag([0.5, 0.75, 2.0, 1.0]))
    assert summary["geometry"] == "NIfTI voxel sizes (no sform or qform)"


def assert_one_error_line(cli, tmp_path, source, *words, args=("--isovalue", ISOVALUE)):
    out = tmp_path / "out.ply"
    proc = run(cli, "mesh", source, "-o", out, "-q", *args)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("isouq: error:"), proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    assert not out.exists()


def test_bad_nifti_files_give_one_line(isouq_cli, tmp_path):
    good = tmp_path / "good.nii"
    nib.save(nib.Nifti1Image(blobs().astype(np.int16), AFFINE), good)
    data = good.read_bytes()
    (tmp_path / "cut_data.nii").write_bytes(data[:len(data) // 2])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "cut_data.nii", "is truncated", "needs 22678 bytes")
    (tmp_path / "cut_header.nii").write_bytes(data[:200])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "cut_header.nii", "not a readable NIfTI file")
    with gzip.open(tmp_path / "cut.nii.gz", "wb") as f:
        f.write(data[:len(data) - 1000])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "cut.nii.gz", "is truncated", "slices")
    (tmp_path / "noise.nii").write_bytes(np.random.default_rng(1).bytes(4000))
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "noise.nii", "not a readable NIfTI file")
    nib.save(nib.Nifti1Image(blobs().astype(np.complex64), np.eye(4)), tmp_path / "complex.nii")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "complex.nii", "datatype COMPLEX64", "scalar volumes")
    nib.save(nib.Nifti1Image(np.zeros(SHAPE + (3,), np.float32), np.eye(4)), tmp_path / "4d.nii")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "4d.nii", "dim[4] = 3", "one 3-D volume")
    singular = AFFINE.copy()
    singular[:, 2] = 0
    image = nib.Nifti1Image(blobs().astype(np.float32), None)
    image.set_sform(singular, code=2)
    nib.save(image, tmp_path / "singular.nii")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "singular.nii", "unusable NIfTI sform", "invertible")
    assert_one_error_line(isouq_cli, tmp_path, good, "--spacing applies to .raw files",
                          args=("--spacing", "1,1,1"))
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "missing.nii.gz", "no such file")
