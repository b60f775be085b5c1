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
source = os.environ.get("FAKE_ISOUQ_PLY", "")


def placeholder(path):
    import re
    found = list(re.finditer(r"#+", os.path.basename(path)))
    if not found:
        return None
    m = found[-1]
    head = os.path.dirname(path)
    name = os.path.basename(path)
    return lambda f: os.path.join(head, name[:m.start()] + f"{f:0{len(m.group())}d}" + name[m.end():])


if placeholder(args[1]):
    read, write = placeholder(args[1]), placeholder(out)
    hidden = placeholder(opt("--hidden-out")) if opt("--hidden-out") else None
    if opt("--frames"):
        span, _, step = opt("--frames").partition(":")
        a, _, b = span.partition("-")
        frames = list(range(int(a), int(b or a) + 1, int(step or 1)))
    else:
        on_disk = sorted(f for f in range(0, 10000) if os.path.isfile(read(f)))
        frames = list(range(on_disk[0], on_disk[-1] + 1))
    missing = [f for f in frames if not os.path.isfile(read(f))]
    if missing and "--skip-missing" not in args:
        sys.stderr.write(f"isouq: error: '{args[1]}': frames {missing} missing\n")
        sys.exit(2)
    frames = [f for f in frames if f not in missing]
    signal.signal(signal.SIGINT, lambda *_: sys.exit(130))
    entries = []
    for i, f in enumerate(frames):
        for pct in (0, 50, 100):
            prefix = f"frame {i}/{len(frames)}, ETA 1 s | " if i else ""
            sys.stderr.write(f"\r{prefix}Meshing    [{'#' * (pct // 10):10s}] {pct:3d}%   0.1s")
            sys.stderr.flush()
            if mode == "sleep":
                time.sleep(float(os.environ.get("FAKE_ISOUQ_FRAME_SECONDS", "0.3")) / 3)
        if not ("--resume" in args and os.path.isfile(write(f))):
            shutil.copy(source, write(f) + ".tmp")
            os.replace(write(f) + ".tmp", write(f))
        if hidden:
            shutil.copy(os.environ.get("FAKE_ISOUQ_HIDDEN_PLY", source), hidden(f))
        print(f"frame {f}: wrote {write(f)}: 1 vertices, 2 triangles, 1 components", flush=True)
        entries.append({"frame": f, "file": read(f), "output": write(f), "vertices": 1,
                        "triangles": 2, "components": 1, "boundary_edges": 0, "empty": False})
    sys.stderr.write(f"\rframe {len(frames)}/{len(frames)}, ETA 0 s | done\n")
    if opt("--summary"):
        with open(opt("--summary"), "w") as f:
            json.dump({"frames": entries, "totals": {"frames": len(frames)},
                       "isovalue": float(opt("--isovalue") or 0), "method": opt("--method"),
                       "sequence": {"input": args[1], "output": out, "first": frames[0],
                                    "last": frames[-1], "step": 1}}, f)
    sys.exit(0)
if mode == "sleep":
    signal.signal(signal.SIGINT, lambda *_: sys.exit(130))
    for pct in range(0, 100, 5):
        sys.stderr.write(f"\rMeshing {pct:3d}%")
        sys.stderr.flush()
        time.sleep(0.2)
    time.sleep(60)
    sys.exit(0)
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
