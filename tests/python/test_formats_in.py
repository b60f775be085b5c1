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


def assert_moved_by(scan, reference, affine, matrix_atol=1e-12):
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
    assert np.allclose(scan.index_to_world, affine, rtol=0, atol=matrix_atol)
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

@pytest.mark.parametrize("kind, suffix, dtype", [
    ("nifti1", ".nii", np.uint8), ("nifti1", ".nii.gz", np.int16), ("nifti2", ".nii", np.float32),
    ("nifti2", ".nii.gz", np.float64), ("nifti1", ".nii", np.int8), ("nifti1", ".nii.gz", np.uint16),
    ("nifti1", ".nii", np.int32), ("nifti1", ".nii", np.uint32), ("nifti2", ".nii", np.int64),
])
@pytest.mark.parametrize("form", ["sform", "qform"])
def test_nifti_is_the_raw_mesh_moved_by_its_affine(isouq_cli, tmp_path, reference, kind, suffix, dtype, form):
    nib = pytest.importorskip("nibabel")
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


@pytest.mark.parametrize("suffix, slope, inter", [(".nii", 1.0, 0.0), (".nii", 0.5, -10.0), (".nii.gz", 1.0, 0.0),
                                                  (".nii.gz", -0.25, 3.0)])
def test_nifti_default_isovalue_is_otsu_of_its_values(isouq_cli, tmp_path, data_dir, suffix, slope, inter):
    """Otsu's default isovalue of a NIfTI against scikit-image's threshold_otsu of the same scaled
    values (SPEC §8): a plain unscaled .nii is read as a raw array (counts per value), the others
    slice by slice (a 256-bin histogram of the decoded floats); unscaled, both must give the raw
    scan's own isovalue exactly."""
    nib = pytest.importorskip("nibabel")
    filters = pytest.importorskip("skimage.filters")
    name = "engine_256x256x128_uint8.raw"
    values = np.fromfile(data_dir / name, dtype=np.uint8).reshape(128, 256, 256).transpose(2, 1, 0)
    image = nib.Nifti1Image(values, np.eye(4))
    image.header.set_slope_inter(slope, inter)
    path = tmp_path / f"engine{suffix}"
    nib.save(image, path)
    _, summary = mesh(isouq_cli, tmp_path, path, "nii", "--linear-only")
    assert summary["isovalue_source"].startswith("Otsu")
    scaled = (values.astype(np.float64) * slope + inter).astype(np.float32)  # as isouq decodes
    expected = filters.threshold_otsu(scaled, nbins=256)
    assert abs(summary["isovalue"] - expected) <= float(scaled.max() - scaled.min()) / 256  # one bin
    if slope == 1.0 and inter == 0.0:
        _, raw = mesh(isouq_cli, tmp_path, data_dir / name, "raw", "--linear-only")
        assert summary["isovalue"] == raw["isovalue"]


def test_nifti_scaling_is_applied(isouq_cli, tmp_path, reference):
    """Stored = 2 (value + 100) as int16 with scl_slope 0.5, scl_inter -100: isouq meshes the value."""
    nib = pytest.importorskip("nibabel")
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
    nib = pytest.importorskip("nibabel")
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
    assert "isouq geometry NIfTI sform (code 2)" in ply.comments


def test_nifti_without_orientation_uses_the_voxel_sizes(isouq_cli, tmp_path, reference):
    nib = pytest.importorskip("nibabel")
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
    nib = pytest.importorskip("nibabel")
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


# ---- NRRD -------------------------------------------------------------------------------

