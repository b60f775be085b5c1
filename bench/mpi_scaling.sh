#!/usr/bin/env bash
# Strong scaling of `isouq mesh` on MPI ranks with one thread per rank, and per-rank peak memory
# against one process (issue 15; docs/mpi.md). One process, -np 1 and -np 2 take turns R times
# (so a drift of the machine shows in all three alike); prints every run, then the medians, the
# speedup of -np 2 over -np 1 and the peak of a rank at -np 2 over one process's, and the load;
# and each MPI run's stages from its summary (load, measure, mesh).
#   bench/mpi_scaling.sh ISOUQ [WORKDIR] [RADIUS] [R]
#   INPUT=scan.raw bench/mpi_scaling.sh ISOUQ [WORKDIR] - [R]   (any input instead of the sphere)
# The input is a level-set sphere made with pyopenvdb (radius 400 voxels: 12 M active voxels,
# 3.0 M vertices, 6.0 M triangles); every run writes the same PLY, which the script checks. Each
# run writes a new file: the last run's is removed first, outside the timing (replacing a file
# frees the old one inside the rename: 0.25 s for 1.25 GB on the test machine, at any rank count),
# and `sync` runs before each timed run, the ranks' files removed once compared, so that no
# writeback of an earlier output takes a core from a timed run.
set -euo pipefail
isouq=${1:?usage: mpi_scaling.sh ISOUQ [WORKDIR] [RADIUS] [R]}
work=${2:-/tmp/isouq-mpi-bench}
radius=${3:-400}
repeats=${4:-3}
mkdir -p "$work"
input=${INPUT:-$work/sphere$radius.vdb}
if [ -z "${INPUT:-}" ] && [ ! -f "$input" ]; then
  /usr/bin/python3 -c "
import pyopenvdb as vdb
g = vdb.createLevelSetSphere(radius=$radius.0, center=(0, 0, 0), voxelSize=1.0, halfWidth=3.0)
g.name = 'ls'
vdb.write('$input', grids=[g])"
fi
mpirun=(mpirun --oversubscribe --allow-run-as-root -q --bind-to none)
# The machine's own memory scaling before each set (isouq_bench from ISOUQ's build folder).
bench=$(dirname "$(dirname "$(readlink -f "$isouq")")")/bench/isouq_bench
probe() { if [ -x "$bench" ]; then echo "   $("$bench" --memory-probe | head -1)"; else echo "   (no $bench: no memory probe)"; fi; }
median() { sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
for flags in "" "--linear-only"; do
  echo "== isouq mesh $(basename "$input") $flags -j 1, $repeats times ($(uptime | sed 's/.*load/load/'))"
  probe
  log=$work/runs$flags.txt
  : > "$log"
  : > "$work/stages$flags.txt"
  for ((r = 0; r < repeats; ++r)); do
    rm -f "$work/one.ply"
    sync # no writeback of earlier outputs during the timed runs: the flusher takes a core
    /usr/bin/time -f "one %e %M" -a -o "$log" "$isouq" mesh "$input" -o "$work/one.ply" $flags -q -j 1 >/dev/null
    for np in 1 2; do
      rm -f "$work/np$np.ply"
      sync
      "${mpirun[@]}" -np $np /usr/bin/time -f "np$np %e %M" -a -o "$log" \
        "$isouq" mesh "$input" -o "$work/np$np.ply" --summary "$work/np$np.json" $flags -q -j 1 >/dev/null
      cmp -s "$work/one.ply" "$work/np$np.ply" || { echo "np $np: the PLY differs"; exit 1; }
      # Where the time went (rank 0's stages), so that a slow run shows its slow stage.
      /usr/bin/python3 -c "import json, sys; t = json.load(open(sys.argv[1]))['timings_ms']
print('   np$np stages: ' + ', '.join(f'{k} {v:.0f} ms' for k, v in t.items()))" "$work/np$np.json" >>"$work/stages$flags.txt"
      rm -f "$work/np$np.ply" # its dirty pages dropped, never written back
    done
  done
  sed 's/^/   run: /; s/ \([0-9.]*\) \([0-9]*\)$/ \1 s, peak \2 KB/' "$log"
  cat "$work/stages$flags.txt"
  for who in one np1 np2; do
    printf '   %s: median %s s, peak %s KB\n' "$who" "$(awk -v w=$who '$1 == w {print $2}' "$log" | median)" \
      "$(awk -v w=$who '$1 == w {print $3}' "$log" | median)"
  done
  t1=$(awk '$1 == "np1" {print $2}' "$log" | median); t2=$(awk '$1 == "np2" {print $2}' "$log" | median)
  m0=$(awk '$1 == "one" {print $3}' "$log" | median); m2=$(awk '$1 == "np2" {print $3}' "$log" | median)
  echo "   -np 2 against -np 1: $(echo "scale=2; $t1 / $t2" | bc)x; a rank's peak at -np 2 against one process: $(echo "scale=3; $m2 / $m0" | bc)x ($(uptime | sed 's/.*load/load/'))"
done
