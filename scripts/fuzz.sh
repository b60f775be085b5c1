#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/, clang-14, ASan+UBSan) in build-fuzz/ and runs each for
# SECONDS (default 60), one at a time, after replaying every committed crash input. Fails on a
# crash, a leak, undefined behaviour, a timeout (-timeout=10) or running out of memory
# (-rss_limit_mb=2048). Prints the executions per target at the end. docs/hardening.md.
#   scripts/fuzz.sh [SECONDS] [TARGET...]
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
seconds=${1:-60}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(fuzz_raw fuzz_vdb fuzz_formula fuzz_graph fuzz_ply fuzz_vtp fuzz_nifti fuzz_nrrd fuzz_tiff fuzz_dicom)
data=${ISOUQ_DATA_DIR:-$root/../shared/data}
build=${ISOUQ_FUZZ_BUILD:-$root/build-fuzz}
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$(dirname "$root")}

if [ "${ISOUQ_FUZZ_NO_BUILD:-0}" != 1 ]; then # 1: run the fuzzers already built
  scripts/install-deps.sh --fuzz
  CC=clang-14 CXX=clang++-14 cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DISOUQ_BUILD_FUZZERS=ON -DISOUQ_BUILD_TESTS=OFF -DISOUQ_BUILD_BENCH=OFF >/dev/null
  cmake --build "$build" -j"${JOBS:-2}" --target "${targets[@]}" make_vdb_seeds make_nrrd_seeds isouq
fi

export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:allocator_may_return_null=0:abort_on_error=0}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1:suppressions=$root/scripts/sanitizers/ubsan.supp}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/scripts/sanitizers/lsan.supp}
work=$build/fuzz-run
mkdir -p "$work/tmp"
export TMPDIR=$work/tmp

