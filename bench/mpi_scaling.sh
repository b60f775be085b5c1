#!/usr/bin/env bash
# Strong scaling of `isouq mesh` on MPI ranks with one thread per rank, and per-rank peak memory
# against one process (issue 15; docs/mpi.md). Prints one line per run and the load average.
#   bench/mpi_scaling.sh ISOUQ [WORKDIR] [RADIUS]
# The input is a level-set sphere made with pyopenvdb (radius 400 voxels: 12 M active voxels,
# 3.0 M vertices, 6.0 M triangles); every run writes the same PLY, which the script checks.
set -euo pipefail
isouq=${1:?usage: mpi_scaling.sh ISOUQ [WORKDIR] [RADIUS]}
work=${2:-/tmp/isouq-mpi-bench}
radius=${3:-400}
mkdir -p "$work"
input=$work/sphere$radius.vdb
if [ ! -f "$input" ]; then
  /usr/bin/python3 -c "
import pyopenvdb as vdb
g = vdb.createLevelSetSphere(radius=$radius.0, center=(0, 0, 0), voxelSize=1.0, halfWidth=3.0)
g.name = 'ls'
vdb.write('$input', grids=[g])"
fi
mpirun=(mpirun --oversubscribe --allow-run-as-root -q --bind-to none)
for flags in "" "--linear-only"; do
  echo "== isouq mesh sphere$radius.vdb $flags -j 1 ($(uptime | sed 's/.*load/load/'))"
  /usr/bin/time -f "one process: %e s wall, %U+%S s CPU, peak %M KB" "$isouq" mesh "$input" -o "$work/one.ply" $flags -q -j 1 >/dev/null
  for np in 1 2; do
    "${mpirun[@]}" -np $np /usr/bin/time -f "-np $np, a rank: %e s wall, %U+%S s CPU, peak %M KB" \
      "$isouq" mesh "$input" -o "$work/np$np.ply" --summary "$work/np$np.json" $flags -q -j 1 >/dev/null
    cmp -s "$work/one.ply" "$work/np$np.ply" || { echo "np $np: the PLY differs"; exit 1; }
  done
  echo "   ($(uptime | sed 's/.*load/load/'))"
done
