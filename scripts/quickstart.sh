#!/usr/bin/env bash
# Fresh Debian bookworm, as root: install what isouq needs, build it, and run the demo.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j"$(nproc)" --target isouq
./build/houdini_style_nodes/isouq demo --dir isouq-demo
