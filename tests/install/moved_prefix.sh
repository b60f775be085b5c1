#!/usr/bin/env bash
# Installs isouq to a temporary prefix, moves the prefix, removes nothing else, and runs a graph
# with a report node from there: the installed binary finds its report script and PLY reader
# beside itself (Resources.h), not in the source or build tree; and, with pydicom, a DICOM
# series, through the GDCM module it finds at ../lib/isouq (vdb_ops/src/GdcmServer.h).
# Usage: moved_prefix.sh BUILD_DIR GRAPH.json
set -euo pipefail
build=$1 graph=$2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# --strip: debug information names the build tree by design (a sanitizer build has it); what
# must not name it is the code and data that run.
cmake --install "$build" --prefix "$work/first" --strip > /dev/null
mv "$work/first" "$work/moved"
if grep -rlF -e "$build" -e "$(cd "$(dirname "$graph")/.." && pwd)" "$work/moved/bin" "$work/moved/share"; then
  echo "FAIL: the installed files above name the build or source tree"; exit 1
fi
mkdir "$work/run"
cp "$graph" "$work/run/graph.json"
cd "$work/run"
env -u ISOUQ_REPORT_SCRIPT "$work/moved/bin/isouq" run graph.json --quiet
for png in $(find . -name '*.png'); do echo "report picture: $png"; done
test -n "$(find . -name '*.png')" || { echo "FAIL: the report wrote no picture"; exit 1; }
if /usr/bin/python3 -c 'import pydicom' 2>/dev/null; then
  tests=$(cd "$(dirname "$0")/../python" && pwd)
  isovalue=$(/usr/bin/python3 -c "import sys; sys.path.insert(0, '$tests'); from pathlib import Path
from test_formats_in import ISOVALUE, write_series; write_series(Path('series')); print(ISOVALUE)")
  "$work/moved/bin/isouq" mesh series --isovalue "$isovalue" -o series.ply --quiet
  test -s series.ply || { echo "FAIL: no mesh of the DICOM series"; exit 1; }
  echo "DICOM series: meshed with $work/moved/lib/isouq/libisouq_gdcm.so"
fi
echo "moved prefix: OK"
