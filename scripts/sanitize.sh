#!/usr/bin/env bash
# Sanitizer builds (docs/hardening.md), each in its own build folder with ccache:
#   scripts/sanitize.sh [address]  AddressSanitizer + UndefinedBehaviorSanitizer (gcc) in
#                                  build-asan/, then the whole ctest suite (Catch2, Python,
#                                  find_package consumer, Blender add-on: they run the
#                                  sanitized CLI; Blender itself is not sanitized).
#   scripts/sanitize.sh thread     ThreadSanitizer in build-tsan/: the threaded mesher, hidden
#                                  features, the CLI contract and, with MPI, isouq under mpirun
#                                  (ctest -R).
# Any sanitizer report fails the test that caused it (halt_on_error, exitcode). Prints ctest's
# summary; the exit status is ctest's.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
mode=${1:-address}
jobs=${JOBS:-$(nproc)}
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$(dirname "$root")}
scripts/install-deps.sh
# Sanitized code runs several times slower: the tests' latency bounds (a Ctrl-C stops a run within
# a second) scale by this.
export ISOUQ_TEST_TIME_SCALE=${ISOUQ_TEST_TIME_SCALE:-3}

# -O1 keeps the suite's run time near the Release one; line tables give readable stacks.
common=(-DCMAKE_BUILD_TYPE=RelWithDebInfo "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -g1 -DNDEBUG"
        -DISOUQ_BUILD_TESTS=ON -DISOUQ_BUILD_BENCH=OFF)
case $mode in
address)
  build=$root/build-asan
  cmake -S . -B "$build" "${common[@]}" -DISOUQ_SANITIZE=address,undefined >/dev/null
  cmake --build "$build" -j"$jobs"
  # Leaks fail too (LeakSanitizer at exit). Python and Blender start the CLI as a plain
  # subprocess, so nothing needs LD_PRELOAD; these variables reach it through the environment.
  export ASAN_OPTIONS=detect_leaks=1:abort_on_error=0:halt_on_error=1:detect_stack_use_after_return=0:check_initialization_order=1
  export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1:suppressions=$root/scripts/sanitizers/ubsan.supp
  export LSAN_OPTIONS=suppressions=$root/scripts/sanitizers/lsan.supp
  cd "$build"
  ctest --output-on-failure -j"$jobs" --timeout 1800
  ;;
thread)
  build=$root/build-tsan
  cmake -S . -B "$build" "${common[@]}" -DISOUQ_SANITIZE=thread >/dev/null
  cmake --build "$build" -j"$jobs" --target isouq test_MarchingCubes test_HiddenFeatures test_CliContract
  export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$root/scripts/sanitizers/tsan.supp"
  cd "$build"
  ctest --output-on-failure -j"$jobs" --timeout 1800 -R 'MarchingCubes|HiddenFeatures|CliContract|^mpi_'
  ;;
*)
  echo "usage: scripts/sanitize.sh [address|thread]" >&2
  exit 2
  ;;
esac
