# A Blender-baked smoke cache end to end (issue 11), with the real CLI: scripts/bake_smoke.py
# bakes 24 frames of Mantaflow smoke at resolution 40 (OpenVDB cache, grid `density`; about 15 s)
# and meshes each frame with Blender's own Volume to Mesh (Grid resolution, adaptivity 0,
# threshold 0.05). `isouq mesh 'fluid_data_####.vdb'` at the same threshold then meshes every
# frame (frame 1 has all its active values above the threshold); Volume to Mesh is OpenVDB's
# dual mesher (one face per sign-changing voxel edge), isouq's marching cubes has one vertex per
# such edge, so isouq's vertex count equals Volume to Mesh's face count, and its vertex count is
# within a few percent of Volume to Mesh's (a closed quad mesh has faces + 2 per component
# minus 2 per handle vertices). Then the sequence in Blender: import, frame_set in any order,
# and Run isouq on a Volume object that plays the cache.
# Skips only without an isouq binary that meshes sequences.

import json
import os
import subprocess
import time

import bpy
import numpy as np
import pytest

from conftest import REAL_CLI, REAL_CLI_TRIED
from isouq import frames, ply_io, sequence
from test_sequence import assert_shows_file

HERE = os.path.dirname(os.path.abspath(__file__))
BAKE = os.path.join(HERE, "..", "scripts", "bake_smoke.py")
THRESHOLD = 0.05
FRAMES = 24
VOXEL = 2.0 / 40                    # the domain's side over its resolution


@pytest.fixture(scope="module")
def cli():
    if REAL_CLI is None:
        pytest.skip(f"no isouq binary (tried {REAL_CLI_TRIED}): build the `isouq` target")
    help_text = subprocess.run([REAL_CLI, "mesh", "--help"], capture_output=True, text=True).stdout
    if "--frames" not in help_text:
        pytest.skip(f"{REAL_CLI} does not mesh sequences (no --frames): rebuild it")
    return REAL_CLI


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    """(folder, Volume to Mesh truth, bake seconds) of a freshly baked cache."""
    folder = tmp_path_factory.mktemp("smoke")
    truth = folder / "volume_to_mesh.json"
    start = time.perf_counter()
    run = subprocess.run([bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code",
                          "1", "-P", BAKE, "--", "--dir", str(folder), "--resolution", "40",
                          "--frames", str(FRAMES), "--threshold", str(THRESHOLD),
                          "--truth", str(truth)], capture_output=True, text=True, timeout=600)
    seconds = time.perf_counter() - start
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    print(f"bake_smoke.py: {seconds:.1f} s in all ({json.loads(truth.read_text())['bake_s']:.1f}"
          " s baking)")
    return folder, json.loads(truth.read_text()), seconds


