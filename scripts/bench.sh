#!/usr/bin/env bash
# Regenerates the tables of bench/README.md: configures a Release build, builds the benchmark
# and the CLI, runs isouq_bench (in-process, same grid) and, with hyperfine when installed,
# whole processes: `isouq mesh` against `vdb_tool -l2m`. Prints markdown on stdout.
#
#   scripts/bench.sh [isouq_bench options, e.g. --cases sphere256,smoke --repeats 3]
#
# Environment: BUILD_DIR (default build-bench), RUNS (whole-process runs, default 20).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${BUILD_DIR:-$root/build-bench}
runs=${RUNS:-20}
data=$root/../shared/data

cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DISOUQ_BUILD_BENCH=ON >/dev/null
cmake --build "$build" -j2 --target isouq_bench isouq >/dev/null

echo "## isouq benchmark, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$root" rev-parse --short HEAD)"
echo
echo "Machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //');" \
     "load average $(cut -d' ' -f1-3 /proc/loadavg)."
echo
echo "### In one process, same grid: extractIsosurface (linear) vs volumeToMesh (adaptivity 0)"
echo
"$build/bench/isouq_bench" "$@"
echo

echo "### Hidden features (issue 4): the pass against plain MC and volumeToMesh, same grid"
echo
"$build/bench/isouq_bench" --pass hidden --cases teardrop32,tubey32,engine
echo
"$build/bench/isouq_bench" --pass hidden-unfiltered --cases teardrop32,tubey32,engine
echo

echo "### Whole processes: sphere.vdb (k = 0)"
echo
if ! command -v hyperfine >/dev/null || ! command -v vdb_tool >/dev/null; then
    echo "hyperfine or vdb_tool is missing (apt-get install hyperfine libopenvdb-tools): skipped."
    exit 0
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
isouq=$build/houdini_style_nodes/isouq
hyperfine --style none --warmup 3 --runs "$runs" --export-json "$out/runs.json" \
    -n "isouq mesh --linear-only" "$isouq mesh $data/sphere.vdb -o $out/a.ply --linear-only -q" \
    -n "vdb_tool -l2m adapt=0" "vdb_tool -read $data/sphere.vdb -l2m adapt=0 -write $out/b.ply" \
    -n "isouq mesh (all methods)" "$isouq mesh $data/sphere.vdb -o $out/c.ply -q" \
    >/dev/null
/usr/bin/python3 - "$out/runs.json" "$runs" <<'PY'
import json, statistics, sys
results = json.load(open(sys.argv[1]))["results"]
median = {r["command"]: 1e3 * statistics.median(r["times"]) for r in results}
base = median["vdb_tool -l2m adapt=0"]
print(f"hyperfine, 3 warm-up runs, {sys.argv[2]} runs each; ratio = median / vdb_tool's median.\n")
print("| command | median ms | mean ± sd ms | min ms | user ms | sys ms | ratio |")
print("|---|--:|--:|--:|--:|--:|--:|")
for r in results:
    c = r["command"]
    print(f"| `{c}` | {median[c]:.1f} | {1e3 * r['mean']:.1f} ± {1e3 * r['stddev']:.1f} | "
          f"{1e3 * r['min']:.1f} | {1e3 * r['user']:.1f} | {1e3 * r['system']:.1f} | "
          f"**{median[c] / base:.2f}** |")
PY
echo
echo "Phases (median of 5 runs; isouq's --summary timings_ms, vdb_tool's own report):"
echo
for i in 1 2 3 4 5; do
    "$isouq" mesh "$data/sphere.vdb" -o "$out/a.ply" --linear-only -q --summary "$out/s$i.json" >/dev/null
    vdb_tool -read "$data/sphere.vdb" -l2m adapt=0 -write "$out/b.ply" 2>"$out/v$i.txt" >/dev/null
done
/usr/bin/python3 - "$out" <<'PY'
import json, re, statistics, sys
from pathlib import Path
out = Path(sys.argv[1])
isouq = [json.load(open(out / f"s{i}.json"))["timings_ms"] for i in range(1, 6)]
tool = [[float(x) for x in re.findall(r"completed in ([0-9.]+) milliseconds", (out / f"v{i}.txt").read_text())]
        for i in range(1, 6)]
med = lambda xs: statistics.median(xs)
print("| isouq phase | ms | vdb_tool phase | ms |\n|---|--:|---|--:|")
names = ["read", "SDF -> mesh", "write"]
rows = [(p, med([t[p] for t in isouq])) for p in isouq[0]]
for i in range(max(len(rows), len(names))):
    a = f"{rows[i][0]} | {rows[i][1]:.1f}" if i < len(rows) else " | "
    b = f"{names[i]} | {med([t[i] for t in tool]):.1f}" if i < len(names) and all(len(t) > i for t in tool) else " | "
    print(f"| {a} | {b} |")
PY
echo
echo "Output sizes: isouq --linear-only $(stat -c %s "$out/a.ply") B (positions + provenance," \
     "triangles), vdb_tool $(stat -c %s "$out/b.ply") B (positions, quads), isouq all methods" \
     "$(stat -c %s "$out/c.ply") B. Load average after: $(cut -d' ' -f1-3 /proc/loadavg)."
