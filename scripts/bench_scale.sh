#!/usr/bin/env bash
# Reproduces every number of bench/README.md "Scale on one machine" (issue 15's single-machine
# part, issue 12's small-grid latency) in one run, markdown on stdout, `uptime` before each part:
#   1. the 1 GiB uint8 raw sphere scan (scripts/make_raw_sphere.py, written once to SCAN_DIR):
#      isouq::loadVolume alone, 2 threads and 1; whole `isouq mesh --linear-only` and full runs
#      (summary timings, peak RSS); the PLYs of -j 0 and -j 1 compared byte for byte, and with
#      BASE_CLI (an older isouq) too when given; ParaView's FlyingEdges on the same array in memory;
#   2. the mesher's stage scaling at N = 1024 (linear and full pass) and the N = 1024 table;
#   3. the full pass on Tangle 32^3: fresh extractIsosurface and a reused IsosurfaceMesher.
#
#   scripts/bench_scale.sh            # about 10-15 minutes on a quiet 2-core machine
#
# Environment: BUILD_DIR (default build-bench), SCAN_DIR (default /tmp/isouq-scan), SCAN_N
# (default 1024), BASE_CLI (optional), REPEATS (default 5).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${BUILD_DIR:-$root/build-bench}
scanDir=${SCAN_DIR:-/tmp/isouq-scan}
repeats=${REPEATS:-5}
n=${SCAN_N:-1024}
scan=$scanDir/sphere_${n}x${n}x${n}_uint8.raw
cli=$build/houdini_style_nodes/isouq
bench=$build/bench/isouq_bench

cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DISOUQ_BUILD_BENCH=ON >/dev/null
cmake --build "$build" -j2 --target isouq_bench isouq >/dev/null
mkdir -p "$scanDir"
[ -f "$scan" ] || /usr/bin/python3 "$root/scripts/make_raw_sphere.py" "$scan" "$n"
cat "$scan" >/dev/null # into the page cache

load() { echo; echo "uptime: $(uptime)"; echo; }
echo "## Scale on one machine, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$root" rev-parse --short HEAD)"
echo
echo "Machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')."

echo; echo "### 1 GiB raw scan: loading (read, Otsu, dense to sparse)"; load
"$bench" --load "$scan" --threads default,1 --repeats "$repeats"

echo; echo "### 1 GiB raw scan: whole runs"; load
echo "| command | threads | wall s | load ms | mesh ms | measure ms | peak RSS MB | load |"
echo "|---|---|--:|--:|--:|--:|--:|--:|"
for pass in --linear-only ""; do
    for j in 0 1 base; do
        out=$scanDir/out${pass}-j$j
        exe=$cli
        if [ "$j" = base ]; then
            [ -n "${BASE_CLI:-}" ] || continue
            exe=$BASE_CLI
        fi
        /usr/bin/time -f "%e %M" -o "$out.time" "$exe" mesh "$scan" $pass -j "${j/base/0}" -q -o "$out.ply" --summary "$out.json"
        read -r wall rss <"$out.time"
        /usr/bin/python3 - "$out.json" "$pass" "$j" "$wall" "$rss" <<'PY'
import json, os, sys
t = json.load(open(sys.argv[1]))["timings_ms"]
print(f"| isouq mesh {sys.argv[2] or '(all methods)'} | {dict(base='BASE_CLI, default').get(sys.argv[3], sys.argv[3] if sys.argv[3] != '0' else 'default')} | {sys.argv[4]} "
      f"| {t['load']:.0f} | {t['mesh']:.0f} | {t['measure']:.0f} "
      f"| {int(sys.argv[5]) / 1024:.0f} | {os.getloadavg()[0]:.2f} |")
PY
    done
    echo
    cmp "$scanDir/out${pass}-j0.ply" "$scanDir/out${pass}-j1.ply" && echo "-j 0 and -j 1 ${pass:-(all methods)}: byte-identical PLY"
    if [ -n "${BASE_CLI:-}" ]; then
        cmp "$scanDir/out${pass}-jbase.ply" "$scanDir/out${pass}-j0.ply" && echo "BASE_CLI ${pass:-(all methods)}: byte-identical PLY"
    fi
done

echo; echo "### 1 GiB raw scan: ParaView's FlyingEdges on the array in memory"; load
isovalue=$(/usr/bin/python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['isovalue'])" "$scanDir/out--linear-only-j0.json")
echo "| filter | threads | numpy read s | contour s | triangles | SMP backend | load |"
echo "|---|---|--:|--:|--:|---|--:|"
/usr/bin/python3 "$root/bench/flying_edges.py" "$scan" "$isovalue" 0,1 3

echo; echo "### Mesher stages at N = 1024"; load
"$bench" --stages --cases sphere1024 --repeats "$repeats"
"$bench" --stages --pass full --cases sphere1024 --repeats "$repeats" | tail -n 7
echo; load
"$bench" --cases sphere1024 --threads default,1 --repeats "$repeats" --memory-runs 3
"$bench" --pass full --cases sphere1024 --threads default,1 --repeats "$repeats" --memory-runs 3 | grep '^| sphere\|as fast'
echo

echo; echo "### Full pass on Tangle 32^3"; load
# One thread count a run: taking turns would wake the worker threads for every 1-ms call.
first=
for reuse in "" --reuse; do
    [ -z "$reuse" ] || echo "With --reuse (one IsosurfaceMesher and one Mesh for all calls):"
    for threads in default 1; do
        "$bench" --pass full --cases tangle32 --threads $threads --repeats 1001 --memory-runs 1 $reuse |
            if [ -z "$reuse$first" ]; then cat; else grep '^| tangle'; fi
        first=no
    done
done
