#!/usr/bin/python3
# A stand-in for the isouq CLI (SPEC §8) in the pipeline tests. `nodes --json` prints the mesh
# node's method menu and the `columns` and `methods` tables (SPEC §10; test_real_cli checks them
# against the real binary's). For `mesh`, FAKE_ISOUQ_MODE picks the behaviour: ok (copy
# FAKE_ISOUQ_PLY to -o, write --summary and --hidden-out), fail (exit 2 with an `isouq: error:`
# line), garbage (a truncated PLY, exit 0), sleep (until SIGINT, exit 130).
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
if args == ["nodes", "--json"]:
    methods = [{"token": "linear", "label": "Linear", "column": "t_linear"},
               {"token": "cubic", "label": "Cubic (4-point Lagrange)", "column": "t_cubic"},
               {"token": "weno", "label": "WENO (6th order)", "column": "t_weno"},
               {"token": "weno-paper", "label": "WENO (paper's constant weights)",
                "column": "t_weno_paper"}]

    def column(name, kind, text, measure=False, element="vertex"):
        return {"name": name, "type": kind, "element": element, "description": text,
                "measure": measure, "summary": measure}

    columns = [column(a, "float32", f"position {a}") for a in "xyz"]
    columns += [column(m["column"], "float32", f"{m['label']} crossing along the edge")
                for m in methods]
    columns += [column(f"edge_{a}", "int32", f"edge voxel {a}") for a in "ijk"]
    columns += [column("edge_axis", "uint8", "edge axis"), column("order", "uint8", "order used")]
    columns += [column(name, "float32", f"measure {name}", True) for name in (
        "err_est", "err_bound", "err_best", "err_best_surface", "err_est_cubic", "err_est_weno",
        "d_lc", "d_lw", "d_cw", "max_var", "err_true_linear", "err_true_cubic", "err_true_weno",
        "err_true_weno_paper", "dist_true", "dist_true_linear", "dist_true_cubic",
        "dist_true_weno", "dist_true_weno_paper", "dist_metro_linear")]
    columns += [column(name, "uint8", name) for name in ("hidden", "above", "in_box")]
    columns += [column("compare_dist", "float32", "distance of two crossings", True)]
    columns += [column(name, "uint8", f"colour {name}") for name in ("red", "green", "blue")]
    columns += [column("quality", "float32", "the coloured measure"),
                column("vertex_indices", "list", "triangle corners", element="face"),
                column("hidden", "uint8", "refined face", element="face")]
    mesh = {"type": "mesh", "parms": [{"token": "method", "default": "weno",
                                       "menu": [m["token"] for m in methods]}]}
    json.dump({"format": "isouq-nodes", "format_version": 1, "nodes": [mesh],
               "columns": columns, "methods": methods}, sys.stdout)
    sys.exit(0)
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