# Seeds: the committed ones, plus those made here (too big to commit, or made by the build).
seed() { # TARGET: fills $work/corpus/TARGET
  local t=$1 c=$work/corpus/$1
  mkdir -p "$c"
  cp -f fuzz/corpus/"$t"/* "$c"/ 2>/dev/null || true
  case $t in
  fuzz_raw)
    [ -f "$data/bucky_32x32x32_uint8.raw" ] &&
      { printf 'bucky_32x32x32_uint8.raw\n'; cat "$data/bucky_32x32x32_uint8.raw"; } >"$c/bucky" ;;
  fuzz_vdb)
    "$build/fuzz/make_vdb_seeds" "$c"
    for f in sphere smoke; do
      [ -f "$data/$f.vdb" ] || continue
      for n in 512 4096 65536; do head -c $n "$data/$f.vdb" >"$c/${f}_prefix_$n.vdb"; done
    done ;;
  fuzz_graph)
    cp -f examples/*.json "$c"/ ;;
  fuzz_nrrd)
    "$build/fuzz/make_nrrd_seeds" "$c" ;;
  fuzz_nifti | fuzz_tiff | fuzz_dicom) # nibabel, tifffile, pydicom (scripts/install-deps.sh)
    /usr/bin/python3 fuzz/make_scan_seeds.py "$work/scan-seeds" && cp -f "$work/scan-seeds/$t"/* "$c"/ || true ;;
  fuzz_ply)
    local cli=$build/houdini_style_nodes/isouq
    ASAN_OPTIONS=detect_leaks=0 "$cli" mesh field:sphere --resolution 6 -o "$c/sphere.ply" >/dev/null 2>&1 || true
    ASAN_OPTIONS=detect_leaks=0 "$cli" mesh field:teardrop --resolution 8 --hidden-features \
      --hidden-out "$c/teardrop_hidden.ply" -o "$c/teardrop.ply" >/dev/null 2>&1 || true ;;
  fuzz_vtp) # isouq's own .vtp files, and VTK's writer's (ascii and raw appended) where ParaView is installed
    local cli=$build/houdini_style_nodes/isouq
    ASAN_OPTIONS=detect_leaks=0 "$cli" mesh field:sphere --resolution 6 -o "$c/sphere.vtp" >/dev/null 2>&1 || true
    ASAN_OPTIONS=detect_leaks=0 "$cli" mesh field:teardrop --resolution 8 --hidden-features \
      --hidden-out "$c/teardrop_hidden.vtp" -o "$c/teardrop.vtp" >/dev/null 2>&1 || true
    /usr/bin/python3 - "$c" <<'PY' 2>/dev/null || true
import sys
from vtkmodules.vtkIOXML import vtkXMLPolyDataReader, vtkXMLPolyDataWriter
for mode in ("ascii", "raw"):
    r = vtkXMLPolyDataReader(); r.SetFileName(sys.argv[1] + "/sphere.vtp"); r.Update()
    w = vtkXMLPolyDataWriter(); w.SetInputData(r.GetOutput()); w.SetFileName(f"{sys.argv[1]}/vtk_{mode}.vtp")
    w.SetCompressorTypeToNone()
    if mode == "ascii": w.SetDataModeToAscii()
    else: w.SetDataModeToAppended(); w.EncodeAppendedDataOff()
    w.Write()
PY
    ;;
  esac
}
max_len() { case $1 in fuzz_raw) echo 40000 ;; fuzz_vdb) echo 65536 ;; fuzz_ply | fuzz_vtp | fuzz_nifti | fuzz_nrrd | fuzz_tiff) echo 16384 ;;
  fuzz_dicom) echo 32768 ;; *) echo 8192 ;; esac; }
dict() { case $1 in fuzz_raw | fuzz_vdb) ;; *) echo "fuzz/dict/${1#fuzz_}.dict" ;; esac; }

status=0
declare -A execs result
for t in "${targets[@]}"; do
  bin=$build/fuzz/$t
  # Every committed crash input first: each must now run clean.
  if compgen -G "fuzz/regressions/$t/*" >/dev/null; then
    if ! "$bin" -timeout=10 -rss_limit_mb=2048 fuzz/regressions/"$t"/* >"$work/$t.replay.log" 2>&1; then
      echo "isouq: fuzz: $t fails on a committed regression input (see $work/$t.replay.log)" >&2
      tail -40 "$work/$t.replay.log" >&2
      status=1
    fi
  fi
  seed "$t"
  mkdir -p "$work/artifacts/$t"
  # One forked worker (-fork=1): a crash, leak, timeout or OOM is saved and counted, and the run
  # goes on, so one run lists every distinct failure it can find in the time.
  args=(-fork=1 -ignore_crashes=1 -ignore_timeouts=1 -ignore_ooms=1
        -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len="$(max_len "$t")"
        -artifact_prefix="$work/artifacts/$t/")
  d=$(dict "$t"); [ -n "$d" ] && args+=(-dict="$d")
  echo "isouq: fuzz: $t for ${seconds}s (log $work/$t.log)"
  rm -f "$work/artifacts/$t"/*
  rc=0
  "$bin" "${args[@]}" "$work/corpus/$t" >"$work/$t.log" 2>&1 || rc=$?
  last=$(grep -E '^#[0-9]+: ' "$work/$t.log" | tail -1)
  execs[$t]=$(sed -E 's/^#([0-9]+):.*/\1/' <<<"$last")
  counts=$(grep -oE 'oom/timeout/crash: [0-9]+/[0-9]+/[0-9]+' <<<"$last" | cut -d' ' -f2)
  found=$(find "$work/artifacts/$t" -type f | wc -l)
  if [ "$rc" -eq 0 ] && [ "$found" -eq 0 ]; then
    result[$t]=clean
  else
    result[$t]="FAILED: exit $rc, oom/timeout/crash ${counts:-?}, $found inputs in $work/artifacts/$t"
    { grep -E 'ERROR: |SUMMARY: |runtime error' "$work/$t.log" || true; } | sort | uniq -c | sort -rn | head -20 >&2
    status=1
  fi
done

echo
printf '%-14s %14s  %s\n' target executions result
for t in "${targets[@]}"; do printf '%-14s %14s  %s\n' "$t" "${execs[$t]:-?}" "${result[$t]}"; done
exit $status
