# Running `isouq mesh` from Blender (SPEC §8): command line, import of the outputs, errors of a
# missing, failing or garbage-writing binary (no object is left behind), and cancelling, with a
# fake binary. The real CLI is exercised in test_real_cli.py.

import json
import os
import time

import bpy
import pytest

from conftest import FAKE, scene_delta, snapshot
from isouq import pipeline

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.environ.get("ISOUQ_DATA_DIR", os.path.join(HERE, "..", "..", "..", "shared", "data"))
SPHERE_VDB = os.path.join(DATA, "sphere.vdb")


@pytest.fixture
def fake(sphere_ply, tmp_path, monkeypatch):
    """The fake binary as the add-on preference; returns its log path."""
    prefs = bpy.context.preferences.addons["isouq"].preferences
    prefs.binary = FAKE
    log = tmp_path / "argv.jsonl"
    monkeypatch.setenv("FAKE_ISOUQ_LOG", str(log))
    monkeypatch.setenv("FAKE_ISOUQ_PLY", sphere_ply[0])
    monkeypatch.setenv("FAKE_ISOUQ_MODE", "ok")
    vdb = tmp_path / "input.vdb"
    vdb.write_bytes(b"not read by the fake")
    bpy.context.scene.isouq.input_path = str(vdb)
    yield log
    prefs.binary = ""


def logged(log):
    """The fake's `mesh` invocations (the add-on also asks `nodes --json` for the methods)."""
    runs = [json.loads(line) for line in log.read_text().splitlines()]
    return [argv for argv in runs if argv[:1] == ["mesh"]]


def test_run_imports_mesh_hidden_mesh_and_summary(fake):
    s = bpy.context.scene.isouq
    s.use_isovalue, s.isovalue, s.method = True, 0.25, "cubic"
    s.hidden_features, s.subdivisions, s.grid = True, 3, "density"
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    (argv,) = logged(fake)
    assert argv[:2] == ["mesh", s.input_path]
    opts = {flag: argv[argv.index(flag) + 1] for flag in
            ("-o", "--method", "--isovalue", "--grid", "--subdivisions", "--hidden-out")}
    assert opts["--method"] == "cubic" and float(opts["--isovalue"]) == 0.25
    assert opts["--grid"] == "density" and opts["--subdivisions"] == "3"
    assert "--hidden-features" in argv and "--hidden-out" in argv and "--summary" in argv
    standard, hidden = bpy.data.objects["input"], bpy.data.objects["input_hidden"]
    assert (standard.isouq.role, hidden.isouq.role) == ("MESH", "HIDDEN")
    assert standard.isouq.partner == hidden and hidden.isouq.partner == standard
    assert json.loads(standard.isouq.summary)["method"] == "cubic"
    assert "err_est" in standard.data.attributes
    assert not os.path.exists(os.path.dirname(opts["-o"]))          # temp outputs removed


def test_volume_object_input_uses_its_file_and_transform(fake):
    if not os.path.isfile(SPHERE_VDB):
        pytest.skip(f"{SPHERE_VDB} missing")
    volume = bpy.data.objects.new("vol", bpy.data.volumes.new("vol"))
    volume.data.filepath = SPHERE_VDB
    volume.location = (1.0, 2.0, 3.0)
    bpy.context.collection.objects.link(volume)
    s = bpy.context.scene.isouq
    s.volume, s.input_path = volume, ""
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    (argv,) = logged(fake)
    assert argv[1] == SPHERE_VDB
    assert volume.data.grids.is_loaded                # Blender built with OpenVDB
    assert argv[argv.index("--grid") + 1] == "ls_sphere"
    # the Volume's transform and half a voxel (0.05 / 2): Blender draws voxel i over [i, i+1]
    # and its Volume to Mesh shifts by as much (operators.volume_mesh_matrix)
    location = tuple(bpy.data.objects["sphere"].location)
    assert location == pytest.approx((1.025, 2.025, 3.025), abs=1e-6)


@pytest.mark.parametrize("mode,message", [
    ("fail", "isouq: error: grid 'density' is not a float grid"),
    ("garbage", "isouq output unreadable: PLY file is truncated")])
def test_failing_binary_reports_and_builds_nothing(fake, monkeypatch, mode, message):
    monkeypatch.setenv("FAKE_ISOUQ_MODE", mode)
    before = snapshot()
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.isouq.run_pipeline()
    assert scene_delta(before) == (set(), set())


def test_missing_binary_or_input_reports(fake, tmp_path):
    prefs = bpy.context.preferences.addons["isouq"].preferences
    before = snapshot()
    prefs.binary = str(tmp_path / "no_such_isouq")
    with pytest.raises(RuntimeError, match="isouq binary not found"):
        bpy.ops.isouq.run_pipeline()
    prefs.binary = FAKE
    bpy.context.scene.isouq.input_path = str(tmp_path / "missing.vdb")
    with pytest.raises(RuntimeError, match="input file not found"):
        bpy.ops.isouq.run_pipeline()
    assert scene_delta(before) == (set(), set())


def test_cancel_stops_the_run_and_progress_is_read(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ISOUQ_MODE", "sleep")
    job = pipeline.Job(pipeline.MeshRequest(str(tmp_path / "in.vdb")), FAKE).start()
    deadline = time.time() + 20
    while (job.progress() or 0) < 0.1 and time.time() < deadline:
        time.sleep(0.1)
    assert 0.1 <= job.progress() < 1.0
    start = time.time()
    job.cancel()
    assert job.poll() == 130 and time.time() - start < 3
    assert not os.path.exists(job.mesh_path)
    job.cleanup()


def test_binary_lookup_order(tmp_path, monkeypatch):
    monkeypatch.setenv(pipeline.ENV_BINARY, FAKE)
    assert pipeline.find_binary("")[0] == FAKE
    assert pipeline.find_binary(str(tmp_path / "nope"))[0] is None
    monkeypatch.setenv(pipeline.ENV_BINARY, str(tmp_path / "nope"))
    assert pipeline.find_binary("")[0] is None

