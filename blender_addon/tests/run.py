# Runs the add-on's pytest suite inside Blender:
#   blender -b --factory-startup --python-exit-code 1 -P blender_addon/tests/run.py [-- PYTEST ARGS]
# Puts the add-on on sys.path, enables it, runs pytest and exits non-zero on failure.

import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(HERE), HERE]
args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
code = pytest.main([HERE, "-p", "no:cacheprovider", "-ra"] + args)
if code != 0:
    raise SystemExit(f"add-on tests failed (pytest status {int(code)})")
