"""The node layer's command line: graph errors (one line naming node and parameter, exit 2,
nothing written), `isouq nodes --json` against a schema, the generated docs table, Ctrl-C."""
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def run(cli, *args, **kw):
    return subprocess.run([cli, *map(str, args)], capture_output=True, text=True, timeout=300, **kw)


def graph(*nodes):
    return {"nodes": list(nodes)}


READ = {"id": "read", "type": "read_volume", "parms": {"input": "field:sphere", "resolution": 16}}
MESH = {"id": "mesh", "type": "mesh", "inputs": {"volume": "read"}}
SAVE = {"id": "save", "type": "write_ply", "inputs": {"mesh": "mesh"}, "parms": {"path": "out.ply"}}

BAD_GRAPHS = {
    "unknown node": (graph(READ, {"id": "x", "type": "smooth"}), ["node 'x'", "unknown node type 'smooth'"]),
    "unknown parameter": (graph(READ, dict(MESH, parms={"methd": "weno"}), SAVE),
                          ["node 'mesh' (mesh)", "unknown parameter 'methd'"]),
    "wrong type": (graph(dict(READ, parms={"input": "field:sphere", "resolution": "big"}), MESH, SAVE),
                   ["node 'read' (read_volume)", "parameter 'resolution'", "expected an integer"]),
    "outside hard range": (graph(READ, MESH, {"id": "thr", "type": "threshold", "inputs": {"mesh": "mesh"},
                                              "parms": {"percentile": 150}},
                                 dict(SAVE, inputs={"mesh": "thr"})),
                           ["node 'thr' (threshold)", "parameter 'percentile'", "outside the hard range [0, 100]"]),
    "bad menu token": (graph(READ, dict(MESH, parms={"method": "quintic"}), SAVE),
                       ["node 'mesh' (mesh)", "parameter 'method'", "not one of linear|cubic|weno|weno-paper"]),
    "cycle": (graph(READ, {"id": "a", "type": "box_select", "inputs": {"mesh": "b"}},
                    {"id": "b", "type": "threshold", "inputs": {"mesh": "a"}}, dict(SAVE, inputs={"mesh": "a"})),
              ["node 'a' (box_select)", "input cycle: a <- b <- a"]),  # a reads b, b reads a
    "missing input": (graph(READ, {"id": "mesh", "type": "mesh"}, SAVE),
                      ["node 'mesh' (mesh)", "input 'volume' is not connected"]),
    "input from nowhere": (graph(READ, dict(MESH, inputs={"volume": "reed"}), SAVE),
                           ["node 'mesh' (mesh)", "input 'volume': no node 'reed'"]),
    "wrong port type": (graph(READ, dict(MESH, inputs={"volume": "read"}), dict(SAVE, inputs={"mesh": "read"})),
                        ["node 'save' (write_ply)", "input 'mesh'", "has no mesh output"]),
    "two outputs to one path": (graph(READ, MESH, SAVE, dict(SAVE, id="again")),
                                ["node 'again' (write_ply)", "parameter 'path'", "also written by node 'save'"]),
    "unset variable": (graph(dict(READ, parms={"input": "${ISOUQ_NO_SUCH_VARIABLE}/x.raw"}), MESH, SAVE),
                       ["node 'read' (read_volume)", "parameter 'input'", "ISOUQ_NO_SUCH_VARIABLE is not set"]),
    "failing cook": (graph(READ, MESH, {"id": "blend", "type": "method_blend", "inputs": {"mesh": "mesh"}},
                           dict(SAVE, inputs={"mesh": "blend"})),
                     ["node 'blend' (method_blend)", "parameter 'selection'", "no per-vertex 'in_box'"]),
}


def test_missing_graph_file(isouq_cli, tmp_path):
    proc = run(isouq_cli, "run", tmp_path / "none.json", "--quiet")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == f"isouq: error: cannot read {tmp_path / 'none.json'}: no such file"


@pytest.mark.parametrize("case", sorted(BAD_GRAPHS))
def test_graph_error(isouq_cli, tmp_path, case):
    doc, needles = BAD_GRAPHS[case]
    (tmp_path / "g.json").write_text(json.dumps(doc))
    out = tmp_path / "out"
    out.mkdir()
    (out / "out.ply").write_text("keep me")  # an existing output stays untouched
    proc = run(isouq_cli, "run", tmp_path / "g.json", "--out-dir", out, "--quiet")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("isouq: error: "), proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert sorted(p.name for p in out.iterdir()) == ["out.ply"]
    assert (out / "out.ply").read_text() == "keep me"
    assert proc.stdout == ""