def nrrd_header(dtype, encoding="raw", endian="little", geometry="directions", extra=()):
    """A NRRD0004 header written from the format's documentation (teem's "NRRD file format")."""
    types = {np.uint8: "uint8", np.int8: "int8", np.int16: "short", np.uint16: "ushort", np.int32: "int",
             np.float32: "float", np.float64: "double", np.uint64: "unsigned long long int"}
    lines = ["NRRD0004", "# written by test_formats_in.py", f"type: {types[dtype]}", "dimension: 3",
             "sizes: " + " ".join(map(str, SHAPE)), f"encoding: {encoding}"]
    if np.dtype(dtype).itemsize > 1:
        lines.append(f"endian: {endian}")
    if geometry == "directions":
        vector = lambda v: "(" + ",".join(repr(float(x)) for x in v) + ")"  # noqa: E731
        lines += ["space: left-posterior-superior",
                  "space directions: " + " ".join(vector(AFFINE[:3, a]) for a in range(3)),
                  "space origin: " + vector(AFFINE[:3, 3])]
    elif geometry == "spacings":
        lines.append("spacings: 0.5 0.75 2")
    return "\n".join(lines + list(extra)) + "\n"


def nrrd_data(dtype, encoding="raw", endian="little"):
    values = blobs().transpose(2, 1, 0).astype(np.dtype(dtype).newbyteorder("<" if endian == "little" else ">"))
    data = values.tobytes()
    return gzip.compress(data) if encoding == "gzip" else data


@pytest.mark.parametrize("dtype, encoding, endian", [
    (np.uint8, "raw", "little"), (np.int16, "gzip", "big"), (np.float32, "raw", "big"),
    (np.float64, "gzip", "little"), (np.uint16, "raw", "little"), (np.int8, "gzip", "little"),
    (np.int32, "raw", "big"), (np.uint64, "raw", "little"),
])
def test_attached_nrrd_is_the_raw_mesh_moved_by_its_space(isouq_cli, tmp_path, reference, dtype, encoding, endian):
    path = tmp_path / "scan.nrrd"
    path.write_bytes(nrrd_header(dtype, encoding, endian).encode() + b"\n" + nrrd_data(dtype, encoding, endian))
    ply, summary = mesh(isouq_cli, tmp_path, path, "nrrd", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, AFFINE)
    assert summary["geometry"] == "NRRD space directions (left-posterior-superior)"
    assert summary["description"].startswith(f"scan.nrrd: NRRD {np.dtype(dtype).name} ({encoding})")


@pytest.mark.parametrize("encoding", ["raw", "gzip"])
def test_detached_nhdr_reads_its_data_file(isouq_cli, tmp_path, reference, encoding):
    (tmp_path / "data").mkdir()
    name = "data/voxels.raw" + (".gz" if encoding == "gzip" else "")
    (tmp_path / name).write_bytes(b"JUNK" + nrrd_data(np.int16, encoding) if encoding == "raw"
                                  else nrrd_data(np.int16, encoding))
    extra = [f"data file: {name}"] + (["byte skip: 4"] if encoding == "raw" else [])
    (tmp_path / "scan.nhdr").write_text(nrrd_header(np.int16, encoding, extra=extra))
    ply, _ = mesh(isouq_cli, tmp_path, tmp_path / "scan.nhdr", "nhdr", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, AFFINE)


def test_nrrd_ascii_and_data_at_the_end(isouq_cli, tmp_path, reference):
    """ascii data (decoded by teem whole) and `byte skip: -1` (raw data are the file's last bytes)."""
    text = " ".join(str(int(v)) for v in blobs().transpose(2, 1, 0).ravel())
    (tmp_path / "text.nrrd").write_text(nrrd_header(np.int16, "ascii") + "\n" + text + "\n")
    ply, summary = mesh(isouq_cli, tmp_path, tmp_path / "text.nrrd", "text", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, AFFINE)
    assert "(ASCII)" in summary["description"]  # teem's name of the encoding
    (tmp_path / "tail.raw").write_bytes(b"a preamble of any length" + nrrd_data(np.uint16))
    (tmp_path / "tail.nhdr").write_text(nrrd_header(np.uint16, extra=["data file: tail.raw", "byte skip: -1"]))
    ply, _ = mesh(isouq_cli, tmp_path, tmp_path / "tail.nhdr", "tail", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, AFFINE)


def test_nrrd_spacings_without_a_space(isouq_cli, tmp_path, reference):
    path = tmp_path / "spaced.nrrd"
    path.write_bytes(nrrd_header(np.float32, geometry="spacings").encode() + b"\n" + nrrd_data(np.float32))
    ply, summary = mesh(isouq_cli, tmp_path, path, "spaced", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, np.diag([0.5, 0.75, 2.0, 1.0]))
    assert summary["geometry"] == "NRRD spacings"


