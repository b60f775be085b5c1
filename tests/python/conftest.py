"""Fixtures shared by the Python reference tests: the isouq CLI and the data folder.

ctest sets ISOUQ_CLI (the isouq binary) and ISOUQ_DATA_DIR; run by hand as
`ISOUQ_CLI=build/houdini_style_nodes/isouq /usr/bin/python3 -m pytest tests/python`.
"""
import os
import subprocess
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def isouq_cli():
    """Path of the isouq binary; the test is skipped (with the reason) when it is missing."""
    cli = os.environ.get("ISOUQ_CLI", "")
    if not cli:
        pytest.skip("ISOUQ_CLI is not set (ctest sets it to the isouq binary)")
    if not (os.path.isfile(cli) and os.access(cli, os.X_OK)):
        pytest.skip(f"ISOUQ_CLI={cli} is not an executable file (build the 'isouq' target)")
    return cli


@pytest.fixture(scope="session")
def data_dir():
    """The shared test volumes (data/README.md); skipped when absent."""
    default = Path(__file__).resolve().parents[3] / "shared" / "data"
    path = Path(os.environ.get("ISOUQ_DATA_DIR", default))
    if not path.is_dir():
        pytest.skip(f"data folder {path} not found (set ISOUQ_DATA_DIR)")
    return path


@pytest.fixture(scope="session")
def isouq_mesh(isouq_cli, tmp_path_factory):
    """isouq_mesh(INPUT, *args) runs `isouq mesh INPUT -o OUT.ply *args --quiet` once per
    argument list and returns the PLY path."""
    folder = tmp_path_factory.mktemp("isouq_mesh")
    done = {}

    def run(source, *args):
        key = (str(source),) + tuple(str(a) for a in args)
        if key not in done:
            out = folder / f"mesh{len(done)}.ply"
            cmd = [isouq_cli, "mesh", str(source), "-o", str(out), *map(str, args), "--quiet"]
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
            assert proc.returncode == 0, f"{' '.join(cmd)} failed: {proc.stderr.strip()}"
            done[key] = out
        return done[key]

    return run
