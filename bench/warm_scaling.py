#!/usr/bin/env python3
"""Thread scaling of a whole `isouq mesh` run with warm memory (issue 15; bench/journal/
2026-12-05.md, 02:36): the graph `isouq mesh SCAN --linear-only --save-graph` writes, run by the
`isouq` Python module again and again in one process, at 0 threads (every core) and 1,
interleaved, with glibc's malloc told to keep what it frees (glibc.malloc.mmap_max=0 and a
trim threshold of 64 GiB, beside the CLI's own huge-page tunables). From the second round on,
no heap page is new to the process: what is left of a fresh page's cost is the PLY's page
cache. On a VM whose freed pages go back to the host at once, this separates what the threads
do from what the host charges for memory; scan_threads.py times the CLI as users run it.

  bench/warm_scaling.py SCAN ROUNDS [MODULE_DIR]
  e.g. bench/warm_scaling.py /tmp/isouq-scan/sphere_1024x1024x1024_uint8.raw 6 build/python

Prints per run: wall s and the summary's stage times; then the medians of rounds 2 on, their
ratio and each round's, and the load average before and after. Writes its files in a temporary
folder.
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

KEEP = ("glibc.malloc.hugetlb=1:glibc.malloc.arena_max=1:glibc.malloc.top_pad=16777216:"
        "glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=68719476736")


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    if os.environ.get("GLIBC_TUNABLES") != KEEP:  # glibc reads its tunables at start only
        os.execve(sys.executable, [sys.executable] + sys.argv, dict(os.environ, GLIBC_TUNABLES=KEEP))
    scan, rounds = os.path.abspath(sys.argv[1]), int(sys.argv[2])
    module = os.path.abspath(sys.argv[3] if len(sys.argv) > 3 else "build/python")
    cli = os.path.join(os.path.dirname(module), "houdini_style_nodes", "isouq")
    sys.path.insert(0, module)
    import isouq
    print("load average before:", " ".join(open("/proc/loadavg").read().split()[:3]))
    walls = {0: [], 1: []}
    with tempfile.TemporaryDirectory() as folder:
        graph = os.path.join(folder, "g.json")
        # The CLI writes the graph of the command (and meshes once, which warms the page cache).
        subprocess.run([cli, "mesh", scan, "--linear-only", "-q", "-o", "o.ply", "--summary", "s.json",
                        "--save-graph", graph], cwd=folder, check=True, stdout=subprocess.DEVNULL)
        for r in range(rounds):
            for j in ((0, 1) if r % 2 == 0 else (1, 0)):
                for name in ("o.ply", "s.json"):
                    os.remove(os.path.join(folder, name))
                os.sync()  # no writeback of the last PLY during the run
                start = time.perf_counter()
                isouq.run(graph, threads=j, output_dir=folder)
                wall = time.perf_counter() - start
                stages = json.load(open(os.path.join(folder, "s.json")))["timings_ms"]
                walls[j].append(wall)
                print(f"round {r + 1} -j {j}: {wall:.3f} s, " + ", ".join(f"{k} {v:.0f} ms" for k, v in stages.items()),
                      flush=True)
    print("load average after:", " ".join(open("/proc/loadavg").read().split()[:3]))
    if rounds < 2:
        return
    med = {j: statistics.median(walls[j][1:]) for j in (0, 1)}
    print(f"rounds 2-{rounds}, medians: -j 0 {med[0]:.3f} s, -j 1 {med[1]:.3f} s, ratio {med[1] / med[0]:.2f}x; "
          "per round " + " ".join(f"{b / a:.2f}" for a, b in zip(walls[0][1:], walls[1][1:])))


if __name__ == "__main__":
    main()
