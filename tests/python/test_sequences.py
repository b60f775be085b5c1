"""Frame sequences (SPEC §10 "Sequences", issue 11) through the real CLI, on caches written here
with pyopenvdb: one isovalue for every frame, empty frames, missing frames, --resume, Ctrl-C,
frames at once, and the sequence summary."""
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "blender_addon" / "isouq"))
import ply_io  # noqa: E402  (the project's one PLY reader)

vdb = pytest.importorskip("pyopenvdb")


def fog_cache(folder, frames=range(1, 7), empty=(4,), absent=()):
    """Mantaflow-like fog frames: a ball of density 0.2..1 (every active value above a low
    threshold), background 0; `empty` frames have an empty grid, `absent` ones none at all."""
    folder.mkdir(parents=True, exist_ok=True)
    for f in frames:
        grid = vdb.FloatGrid(background=0.0)
        grid.name = "density" if f not in absent else "flame"
        grid.gridClass = vdb.GridClass.FOG_VOLUME
        if f not in empty and f not in absent:
            r = 3 + f
            acc = grid.getAccessor()
            for x in range(-r, r + 1):
                for y in range(-r, r + 1):
                    for z in range(-r, r + 1):
                        d = (x * x + y * y + z * z) ** 0.5
                        if d <= r:
                            acc.setValueOn((x + f, y, z), max(0.2, 1.0 - d / (r + 1)))
        vdb.write(str(folder / f"fluid_data_{f:04d}.vdb"), grids=[grid])


def run(cli, *args, cwd, check=True):
    proc = subprocess.run([cli, "mesh", *args, "--quiet"], cwd=cwd, capture_output=True, text=True, timeout=600)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def test_every_frame_meshed_closed_with_one_isovalue(isouq_cli, tmp_path):
    fog_cache(tmp_path / "cache", absent=(5,))
    # The output folders are made, the summary's too.
    run(isouq_cli, "cache/fluid_data_####.vdb", "--grid", "density", "-k", "0.05", "-o", "out/smoke.####.ply",
        "--summary", "runs/a/seq.json", cwd=tmp_path)
    summary = json.loads((tmp_path / "runs/a/seq.json").read_text())
    assert [e["frame"] for e in summary["frames"]] == [1, 2, 3, 4, 5, 6]
    assert summary["totals"]["empty"] == 2 and summary["isovalue"] == 0.05
    for e in summary["frames"]:
        mesh = ply_io.read_ply(str(tmp_path / e["output"]))
        assert len(mesh.positions) == e["vertices"]
        assert mesh.isovalue == pytest.approx(0.05)
        if e["frame"] in (4, 5):  # an empty and an absent grid: an empty, valid mesh
            assert e["empty"] and e["vertices"] == 0
        else:  # every active value is above k: the surface is where they meet the background
            assert e["vertices"] > 100 and e["boundary_edges"] == 0 and e["components"] == 1
            assert set(e["err_est"]) >= {"min", "max", "mean", "rms"}
    assert summary["frames"][5]["vertices"] > summary["frames"][0]["vertices"]  # the ball grows


def test_default_isovalue_comes_from_the_first_frame_with_data(isouq_cli, tmp_path):
    fog_cache(tmp_path / "cache", frames=range(1, 5), empty=(1,))
    run(isouq_cli, "cache/fluid_data_%04d.vdb", "-o", "out/m.%04d.ply", "--summary", "s.json", cwd=tmp_path)
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["isovalue_source"].endswith("of frame 2")
    headers = [ply_io.read_ply(str(tmp_path / e["output"])).isovalue for e in summary["frames"][1:]]
    assert headers == pytest.approx([summary["isovalue"]] * 3)


def test_patterns_with_a_literal_percent_two_numbers_or_no_range(isouq_cli, tmp_path):
    # printf's "%%" is a literal % (it was read as the start of %04d); a name with two frame
    # numbers is refused (only the last was replaced); an empty --frames is an error (was "all").
    fog_cache(tmp_path / "cache", frames=range(1, 3), empty=())
    for f in (1, 2):
        os.rename(tmp_path / "cache" / f"fluid_data_{f:04d}.vdb", tmp_path / "cache" / f"fog100%_{f:04d}.vdb")
    run(isouq_cli, "cache/fog100%%_%04d.vdb", "-k", "0.1", "-o", "out/m%%.%04d.ply", cwd=tmp_path)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["m%.0001.ply", "m%.0002.ply"]
    for args, words in ((["cache/fog100%%_%04d.vdb", "-o", "out/a_####_####.ply"], "two frame numbers"),
                        (["cache/f_##_####.vdb", "-o", "out/a_####.ply"], "two frame numbers"),
                        (["cache/fog100%%_%04d.vdb", "--frames", "", "-o", "out/b_####.ply"], "got ''")):
        proc = run(isouq_cli, *args, "-k", "0.1", cwd=tmp_path, check=False)
        assert proc.returncode == 2 and words in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["m%.0001.ply", "m%.0002.ply"]


