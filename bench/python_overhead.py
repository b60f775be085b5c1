"""The Python module's call overhead on small grids (issue 12; bench/README.md "Python call
overhead"): Tangle (SPEC §5) at 32^3 as a numpy array, meshed with the full pass (every method
and estimate) through isouq.mesh, against the C++ work inside the same calls (each node's cook
time, from the summary's timings_ms) and against `isouq_bench --pass estimate --cases tangle32`
(extractIsosurface alone, run separately). Medians of --repeats calls after 20 warm-ups;
CPU time is the process's (every thread), as isouq_bench reports it.

    PYTHONPATH=build/python /usr/bin/python3 bench/python_overhead.py [--repeats 300]
"""
import argparse
import os
import statistics
import time

import numpy as np

import isouq


def tangle(n=32):
    """Tangle on [-1, 1]^3 as isouq_bench's tangle32 (x^4 + y^4 + z^4 - (x^2 + y^2 + z^2) + 0.4)."""
    z, y, x = np.mgrid[-1:1:n * 1j, -1:1:n * 1j, -1:1:n * 1j]
    return (x**4 + y**4 + z**4 - (x * x + y * y + z * z) + 0.4).astype(np.float32)


def timed(call, repeats):
    for _ in range(20):
        call()
    walls, cpus, results = [], [], []
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        results.append(call())
        walls.append(1e3 * (time.perf_counter() - start))
        cpus.append(1e3 * (time.process_time() - cpu))
    return statistics.median(walls), statistics.median(cpus), results


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=300)
    args = parser.parse_args()
    a = tangle()
    volume = isouq.load(a, isovalue=0.1)
    # The runner and the binding alone: a graph of one read node on a tiny field (16^3).
    trivial = {"nodes": [{"id": "load", "type": "read_volume", "parms": {"input": "field:sphere", "resolution": 16}}]}
    cases = [
        ("isouq.mesh(array, isovalue=0.1)", lambda: isouq.mesh(a, isovalue=0.1)),
        ("isouq.mesh(array, isovalue=0.1, summary=False)", lambda: isouq.mesh(a, isovalue=0.1, summary=False)),
        ("isouq.mesh(volume, isovalue=0.1)", lambda: isouq.mesh(volume, isovalue=0.1)),
        ("isouq.mesh(volume, isovalue=0.1, summary=False)", lambda: isouq.mesh(volume, isovalue=0.1, summary=False)),
        ("isouq.run(read_volume only)", lambda: isouq.run(trivial)),
    ]
    print(f"load average {os.getloadavg()[0]:.2f}; {args.repeats} calls each; Tangle 32^3, k = 0.1, full pass")
    print("| call | wall ms | CPU ms (all threads) | mesh node ms | all nodes ms | Python + runner ms |")
    print("|---|--:|--:|--:|--:|--:|")
    for label, call in cases:
        wall, cpu, results = timed(call, args.repeats)
        row = f"| `{label}` | {wall:.3f} | {cpu:.3f} |"
        if getattr(results[0], "summary", None):
            t = [r.summary["timings_ms"] for r in results]
            mesh = statistics.median(x["mesh"] for x in t)
            nodes = statistics.median(sum(x.values()) for x in t)
            row += f" {mesh:.3f} | {nodes:.3f} | {wall - nodes:.3f} |"
        else:
            row += " | | |"
        print(row)
    m = isouq.mesh(volume, isovalue=0.1)
    print(f"{len(m.vertices)} vertices, {len(m.triangles)} triangles; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
