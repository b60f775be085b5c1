# scripts/sequence_report.py (issue 11): the per-frame series of a sequence summary as a PNG, run
# as a user would (Debian's python3 with matplotlib, outside Blender); empty and missing frames
# are drawn, bad input gives one line and exit status 2, nothing is left behind.

import json
import os
import subprocess

import bpy
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "..", "scripts", "sequence_report.py")
PYTHON = "/usr/bin/python3"


def summary(frames=8, empty=(4,), missing=(6,)):
    entries = []
    for k in range(1, frames + 1):
        if k in missing:
            continue
        n = 0 if k in empty else 100 * k
        stat = lambda s: {"min": s / 10, "max": s * 3, "mean": s, "rms": 1.2 * s, "count": n} \
            if n else {"min": None, "max": None, "mean": None, "rms": None, "count": 0}
        entries.append({"frame": k, "file": f"in.{k:04d}.vdb", "output": f"o.{k:04d}.ply",
                        "vertices": n, "triangles": 2 * n, "components": 1 + k % 3,
                        "boundary_edges": 0, "empty": n == 0, "err_est": stat(0.01 * k),
                        "err_bound": stat(0.05), "d_lc": stat(0.002 * k),
                        "hidden": {"components_before": 1 + k % 3, "components_after": 1}})
    return {"frames": entries, "isovalue": 0.05, "method": "weno",
            "totals": {"frames": len(entries), "missing": list(missing)},
            "sequence": {"input": "cache/in.####.vdb", "output": "o.####.ply"}}


def run(*args):
    if not os.access(PYTHON, os.X_OK):
        pytest.skip(f"{PYTHON} missing")
    return subprocess.run([PYTHON, SCRIPT, *args], capture_output=True, text=True, timeout=120)


def test_report_draws_every_frame(tmp_path):
    path, out = tmp_path / "seq.json", tmp_path / "seq.png"
    path.write_text(json.dumps(summary()))
    done = run(str(path), str(out))
    assert done.returncode == 0, done.stderr
    assert "7 frames" in done.stdout
    image = bpy.data.images.load(str(out))
    assert image.size[0] >= 800 and image.size[1] >= 800
    assert sorted(os.listdir(tmp_path)) == ["seq.json", "seq.png"]       # no temporary left
    done = run(str(path), str(out), "--measures", "d_lc", "--title", "smoke")
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("content,args,message", [
    ("{}", (), "not a sequence summary"),
    ("not json", (), "cannot read"),
    (json.dumps(summary()), ("--measures", "nope"), "no measure nope"),
])
def test_bad_input_gives_one_line(tmp_path, content, args, message):
    path, out = tmp_path / "seq.json", tmp_path / "seq.png"
    path.write_text(content)
    done = run(str(path), str(out), *args)
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("sequence_report.py: error:") and message in line
    assert not out.exists()