def test_without_grid_every_frame_meshes_the_first_frames_grid(isouq_cli, tmp_path):
    # Frame 2 stores flame before density and frame 3 only flame: each used to mesh its own
    # first grid (hostile sweep, 7 Dec). Now density throughout, as with --grid density.
    fog_cache(tmp_path / "a", frames=range(1, 4), empty=())
    for f, order in ((1, ("density", "flame")), (2, ("flame", "density")), (3, ("flame",))):
        density = vdb.read(str(tmp_path / "a" / f"fluid_data_{f:04d}.vdb"), "density")
        flame = vdb.FloatGrid(background=0.0)
        flame.name = "flame"
        flame.gridClass = vdb.GridClass.FOG_VOLUME
        flame.fill((20, 20, 20), (23, 23, 23), 0.9)
        grids = {"density": density, "flame": flame}
        vdb.write(str(tmp_path / "a" / f"fluid_data_{f:04d}.vdb"), grids=[grids[g] for g in order])
    run(isouq_cli, "a/fluid_data_####.vdb", "-k", "0.1", "-o", "x/m.####.ply", "--summary", "x.json", cwd=tmp_path)
    run(isouq_cli, "a/fluid_data_####.vdb", "-k", "0.1", "--grid", "density", "-o", "y/m.####.ply",
        "--summary", "y.json", cwd=tmp_path)
    x, y = (json.loads((tmp_path / n).read_text()) for n in ("x.json", "y.json"))
    assert x["sequence"]["grid"] == "density" and [e["grid"] for e in x["frames"]] == ["density"] * 3
    assert [e["vertices"] for e in x["frames"]] == [e["vertices"] for e in y["frames"]]
    assert x["frames"][1]["vertices"] > 0 and x["frames"][2]["empty"]
    for f in (1, 2, 3):
        assert (tmp_path / f"x/m.{f:04d}.ply").read_bytes() == (tmp_path / f"y/m.{f:04d}.ply").read_bytes()
    proc = subprocess.run([isouq_cli, "mesh", "a/fluid_data_####.vdb", "-k", "0.1", "-o", "z/m.####.ply"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert "grid 'density' (the first float grid of frame 1) for every frame" in proc.stderr, proc.stderr


def test_missing_frames_are_listed_before_any_work(isouq_cli, tmp_path):
    fog_cache(tmp_path / "cache", frames=[1, 2, 3, 6], empty=())
    (tmp_path / "file").write_text("")  # a folder that cannot be made: one line, nothing written
    proc = run(isouq_cli, "cache/fluid_data_####.vdb", "--skip-missing", "-k", "0.1", "-o", "made/m.####.ply",
               "--summary", "file/s.json", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith(
        "isouq: error: cannot write file/s.json: cannot make its folder file: Not a directory"), proc.stderr
    assert not any((tmp_path / "made").iterdir())
    proc = run(isouq_cli, "cache/fluid_data_####.vdb", "-k", "0.1", "-o", "out/m.####.ply", cwd=tmp_path, check=False)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("isouq: error:") and "frames 4-5 of 1-6 missing" in lines[0]
    assert not (tmp_path / "out").exists()
    # A step: the range as it runs (2-9:2 is frames 2, 4, 6, 8), not as 2-8 with every frame.
    proc = run(isouq_cli, "cache/fluid_data_####.vdb", "--frames", "2-9:2", "-k", "0.1", "-o", "out/m.####.ply",
               cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "frames 4, 8 of 2-8:2 missing (2 of 4)" in proc.stderr, proc.stderr
    run(isouq_cli, "cache/fluid_data_####.vdb", "--skip-missing", "-k", "0.1", "-o", "out/m.####.ply", cwd=tmp_path)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f"m.{f:04d}.ply" for f in (1, 2, 3, 6)]


def test_resume_keeps_finished_frames_and_frame_jobs_change_nothing(isouq_cli, tmp_path):
    fog_cache(tmp_path / "cache")
    args = ["cache/fluid_data_####.vdb", "-k", "0.05", "--hidden-features", "--hidden-out", "hf/h.####.ply"]
    run(isouq_cli, *args, "-o", "a/m.####.ply", "--summary", "a.json", cwd=tmp_path)
    run(isouq_cli, *args, "-o", "b/m.####.ply", "--frame-jobs", "2", cwd=tmp_path)
    for f in range(1, 7):
        assert (tmp_path / f"a/m.{f:04d}.ply").read_bytes() == (tmp_path / f"b/m.{f:04d}.ply").read_bytes()
    gone = tmp_path / "a/m.0003.ply"
    gone.unlink()
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "a").iterdir()}
    run(isouq_cli, *args, "-o", "a/m.####.ply", "--resume", "--summary", "r.json", cwd=tmp_path)
    assert all(p.stat().st_mtime_ns == t for p, t in before.items())  # kept, not rewritten
    assert gone.read_bytes() == (tmp_path / "b/m.0003.ply").read_bytes()
    first, resumed = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "r.json"))
    assert resumed["totals"]["resumed"] == 5
    for a, r in zip(first["frames"], resumed["frames"]):
        assert (a["vertices"], a["triangles"], a["components"]) == (r["vertices"], r["triangles"], r["components"])
        assert a["err_est"] == r["err_est"]


