# Shared fixtures: the add-on enabled once per session, an empty scene per test, fixture PLYs.
# Without a real isouq binary the fake CLI stands in as $ISOUQ_CLI, so the add-on's menus always
# list a binary's vocabulary (test_real_cli keeps the fake's tables equal to the real ones).

import os

import addon_utils
import bpy
import pytest

import plyfixture
from isouq import pipeline

ADDON = "isouq"
FAKE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fake_isouq.py")
REAL_CLI, REAL_CLI_TRIED = pipeline.find_binary("")
if REAL_CLI is None or os.path.samefile(REAL_CLI, FAKE):
    REAL_CLI = None
    os.environ[pipeline.ENV_BINARY] = FAKE
# The suites written for the CLI (fake and real) run it as a subprocess; test_native_live.py
# turns the in-process module (native.py) back on.
os.environ["ISOUQ_NATIVE"] = "0"


def enable():
    addon_utils.enable(ADDON, default_set=True, handle_error=lambda e: (_ for _ in ()).throw(e))
    assert hasattr(bpy.types.Scene, "isouq")


@pytest.fixture(scope="session", autouse=True)
def addon():
    enable()
    yield
    addon_utils.disable(ADDON, default_set=True)


@pytest.fixture(autouse=True)
def empty_scene(addon):
    """Resets the homefile to an empty scene (the add-on stays enabled)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    if not hasattr(bpy.types.Scene, "isouq"):
        enable()
    yield bpy.context


@pytest.fixture(scope="session")
def sphere_ply(tmp_path_factory):
    """(path, (positions, faces, attrs, face_attrs, comments)) of a bumpy sphere fixture."""
    path = str(tmp_path_factory.mktemp("ply") / "sphere.ply")
    return path, plyfixture.write_sphere(path, n=16, radius=5.5, bump=1.5)


def scene_delta(before):
    """Objects and meshes created since `before` = (objects, meshes) name sets."""
    return (set(bpy.data.objects.keys()) - before[0], set(bpy.data.meshes.keys()) - before[1])


def snapshot():
    return set(bpy.data.objects.keys()), set(bpy.data.meshes.keys())


def make_box(location, rotation, scale):
    """The C2 selection box: an empty cube at @location, rotated (Euler) and scaled."""
    from mathutils import Euler
    box = bpy.data.objects.new("box", None)
    box.empty_display_type = "CUBE"
    box.location, box.rotation_euler, box.scale = location, Euler(rotation), scale
    bpy.context.collection.objects.link(box)
    bpy.context.scene.isouq.box = box
    bpy.context.view_layer.update()
    return box
