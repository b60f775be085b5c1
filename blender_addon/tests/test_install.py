# The one-command install (install.py) into a scratch user folder: linked, enabled and saved,
# so a new Blender has the add-on; --remove undoes it.

import os
import subprocess

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
INSTALL = os.path.join(HERE, "..", "install.py")
CHECK = "import addon_utils; print('ISOUQ_ENABLED', addon_utils.check('isouq')[1])"


def blender(env, *args):
    run = subprocess.run([bpy.app.binary_path, "-b", "--python-exit-code", "1", *args],
                         capture_output=True, text=True, timeout=300, env=env)
    assert run.returncode == 0, run.stdout[-1500:] + run.stderr[-1500:]
    return run.stdout


def test_install_links_enables_and_removes(tmp_path):
    env = dict(os.environ, HOME=str(tmp_path), BLENDER_USER_CONFIG=str(tmp_path / "config"),
               BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"))
    assert "linked" in blender(env, "-P", INSTALL)
    link = tmp_path / "scripts" / "addons" / "isouq"
    assert link.is_symlink()
    assert os.path.realpath(link) == os.path.realpath(os.path.join(HERE, "..", "isouq"))
    assert "ISOUQ_ENABLED True" in blender(env, "--python-expr", CHECK)
    assert "removed" in blender(env, "-P", INSTALL, "--", "--remove")
    assert not os.path.lexists(link)
    assert "ISOUQ_ENABLED False" in blender(env, "--python-expr", CHECK)