def test_bad_nrrd_files_give_one_line(isouq_cli, tmp_path):
    good = nrrd_header(np.int16).encode() + b"\n" + nrrd_data(np.int16)
    (tmp_path / "cut.nrrd").write_bytes(good[:len(good) // 2])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "cut.nrrd", "cannot read the data of")
    gz = nrrd_header(np.int16, "gzip").encode() + b"\n" + nrrd_data(np.int16, "gzip")
    (tmp_path / "cut_gz.nrrd").write_bytes(gz[:len(gz) - 500])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "cut_gz.nrrd", "cannot read the data of")
    (tmp_path / "four.nrrd").write_text("NRRD0004\ntype: float\ndimension: 4\nsizes: 2 3 4 5\nencoding: raw\n"
                                        "endian: little\n\n" + "\0" * 480)
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "four.nrrd", "dimension 4", "one 3-D scalar volume")
    (tmp_path / "block.nrrd").write_text("NRRD0004\ntype: block\nblock size: 2\ndimension: 3\nsizes: 2 2 2\nendian: little\n"
                                         "encoding: raw\n\n" + "\0" * 16)
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "block.nrrd", "NRRD type block", "scalar volumes")
    (tmp_path / "typo.nrrd").write_text("NRRD0004\ntype: flaot\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "typo.nrrd", "not a readable NRRD file")
    (tmp_path / "lost.nhdr").write_text(nrrd_header(np.int16, extra=["data file: nowhere.raw"]))
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "lost.nhdr", "lost.nhdr")
    (tmp_path / "noise.nrrd").write_bytes(np.random.default_rng(2).bytes(3000))
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "noise.nrrd", "not a readable NRRD file")


# ---- TIFF stacks ------------------------------------------------------------------------

def zyx(dtype):
    return np.ascontiguousarray(blobs().transpose(2, 1, 0).astype(dtype))  # pages, rows, columns


@pytest.mark.parametrize("dtype, options", [
    (np.uint8, {}), (np.uint16, {"compression": "zlib"}), (np.float32, {"tile": (16, 16)}),
    (np.int16, {"compression": "zlib", "predictor": True}), (np.float64, {}), (np.int32, {"tile": (16, 16)}),
])
def test_multipage_tiff_is_the_raw_mesh(isouq_cli, tmp_path, reference, dtype, options):
    tifffile = pytest.importorskip("tifffile")
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, zyx(dtype), **options)
    ply, summary = mesh(isouq_cli, tmp_path, path, "tif", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, np.eye(4))
    assert summary["description"].startswith(f"stack.tif: TIFF {np.dtype(dtype).name}")
    spaced, summary = mesh(isouq_cli, tmp_path, path, "tif_spaced", "--isovalue", ISOVALUE, "--spacing", "0.5,0.75,2")
    assert_moved_by(spaced, reference, np.diag([0.5, 0.75, 2.0, 1.0]))
    assert summary["geometry"] == "--spacing"


def test_folder_of_numbered_slices_sorts_by_number(isouq_cli, tmp_path, reference):
    tifffile = pytest.importorskip("tifffile")
    folder = tmp_path / "slices"
    folder.mkdir()
    for z, page in enumerate(zyx(np.uint16)):
        tifffile.imwrite(folder / f"slice_{z + 1}.tiff", page)  # 1, 2, ..., 10: not in name order
    (folder / "notes.txt").write_text("not a slice")
    ply, summary = mesh(isouq_cli, tmp_path, folder, "folder", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, np.eye(4))
    assert summary["description"].startswith("slice_1.tiff and 28 more slices: TIFF uint16")