def test_resume_reads_vtp_frames_back_also_as_vtk_writes_them(isouq_cli, tmp_path):
    """--resume on a .vtp cache reads the kept frames back (readVtp): one of them rewritten by
    VTK's own vtkXMLPolyDataWriter (raw appended, uncompressed), which puts field data, the
    points and the cells in its own order, with its own array attributes."""
    vtk_xml = pytest.importorskip("vtkmodules.vtkIOXML")
    fog_cache(tmp_path / "cache")
    args = ["cache/fluid_data_####.vdb", "-k", "0.05", "-o", "v/m.####.vtp"]
    run(isouq_cli, *args, "--summary", "a.json", cwd=tmp_path)
    def rewrite(frame, ascii):  # frame's .vtp read by VTK and written by VTK, uncompressed
        path = tmp_path / f"v/m.{frame:04d}.vtp"
        reader = vtk_xml.vtkXMLPolyDataReader()
        reader.SetFileName(str(path))
        reader.Update()
        writer = vtk_xml.vtkXMLPolyDataWriter()
        writer.SetInputData(reader.GetOutput())
        writer.SetFileName(str(path))
        writer.SetCompressorTypeToNone()
        if ascii:
            writer.SetDataModeToAscii()
        else:
            writer.SetDataModeToAppended()
            writer.EncodeAppendedDataOff()
            writer.SetHeaderTypeToUInt64()
        assert writer.Write() == 1
        assert b"RangeMin" in path.read_bytes()  # VTK's writer, not ours
        return path

    ours = rewrite(2, ascii=False)
    rewrite(6, ascii=True)
    rewritten = ours.read_bytes()
    (tmp_path / "v/m.0003.vtp").unlink()

    def resume(*extra):  # without --quiet: the notes say which frames are meshed again, and why
        proc = subprocess.run([isouq_cli, "mesh", *args, "--resume", *extra], cwd=tmp_path, capture_output=True,
                              text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        return proc.stderr

    assert "meshed again" not in resume("--summary", "r.json")
    assert ours.read_bytes() == rewritten  # kept, not written again
    first, resumed = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "r.json"))
    assert [bool(e.get("resumed")) for e in resumed["frames"]] == [True, True, False, True, True, True]
    assert resumed["isovalue"] == pytest.approx(first["isovalue"]) and resumed["method"] == first["method"]
    for a, r in zip(first["frames"], resumed["frames"]):
        assert (a["vertices"], a["triangles"], a["components"], a["boundary_edges"]) == \
            (r["vertices"], r["triangles"], r["components"], r["boundary_edges"])
        assert a["err_est"] == r["err_est"]
    # A kept frame that is not VTK XML (cut short) is meshed again, with a note saying why.
    cut = tmp_path / "v/m.0005.vtp"
    cut.write_bytes(cut.read_bytes()[:len(cut.read_bytes()) // 2])
    notes = resume()
    assert "isouq: frame 5: meshed again, as cannot read v/m.0005.vtp: truncated data" in notes, notes
    assert notes.count("meshed again") == 1, notes


def test_resume_after_an_empty_first_frame_keeps_the_runs_isovalue(isouq_cli, tmp_path):
    """An empty first frame records the isovalue it was meshed at (0, an empty grid's) in its
    PLY; --resume took that for the run's and meshed every other frame again at 0 (no surface
    in a fog volume). The first frame with data sets it, as in the first run."""
    fog_cache(tmp_path / "cache", empty=(1,))
    run(isouq_cli, "cache/fluid_data_####.vdb", "-o", "a/m.####.ply", "--summary", "a.json", cwd=tmp_path)
    (tmp_path / "a/m.0003.ply").unlink()
    run(isouq_cli, "cache/fluid_data_####.vdb", "-o", "a/m.####.ply", "--resume", "--summary", "r.json", cwd=tmp_path)
    first, resumed = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "r.json"))
    assert first["isovalue_source"].startswith("Otsu") and first["frames"][0]["empty"]
    assert resumed["isovalue"] == pytest.approx(first["isovalue"])
    assert resumed["totals"]["resumed"] == 5
    assert [e["triangles"] for e in resumed["frames"]] == [e["triangles"] for e in first["frames"]]


