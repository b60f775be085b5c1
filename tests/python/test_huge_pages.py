"""The CLI's restart with glibc's malloc.hugetlb and arena_max tunables for large inputs
(docs/mesher.md "Memory pages"; houdini_style_nodes/cli/HugePages.cc): counted by strace's
execve records, which show the restarted environment, and the restarted run's PLY
byte-identical to a run without it."""
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

N = 256  # 256^3 uint8: 16 MiB, the size from which the CLI restarts


def sanitized(cli):
    with open(cli, "rb") as f:
        data = f.read()
    return b"__asan_init" in data or b"__tsan_init" in data


def thp_never():
    try:
        return "[never]" in Path("/sys/kernel/mm/transparent_hugepage/enabled").read_text()
    except OSError:
        return True


@pytest.fixture(scope="module")
def volumes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("huge_pages")
    x = np.arange(N, dtype=np.float32) - N / 2
    r = np.sqrt(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2)
    ball = np.clip(200 - 2 * r, 0, 255).astype(np.uint8)  # 100 at radius 50
    big = folder / f"ball_{N}x{N}x{N}_uint8.raw"
    ball.tofile(big)
    small = folder / "ball_64x64x64_uint8.raw"
    np.ascontiguousarray(ball[96:160, 96:160, 96:160]).tofile(small)
    assert big.stat().st_size == 16 << 20
    return folder, big, small


# The heap's growth the restart adds (houdini_style_nodes/cli/HugePages.cc).
HEAP = "glibc.malloc.top_pad=16777216"


def run(cli, folder, source, name, **env_changes):
    """Runs `isouq mesh` under strace; returns (execve calls of the binary, PLY bytes)."""
    env = {k: v for k, v in os.environ.items() if k not in ("GLIBC_TUNABLES", "ISOUQ_HUGE_PAGES")}
    env.update(env_changes)
    log = folder / f"{name}.strace"
    out = folder / f"{name}.ply"
    subprocess.run(["strace", "-f", "-qq", "-v", "-s", "512", "-e", "trace=execve", "-o", str(log), cli, "mesh",
                    str(source), "--isovalue", "100", "--linear-only", "-q", "-o", str(out)], env=env, check=True)
    execs = [line for line in log.read_text().splitlines() if "execve(" in line and "= 0" in line]
    return execs, out.read_bytes()


@pytest.mark.skipif(shutil.which("strace") is None, reason="strace is not installed")
def test_large_input_restarts_once_with_the_tunable(isouq_cli, volumes):
    if sanitized(isouq_cli):
        pytest.skip("a sanitized CLI keeps its own allocator and does not restart")
    folder, big, small = volumes
    expected = 1 if thp_never() else 2
    execs, restarted = run(isouq_cli, folder, big, "default")
    assert len(execs) == expected, "the CLI should restart once for a 16 MiB input"
    if expected == 2:
        assert f'"GLIBC_TUNABLES=glibc.malloc.hugetlb=1:glibc.malloc.arena_max=1:{HEAP}"' in execs[1], execs[1]
    execs, plain = run(isouq_cli, folder, big, "off", ISOUQ_HUGE_PAGES="0")
    assert len(execs) == 1, "ISOUQ_HUGE_PAGES=0 should keep the first process"
    assert restarted == plain, "the restarted run wrote a different PLY"
    execs, preset = run(isouq_cli, folder, big, "preset", GLIBC_TUNABLES="glibc.malloc.hugetlb=0")
    assert len(execs) == 1, "a tunable the user set should be left alone"
    assert preset == plain
    if expected == 2:  # another tunable the user set is kept, and an arena_max of theirs wins
        execs, kept = run(isouq_cli, folder, big, "other", GLIBC_TUNABLES="glibc.malloc.arena_max=4")
        assert len(execs) == 2, execs
        assert f'"GLIBC_TUNABLES=glibc.malloc.arena_max=4:glibc.malloc.hugetlb=1:{HEAP}"' in execs[1], execs
        assert kept == plain
    execs, _ = run(isouq_cli, folder, small, "small")
    assert len(execs) == 1, "a small input should not restart"
