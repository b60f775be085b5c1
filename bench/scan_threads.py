#!/usr/bin/env python3
"""Thread scaling of a whole `isouq mesh` run on a scan (issue 15; bench/README.md): each
binary at -j 0 (every core) and -j 1, interleaved round by round, `--linear-only` (with --full,
the full pass: cubic, WENO and every estimate), with the summary's stage times, and what is
left outside them: start-up (twice with the huge-page restart), writing the files not
overlapped with the summary, the renames and the exit.

  bench/scan_threads.py [--full] SCAN ROUNDS BIN [BIN ...]
  e.g. bench/scan_threads.py /tmp/isouq-scan/sphere_1024x1024x1024_uint8.raw 8 build/houdini_style_nodes/isouq

Prints per run: wall s, peak MB, load/mesh/measure ms, rest s; then per binary the medians,
the ratio -j 1 / -j 0 of each round and of the medians and of the best runs, and the load
average before and after. Writes its files in a temporary folder beside nothing else.

Every run writes a new file: the last run's outputs are removed and `sync` runs before each
timed run, so that no writeback of an earlier run's 175 MB PLY takes a core from it (ext4
writes a file back when a rename replaces it, and the flusher writes the rest), and the order
of the binaries alternates from round to round: without both, the run that followed a short
run lost 50-200 ms to the previous run's writeback, and a second binary always ran there.
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile


def run(binary, scan, threads, folder, flags):
    out, summary, times = (os.path.join(folder, n) for n in ("o.ply", "o.json", "time.txt"))
    for f in (out, summary):
        if os.path.exists(f):
            os.remove(f)
    os.sync()
    cmd = ["/usr/bin/time", "-f", "%e %M", "-o", times, binary, "mesh", scan, *flags, "-j", str(threads),
           "-q", "-o", out, "--summary", summary]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall, peak_kb = open(times).read().split()
    stages = json.load(open(summary))["timings_ms"]
    return {"wall": float(wall), "peak_mb": int(peak_kb) // 1024, **{k: stages[k] for k in ("load", "mesh", "measure")},
            "rest": float(wall) - sum(stages.values()) / 1000.0}


def memory_probe(binary):
    """The machine's memory scaling in this run (isouq_bench --memory-probe, from the build
    folder BIN is in), or a note that there is none."""
    bench = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(binary))), "bench", "isouq_bench")
    if not os.access(bench, os.X_OK):
        return f"(no {bench}: no memory probe)"
    return subprocess.run([bench, "--memory-probe"], check=True, capture_output=True, text=True).stdout.strip()


def main():
    full = sys.argv[1:2] == ["--full"]
    flags, args = ([], sys.argv[2:]) if full else (["--linear-only"], sys.argv[1:])
    if len(args) < 3:
        sys.exit(__doc__)
    scan, rounds, binaries = args[0], int(args[1]), args[2:]
    load = " ".join(open("/proc/loadavg").read().split()[:3])
    print(f"pass: {'full' if full else 'linear'}; load average before: {load}")
    print(memory_probe(binaries[0]), flush=True)
    runs = {(b, j): [] for b in binaries for j in (0, 1)}
    with tempfile.TemporaryDirectory() as folder:
        for r in range(rounds):
            for j in (0, 1):
                for b in (binaries if r % 2 == 0 else binaries[::-1]):
                    x = run(b, scan, j, folder, flags)
                    runs[(b, j)].append(x)
                    print(f"round {r + 1} -j {j} {b}: {x['wall']:.2f} s, {x['peak_mb']} MB, load {x['load']:.0f}, "
                          f"mesh {x['mesh']:.0f}, measure {x['measure']:.0f} ms, rest {x['rest']:.2f} s", flush=True)
    print("load average after:", " ".join(open("/proc/loadavg").read().split()[:3]))
    print(memory_probe(binaries[0]))
    for b in binaries:
        med = {j: {k: statistics.median(x[k] for x in runs[(b, j)]) for k in runs[(b, j)][0]} for j in (0, 1)}
        for j in (0, 1):
            m = med[j]
            print(f"{b} -j {j} medians: {m['wall']:.2f} s, peak {m['peak_mb']:.0f} MB, load {m['load']:.0f}, "
                  f"mesh {m['mesh']:.0f}, measure {m['measure']:.0f} ms, rest {m['rest']:.2f} s")
        rounds_ratio = [a["wall"] / b0["wall"] for a, b0 in zip(runs[(b, 1)], runs[(b, 0)])]
        best = min(x["wall"] for x in runs[(b, 1)]) / min(x["wall"] for x in runs[(b, 0)])
        print(f"{b} -j 1 / -j 0: rounds " + " ".join(f"{x:.2f}" for x in rounds_ratio)
              + f"; medians {med[1]['wall'] / med[0]['wall']:.2f}x; best runs {best:.2f}x; stages (medians): "
              + ", ".join(f"{k} {med[1][k] / med[0][k]:.2f}x" for k in ("load", "mesh", "measure")))


if __name__ == "__main__":
    main()