def test_invalid_json(isouq_cli, tmp_path):
    (tmp_path / "g.json").write_text("{nodes: [")
    proc = run(isouq_cli, "run", tmp_path / "g.json")
    assert proc.returncode == 2 and "not valid JSON" in proc.stderr


PARM_TYPES = ["bool", "int", "float", "string", "menu", "vec2", "vec3", "int3", "path"]
PORT_TYPES = ["volume", "mesh", "json"]
RANGE = {"anyOf": [{"type": "null"},
                   {"type": "array", "minItems": 2, "maxItems": 2, "items": {"type": ["number", "null"]}}]}
PORT = {"type": "object", "required": ["name", "type", "description", "optional"],
        "properties": {"name": {"type": "string"}, "type": {"enum": PORT_TYPES},
                       "description": {"type": "string"}, "optional": {"type": "boolean"}}}
PARM = {"type": "object",
        "required": ["token", "label", "type", "default", "soft_range", "hard_range", "menu", "extensions", "tooltip",
                     "flag"],
        "properties": {"token": {"type": "string", "pattern": "^[a-z][a-z0-9_]*$"}, "label": {"type": "string"},
                       "type": {"enum": PARM_TYPES}, "soft_range": RANGE, "hard_range": RANGE,
                       "menu": {"type": "array", "items": {"type": "string"}},
                       "extensions": {"type": "array", "items": {"type": "string", "pattern": "^[.][a-z0-9]+$"}},
                       "tooltip": {"type": "string"},
                       "flag": {"type": "string"}}}
SCHEMA = {"type": "object", "required": ["format", "format_version", "nodes"],
          "properties": {"format": {"enum": ["isouq-nodes"]}, "format_version": {"type": "integer"},
                         "nodes": {"type": "array", "items": {
                             "type": "object",
                             "required": ["type", "label", "description", "inputs", "outputs", "parms"],
                             "properties": {"type": {"type": "string", "pattern": "^[a-z][a-z0-9_]*$"},
                                            "label": {"type": "string"}, "description": {"type": "string"},
                                            "inputs": {"type": "array", "items": PORT},
                                            "outputs": {"type": "array", "items": PORT},
                                            "parms": {"type": "array", "items": PARM}}}}}}


def validate(value, schema, where="$"):
    """The subset of JSON Schema used above (python3-jsonschema is not in bookworm's base set)."""
    import re
    json_types = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}

    def is_type(v, t):
        if t == "integer":
            return isinstance(v, int) and not isinstance(v, bool)
        if t == "number":
            return isinstance(v, (int, float)) and not isinstance(v, bool)
        return isinstance(v, json_types[t])

    if "anyOf" in schema:
        errors = []
        for option in schema["anyOf"]:
            try:
                return validate(value, option, where)
            except AssertionError as e:
                errors.append(str(e))
        raise AssertionError(f"{where}: matches no option: {errors}")
    if "type" in schema:
        types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        assert any(is_type(value, t) for t in types), f"{where}: {value!r} is not {types}"
    if "enum" in schema:
        assert value in schema["enum"], f"{where}: {value!r} not in {schema['enum']}"
    if "pattern" in schema:
        assert re.search(schema["pattern"], value), f"{where}: {value!r} !~ {schema['pattern']}"
    for key in schema.get("required", []):
        assert key in value, f"{where}: no '{key}'"
    for key, sub in schema.get("properties", {}).items():
        if key in value:
            validate(value[key], sub, f"{where}.{key}")
    if isinstance(value, list):
        assert len(value) >= schema.get("minItems", 0) and len(value) <= schema.get("maxItems", len(value))
        for i, item in enumerate(value):
            if "items" in schema:
                validate(item, schema["items"], f"{where}[{i}]")


def test_nodes_json_schema(isouq_cli):
    proc = run(isouq_cli, "nodes", "--json")
    assert proc.returncode == 0
    doc = json.loads(proc.stdout)
    validate(doc, SCHEMA)
    types = {n["type"]: n for n in doc["nodes"]}
    for required in ("read_volume", "mesh", "error_estimate", "hidden_features", "threshold", "box_select",
                     "method_blend", "compare", "summary", "write_ply", "write_summary", "report"):
        assert required in types
    for node in doc["nodes"]:
        tokens = [p["token"] for p in node["parms"]]
        assert len(tokens) == len(set(tokens)), node["type"]
        for p in node["parms"]:
            assert p["label"][:1].isupper(), p
            if p["type"] == "menu":
                assert p["menu"] and (p["default"] is None or p["default"] in p["menu"]), p
            if p["hard_range"] and isinstance(p["default"], (int, float)) and not isinstance(p["default"], bool):
                lo, hi = p["hard_range"]
                assert (lo is None or p["default"] >= lo) and (hi is None or p["default"] <= hi), p
    # The add-on's vocabulary: the method menu is SPEC §8's.
    method = next(p for p in types["mesh"]["parms"] if p["token"] == "method")
    assert method["menu"] == ["linear", "cubic", "weno", "weno-paper"]


