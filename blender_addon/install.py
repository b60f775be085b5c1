# One-command install of the add-on into this Blender's user add-ons, enabled and saved:
#
#   blender -b -P blender_addon/install.py [-- --copy | --remove]
#
# Default: a symlink to this checkout's blender_addon/isouq (updates with `git pull`);
# --copy installs a frozen copy; --remove disables the add-on and deletes the link or copy.
# The user add-ons folder comes from Blender itself (bpy.utils.user_resource), so any version
# and $BLENDER_USER_SCRIPTS work.

import os
import shutil
import sys

import bpy

SOURCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "isouq")
args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
target = os.path.join(bpy.utils.user_resource("SCRIPTS", path="addons", create=True), "isouq")

if os.path.islink(target):
    os.remove(target)
elif os.path.isdir(target):
    if os.path.realpath(target) == os.path.realpath(SOURCE):
        raise SystemExit(f"isouq install: error: {target} is the source itself")
    shutil.rmtree(target)
if "--remove" in args:
    bpy.ops.preferences.addon_disable(module="isouq")
    print(f"isouq install: removed {target}")
else:
    if "--copy" in args:
        shutil.copytree(SOURCE, target, ignore=shutil.ignore_patterns("__pycache__"))
    else:
        os.symlink(SOURCE, target)
    bpy.utils.refresh_script_paths()              # a just-created folder joins sys.path
    bpy.ops.preferences.addon_refresh()
    bpy.ops.preferences.addon_enable(module="isouq")
    print(f"isouq install: {'copied' if '--copy' in args else 'linked'} {SOURCE} -> {target}")
bpy.ops.wm.save_userpref()
