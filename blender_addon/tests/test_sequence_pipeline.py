# Run isouq on a Volume object that is a sequence (issue 11), with the fake CLI: the command line
# (the #### pattern of the Volume's file, its frames), the import of the written frames as a
# sequence object timed and placed like the Volume, progress over frames and cancel (finished
# frames stay, nothing half-written). The real CLI on a baked smoke cache: test_smoke_sequence.py.

import json
import os
import time

import bpy
import pytest

from conftest import FAKE, scene_delta, snapshot
from isouq import frames, pipeline


@pytest.fixture
def fake(sphere_ply, tmp_path, monkeypatch):
    prefs = bpy.context.preferences.addons["isouq"].preferences
    prefs.binary = FAKE
    log = tmp_path / "argv.jsonl"
    monkeypatch.setenv("FAKE_ISOUQ_LOG", str(log))
    monkeypatch.setenv("FAKE_ISOUQ_PLY", sphere_ply[0])
    monkeypatch.setenv("FAKE_ISOUQ_MODE", "ok")
    yield log
    prefs.binary = ""


def logged(log):
    runs = [json.loads(line) for line in log.read_text().splitlines()]
    return [argv for argv in runs if argv[:1] == ["mesh"]]


def volume_sequence(tmp_path, first=5, count=5, frame_start=20, mode="REPEAT"):
    """A Volume object on cache/fluid_data_0005.vdb .. 0009.vdb, played from scene frame 20."""
    cache = tmp_path / "cache"
    cache.mkdir()
    for k in range(first, first + count):
        (cache / f"fluid_data_{k:04d}.vdb").write_bytes(b"not read by the fake")
    vol = bpy.data.volumes.new("smoke")
    vol.filepath = str(cache / f"fluid_data_{first:04d}.vdb")
    vol.is_sequence = True
    vol.frame_duration, vol.frame_start, vol.frame_offset = count, frame_start, first - 1
    vol.sequence_mode = mode
    obj = bpy.data.objects.new("smoke", vol)
    obj.location = (1.0, 2.0, 3.0)
    bpy.context.collection.objects.link(obj)
    s = bpy.context.scene.isouq
    s.volume, s.input_path, s.grid = obj, "", "density"
    s.sequence_dir = str(tmp_path / "out")
    return obj, cache


def test_volume_sequence_meshes_every_frame_and_imports_the_sequence(fake, tmp_path):
    volume, cache = volume_sequence(tmp_path)
    s = bpy.context.scene.isouq
    s.use_isovalue, s.isovalue = True, 0.05
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    (argv,) = logged(fake)
    opt = lambda flag: argv[argv.index(flag) + 1]
    assert argv[1] == str(cache / "fluid_data_####.vdb")
    assert opt("--frames") == "5-9" and opt("--grid") == "density"
    out = tmp_path / "out" / "smoke"
    assert opt("-o") == str(out / "smoke.####.ply") and opt("--summary") == str(out / "smoke.json")
    assert "--resume" not in argv and "--skip-missing" not in argv
    obj = bpy.context.active_object
    assert obj.isouq.sequence == str(out / "smoke.####.ply")
    assert obj.isouq.sequence_summary == str(out / "smoke.json")
    assert frames.detect(obj.isouq.sequence).frames == [5, 6, 7, 8, 9]
    # timed like the Volume: scene frame 20 shows file 5 (offset 5 - 20), looping as it does
    assert (obj.isouq.sequence_offset, obj.isouq.sequence_mode) == (-15, "REPEAT")
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (20, 24)
    scene.frame_set(22)
    assert obj.isouq.sequence_frame == 7
    assert json.loads(obj.isouq.summary)["frame"] == 7
    scene.frame_set(26)
    assert obj.isouq.sequence_frame == 6
    assert tuple(obj.matrix_world.translation) == (1.0, 2.0, 3.0)


def test_mesh_sequence_follows_the_volume_frame_for_frame(fake, tmp_path):
    """Blender's own choice of file per scene frame (Volume grids.frame_filepath) and the mesh
    sequence's agree, for every frame mode and an offset start."""
    volume, cache = volume_sequence(tmp_path, first=3, count=4, frame_start=11, mode="EXTEND")
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    obj = bpy.context.active_object
    scene = bpy.context.scene
    for mode in ("EXTEND", "REPEAT", "PING_PONG", "CLIP"):
        volume.data.sequence_mode = obj.isouq.sequence_mode = mode
        for k in range(5, 25):
            scene.frame_set(k)
            volume.data.grids.load()
            blender = volume.data.grids.frame_filepath
            shown = obj.isouq.sequence_frame
            if mode == "CLIP" and not 11 <= k <= 14:
                assert len(obj.data.vertices) == 0, (mode, k)
                continue
            assert blender and frames.frame_of(blender) == shown, (mode, k, blender, shown)


def test_sequence_options_and_missing_frames(fake, tmp_path):
    volume_sequence(tmp_path)
    s = bpy.context.scene.isouq
    s.resume, s.skip_missing = True, True
    (tmp_path / "cache" / "fluid_data_0007.vdb").unlink()
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    (argv,) = logged(fake)
    assert "--resume" in argv and "--skip-missing" in argv
    assert frames.detect(bpy.context.active_object.isouq.sequence).frames == [5, 6, 8, 9]
    bpy.context.scene.frame_set(22)                          # file 7 missing: holds 6
    assert bpy.context.active_object.isouq.sequence_frame == 6
    s.skip_missing = False
    before = snapshot()
    with pytest.raises(RuntimeError, match="frames \\[7\\] missing"):
        bpy.ops.isouq.run_pipeline()
    assert scene_delta(before) == (set(), set())


def test_current_frame_only_when_asked(fake, tmp_path):
    volume, cache = volume_sequence(tmp_path)
    bpy.context.scene.isouq.whole_sequence = False
    bpy.context.scene.frame_set(21)
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    (argv,) = logged(fake)
    assert "--frames" not in argv and "#" not in argv[1]
    assert not bpy.context.active_object.isouq.sequence


def test_sequence_progress_counts_frames_and_cancel_keeps_finished_ones(tmp_path, monkeypatch,
                                                                        sphere_ply):
    monkeypatch.setenv("FAKE_ISOUQ_MODE", "sleep")
    monkeypatch.setenv("FAKE_ISOUQ_PLY", sphere_ply[0])
    monkeypatch.setenv("FAKE_ISOUQ_FRAME_SECONDS", "0.6")
    for k in range(1, 9):
        (tmp_path / f"in.{k:04d}.vdb").write_bytes(b"")
    request = pipeline.MeshRequest(str(tmp_path / "in.####.vdb"), frames="1-8")
    job = pipeline.SequenceJob(request, FAKE, output_dir=str(tmp_path / "out"), name="m",
                               total=8).start()
    seen = []
    deadline = time.time() + 30
    while (job.frames_done() or (0, 8))[0] < 3 and time.time() < deadline:
        seen.append(job.progress() or 0.0)
        time.sleep(0.05)
    done, total = job.frames_done()
    assert total == 8 and 3 <= done < 8
    assert seen == sorted(seen) and 0.3 <= max(seen) < 1.0    # never goes back
    job.cancel()
    assert job.poll() == 130
    written = frames.parse_pattern(job.mesh_path).scan().frames
    assert len(written) >= 3 and written == list(range(1, len(written) + 1))
    assert not any(n.endswith(".tmp") for n in os.listdir(tmp_path / "out"))
    job.cleanup()
    assert os.path.isdir(tmp_path / "out")                    # the frames stay
