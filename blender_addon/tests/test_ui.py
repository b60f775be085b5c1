# The sidebar panels draw without errors, and every property and operator they name exists
# (background Blender draws no UI, so a recording layout stands in for it).

import bpy
import pytest

from isouq import ui


class RecordingLayout:
    """Accepts the UILayout calls the panels make and checks what they name."""

    def __init__(self, log):
        self.log = log
        self.enabled = True

    def _child(self, *args, **kwargs):
        return RecordingLayout(self.log)

    column = row = split = box = _child

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property {name}"
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        module, name = idname.split(".")
        assert hasattr(bpy.types, f"{module.upper()}_OT_{name}"), idname
        self.log.append(("operator", idname))
        return type("OperatorProperties", (), {})()

    def label(self, text="", **kwargs):
        self.log.append(("label", text))

    def template_icon(self, icon_value=0, scale=1.0):
        # background Blender creates no icons (icon_id 0); the UI assigns one when drawn
        self.log.append(("icon", icon_value))


def draw_all(context):
    log = []
    for cls in ui.classes:
        cls.draw(type("PanelStub", (), {"layout": RecordingLayout(log)})(), context)
    return log


def test_panels_draw_without_a_mesh():
    log = draw_all(bpy.context)
    assert ("operator", "isouq.import_mesh") in log
    assert ("label", "Select an isouq mesh") in log


def test_panels_draw_with_a_mesh_and_plots(sphere_ply):
    bpy.ops.isouq.import_mesh(filepath=sphere_ply[0])
    bpy.ops.isouq.apply_threshold()
    bpy.context.scene.isouq.hidden_features = True
    log = draw_all(bpy.context)
    assert ("prop", "subdivisions") in log
    assert any(kind == "icon" for kind, _ in log)                 # the CDF preview
    assert "cdf" in ui._previews
    assert ("operator", "isouq.open_plot") in log
    assert any(kind == "label" and text == "vertices" for kind, text in log)   # C7 rows


def test_panels_draw_a_sequence_and_a_volume_sequence(sphere_ply, tmp_path):
    import shutil
    for k in (1, 2):
        shutil.copy(sphere_ply[0], tmp_path / f"s.{k:04d}.ply")
    assert bpy.ops.isouq.import_sequence(filepath=str(tmp_path / "s.0001.ply")) == {"FINISHED"}
    vol = bpy.data.volumes.new("v")
    vol.is_sequence = True
    volume = bpy.data.objects.new("v", vol)
    bpy.context.collection.objects.link(volume)
    bpy.context.scene.isouq.volume = volume
    log = draw_all(bpy.context)
    assert ("operator", "isouq.import_sequence") in log
    assert ("label", "sequence frame 1") in log
    for name in ("sequence_mode", "sequence_offset", "heat_range_scope", "whole_sequence",
                 "sequence_dir", "resume", "skip_missing"):
        assert ("prop", name) in log, name
