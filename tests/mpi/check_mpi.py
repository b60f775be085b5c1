#!/usr/bin/env python3
"""isouq mesh under mpirun against one process (SPEC §10 "MPI"; docs/mpi.md).

  check_mpi.py --cli ISOUQ --mpirun MPIRUN --np N --case CASE[,CASE...] --data DIR --work DIR
  check_mpi.py --cli ISOUQ --srun SRUN ...   (a private one-machine Slurm cluster, slurm_local.py)

Cases: sphere, sphere_linear, fog (smoke.vdb, Otsu isovalue), fog_k (smoke.vdb --isovalue 0.1),
raw (fuel, uint8, Otsu), raw_float (skull, float32, Otsu, cubic), raw_k (engine --isovalue 71),
field (field:tubey at 48^3, with its truth node), field_hidden (field:tubey at 32^3 with
--hidden-features --hidden-out: both PLY files), formula (formula: at 40^3, cubic), few_blocks
(field:sphere at 8^3 and an 8x8x64 scan with its surface in the top layers: ranks with nothing),
scans with headers written here from the data's raw scans by nibabel, tifffile and pydicom
(SCANS: nifti, nifti_gz, nrrd, nhdr_gz, tiff, tiff_folder, dicom), color (--color-by), bad_input, interrupt,
threads (-j 0's share of the cores), progress (rank 0's progress lines), sequence (a .vdb cache
of four frames, the first empty: every frame, --resume, a broken frame and the sequence errors).
Under --srun also: slurm_signals (scancel and Ctrl-C through srun), slurm_threads (-j 0 on the
CPUs Slurm binds a rank to), slurm_no_pmix (srun without --mpi=pmix).
Exit 0 when the check holds; prints what differs otherwise.
"""
import argparse
import glob
import gzip
import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np

TIMINGS = ("timings_ms", "ranks")
SCANS = ("nifti", "nifti_gz", "nrrd", "nhdr_gz", "tiff", "tiff_folder", "dicom")


def run(cmd, **kw):
    return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def mpirun(args, np_):
    """The launcher's words before the command: mpirun, or srun with Open MPI's PMIx."""
    if args.srun:
        return [args.srun, "--mpi=pmix", "-n", str(np_)]
    return [args.mpirun, "--oversubscribe", "--allow-run-as-root", "-q", "-np", str(np_)]


def leaf_origin(ijk):
    return tuple(c & ~7 for c in ijk)


def order_key(block):
    # The mesher's block order (docs/mpi.md): a tree over block coordinates with 8^3 children
    # at each of its three levels (Tree4<int32, 3, 3, 3>), each node's children x-major, the
    # root's children by their origin.
    b = [c >> 3 for c in block]
    return (tuple(c >> 9 for c in b), tuple((c >> 6) & 7 for c in b), tuple((c >> 3) & 7 for c in b),
            tuple(c & 7 for c in b))


def plan_bound(path, grid, np_):
    """Per rank, from the grid alone: the blocks and weight of its piece (SPEC §9, docs/mpi.md:
    the blocks within one block of a non-empty leaf or of an active tile's border, weight 1 plus
    the leaf's active voxels, cut at p W / P) and the voxels of the leaves it may read: those of
    its blocks and of the leaves one leaf around them (the 3-voxel halo of the cubic and WENO
    stencils, SPEC §2, fits in one leaf)."""
    import pyopenvdb as vdb
    g = vdb.read(path, grid)
    active, leaves, tiles = {}, set(), []
    for v in g.iterOnValues():
        if v["depth"] == 3:
            o = leaf_origin(v["min"])
            active[o] = active.get(o, 0) + 1
        else:
            tiles.append((v["min"], v["max"]))
    leaves = set(active)
    if len(leaves) < g.leafCount():  # leaves without active voxels exist and may be read too
        for v in g.iterOffValues():
            if v["depth"] == 3:
                leaves.add(leaf_origin(v["min"]))
    blocks = set()
    steps = [(dx, dy, dz) for dx in (-8, 0, 8) for dy in (-8, 0, 8) for dz in (-8, 0, 8)]
    for o in active:
        blocks.update((o[0] + dx, o[1] + dy, o[2] + dz) for dx, dy, dz in steps)
    for lo, hi in tiles:
        a, b = [c >> 3 for c in lo], [c >> 3 for c in hi]
        for bx in range(a[0] - 1, b[0] + 2):
            for by in range(a[1] - 1, b[1] + 2):
                for bz in range(a[2] - 1, b[2] + 2):
                    inner = all(a[i] + 1 <= c <= b[i] - 1 for i, c in enumerate((bx, by, bz)))
                    if not (inner and all(b[i] - a[i] >= 2 for i in range(3))):
                        blocks.add((8 * bx, 8 * by, 8 * bz))
    order = sorted(blocks, key=order_key)
    prefix = [0]
    for o in order:
        prefix.append(prefix[-1] + 1 + active.get(o, 0))
    total = prefix[-1]
    bounds = [0]
    for p in range(1, np_):
        target = total // np_ * p + total % np_ * p // np_
        bounds.append(next((i for i in range(len(order)) if prefix[i] >= target), len(order)))
    bounds.append(len(order))
    out = []
    for p in range(np_):
        mine = order[bounds[p]:bounds[p + 1]]
        near = {(o[0] + dx, o[1] + dy, o[2] + dz) for o in mine for dx, dy, dz in steps} & leaves
        out.append({"blocks": len(mine), "weight": prefix[bounds[p + 1]] - prefix[bounds[p]],
                    "bound": 512 * len(near), "share": 512 * len(set(mine) & leaves)})
    return out, 512 * len(leaves)