def test_imagej_tiff_spacing(isouq_cli, tmp_path, reference):
    tifffile = pytest.importorskip("tifffile")
    path = tmp_path / "imagej.tif"
    tifffile.imwrite(path, zyx(np.uint16), imagej=True, resolution=(1 / 0.5, 1 / 0.75),
                     metadata={"spacing": 2.0, "unit": "um"})
    ply, summary = mesh(isouq_cli, tmp_path, path, "imagej", "--isovalue", ISOVALUE)
    # The resolutions are TIFF rationals that libtiff returns as float: 1/0.75 to 7 digits.
    assert_moved_by(ply, reference, np.diag([0.5, 0.75, 2.0, 1.0]), matrix_atol=1e-7)
    assert summary["geometry"] == "ImageJ description (unit um)"


def test_bad_tiff_stacks_give_one_line(isouq_cli, tmp_path):
    tifffile = pytest.importorskip("tifffile")
    tifffile.imwrite(tmp_path / "good.tif", zyx(np.uint16))
    data = (tmp_path / "good.tif").read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[:len(data) // 2])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "cut.tif", "cut.tif")
    (tmp_path / "head.tif").write_bytes(data[:6])
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "head.tif", "not a readable TIFF file")
    tifffile.imwrite(tmp_path / "rgb.tif", np.zeros((4, 8, 8, 3), np.uint8), photometric="rgb")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "rgb.tif", "3 samples per pixel", "one-channel")
    folder = tmp_path / "mixed"
    folder.mkdir()
    tifffile.imwrite(folder / "s0.tif", np.zeros((8, 8), np.uint8))
    tifffile.imwrite(folder / "s1.tif", np.zeros((8, 9), np.uint8))
    assert_one_error_line(isouq_cli, tmp_path, folder, "s1.tif' is 9x8 uint8", "every slice of a stack must match")
    tifffile.imwrite(tmp_path / "half.tif", np.zeros((4, 8, 8), np.float16), photometric="minisblack")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "half.tif", "16-bit samples of format 3",
                          "isouq reads 8, 16, 32 or 64-bit integers")
    assert_one_error_line(isouq_cli, tmp_path, tmp_path / "good.tif", "--dims applies to .raw files",
                          args=("--dims", "23,17,29"))


# ---- DICOM series -----------------------------------------------------------------------

def write_series(folder, dtype=np.int16, slope=0.5, intercept=-1024.0, positions=None, series_uid=None,
                 shape=SHAPE, values=None):
    """One CT series written with pydicom, one file per slice under a random name, instance numbers
    reversed: isouq must sort by Image Position (Patient). Returns the file paths by slice."""
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid
    folder.mkdir(exist_ok=True)
    nx, ny, nz = shape
    values = blobs(shape) if values is None else values
    stored = np.round((values - intercept) / slope).astype(dtype)
    assert np.array_equal(stored * slope + intercept, values)
    series_uid = series_uid or generate_uid()
    if positions is None:
        positions = [AFFINE[:3, 3] + k * AFFINE[:3, 2] for k in range(nz)]
    rng = np.random.default_rng()  # file names in no order
    paths = []
    for k in range(nz):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        path = folder / f"IM{rng.integers(1 << 40):012x}"
        ds = FileDataset(str(path), {}, file_meta=meta, preamble=b"\0" * 128)
        ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.StudyInstanceUID, ds.SeriesInstanceUID = "1.2.3.4", series_uid
        ds.Modality, ds.PatientName, ds.InstanceNumber = "CT", "Test^Blobs", nz - k
        ds.Rows, ds.Columns = ny, nx
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        bits = np.dtype(dtype).itemsize * 8
        ds.BitsAllocated, ds.BitsStored, ds.HighBit = bits, bits, bits - 1
        ds.PixelRepresentation = 1 if np.dtype(dtype).kind == "i" else 0
        ds.ImagePositionPatient = [float(v) for v in positions[k]]
        ds.ImageOrientationPatient = [float(v) for v in (*(AFFINE[:3, 0] / 0.9), *(AFFINE[:3, 1] / 1.1))]
        ds.PixelSpacing = [1.1, 0.9]  # between rows (y), between columns (x)
        ds.SliceThickness = 2.5
        ds.RescaleSlope, ds.RescaleIntercept = slope, intercept
        ds.PixelData = np.ascontiguousarray(stored[:, :, k].T).astype(np.dtype(dtype).newbyteorder("<")).tobytes()
        ds.is_little_endian, ds.is_implicit_VR = True, False
        ds.save_as(str(path))
        paths.append(path)
    return paths