def test_docs_table_is_generated(isouq_cli):
    proc = run(isouq_cli, "nodes", "--markdown")
    assert proc.returncode == 0
    committed = (ROOT / "docs" / "node-parameters.md").read_text()
    assert proc.stdout == committed, ("docs/node-parameters.md is stale: regenerate it with "
                                      "'isouq nodes --markdown > docs/node-parameters.md'")


def test_mesh_flags_come_from_the_specs(isouq_cli):
    doc = json.loads(run(isouq_cli, "nodes", "--json").stdout)
    help_text = run(isouq_cli, "mesh", "--help").stdout
    for node in doc["nodes"]:
        if node["type"] in ("read_volume", "mesh", "write_ply", "write_summary", "hidden_features"):
            for p in node["parms"]:
                for name in filter(None, p["flag"].split(",")):
                    if name.startswith("-"):
                        assert name in help_text, name
                        assert p["tooltip"].split(" (")[0] in help_text.replace("\n", " "), p["tooltip"]


def test_hidden_features_summary(isouq_cli, tmp_path):
    proc = run(isouq_cli, "mesh", "field:teardrop", "-n", 32, "-o", tmp_path / "mc.ply", "--hidden-features",
               "--subdivisions", 4, "--hidden-out", tmp_path / "hf.ply", "--summary", tmp_path / "s.json", "-q")
    assert proc.returncode == 0, proc.stderr
    hidden = json.loads((tmp_path / "s.json").read_text())["hidden"]
    for key in ("cells_flagged", "cells_total", "fraction", "components_before", "components_after", "boundary_edges"):
        assert key in hidden
    assert hidden["components_before"] == 2 and hidden["components_after"] == 1  # SPEC §4 claim
    assert hidden["fraction"] == pytest.approx(hidden["cells_flagged"] / hidden["cells_total"])
    assert (tmp_path / "hf.ply").exists()
    # The filter is on by default; --no-hidden-filter refines every flagged cell the tricubic
    # surface passes through: more cells, the same reconnection.
    assert hidden["filter"] is True
    proc = run(isouq_cli, "mesh", "field:teardrop", "-n", 32, "-o", tmp_path / "mc2.ply", "--hidden-features",
               "--no-hidden-filter", "--summary", tmp_path / "s2.json", "-q")
    assert proc.returncode == 0, proc.stderr
    unfiltered = json.loads((tmp_path / "s2.json").read_text())["hidden"]
    assert unfiltered["filter"] is False
    assert unfiltered["cells_refined"] > hidden["cells_refined"]
    assert unfiltered["cells_flagged"] == hidden["cells_flagged"]
    assert unfiltered["components_after"] == 1


def test_ctrl_c_cancels_within_a_second(isouq_cli, tmp_path):
    """A run on a large field, interrupted mid-way: exit 130 within 1 s, no partial file, the
    existing output untouched, no temporary file left."""
    doc = graph({"id": "read", "type": "read_volume", "parms": {"input": "field:tangle", "resolution": 900}},
                MESH, SAVE)
    (tmp_path / "g.json").write_text(json.dumps(doc))
    out = tmp_path / "out"
    out.mkdir()
    (out / "out.ply").write_text("old")
    proc = subprocess.Popen([isouq_cli, "run", str(tmp_path / "g.json"), "--out-dir", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(2.0)
    assert proc.poll() is None, "the run finished before it could be interrupted: use a larger field"
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    elapsed = time.monotonic() - sent
    err = proc.stderr.read()
    assert proc.returncode == 130, err
    assert err == "isouq: interrupted; no output written\n"  # one line, no blank one before it (-q: no bar)
    # A sanitized build runs several times slower: scripts/sanitize.sh sets ISOUQ_TEST_TIME_SCALE.
    assert elapsed < 1.0 * float(os.environ.get("ISOUQ_TEST_TIME_SCALE", "1")), f"took {elapsed:.2f} s to stop"
    assert sorted(p.name for p in out.iterdir()) == ["out.ply"]
    assert (out / "out.ply").read_text() == "old"
