#!/usr/bin/env bash
# Sanitizer builds (docs/hardening.md), each in its own build folder with ccache:
#   scripts/sanitize.sh [address]  AddressSanitizer + UndefinedBehaviorSanitizer (gcc) in
#                                  build-asan/, then the whole ctest suite (Catch2, Python,
#                                  find_package consumer, Blender add-on: they run the
#                                  sanitized CLI; Blender itself is not sanitized).
#   scripts/sanitize.sh thread     ThreadSanitizer in build-tsan/: the threaded mesher and block set, the
#                                  mesh measures (a union-find with atomics), the PLY writer (a
#                                  task formats while a chunk is written), hidden features,
#                                  the CLI contract and, with MPI, isouq under mpirun (ctest -R).
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
  # TSan sees the happens-before edges of TBB's scheduler only in a TBB built with TSan, and
  # Debian ships none: build Debian's own onetbb source (the version libtbb-dev's headers are)
  # with TBB_SANITIZE=thread, once, into build-tsan/tbb/lib. The isouq binaries find it by
  # DT_RPATH (which also serves libopenvdb's libtbb.so.12), so no LD_LIBRARY_PATH reaches the
  # plain python3 that drives the tests (pyopenvdb there keeps Debian's libtbb).
  tbb=$build/tbb
  if [ ! -e "$tbb/lib/libtbb.so.12" ]; then
    if ! grep -rqs '^Types:.*deb-src' /etc/apt/sources.list.d/ /etc/apt/sources.list; then
      sed 's/^Types: deb$/Types: deb-src/' /etc/apt/sources.list.d/debian.sources \
        > /etc/apt/sources.list.d/isouq-src.sources
      apt-get update -qq
    fi
    dpkg-query -W -f='${Status}' dpkg-dev 2>/dev/null | grep -q "install ok installed" ||
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq dpkg-dev >/dev/null
    version=$(dpkg-query -W -f='${source:Version}' libtbb-dev)
    rm -rf "$build/tbb-src" && mkdir -p "$build/tbb-src"
    (cd "$build/tbb-src" && apt-get source -qq "onetbb=$version" >/dev/null)
    src=$(find "$build/tbb-src" -mindepth 1 -maxdepth 1 -type d -name 'onetbb-*')
    cmake -S "$src" -B "$build/tbb-build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DTBB_SANITIZE=thread -DTBB_TEST=OFF -DTBBMALLOC_BUILD=OFF -DTBB_STRICT=OFF \
      -DTBB_DISABLE_HWLOC_AUTOMATIC_SEARCH=ON -DTBB_OUTPUT_DIR_BASE=lib >/dev/null
    cmake --build "$build/tbb-build" -j"$jobs" --target tbb
    mkdir -p "$tbb/lib" && cp -a "$build"/tbb-build/lib_*/libtbb.so* "$tbb/lib/"
  fi
  # (grep reads all its input: grep -q would end the pipe early, a failure under pipefail)
  nm -D "$tbb/lib/libtbb.so.12" | grep __tsan_func_entry >/dev/null ||
    { echo "isouq: sanitize: $tbb/lib/libtbb.so.12 is not built with TSan" >&2; exit 1; }
  cmake -S . -B "$build" "${common[@]}" -DISOUQ_SANITIZE=thread \
    "-DCMAKE_BUILD_RPATH=$tbb/lib" "-DCMAKE_EXE_LINKER_FLAGS=-Wl,--disable-new-dtags" \
    "-DCMAKE_MODULE_LINKER_FLAGS=-Wl,--disable-new-dtags" >/dev/null
  cmake --build "$build" -j"$jobs" --target isouq test_BlockSet test_MarchingCubes test_MeshTopology test_MeshIO test_HiddenFeatures test_CliContract test_Graph
  # The command line module (houdini_style_nodes/cli/CliModule.h) is what links TBB.
  ldd "$build/lib/isouq/libisouq_cli.so" | grep -F "$tbb/lib/libtbb.so.12" >/dev/null ||
    { echo "isouq: sanitize: the TSan isouq does not load $tbb/lib/libtbb.so.12" >&2; exit 1; }
  export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$root/scripts/sanitizers/tsan.supp"
  cd "$build"
  ctest --output-on-failure -j"$jobs" --timeout 1800 -R 'BlockSet|MarchingCubes|MeshTopology|MeshIO|HiddenFeatures|CliContract|test_Graph:|^mpi_'
  ;;
*)
  echo "usage: scripts/sanitize.sh [address|thread]" >&2
  exit 2
  ;;
esac