@pytest.mark.parametrize("dtype, slope, intercept", [(np.int16, 0.5, -1024.0), (np.uint16, 1.0, 0.0),
                                                     (np.uint8, 1.0, 0.0)])
def test_dicom_series_is_the_raw_mesh_moved_by_its_geometry(isouq_cli, tmp_path, reference, dtype, slope, intercept):
    pydicom = pytest.importorskip("pydicom")
    paths = write_series(tmp_path / "series", dtype, slope, intercept)
    (tmp_path / "series" / "DICOMDIR.txt").write_text("not DICOM")  # ignored
    assert pydicom.dcmread(paths[0]).pixel_array.shape == (SHAPE[1], SHAPE[0])
    ply, summary = mesh(isouq_cli, tmp_path, tmp_path / "series", "dicom", "--isovalue", ISOVALUE)
    assert_moved_by(ply, reference, AFFINE, matrix_atol=1e-9)
    assert summary["geometry"] == "DICOM image position and orientation (LPS)"
    assert summary["description"].startswith(f"series: DICOM series of 29 slices, {np.dtype(dtype).name}")


def test_dicom_series_with_a_tilt(isouq_cli, tmp_path, reference):
    """Gantry tilt: positions step along a vector that is not the normal; the affine follows them."""
    pydicom = pytest.importorskip("pydicom")
    step = np.array([0.0, 0.3, 2.5])
    origin = AFFINE[:3, 3]
    write_series(tmp_path / "tilted", positions=[origin + k * step for k in range(SHAPE[2])])
    ply, _ = mesh(isouq_cli, tmp_path, tmp_path / "tilted", "tilted", "--isovalue", ISOVALUE)
    affine = AFFINE.copy()
    affine[:3, 2] = step
    assert_moved_by(ply, reference, affine, matrix_atol=1e-9)


def test_bad_dicom_folders_give_one_line(isouq_cli, tmp_path):
    pydicom = pytest.importorskip("pydicom")
    small = (5, 4, 3)
    values = np.arange(60, dtype=np.float64).reshape(small)
    two = tmp_path / "two_series"
    write_series(two, shape=small, values=values, series_uid="1.2.3.1")
    write_series(two, shape=small, values=values, series_uid="1.2.3.2")
    assert_one_error_line(isouq_cli, tmp_path, two, "holds 2 DICOM series", args=())
    gaps = tmp_path / "gaps"
    write_series(gaps, shape=small, values=values,
                 positions=[AFFINE[:3, 3] + k * AFFINE[:3, 2] for k in (0, 1, 3)])
    assert_one_error_line(isouq_cli, tmp_path, gaps, "not evenly spaced", args=())
    cut = tmp_path / "cut"
    paths = write_series(cut, shape=small, values=values)
    paths[1].write_bytes(paths[1].read_bytes()[:-20])
    assert_one_error_line(isouq_cli, tmp_path, cut, str(paths[1].name), args=())
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("nothing here")
    assert_one_error_line(isouq_cli, tmp_path, empty, "holds no TIFF slices and no DICOM files", args=())
    one = tmp_path / "one"
    write_series(one, shape=(5, 4, 1), values=values[:, :, :1])
    assert_one_error_line(isouq_cli, tmp_path, one, "holds one DICOM slice", args=())
    assert_one_error_line(isouq_cli, tmp_path, two, "--spacing applies to .raw files and TIFF",
                          args=("--spacing", "1,1,1"))
    # Row and column directions 5.7 degrees from perpendicular: GDCM would put the identity in
    # their place, so isouq refuses them (PS3.3 C.7.6.2.1.1).
    skew = tmp_path / "skew"
    for path in write_series(skew, shape=small, values=values):
        ds = pydicom.dcmread(path)
        ds.ImageOrientationPatient = [1.0, 0.0, 0.0, 0.0995037, 0.9950372, 0.0]
        ds.save_as(path)
    assert_one_error_line(isouq_cli, tmp_path, skew, "not orthonormal", args=())