def test_ctrl_c_leaves_every_finished_frame_and_nothing_partial(isouq_cli, tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    for f in range(1, 13):  # level sets big enough that a frame takes a moment
        grid = vdb.createLevelSetSphere(radius=40.0 + 3 * f, center=(0, 0, 0), voxelSize=0.5, halfWidth=3.0)
        vdb.write(str(cache / f"ls.{f:04d}.vdb"), grids=[grid])
    proc = subprocess.Popen([isouq_cli, "mesh", "cache/ls.####.vdb", "-o", "out/ls.####.ply", "--summary", "s.json",
                             "--hidden-features"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    first = proc.stdout.readline()
    assert first.startswith("frame 1: wrote")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    written = sorted((tmp_path / "out").iterdir())
    assert 1 <= len(written) < 12
    for p in written:
        assert not p.name.startswith(".") and p.suffix == ".ply"
        assert len(ply_io.read_ply(str(p)).positions) > 1000  # complete
    assert not (tmp_path / "s.json").exists()
    assert not any(".tmp" in name for _, _, files in os.walk(tmp_path) for name in files)
    assert err.strip().endswith("isouq: interrupted; the frames finished so far are written (--resume keeps them)")


def test_resume_meshes_again_what_it_cannot_keep(isouq_cli, tmp_path):
    """Found by a hostile sweep (docs/hardening.md, 7 Dec): --resume stopped at an output cut
    short, kept frames made with another method or format, and blocked on a FIFO."""
    fog_cache(tmp_path / "cache", empty=())
    args = ["cache/fluid_data_####.vdb", "-k", "0.05", "-o", "o/m.####.ply"]
    run(isouq_cli, *args, cwd=tmp_path)
    fresh = (tmp_path / "o/m.0004.ply").read_bytes()
    (tmp_path / "o/m.0004.ply").write_bytes(fresh[:5000])  # a copy cut short
    run(isouq_cli, *args, "--resume", "--summary", "r.json", cwd=tmp_path)
    assert (tmp_path / "o/m.0004.ply").read_bytes() == fresh
    summary = json.loads((tmp_path / "r.json").read_text())
    assert summary["totals"]["resumed"] == 5 and not summary["frames"][3].get("resumed")
    assert summary["method"] == "weno"  # was null when every frame was kept
    # Another method, encoding or colouring: nothing is kept.
    for other in (["-m", "linear"], ["--ply-format", "ascii"], ["--color-by", "err_est"]):
        run(isouq_cli, *args, *other, "--resume", "--summary", "r.json", cwd=tmp_path)
        summary = json.loads((tmp_path / "r.json").read_text())
        assert summary["totals"]["resumed"] == 0, other
        run(isouq_cli, *args, cwd=tmp_path)  # back to the first settings
    # A FIFO at a frame's output: refused before any frame is written, with or without --resume.
    os.remove(tmp_path / "o/m.0002.ply")
    os.remove(tmp_path / "o/m.0001.ply")
    os.mkfifo(tmp_path / "o/m.0002.ply")
    for resume in ([], ["--resume"]):
        proc = run(isouq_cli, *args, *resume, cwd=tmp_path, check=False)
        assert proc.returncode == 2 and "not a regular file" in proc.stderr, proc.stderr
        assert not (tmp_path / "o/m.0001.ply").exists()


def test_a_frame_that_fails_says_which_and_what_stays(isouq_cli, tmp_path):
    fog_cache(tmp_path / "cache", empty=())
    (tmp_path / "cache/fluid_data_0004.vdb").write_bytes(b"garbage")
    proc = run(isouq_cli, "cache/fluid_data_####.vdb", "-k", "0.05", "-o", "o/m.####.ply", cwd=tmp_path, check=False)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("isouq: error: frame 4: ") and "--resume keeps them" in lines[0]
