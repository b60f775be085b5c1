# Registration: enabling and disabling the add-on twice (through addon_utils, as Preferences
# does, and through the module's own register/unregister) leaves nothing behind.

import addon_utils
import bpy

import isouq

NAMES = ("ISOUQ_OT_import_mesh", "ISOUQ_OT_run_pipeline", "VIEW3D_PT_isouq_overlays",
         "ISOUQ_OT_apply_methods")


def registered():
    return [hasattr(bpy.types, n) for n in NAMES] + [hasattr(bpy.types.Scene, "isouq"),
                                                     hasattr(bpy.types.Object, "isouq")]


def import_menu_entries():
    return [f for f in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
            if getattr(f, "__module__", "").startswith("isouq")]


def test_enable_disable_twice_with_addon_utils():
    for _ in range(2):
        addon_utils.disable("isouq", default_set=True)
        assert not any(registered())
        assert import_menu_entries() == []
        addon_utils.enable("isouq", default_set=True)
        assert all(registered())
        assert len(import_menu_entries()) == 1
        assert "isouq" in bpy.context.preferences.addons


def test_register_unregister_twice_directly():
    addon_utils.disable("isouq", default_set=True)
    try:
        for _ in range(2):
            isouq.register()
            assert all(registered())
            isouq.unregister()
            assert not any(registered())
    finally:
        addon_utils.enable("isouq", default_set=True)
    assert all(registered())


def test_operator_runs_after_reenable(sphere_ply):
    addon_utils.disable("isouq", default_set=True)
    addon_utils.enable("isouq", default_set=True)
    assert bpy.ops.isouq.import_mesh(filepath=sphere_ply[0]) == {"FINISHED"}