def layers_bound(dims, np_):
    """Per rank, the samples it may read of a raw scan or compute of a field (dims X, Y, Z): its
    z-layers of 8 slices, layers [L p / P, L (p + 1) / P), and the 3 slices on either side that
    the stencils reach (SPEC §2), inside the volume; and the whole volume's samples."""
    x, y, z = dims
    layers = (z + 7) // 8
    out = []
    for p in range(np_):
        z0, z1 = min(8 * (layers * p // np_), z), min(8 * (layers * (p + 1) // np_), z)
        out.append(0 if z0 >= z1 else x * y * (min(z1 + 3, z) - max(z0 - 3, 0)))
    return out, x * y * z


def compare(args, name, inputs, extra, grid=None, dims=None, hidden=False, ext=".ply"):
    """One process against the ranks: the mesh (and with @hidden the --hidden-out mesh of
    --hidden-features), a .ply or with @ext a .vtp, byte for byte, the summary, the ranks block;
    @grid (a .vdb's) or @dims (a raw scan's or a field's) bound what each rank reads."""
    work = os.path.join(args.work, f"{name}_np{args.np}")
    os.makedirs(work, exist_ok=True)
    meshes = (ext, "_hidden" + ext) if hidden else (ext,)
    outs = {who: {k: os.path.join(work, f"{who}{k}") for k in meshes + (".json",)} for who in ("one", "mpi")}
    for f in list(outs["one"].values()) + list(outs["mpi"].values()):
        if os.path.exists(f):
            os.remove(f)

    def command(who):
        o = outs[who]
        cmd = [args.cli, "mesh", inputs, "-o", o[ext], "--summary", o[".json"], "-q", "-j", "1"] + extra
        return cmd + (["--hidden-features", "--hidden-out", o["_hidden" + ext]] if hidden else [])

    one = run(command("one"))
    if one.returncode != 0:
        sys.exit(f"one process failed: {one.stderr}")
    many = run(mpirun(args, args.np) + command("mpi"))
    if many.returncode != 0:
        sys.exit(f"mpirun -np {args.np} failed ({many.returncode}): {many.stderr}")
    expected = one.stdout
    for k in outs["one"]:
        expected = expected.replace(outs["one"][k], outs["mpi"][k])
    if many.stdout != expected:
        sys.exit(f"printed lines differ:\n{one.stdout}\n{many.stdout}")
    for k in meshes:
        a, b = open(outs["one"][k], "rb").read(), open(outs["mpi"][k], "rb").read()
        if a != b:
            at = next((i for i in range(min(len(a), len(b))) if a[i] != b[i]), min(len(a), len(b)))
            sys.exit(f"{k} files differ ({len(a)} and {len(b)} bytes), first at byte {at}")
    one_json, mpi_json = outs["one"][".json"], outs["mpi"][".json"]
    s1, s2 = json.load(open(one_json)), json.load(open(mpi_json))
    ranks = s2.get("ranks")
    if not isinstance(ranks, list) or len(ranks) != args.np:
        sys.exit(f"ranks block: {ranks}")
    for s in (s1, s2):
        for k in TIMINGS:
            s.pop(k, None)
        s.pop("output", None)
        s.get("hidden", {}).pop("output", None)
    if s1 != s2:
        keys = sorted(k for k in set(s1) | set(s2) if s1.get(k) != s2.get(k))
        sys.exit("summaries differ in " + ", ".join(f"{k}: {s1.get(k)} vs {s2.get(k)}" for k in keys))
    if sum(r["triangles"] for r in ranks) != s1["triangles"] or sum(r["vertices"] for r in ranks) != s1["vertices"]:
        sys.exit(f"ranks do not add up: {ranks}")
    if any(r.get("threads") != 1 for r in ranks):
        sys.exit(f"ranks block: threads {[r.get('threads') for r in ranks]} at -j 1")
    if grid is not None:
        # Each rank reads at most its share (the leaves of its blocks) plus the halo its
        # stencils need (the leaves one leaf around its blocks), both computed here.
        plan, total = plan_bound(inputs, grid, args.np)
        reads = [r["voxels_read"] for r in ranks]
        for r, p in zip(ranks, plan):
            if (r["blocks"], r["weight"]) != (p["blocks"], p["weight"]):
                sys.exit(f"rank {r['rank']}: blocks and weight {r['blocks']}, {r['weight']}, expected {p}")
            if r["voxels_read"] > p["bound"]:
                sys.exit(f"rank {r['rank']} read {r['voxels_read']} voxels, more than its share {p['share']} "
                         f"plus halo: {p['bound']} of {total}")
        print(f"voxels read per rank: {reads}, bounds {[p['bound'] for p in plan]}, shares "
              f"{[p['share'] for p in plan]} of {total}")
    if dims is not None:
        bounds, total = layers_bound(dims, args.np)
        reads = [r["voxels_read"] for r in ranks]
        for r, b in zip(ranks, bounds):
            if r["voxels_read"] > b:
                sys.exit(f"rank {r['rank']} read {r['voxels_read']} samples, more than its slices and halo: {b} of {total}")
        if args.np > 1 and sum(reads) >= args.np * total:
            sys.exit(f"every rank read the whole scan: {reads} of {total}")
        print(f"samples read per rank: {reads}, bounds {bounds} of {total}")
    print(f"np {args.np}: {name}: byte-identical {ext[1:].upper()}{' files' if hidden else ''}, equal summary")


def raw_xyz(data, name, dtype):
    """A raw scan of ../shared/data as an x, y, z array (the file is x fastest)."""
    x, y, z = (int(v) for v in re.search(r"_(\d+)x(\d+)x(\d+)_", name).groups())
    return np.fromfile(os.path.join(data, name), dtype=dtype).reshape(z, y, x).transpose(2, 1, 0)


# An oblique index-to-world affine (column vectors), so that a rank's transform is checked too.
AFFINE = np.array([[0.9, 0.1, 0.0, -5.0], [0.0, 1.1, 0.05, 3.0], [0.0, 0.0, 1.3, 7.0], [0.0, 0.0, 0.0, 1.0]])


def write_nrrd(path, values, data_file=None, gzip_data=False, endian="big"):
    """A NRRD0004 (teem's "NRRD file format"), data attached or in @data_file."""
    types = {np.dtype(np.uint8): "uint8", np.dtype(np.int16): "short", np.dtype(np.float32): "float"}
    vec = lambda v: "(" + ",".join(repr(float(c)) for c in v) + ")"  # noqa: E731
    head = ["NRRD0004", f"type: {types[values.dtype]}", "dimension: 3", "sizes: " + " ".join(map(str, values.shape)),
            "encoding: " + ("gzip" if gzip_data else "raw"), f"endian: {endian}", "space: left-posterior-superior",
            "space directions: " + " ".join(vec(AFFINE[:3, a]) for a in range(3)), "space origin: " + vec(AFFINE[:3, 3])]
    data = values.transpose(2, 1, 0).astype(values.dtype.newbyteorder(">" if endian == "big" else "<")).tobytes()
    data = gzip.compress(data) if gzip_data else data
    if data_file:
        open(os.path.join(os.path.dirname(path), data_file), "wb").write(data)
        open(path, "w").write("\n".join(head + [f"data file: {data_file}"]) + "\n")
    else:
        open(path, "wb").write(("\n".join(head) + "\n\n").encode() + data)


# DICOM's row and column directions are orthonormal (PS3.3 C.7.6.2.1.1): a rotation about z by
# 30 degrees with spacings 0.9 and 1.1, slices 1.3 apart.
C30, S30 = np.cos(np.pi / 6), np.sin(np.pi / 6)
DICOM_AFFINE = np.array([[0.9 * C30, -1.1 * S30, 0.0, -5.0], [0.9 * S30, 1.1 * C30, 0.0, 3.0], [0.0, 0.0, 1.3, 7.0],
                         [0.0, 0.0, 0.0, 1.0]])


def write_dicom(folder, values, slope, intercept):
    """One CT series, one file per slice under names in no order (pydicom), DICOM_AFFINE."""
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid
    os.makedirs(folder, exist_ok=True)
    series = generate_uid()
    for k in range(values.shape[2]):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = CTImageStorage, generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        path = os.path.join(folder, f"IM{(k * 7919) % 1000:03d}{k}")
        ds = FileDataset(path, {}, file_meta=meta, preamble=b"\0" * 128)
        ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.StudyInstanceUID, ds.SeriesInstanceUID, ds.Modality, ds.InstanceNumber = "1.2.3.4", series, "CT", k + 1
        ds.Rows, ds.Columns = values.shape[1], values.shape[0]
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
        ds.ImagePositionPatient = [float(v) for v in DICOM_AFFINE[:3, 3] + k * DICOM_AFFINE[:3, 2]]
        ds.ImageOrientationPatient = [float(v) for v in (*(DICOM_AFFINE[:3, 0] / np.linalg.norm(DICOM_AFFINE[:3, 0])),
                                                         *(DICOM_AFFINE[:3, 1] / np.linalg.norm(DICOM_AFFINE[:3, 1])))]
        ds.PixelSpacing = [float(np.linalg.norm(DICOM_AFFINE[:3, 1])), float(np.linalg.norm(DICOM_AFFINE[:3, 0]))]
        ds.RescaleSlope, ds.RescaleIntercept = slope, intercept
        ds.PixelData = np.ascontiguousarray(values[:, :, k].T).astype("<i2").tobytes()
        ds.is_little_endian, ds.is_implicit_VR = True, False
        ds.save_as(path)


def write_scan(args, case):
    """The input of a SCANS case, written in its work folder; its path and dims."""
    work = os.path.join(args.work, f"{case}_np{args.np}")
    os.makedirs(work, exist_ok=True)
    if case in ("nifti", "nifti_gz"):  # an MRI, int16: plain (read as a raw array), or gzip and
        import nibabel                   # scaled by 0.5 + 2 (scl_slope, scl_inter: read by slices)
        values = raw_xyz(args.data, "brainsmall_128x128x84_uint8.raw", np.uint8).astype(np.int16)
        image = nibabel.Nifti1Image(values, AFFINE)
        image.header.set_slope_inter(*((0.5, 2.0) if case == "nifti_gz" else (1.0, 0.0)))
        path = os.path.join(work, "brain.nii" + (".gz" if case == "nifti_gz" else ""))
        nibabel.save(image, path)
    elif case == "nrrd":  # attached, little-endian int16: a raw array
        values = raw_xyz(args.data, "t1_kmeans_128x128x62_int16.raw", np.int16)
        path = os.path.join(work, "t1.nrrd")
        write_nrrd(path, values, endian="little")
    elif case == "nhdr_gz":  # detached big-endian gzip data: every rank decompresses up to its slices
        values = raw_xyz(args.data, "brainsmall_128x128x84_uint8.raw", np.uint8)
        path = os.path.join(work, "brain.nhdr")
        write_nrrd(path, values, data_file="brain.raw.gz", gzip_data=True)
    elif case == "tiff":  # one multi-page float32 file
        import tifffile
        values = raw_xyz(args.data, "skull_64x64x64_float32.raw", np.float32)
        path = os.path.join(work, "skull.tif")
        tifffile.imwrite(path, np.ascontiguousarray(values.transpose(2, 1, 0)))
    elif case == "tiff_folder":  # one file per slice, numbered
        import tifffile
        values = raw_xyz(args.data, "fuel_64x64x64_uint8.raw", np.uint8)
        path = os.path.join(work, "fuel")
        os.makedirs(path, exist_ok=True)
        for k in range(values.shape[2]):
            tifffile.imwrite(os.path.join(path, f"slice_{k:03d}.tif"), np.ascontiguousarray(values[:, :, k].T))
    else:  # dicom: a CT series, int16 with a rescale
        values = raw_xyz(args.data, "stent_128x128x256_int16.raw", np.int16)[:, :, 60:130]
        path = os.path.join(work, "stent")
        write_dicom(path, values, 0.5, -100.0)
    return path, values.shape


def bad_input(args):
    work = os.path.join(args.work, f"bad_np{args.np}")
    os.makedirs(work, exist_ok=True)
    out = os.path.join(work, "out.ply")
    truncated = os.path.join(work, "truncated.vdb")
    with open(os.path.join(args.data, "sphere.vdb"), "rb") as f:
        open(truncated, "wb").write(f.read()[:300000])
    # A non-finite value that only the last rank reads (x > 0 is at the end of the block order).
    nan_vdb = os.path.join(work, "nan.vdb")
    import pyopenvdb as vdb
    g = vdb.read(os.path.join(args.data, "sphere.vdb"), "ls_sphere")
    g.getAccessor().setValueOn((60, 1, 2), float("nan"))
    vdb.write(nan_vdb, grids=[g])
    inputs = [
        [nan_vdb],
        [os.path.join(work, "missing.vdb")],
        [truncated],
        [os.path.join(args.data, "sphere.vdb"), "--isovalue", "1e9"],
        [os.path.join(args.data, "smoke.vdb"), "--grid", "nothere"],
        [os.path.join(args.data, "fuel_64x64x64_uint8.raw"), "--isovalue", "1e9"],
        [os.path.join(args.data, "fuel_64x64x64_uint8.raw"), "--dims", "64,64,63"],
    ]
    # Scans with headers: a gzip stream cut short, which only the ranks reading its end find out;
    # a detached NRRD whose data file is missing.
    import nibabel
    values = raw_xyz(args.data, "fuel_64x64x64_uint8.raw", np.uint8)
    full = os.path.join(work, "full.nii.gz")
    nibabel.save(nibabel.Nifti1Image(values, np.eye(4)), full)
    cut = os.path.join(work, "cut.nii.gz")
    open(cut, "wb").write(open(full, "rb").read()[:int(os.path.getsize(full) * 0.7)])
    detached = os.path.join(work, "detached.nhdr")
    write_nrrd(detached, values, data_file="gone.raw")
    os.remove(os.path.join(work, "gone.raw"))
    inputs += [[cut], [detached]]
    # The disk takes 100 kB of the 3.7 MB PLY (a file size limit: the same EFBIG as a quota),
    # on the ranks only: the launcher writes its own files.
    small_disk = ["prlimit", "--fsize=100000"]
    cases = [(extra, [], out) for extra in inputs]
    cases.append(([os.path.join(args.data, "sphere.vdb"), "--linear-only"], small_disk, out))
    cases.append(([os.path.join(args.data, "sphere.vdb"), "--linear-only"], small_disk, os.path.join(work, "out.vtp")))
    # A progress delay that is not a number of seconds, read by every rank.
    cases.append(([os.path.join(args.data, "sphere.vdb")], ["env", "ISOUQ_PROGRESS_SECONDS=10s"], out))
    for extra, limit, out in cases:
        r = run(mpirun(args, args.np) + limit + [args.cli, "mesh"] + extra + ["-o", out, "-j", "1"])
        lines = [l for l in r.stderr.splitlines() if l.startswith("isouq: error:")]
        if r.returncode != 2 or len(lines) != 1:
            sys.exit(f"{extra}: exit {r.returncode}, error lines {lines}\n{r.stderr}")
        if os.path.exists(out) or glob.glob(os.path.join(work, ".isouq-*")):
            sys.exit(f"{extra}: an output was left behind")
        one = run(limit + [args.cli, "mesh"] + extra + ["-o", out, "-j", "1"])  # says the same
        if one.returncode != 2 or one.stderr.strip() != lines[0]:
            sys.exit(f"{extra}: one process says {one.stderr.strip()!r}, the ranks {lines[0]!r}")
        print(f"np {args.np}: {' '.join(os.path.basename(e) for e in extra)}: {lines[0]}")


def write_smoke_sequence(folder):
    """A fog cache written by pyopenvdb: smoke_0001.vdb to smoke_0004.vdb, grid 'density', frame 1
    with no active voxel (nothing emitted yet), then a soft ball that grows and moves."""
    import pyopenvdb as vdb
    os.makedirs(folder, exist_ok=True)
    z, y, x = np.mgrid[0:40, 0:40, 0:40].astype(np.float32)
    for f in range(1, 5):
        g = vdb.FloatGrid()
        g.name = "density"
        g.gridClass = vdb.GridClass.FOG_VOLUME
        if f > 1:
            d = np.sqrt((x - 20 + f) ** 2 + (y - 18) ** 2 + (z - 20) ** 2)
            g.copyFromArray(np.clip((6 + 3 * f - d) / 4, 0, 1).astype(np.float32).transpose(2, 1, 0).copy(), tolerance=0)
        vdb.write(os.path.join(folder, f"smoke_{f:04d}.vdb"), grids=[g])
    return os.path.join(folder, "smoke_####.vdb")


def sequence(args):
    """A frame sequence under mpirun against one process (docs/mpi.md "Sequences"): each frame's
    PLY byte-identical, the same printed lines, the sequence summary equal plus each frame's
    ranks block; with --frame-jobs (groups of ranks, each every N-th frame) too; then --resume
    after a lost frame, and the errors of a sequence (a frame cut short, missing frames, more
    frame jobs than ranks) as one error line and exit 2 from every rank."""
    work = os.path.join(args.work, f"sequence_np{args.np}")
    inputs = write_smoke_sequence(os.path.join(work, "cache"))
    dirs = {who: os.path.join(work, who) for who in ("one", "mpi")}
    for d in dirs.values():
        os.makedirs(d, exist_ok=True)
        for f in glob.glob(os.path.join(d, "*")) + glob.glob(os.path.join(d, ".isouq-*")):
            os.remove(f)

    def command(who, *extra):
        return [args.cli, "mesh", inputs, "-o", os.path.join(dirs[who], "m_####.ply"), "--summary",
                os.path.join(dirs[who], "s.json"), "-j", "1"] + list(extra)

    # Frame jobs at 2 to 4 ranks: groups of one rank, of two and one, of two, one and one.
    jobs = ["--frame-jobs", str(min(args.np, 3))] if args.np > 1 else []

    def both(*extra, mpi_only=()):
        # One process meshes the frames in order, and rank 0 reports frame jobs' frames in order.
        one = run(command("one", *extra))
        many = run(mpirun(args, args.np) + command("mpi", *extra, *mpi_only))
        if one.returncode != 0 or many.returncode != 0:
            sys.exit(f"exit {one.returncode} and {many.returncode}: {one.stderr}\n{many.stderr}")
        if many.stdout != one.stdout.replace(dirs["one"], dirs["mpi"]):
            sys.exit(f"printed lines differ:\n{one.stdout}\n{many.stdout}")
        for f in range(1, 5):
            a, b = (open(os.path.join(dirs[w], f"m_{f:04d}.ply"), "rb").read() for w in ("one", "mpi"))
            if a != b:
                sys.exit(f"frame {f}: the PLY files differ ({len(a)} and {len(b)} bytes)")
        s1, s2 = (json.load(open(os.path.join(dirs[w], "s.json"))) for w in ("one", "mpi"))
        for s in (s1, s2):
            s.pop("timings_ms")
            s["sequence"].pop("output")
            for e in s["frames"]:
                e.pop("output")
        # Frames 1 and 2 set the grid and the isovalue on every rank; frame jobs mesh the others.
        groups = int(mpi_only[1]) if mpi_only else 1
        for e in s2["frames"]:
            ranks = e.pop("ranks", None)
            if e.get("resumed"):
                continue
            k = e["frame"] - 3  # the frame's place among the frame jobs' frames
            size = args.np if k < 0 else len(range(k % groups, args.np, groups))
            if len(ranks) != size or sum(r["triangles"] for r in ranks) != e["triangles"]:
                sys.exit(f"frame {e['frame']}: ranks block {ranks}, expected {size} ranks")
        if s1 != s2:
            sys.exit(f"sequence summaries differ:\n{s1}\n{s2}")
        return s2

    s = both()
    if [e["empty"] for e in s["frames"]] != [True, False, False, False] or s["totals"]["triangles"] == 0:
        sys.exit(f"frames: {s['frames']}")
    if jobs:
        both(mpi_only=jobs)
    for who in dirs:  # a lost frame, meshed again; the others kept (frame 4 read back by group 1)
        os.remove(os.path.join(dirs[who], "m_0003.ply"))
    first = s
    # The empty frame 1 does not set the isovalue: frame 2 does. With the grid given, the frames
    # after it go to the frame jobs (a kept frame does not tell which grid the run meshes).
    s = both("--resume", "--grid", "density", mpi_only=jobs)
    if [bool(e.get("resumed")) for e in s["frames"]] != [True, True, False, True] or \
            (s["isovalue"], s["totals"]["triangles"]) != (first["isovalue"], first["totals"]["triangles"]):
        sys.exit(f"--resume: {s}")

    broken = os.path.join(work, "broken")
    write_smoke_sequence(broken)
    frame3 = os.path.join(broken, "smoke_0003.vdb")
    head = open(frame3, "rb").read()[:2000]
    open(frame3, "wb").write(head)  # cut short: grid 'density' ends past the end of the file
    out = os.path.join(work, "bad", "m_####.ply")
    cases = [([os.path.join(broken, "smoke_####.vdb")], ["m_0001.ply", "m_0002.ply"]),
             ([inputs, "--frames", "1-6"], []), ([inputs, "--frame-jobs", str(args.np + 1)], [])]
    broken4 = os.path.join(work, "broken4")
    if jobs:  # frame 4 cut short, in the second frame job: one error line, frame 3 written
        write_smoke_sequence(broken4)
        open(os.path.join(broken4, "smoke_0004.vdb"), "wb").write(head)
        cases.append(([os.path.join(broken4, "smoke_####.vdb"), "--grid", "density"] + jobs,
                      ["m_0001.ply", "m_0002.ply", "m_0003.ply"]))
    for extra, kept in cases:
        for f in glob.glob(os.path.join(work, "bad", "*")) + glob.glob(os.path.join(work, "bad", ".isouq-*")):
            os.remove(f)
        r = run(mpirun(args, args.np) + [args.cli, "mesh"] + extra + ["-o", out, "-j", "1"])
        lines = [l for l in r.stderr.splitlines() if l.startswith("isouq: error:")]
        if r.returncode != 2 or len(lines) != 1:
            sys.exit(f"{extra}: exit {r.returncode}, error lines {lines}\n{r.stderr}")
        left = sorted(os.listdir(os.path.join(work, "bad"))) if os.path.isdir(os.path.join(work, "bad")) else []
        if left != kept:
            sys.exit(f"{extra}: left {left}, expected {kept}")
        if "--frame-jobs" not in extra or extra[0].startswith(broken4):  # one process says the same
            one = run([args.cli, "mesh"] + extra + ["-o", out, "-j", "1"])
            if one.returncode != 2 or one.stderr.strip().splitlines()[-1] != lines[0]:
                sys.exit(f"{extra}: one process says {one.stderr.strip()!r}, the ranks {lines[0]!r}")
        print(f"np {args.np}: {' '.join(os.path.basename(e) for e in extra)}: {lines[0]}")
    for f in glob.glob(os.path.join(work, "bad", "*")):
        os.remove(f)
    if args.np <= 2:  # Ctrl-C as srun forwards it, in the first of three frames of big_sphere
        frames = os.path.join(work, "big")
        os.makedirs(frames, exist_ok=True)
        for f in range(1, 4):
            link = os.path.join(frames, f"big_{f:04d}.vdb")
            if not os.path.lexists(link):
                os.symlink(big_sphere(args.work), link)
        out = os.path.join(work, "bad", "big_####.ply")
        # In the first frame; at 2 ranks also in the first round of two frame jobs (grid and
        # isovalue given: no frame is meshed by every rank first).
        for extra in [[]] + ([["--grid", "ls", "--isovalue", "0"] + jobs] if jobs else []):
            p = subprocess.Popen(mpirun(args, args.np) + [args.cli, "mesh", os.path.join(frames, "big_####.vdb"), "-o",
                                                          out, "--summary", os.path.join(work, "bad", "s.json"), "-j", "1",
                                                          "--hidden-features", "--no-hidden-filter", "--subdivisions",
                                                          "12"] + extra,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for pid in ranks_with_handlers(args, p):
                os.kill(pid, signal.SIGINT)
            got, err = p.communicate(timeout=300)
            left = os.listdir(os.path.join(work, "bad"))
            if p.returncode != 130 or "the frames finished so far are written" not in err or left:
                sys.exit(f"SIGINT in a sequence {extra}: exit {p.returncode}, left {left}\n{got}\n{err}")
            print(f"np {args.np}: SIGINT in a sequence's first frame {' '.join(extra)}: exit 130, nothing written")
    print(f"np {args.np}: sequence: byte-identical PLY files, equal summaries, --resume")


def big_sphere(work):
    # Big enough that a run on a quiet machine is still meshing when the signal comes.
    path = os.path.join(work, "big_sphere_r400.vdb")
    if not os.path.exists(path):
        import pyopenvdb as vdb
        g = vdb.createLevelSetSphere(radius=400.0, center=(0, 0, 0), voxelSize=1.0, halfWidth=3.0)
        g.name = "ls"
        vdb.write(path, grids=[g])
    return path


def children(pid):
    try:
        out = run(["ps", "-o", "pid=", "--ppid", str(pid)]).stdout.split()
    except OSError:
        return []
    return [int(p) for p in out]


def handles_signals(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            caught = next(int(line.split()[1], 16) for line in f if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return all(caught >> (s - 1) & 1 for s in (signal.SIGINT, signal.SIGTERM))


def ranks_with_handlers(args, p):
    """The ranks of mpirun @p once each has its SIGINT and SIGTERM handlers (/proc's SigCgt),
    however slow its start (sanitizers): the run has seconds of work left then."""
    ranks = []
    deadline = time.time() + 300
    while time.time() < deadline and not (len(ranks) == args.np and all(map(handles_signals, ranks))):
        ranks = children(p.pid)
        time.sleep(0.02)
    return ranks


def interrupt(args):
    work = os.path.join(args.work, f"interrupt_np{args.np}")
    os.makedirs(work, exist_ok=True)
    src = big_sphere(args.work)
    out = os.path.join(work, "out.ply")
    # SIGINT to every rank, as srun forwards Ctrl-C (mpirun itself turns it into SIGTERM).
    for target in ("ranks", "mpirun"):
        for stale in glob.glob(out) + glob.glob(os.path.join(work, ".isouq-*")):
            os.remove(stale)  # an earlier run's
        # Hidden features at -j 1 keep the ranks busy for seconds after the load: mpirun sends
        # SIGTERM only a second after its SIGINT, and the plain pass would often be done by then.
        p = subprocess.Popen(mpirun(args, args.np) + [args.cli, "mesh", src, "-o", out, "-j", "1",
                                                      "--hidden-features", "--no-hidden-filter",
                                                      "--subdivisions", "12"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        ranks = ranks_with_handlers(args, p)
        if target == "ranks":
            for pid in ranks:
                os.kill(pid, signal.SIGINT)
        else:
            p.send_signal(signal.SIGINT)
        got, err = p.communicate(timeout=300)
        if "wrote" in got:
            sys.exit(f"SIGINT to the {target}: the run ended before the signal reached the ranks; "
                     f"give them more work (big_sphere, the options above)\n{got}")
        # mpirun sends SIGKILL a second after its SIGTERM: sanitized ranks may still be unwinding.
        if target == "ranks" and "interrupted" not in err:
            sys.exit(f"SIGINT to the {target}: no rank said it was interrupted\n{err}")
        expect = 130 if target == "ranks" else None
        if expect is not None and p.returncode != expect:
            sys.exit(f"SIGINT to the {target}: exit {p.returncode}, expected {expect}\n{err}")
        if os.path.exists(out) or glob.glob(os.path.join(work, ".isouq-*")):
            sys.exit(f"SIGINT to the {target}: an output was left behind (exit {p.returncode})")
        print(f"np {args.np}: SIGINT to the {target}: exit {p.returncode}, no output")


def threads(args):
    """-j 0 (the default) under mpirun: the cores a rank may use shared among the ranks of its
    machine (docs/mpi.md), every rank here; an explicit -j is taken as given (up to the cores:
    the ranks block counts the threads a loop gets)."""
    work = os.path.join(args.work, f"threads_np{args.np}")
    os.makedirs(work, exist_ok=True)
    cores = len(os.sched_getaffinity(0))  # --bind-to none: every rank may use the test's cores
    for flags, want in (([], max(1, cores // args.np)), (["-j", "3"], min(3, cores))):
        out, summary = os.path.join(work, "t.ply"), os.path.join(work, "t.json")
        r = run(mpirun(args, args.np) + ["--bind-to", "none", args.cli, "mesh", "field:tubey", "--resolution", "32",
                                         "-o", out, "--summary", summary, "-q"] + flags)
        if r.returncode != 0:
            sys.exit(f"mpirun -np {args.np} failed ({r.returncode}): {r.stderr}")
        got = [x["threads"] for x in json.load(open(summary))["ranks"]]
        if got != [want] * args.np:
            sys.exit(f"np {args.np}, {cores} cores, {flags or 'no -j'}: threads per rank {got}, expected {want}")
        print(f"np {args.np}, {cores} cores, {' '.join(flags) or 'no -j'}: {want} threads per rank")


def ranks_named(args, marker):
    """The rank processes whose command line names @marker (srun's tasks are children of
    slurmstepd, not of srun), once each has its SIGINT and SIGTERM handlers."""
    deadline = time.time() + 300
    while time.time() < deadline:
        ranks = []
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                words = open(f"/proc/{pid}/cmdline", "rb").read().split(b"\0")
            except OSError:
                continue
            if marker.encode() in words and os.path.basename(words[0]) == b"isouq":
                ranks.append(int(pid))
        if len(ranks) == args.np and all(map(handles_signals, ranks)):
            return ranks
        time.sleep(0.02)
    sys.exit(f"the {args.np} ranks naming {marker} did not start")


def slurm_signals(args):
    """scancel (Slurm's SIGTERM, SIGKILL only KillWait seconds later) stops every rank at its next
    check: one line, exit 143 from every rank and from srun, nothing left. Ctrl-C through srun
    (--quit-on-interrupt, as a second Ctrl-C within a second) is SIGINT and at once SIGKILL: srun
    exits 137 (130 if the ranks stop first) and, the signal coming before the write, no file is
    left either."""
    work = os.path.join(args.work, f"slurm_signals_np{args.np}")
    os.makedirs(work, exist_ok=True)
    src = big_sphere(args.work)
    for how in ("scancel", "ctrl-c"):
        out = os.path.join(work, f"{how}.ply")
        launch = mpirun(args, args.np)
        if how == "ctrl-c":
            launch.insert(1, "--quit-on-interrupt")
        p = subprocess.Popen(launch + [args.cli, "mesh", src, "-o", out, "-j", "1", "--hidden-features",
                                       "--no-hidden-filter", "--subdivisions", "12"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        ranks = ranks_named(args, out)
        if how == "scancel":  # the ranks' own job (an earlier case's may still be completing)
            environ = open(f"/proc/{ranks[0]}/environ", "rb").read().split(b"\0")
            job = next(v.split(b"=", 1)[1].decode() for v in environ if v.startswith(b"SLURM_JOB_ID="))
            run(["scancel", job])
        else:
            p.send_signal(signal.SIGINT)
        got, err = p.communicate(timeout=300)
        left = [f for f in os.listdir(work) if f.startswith(f"{how}.") or f.startswith(".isouq-")]
        if "wrote" in got or left:
            sys.exit(f"{how}: the run ended with files {left}\n{got}\n{err}")
        interrupted = [l for l in err.splitlines() if l.startswith("isouq: interrupted")]
        # The SIGKILL that follows srun's SIGINT may come after a rank has stopped (exit 130).
        if how == "scancel":
            ok = p.returncode == 143 and len(interrupted) == 1
        else:
            ok = p.returncode in (130, 137)
        if not ok:
            sys.exit(f"{how}: srun exit {p.returncode}, {len(interrupted)} interrupted lines\n{err}")
        print(f"np {args.np}: {how} under srun: exit {p.returncode}, nothing written")


def slurm_threads(args):
    """-j 0 (the default) under srun: each rank runs a thread on each CPU Slurm bound it to
    (task/affinity): all of the node's with one task, one each with a task a CPU."""
    cpus = len(os.sched_getaffinity(0))
    out, summary = (os.path.join(args.work, f"slurm_threads_np{args.np}.{e}") for e in ("ply", "json"))
    for tasks, per_task in ((1, cpus), (min(args.np, cpus), 1)):
        r = run([args.srun, "--mpi=pmix", "-n", str(tasks), "-c", str(per_task), args.cli, "mesh",
                 os.path.join(args.data, "sphere.vdb"), "-o", out, "--summary", summary, "-q"])
        if r.returncode != 0:
            sys.exit(f"srun -n {tasks} -c {per_task}: exit {r.returncode}\n{r.stderr}")
        threads = [rank["threads"] for rank in json.load(open(summary))["ranks"]]
        if threads != [per_task] * tasks:
            sys.exit(f"srun -n {tasks} -c {per_task}: the ranks ran {threads} threads")
        print(f"np {args.np}: srun -n {tasks} -c {per_task}: threads {threads}")


def slurm_no_pmix(args):
    """srun without PMIx (Slurm's default MpiDefault=none, or --mpi=pmi2): one error line from
    the first task, exit 2 from every task, nothing written; one task without PMI is a plain run."""
    work = os.path.join(args.work, f"slurm_no_pmix_np{args.np}")
    os.makedirs(work, exist_ok=True)
    out = os.path.join(work, "out.ply")
    for mpi in ([], ["--mpi=pmi2"]):
        r = run([args.srun, "-n", str(args.np)] + mpi + [args.cli, "mesh", os.path.join(args.data, "sphere.vdb"), "-o", out])
        lines = [l for l in r.stderr.splitlines() if l.startswith("isouq: error:")]
        if args.np == 1 and not mpi:  # one task without PMI: no launcher as far as isouq knows, a plain run
            if r.returncode != 0 or not os.path.exists(out):
                sys.exit(f"srun -n 1 {mpi}: exit {r.returncode}\n{r.stderr}")
            os.remove(out)
            continue
        if r.returncode != 2 or len(lines) != 1 or "srun --mpi=pmix" not in lines[0] or os.listdir(work):
            sys.exit(f"srun {mpi}: exit {r.returncode}, error lines {lines}, left {os.listdir(work)}\n{r.stderr}")
        print(f"np {args.np}: srun {' '.join(mpi) or '(MpiDefault=none)'}: {lines[0]}")


def progress(args):
    """Rank 0 alone shows progress under mpirun, as lines (its stderr is the launcher's pipe):
    a line at each tenth of a stage once it has run ISOUQ_PROGRESS_SECONDS, then one saying it is
    done; none with -q, none in a short run at the default 10 s, none from one process into a pipe."""
    work = os.path.join(args.work, f"progress_np{args.np}")
    os.makedirs(work, exist_ok=True)
    out = os.path.join(work, "p.ply")
    engine, fuel = (os.path.join(args.data, n) for n in ("engine_256x256x128_uint8.raw", "fuel_64x64x64_uint8.raw"))
    line = re.compile(r"isouq: (Loading volume|Counting triangles|Meshing) (\d+)% \(\d+\.\d s\)$")
    done = re.compile(r"isouq: (Loading volume|Counting triangles|Meshing) done \(\d+\.\d s\)$")

    def mesh(launcher, seconds, src, flags=()):
        env = dict(os.environ, ISOUQ_PROGRESS_SECONDS=seconds)
        r = run(launcher + [args.cli, "mesh", src, "-o", out, "-j", "1"] + list(flags), env=env)
        if r.returncode != 0:
            sys.exit(f"{' '.join(launcher)} failed ({r.returncode}): {r.stderr}")
        return [x for x in r.stderr.splitlines() if line.match(x) or done.match(x)]

    lines = mesh(mpirun(args, args.np) + ["-x", "ISOUQ_PROGRESS_SECONDS"], "0", engine, ["--isovalue", "71"])
    stages, last = [], None
    for x in lines:  # each stage: its tenths rising, then its done line
        m = line.match(x)
        if m:
            if last is not None and (m.group(1) != last[0] or int(m.group(2)) <= last[1]):
                sys.exit(f"np {args.np}: progress out of order at '{x}':\n" + "\n".join(lines))
            last = (m.group(1), int(m.group(2)))
        else:
            if last is None or done.match(x).group(1) != last[0]:
                sys.exit(f"np {args.np}: '{x}' without its stage's lines:\n" + "\n".join(lines))
            stages.append(last[0])
            last = None
    # One load (every rank's would be np), then the mesher's count and fill passes.
    if last is not None or stages != ["Loading volume", "Counting triangles", "Meshing"]:
        sys.exit(f"np {args.np}: expected one rank's stages, each ended:\n" + "\n".join(lines))
    # The short run: the 64^3 fuel scan, well under the default 10 s even with sanitizers.
    for what, launcher, seconds, src, flags in (
            ("-q", mpirun(args, args.np) + ["-x", "ISOUQ_PROGRESS_SECONDS"], "0", engine, ["--isovalue", "71", "-q"]),
            ("the default delay", mpirun(args, args.np), "10", fuel, []),
            ("one process into a pipe", [], "0", engine, ["--isovalue", "71"])):
        if mesh(launcher, seconds, src, flags):
            sys.exit(f"np {args.np}: progress lines with {what}")
    print(f"np {args.np}: {len(lines)} progress lines from one rank ({', '.join(stages)}); none with -q, "
          "the default delay or one process into a pipe")


def main():
    ap = argparse.ArgumentParser()
    for k in ("cli", "case", "data", "work"):
        ap.add_argument("--" + k, required=True)
    launcher = ap.add_mutually_exclusive_group(required=True)
    launcher.add_argument("--mpirun")
    launcher.add_argument("--srun")
    ap.add_argument("--np", type=int, required=True)
    args = ap.parse_args()
    os.makedirs(args.work, exist_ok=True)
    if not args.srun:
        for case in args.case.split(","):
            run_case(args, case)
        return
    from slurm_local import LocalSlurm, missing_programs
    if os.geteuid() != 0 or missing_programs():
        print(f"skipped: the srun tests start slurmd, which needs root and {' '.join(missing_programs()) or 'Slurm'}")
        sys.exit(77)
    # Slurm's CPUs and binding where the machine has a core a rank, else a node of 4 CPUs unbound.
    cores = len(os.sched_getaffinity(0))
    with LocalSlurm(os.path.join(args.work, f"slurm_np{args.np}"), cpus=None if args.np <= cores else max(4, args.np)) as env:
        os.environ.update(env)
        for case in args.case.split(","):
            run_case(args, case)


def run_case(args, case):
    sphere, smoke = os.path.join(args.data, "sphere.vdb"), os.path.join(args.data, "smoke.vdb")
    args.case = case
    if args.case == "sphere":
        compare(args, "sphere", sphere, [], grid="ls_sphere")
    elif args.case == "sphere_linear":
        compare(args, "sphere_linear", sphere, ["--linear-only"], grid="ls_sphere")
    elif args.case == "fog":
        compare(args, "fog", smoke, ["--grid", "density"], grid="density")
    elif args.case == "fog_k":
        compare(args, "fog_k", smoke, ["--isovalue", "0.1", "--method", "cubic"], grid="density")
    elif args.case == "raw":
        compare(args, "raw", os.path.join(args.data, "fuel_64x64x64_uint8.raw"), [], dims=(64, 64, 64))
    elif args.case == "raw_float":
        compare(args, "raw_float", os.path.join(args.data, "skull_64x64x64_float32.raw"), ["--method", "cubic"],
                dims=(64, 64, 64))
    elif args.case == "raw_k":
        compare(args, "raw_k", os.path.join(args.data, "engine_256x256x128_uint8.raw"), ["--isovalue", "71"],
                dims=(256, 256, 128))
    elif args.case == "field":  # SPEC §5 Tubey at 48^3: sampled by z-layers, with its truth node
        compare(args, "field", "field:tubey", ["--resolution", "48"], dims=(48, 48, 48))
    elif args.case == "field_hidden":  # SPEC §4 on Tubey: refined and transition cells on brick faces
        compare(args, "field_hidden", "field:tubey", [], dims=(32, 32, 32), hidden=True)
    elif args.case == "formula":
        compare(args, "formula", "formula:x*x+y*y+z*z-0.5+0.1*sin(9*x)", ["--resolution", "40", "--method", "cubic"],
                dims=(40, 40, 40))
    elif args.case == "color":  # --color-by: the 2nd and 98th percentiles of every rank's values
        compare(args, "color", sphere, ["--color-by", "err_est"], grid="ls_sphere")
        # A signed measure (negative keys of the radix select) and the hidden mesh's NaN rows.
        compare(args, "color_signed", "field:tubey", ["--color-by", "dist_true", "--colormap", "coolwarm"],
                dims=(32, 32, 32), hidden=True)
    elif args.case == "vtp":  # -o .vtp: each rank's rows of every appended block at their offsets
        compare(args, "vtp", sphere, [], grid="ls_sphere", ext=".vtp")
        # Three sections a rank, a face column, colours (uint8 columns) and a fog volume.
        compare(args, "vtp_hidden", "field:tubey", ["--color-by", "err_est"], dims=(32, 32, 32), hidden=True, ext=".vtp")
        compare(args, "vtp_fog", smoke, ["--grid", "density"], grid="density", ext=".vtp")
    elif args.case == "ascii":  # --ply-format ascii: each rank's lines at offsets from every rank's byte counts
        compare(args, "ascii", sphere, ["--ply-format", "ascii"], grid="ls_sphere")
        compare(args, "ascii_hidden", "field:tubey", ["--ply-format", "ascii", "--color-by", "err_est"],
                dims=(32, 32, 32), hidden=True)
    elif args.case == "few_blocks":  # ranks with no active voxel: a tiny field, a scan's surface in its top layers
        compare(args, "few_blocks_field", "field:sphere", ["--resolution", "8"], dims=(8, 8, 8))
        z, y, x = np.mgrid[0:64, 0:8, 0:8]
        values = np.where((x - 3.5) ** 2 + (y - 3.5) ** 2 + (z - 59.5) ** 2 < 9, 200, 10).astype(np.uint8)
        path = os.path.join(args.work, "top_8x8x64_uint8.raw")
        values.tofile(path)
        compare(args, "few_blocks_raw", path, ["--isovalue", "100"], dims=(8, 8, 64))
    elif args.case in SCANS:
        path, dims = write_scan(args, args.case)
        compare(args, args.case, path, ["--method", "cubic"] if args.case == "tiff" else [], dims=dims)
    elif args.case == "bad_input":
        bad_input(args)
    elif args.case == "interrupt":
        interrupt(args)
    elif args.case == "threads":
        threads(args)
    elif args.case == "progress":
        progress(args)
    elif args.case == "sequence":
        sequence(args)
    elif args.case == "slurm_signals" and args.srun:
        slurm_signals(args)
    elif args.case == "slurm_threads" and args.srun:
        slurm_threads(args)
    elif args.case == "slurm_no_pmix" and args.srun:
        slurm_no_pmix(args)
    else:
        sys.exit("unknown case " + args.case)


if __name__ == "__main__":
    main()
