"""`import _isouq_path` makes `import ply_io` (the one isouq PLY reader) work in isouq's scripts.

Installed, ply_io.py sits beside this file (PREFIX/share/isouq); in the source tree it is the
add-on's blender_addon/isouq/ply_io.py (numpy only, no bpy).
"""
import os
import sys

_HERE = os.path.dirname(os.path.realpath(__file__))

for _folder in (_HERE, os.path.join(os.path.dirname(_HERE), "blender_addon", "isouq")):
    if os.path.isfile(os.path.join(_folder, "ply_io.py")):
        if _folder not in sys.path:
            sys.path.insert(0, _folder)
        break
else:
    raise ImportError(f"ply_io.py is neither in {_HERE} nor in ../blender_addon/isouq")
