#!/usr/bin/env bash
# Frames per second of `isouq mesh` on a frame sequence (issue 11): one process for the whole
# sequence, one frame at a time with every thread (--frame-jobs 1) and two frames at once
# (--frame-jobs 2), against one `isouq mesh` process per frame, on the same cache in one run.
# Prints a markdown table with the load average.
#
#   scripts/bench_sequence.sh [FRAMES (default 24)] [RADIUS0 (voxels, default 60)]
#
# The cache is level-set spheres written with pyopenvdb (python3-openvdb), growing by 2 voxels
# a frame, in a temporary folder. BUILD_DIR (default build) holds the isouq binary.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cli=${BUILD_DIR:-$root/build}/houdini_style_nodes/isouq
frames=${1:-24} radius=${2:-60}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
/usr/bin/python3 - "$work" "$frames" "$radius" <<'PY'
import sys, pyopenvdb as vdb
work, frames, radius = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
for f in range(1, frames + 1):
    g = vdb.createLevelSetSphere(radius=radius + 2 * f, center=(0, 0, 0), voxelSize=1.0, halfWidth=3.0)
    vdb.write(f"{work}/ls.{f:04d}.vdb", grids=[g])
PY
now() { date +%s.%N; }
cd "$work"
"$cli" mesh 'ls.####.vdb' -o 'warm.####.ply' -q > /dev/null # page cache, binary
t0=$(now); "$cli" mesh 'ls.####.vdb' -o 'a.####.ply' -q --frame-jobs 1 > /dev/null; t1=$(now)
"$cli" mesh 'ls.####.vdb' -o 'b.####.ply' -q --frame-jobs 2 > /dev/null; t2=$(now)
for f in $(seq -f '%04g' 1 "$frames"); do "$cli" mesh "ls.$f.vdb" -o "c.$f.ply" -q > /dev/null; done; t3=$(now)
for f in $(seq -f '%04g' 1 "$frames"); do cmp -s "a.$f.ply" "b.$f.ply" && cmp -s "a.$f.ply" "c.$f.ply" || { echo "frame $f differs"; exit 1; }; done
echo "Sequence of $frames level-set spheres (radius $radius + 2f voxels), full pass; $(nproc) cores;" \
     "load average $(cut -d' ' -f1-3 /proc/loadavg); commit $(git -C "$root" rev-parse --short HEAD)."
echo
echo "| run | seconds | frames/s | vs one process per frame |"
echo "|---|---|---|---|"
base=$(awk -v a="$t2" -v b="$t3" 'BEGIN { print b - a }')
for row in "one process, --frame-jobs 1:$t0:$t1" "one process, --frame-jobs 2:$t1:$t2" "one process per frame:$t2:$t3"; do
  IFS=: read -r name a b <<< "$row"
  awk -v n="$name" -v a="$a" -v b="$b" -v f="$frames" -v base="$base" \
    'BEGIN { printf "| %s | %.2f | %.2f | %.2fx |\n", n, b - a, f / (b - a), base / (b - a) }'
done
echo
echo "Outputs of the three runs are byte-identical (cmp)."
