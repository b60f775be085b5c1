#!/usr/bin/env bash
# Builds everything (tests included) and runs every test: Catch2, Python references, the
# find_package consumer and the Blender add-on. Prints ctest's summary; exit status is ctest's.
set -euo pipefail
cd "$(dirname "$0")/.."
# ccache hits across clones in other folders (CI clones anew): paths below the parent are relative.
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$(dirname "$PWD")}
scripts/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DISOUQ_BUILD_TESTS=ON
cmake --build build -j"$(nproc)"
cd build
ctest --output-on-failure -j"$(nproc)" --timeout 1800