@pytest.mark.parametrize("name", ["CT_small.dcm", "MR_small_bigendian.dcm", "MR_small_RLE.dcm", "MR_small_implicit.dcm"])
def test_dicom_series_from_pydicom_test_files(isouq_cli, tmp_path, name):
    """Real scanner slices from python3-pydicom's test data (CT int16 with a rescale, MR big-endian,
    RLE-compressed and implicit VR), copied four times along the slice normal as one series; the truth
    is pydicom's own decoding of the pixels (the synthetic series above checks the sorting)."""
    pydicom = pytest.importorskip("pydicom")
    source = Path(pydicom.__file__).parent / "data" / "test_files" / name
    if not source.exists():
        pytest.skip(f"{source} is not installed")
    from pydicom.uid import generate_uid
    folder = tmp_path / "series"
    folder.mkdir()
    first = pydicom.dcmread(source)
    row, col = np.array(first.ImageOrientationPatient[:3], float), np.array(first.ImageOrientationPatient[3:], float)
    normal = np.cross(row, col)
    for k, shift in enumerate([0.0, 3.0, 1.0, 2.0]):  # written out of order
        ds = pydicom.dcmread(source)
        ds.SeriesInstanceUID, ds.SOPInstanceUID = "1.2.826.0.1.3680043.8.498.1", generate_uid()
        ds.ImagePositionPatient = [float(v) for v in np.array(first.ImagePositionPatient, float) + 1.5 * shift * normal]
        ds.save_as(str(folder / f"slice{k}.dcm"))
    pixels = pydicom.dcmread(source).pixel_array.astype(np.float64)
    slope, intercept = float(getattr(first, "RescaleSlope", 1)), float(getattr(first, "RescaleIntercept", 0))
    values = np.stack([pixels * slope + intercept] * 4, axis=0).transpose(2, 1, 0)  # x, y, z
    isovalue = float(np.percentile(values, 60))
    ply, summary = mesh(isouq_cli, tmp_path, folder, "real", "--isovalue", isovalue)
    ref, _ = mesh(isouq_cli, tmp_path, write_raw(tmp_path, values, "real"), "real_raw", "--isovalue", isovalue)
    spacing = [float(v) for v in first.PixelSpacing]
    affine = np.eye(4)
    affine[:3, 0], affine[:3, 1], affine[:3, 2] = row * spacing[1], col * spacing[0], 1.5 * normal
    affine[:3, 3] = np.array(first.ImagePositionPatient, float)
    assert_moved_by(ply, ref, affine, matrix_atol=1e-6)
    assert summary["description"].startswith("series: DICOM series of 4 slices")


def test_dicom_element_walk_against_pydicom(isouq_cli, tmp_path):
    """isouq walks each DICOM file's elements before GDCM sees it and refuses a length that
    overruns the file (docs/hardening.md). Truth: every file of python3-pydicom's test data that
    pydicom parses to its last element passes the walk, and the files its authors cut short
    (named *truncated*) are refused as damaged."""
    pydicom = pytest.importorskip("pydicom")
    data = Path(pydicom.__file__).parent / "data" / "test_files"
    checked = refused = 0
    for source in sorted(data.glob("*.dcm")):
        try:
            list(pydicom.dcmread(source).iterall())
        except Exception:  # pydicom cannot read it either: no truth here
            continue
        folder = tmp_path / source.stem
        folder.mkdir()
        (folder / "s0").write_bytes(source.read_bytes())  # the walk comes before the count of slices
        r = subprocess.run([isouq_cli, "mesh", str(folder), "-q", "-o", str(tmp_path / "o.ply")],
                           capture_output=True, text=True, timeout=120)
        damaged = "damaged DICOM file: at byte" in r.stderr  # the walk's refusal, not GDCM's
        assert damaged == ("truncated" in source.name), (source.name, r.stderr)
        assert r.returncode in (0, 2) and len(r.stderr.strip().splitlines()) <= 1, (source.name, r.stderr)
        checked += 1
        refused += damaged
    assert checked >= 40 and refused >= 2, (checked, refused)