@pytest.fixture(scope="module")
def meshed(cli, smoke):
    """The whole cache meshed by one `isouq mesh` run: (output folder, sequence summary)."""
    folder, _, _ = smoke
    out = folder / "isouq"
    out.mkdir()
    run = subprocess.run([cli, "mesh", str(folder / "cache_fluid" / "data" / "fluid_data_####.vdb"),
                          "--grid", "density", "--isovalue", str(THRESHOLD),
                          "-o", str(out / "smoke.####.ply"), "--summary", str(out / "smoke.json"),
                          "--quiet"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    return out, json.loads((out / "smoke.json").read_text())


def test_bake_is_small_and_quick(smoke):
    folder, truth, seconds = smoke
    files = sorted(os.listdir(folder / "cache_fluid" / "data"))
    assert files == [f"fluid_data_{k:04d}.vdb" for k in range(1, FRAMES + 1)]
    assert seconds < 120 and truth["bake_s"] < 90
    counts = [f["vertices"] for f in truth["frames"]]
    assert len(set(counts)) > FRAMES // 2 and min(counts) > 0       # the frames differ


def test_every_frame_matches_volume_to_mesh(smoke, meshed):
    _, truth, _ = smoke
    out, summary = meshed
    entries = frames.frame_entries(summary)
    assert sorted(entries) == list(range(1, FRAMES + 1))            # the summary lists every frame
    assert summary["isovalue"] == THRESHOLD and summary["totals"]["frames"] == FRAMES
    worst, offsets = 0.0, []
    for blender in truth["frames"]:
        k = blender["frame"]
        e = entries[k]
        assert os.path.basename(e["file"]) == f"fluid_data_{k:04d}.vdb"
        assert e["vertices"] > 0 and not e["empty"]
        assert e["boundary_edges"] == 0                               # closed, every frame
        assert e["vertices"] == blender["polygons"], k                # one per crossed edge
        worst = max(worst, abs(e["vertices"] - blender["vertices"]) / blender["vertices"])
        mesh = ply_io.read_ply(str(out / f"smoke.{k:04d}.ply"))
        assert mesh.vertex_count == e["vertices"]
        # the same place, once isouq's mesh has Blender's half-voxel shift (volume_mesh_matrix):
        # extremes within a voxel (dual vertices sit inside cells, isouq's on edges) and
        # no shift left on average
        lo, hi = mesh.positions.min(0) + VOXEL / 2, mesh.positions.max(0) + VOXEL / 2
        assert np.allclose(lo, blender["bbox_min"], atol=VOXEL), k
        assert np.allclose(hi, blender["bbox_max"], atol=VOXEL), k
        offsets += list(lo - blender["bbox_min"]) + list(hi - blender["bbox_max"])
    mean = float(np.mean(offsets)) / VOXEL
    assert abs(mean) < 0.1, mean
    assert worst < 0.03, worst
    print(f"largest vertex count difference to Volume to Mesh: {100 * worst:.2f}%; mean "
          f"bounding-box offset {mean:+.3f} voxel")


def test_imported_smoke_sequence_gives_frame_k_on_frame_k(meshed):
    out, summary = meshed
    assert bpy.ops.isouq.import_sequence(filepath=str(out / "smoke.0010.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.isouq.sequence_summary == str(out / "smoke.json")      # found beside the frames
    assert obj["isouq_sequence_ranges_from"] == "summary"
    lo = min(e["err_est"]["min"] for e in summary["frames"])
    hi = max(e["err_est"]["max"] for e in summary["frames"])
    assert sequence.measure_range(obj, "err_est") == pytest.approx((lo, hi))
    scene = bpy.context.scene
    for k in (17, 3, 24, 1, 11, 17, 8):
        scene.frame_set(k)
        assert_shows_file(obj, str(out / f"smoke.{k:04d}.ply"))
        assert json.loads(obj.isouq.summary)["vertices"] == len(obj.data.vertices)


def test_run_isouq_on_the_volume_sequence(cli, smoke, tmp_path):
    folder, truth, _ = smoke
    vol = bpy.data.volumes.new("smoke")
    vol.filepath = str(folder / "cache_fluid" / "data" / "fluid_data_0001.vdb")
    vol.is_sequence, vol.frame_duration, vol.frame_start = True, FRAMES, 1
    volume = bpy.data.objects.new("smoke", vol)
    bpy.context.collection.objects.link(volume)
    s = bpy.context.scene.isouq
    s.volume, s.input_path, s.grid = volume, "", "density"
    s.use_isovalue, s.isovalue, s.method = True, THRESHOLD, "weno"
    s.hidden_features = True
    s.sequence_dir = str(tmp_path)
    assert bpy.ops.isouq.run_pipeline() == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.isouq.sequence == str(tmp_path / "smoke" / "smoke.####.ply")
    hidden = obj.isouq.partner
    assert hidden.isouq.role == "HIDDEN" and hidden.isouq.partner == obj
    assert hidden.isouq.sequence == str(tmp_path / "smoke" / "smoke_hidden.####.ply")
    shift = np.array(obj.matrix_world.translation)
    assert np.allclose(shift, VOXEL / 2)                              # Blender's half voxel
    scene = bpy.context.scene
    for k in (5, 22, 1, 13):
        scene.frame_set(k)
        blender = truth["frames"][k - 1]
        assert len(obj.data.vertices) == blender["polygons"]
        assert_shows_file(obj, str(tmp_path / "smoke" / f"smoke.{k:04d}.ply"))
        assert_shows_file(hidden, str(tmp_path / "smoke" / f"smoke_hidden.{k:04d}.ply"))
        entry = json.loads(obj.isouq.summary)                     # C7: this frame's entry
        assert entry["frame"] == k and entry["hidden"]["components_before"] == entry["components"]
        co = np.array([obj.matrix_world @ v.co for v in obj.data.vertices])
        assert np.allclose(co.min(0), blender["bbox_min"], atol=VOXEL)


def test_progress_of_a_real_sequence_run_counts_frames(cli, smoke, tmp_path):
    """The CLI draws its bar only on a terminal: the job gives it a pty for stderr, and counts
    the "frame F: wrote ..." lines it flushes on stdout."""
    from isouq import pipeline
    folder, _, _ = smoke
    request = pipeline.MeshRequest(str(folder / "cache_fluid" / "data" / "fluid_data_####.vdb"),
                                   THRESHOLD, "weno", True, 4, "density", frames=f"1-{FRAMES}")
    job = pipeline.SequenceJob(request, cli, output_dir=str(tmp_path), name="p",
                               total=FRAMES).start()
    seen = []
    while job.poll() is None:
        seen.append(job.progress() or 0.0)
        time.sleep(0.01)
    assert job.poll() == 0, job.error_message()
    assert job.frames_done() == (FRAMES, FRAMES) and job.progress() == 1.0
    assert seen == sorted(seen)
    assert frames.parse_pattern(job.hidden_path).scan().frames == list(range(1, FRAMES + 1))
    job.cleanup()


def test_empty_grid_frames_import_as_empty_meshes(cli, smoke, tmp_path):
    """Mantaflow's `flame` grid of a smoke-only bake is empty on every frame: the CLI writes empty
    but valid PLYs, and the sequence plays them as empty meshes with their columns."""
    folder, _, _ = smoke
    run = subprocess.run([cli, "mesh", str(folder / "cache_fluid" / "data" / "fluid_data_####.vdb"),
                          "--grid", "flame", "--isovalue", str(THRESHOLD), "--frames", "1-3",
                          "-o", str(tmp_path / "flame.####.ply"),
                          "--summary", str(tmp_path / "flame.json"), "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert bpy.ops.isouq.import_sequence(filepath=str(tmp_path / "flame.0002.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    for k in (3, 1, 2):
        bpy.context.scene.frame_set(k)
        assert obj.isouq.sequence_frame == k and len(obj.data.vertices) == 0
        assert "err_est" in obj.data.attributes
        assert json.loads(obj.isouq.summary)["empty"] is True
