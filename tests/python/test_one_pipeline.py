"""One pipeline (SPEC §10): `isouq mesh ... --save-graph G.json` writes the graph it ran, and
`isouq run G.json` from the same folder writes byte-identical meshes and an equal summary
(timings aside), for a field, a raw scan and .vdb files, with and without hidden features."""
import json
import os
import shutil
import subprocess

import pytest

CASES = {
    "field": ["field:teardrop", "-n", "32"],
    "raw": ["bucky_32x32x32_uint8.raw", "--isovalue", "51"],
    "vdb-level-set": ["sphere.vdb"],
    "vdb-fog": ["smoke.vdb", "--grid", "density", "--isovalue", "0.1", "--linear-only"],
}


def run(cli, args, cwd):
    proc = subprocess.run([cli, *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"isouq {' '.join(args)}: {proc.stderr.strip()}"
    return proc


def without_timings(path):
    summary = json.loads(path.read_text())
    summary.pop("timings_ms")
    return summary


@pytest.mark.parametrize("hidden", [False, True], ids=["standard", "hidden"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_saved_graph_reproduces_the_mesh_command(isouq_cli, data_dir, tmp_path, case, hidden):
    args = list(CASES[case])
    if not args[0].startswith("field:"):
        os.symlink(data_dir / args[0], tmp_path / args[0])  # relative paths, as a user gives them
    outputs = ["out.ply", "summary.json"]
    args += ["-o", "out.ply", "--summary", "summary.json", "--save-graph", "graph.json"]
    if hidden:
        args += ["--hidden-features", "--hidden-out", "hidden.ply"]
        outputs.append("hidden.ply")
    run(isouq_cli, ["mesh", *args, "--quiet"], tmp_path)

    first = tmp_path / "first"
    first.mkdir()
    for name in outputs:
        shutil.move(tmp_path / name, first / name)
    run(isouq_cli, ["run", "graph.json", "--quiet"], tmp_path)

    for name in outputs:
        if name.endswith(".ply"):
            assert (tmp_path / name).read_bytes() == (first / name).read_bytes(), name
    assert without_timings(tmp_path / "summary.json") == without_timings(first / "summary.json")
    graph = json.loads((tmp_path / "graph.json").read_text())
    assert {n["type"] for n in graph["nodes"]} >= {"read_volume", "mesh", "summary", "write_ply"}
    assert ("hidden_features" in {n["type"] for n in graph["nodes"]}) == hidden


def test_nodes_json_exports_the_column_table(isouq_cli):
    doc = json.loads(run(isouq_cli, ["nodes", "--json"], None).stdout)
    columns = {(c["element"], c["name"]): c for c in doc["columns"]}
    # SPEC §6 names and types, as the PLY writer emits them.
    for name, kind in [("x", "float32"), ("t_linear", "float32"), ("edge_i", "int32"), ("edge_axis", "uint8"),
                       ("order", "uint8"), ("err_est", "float32"), ("max_var", "float32"), ("hidden", "uint8")]:
        assert columns[("vertex", name)]["type"] == kind, name
    assert columns[("face", "hidden")]["type"] == "uint8"
    measures = [c["name"] for c in doc["columns"] if c["measure"]]
    threshold = next(n for n in doc["nodes"] if n["type"] == "threshold")
    menu = next(p for p in threshold["parms"] if p["token"] == "measure")["menu"]
    assert menu == measures  # the node menu is the table's measures
    methods = [m["token"] for m in doc["methods"]]
    mesh = next(n for n in doc["nodes"] if n["type"] == "mesh")
    assert next(p for p in mesh["parms"] if p["token"] == "method")["menu"] == methods
    assert all(("vertex", m["column"]) in columns for m in doc["methods"])
