#!/usr/bin/python3
# A stand-in for the isouq CLI (SPEC §8) in the pipeline tests. FAKE_ISOUQ_MODE picks the
# behaviour: ok (copy FAKE_ISOUQ_PLY to -o, write --summary and --hidden-out), fail (exit 2 with
# an `isouq: error:` line), garbage (a truncated PLY, exit 0), sleep (until SIGINT, exit 130).
# The command line is appended as JSON to FAKE_ISOUQ_LOG.

import json
import os
import shutil
import signal
import sys
import time

args = sys.argv[1:]
if os.environ.get("FAKE_ISOUQ_LOG"):
    with open(os.environ["FAKE_ISOUQ_LOG"], "a") as log:
        log.write(json.dumps(args) + "\n")
mode = os.environ.get("FAKE_ISOUQ_MODE", "ok")
opt = lambda name: args[args.index(name) + 1] if name in args else None
out = opt("-o")
if mode == "fail":
    sys.stderr.write("Meshing  10%\nisouq: error: grid 'density' is not a float grid\n")
    sys.exit(2)
if mode == "sleep":
    signal.signal(signal.SIGINT, lambda *_: sys.exit(130))
    for pct in range(0, 100, 5):
        sys.stderr.write(f"\rMeshing {pct:3d}%")
        sys.stderr.flush()
        time.sleep(0.2)
    time.sleep(60)
    sys.exit(0)
source = os.environ["FAKE_ISOUQ_PLY"]
if mode == "garbage":
    data = open(source, "rb").read()
    open(out, "wb").write(data[: len(data) // 2])
    sys.exit(0)
shutil.copy(source, out)
if opt("--hidden-out"):
    shutil.copy(os.environ.get("FAKE_ISOUQ_HIDDEN_PLY", source), opt("--hidden-out"))
if opt("--summary"):
    with open(opt("--summary"), "w") as f:
        json.dump({"vertices": 1, "triangles": 2, "boundary_edges": 0, "components": 1,
                   "isovalue": float(opt("--isovalue") or 0), "method": opt("--method")}, f)
sys.stderr.write("Meshing 100%\n")
