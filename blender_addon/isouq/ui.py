# Sidebar (N panel, tab "isouq"): the pipeline run and the views C1..C7 of paper sec. 4.3.
# Plots are PNGs (plots.py) shown as previews in the panel and openable in an Image Editor.

import json
import os

import bpy
import bpy.utils.previews

from . import pipeline

_previews = None
_paths = {}


def show_png(key, path):
    """Shows the PNG at `path` as the panel's `key` plot (reloaded when it changes)."""
    _paths[key] = path
    if _previews is None:
        return
    if key in _previews:
        del _previews[key]
    _previews.load(key, path, "IMAGE", force_reload=True)
    image = bpy.data.images.get(f"ISOUQ_{key}")
    if image is not None:
        image.reload()


def plot_image(key):
    """The `key` plot as a bpy image ISOUQ_<key>, or None."""
    path = _paths.get(key)
    if not path or not os.path.isfile(path):
        return None
    image = bpy.data.images.get(f"ISOUQ_{key}")
    if image is None:
        image = bpy.data.images.load(path)
        image.name = f"ISOUQ_{key}"
    return image


def _draw_plot(layout, key, scale=10.0):
    if _previews is not None and key in _previews:
        layout.template_icon(icon_value=_previews[key].icon_id, scale=scale)
        layout.operator("isouq.open_plot", text="Open in Image Editor", icon="IMAGE").key = key


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "isouq"


class VIEW3D_PT_isouq_overlays(_Panel, bpy.types.Panel):
    bl_label = "isouq"

    def draw(self, context):
        obj = context.active_object
        col = self.layout.column()
        if obj is not None and obj.type == "MESH" and obj.isouq.role != "NONE":
            col.label(text=f"{obj.name}: {len(obj.data.vertices)} vertices", icon="MESH_DATA")
            if obj.isouq.method_shown:
                col.label(text=f"showing: {obj.isouq.method_shown}")
            if obj.isouq.sequence:
                _draw_sequence(col, obj)
        else:
            col.label(text="Select an isouq mesh", icon="INFO")
        row = col.row(align=True)
        row.operator("isouq.import_mesh", icon="IMPORT", text="Import")
        row.operator("isouq.import_sequence", icon="SEQUENCE", text="Sequence")
        col.prop(context.scene.isouq, "measure")


def _draw_sequence(col, obj):
    from . import props
    s = obj.isouq
    box = col.box()
    frame = s.sequence_frame
    box.label(text=f"sequence frame {frame}" if frame != props.NO_FRAME else
              "sequence: no frame here", icon="SEQUENCE")
    box.prop(s, "sequence_mode", text="Outside")
    box.prop(s, "sequence_offset")


class VIEW3D_PT_isouq_pipeline(_Panel, bpy.types.Panel):
    bl_label = "Run on a VDB"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        col.prop(s, "input_path")
        if pipeline.is_generated(s.input_path):
            col.prop(s, "resolution")
        col.prop(s, "volume")
        if s.volume is not None and s.volume.type == "VOLUME" and s.volume.data.is_sequence:
            col.prop(s, "whole_sequence")
            if s.whole_sequence:
                col.prop(s, "sequence_dir")
                row = col.row()
                row.prop(s, "resume")
                row.prop(s, "skip_missing")
        col.prop(s, "grid")
        row = col.row(align=True)
        row.prop(s, "use_isovalue", text="")
        sub = row.row()
        sub.enabled = s.use_isovalue
        sub.prop(s, "isovalue")
        col.prop(s, "method")
        col.prop(s, "hidden_features")
        if s.hidden_features:
            col.prop(s, "subdivisions")
        col.operator("isouq.run_pipeline", icon="PLAY")


class VIEW3D_PT_isouq_threshold(_Panel, bpy.types.Panel):
    bl_label = "C1 Distribution and Threshold"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        col.prop(s, "threshold_mode", expand=True)
        col.prop(s, "threshold_percentile" if s.threshold_mode == "PERCENTILE" else "threshold_value")
        row = col.row()
        row.prop(s, "colour_below")
        row.prop(s, "colour_above")
        col.operator("isouq.apply_threshold", icon="SORTSIZE")
        _draw_plot(col, "cdf")


class VIEW3D_PT_isouq_box(_Panel, bpy.types.Panel):
    bl_label = "C2 Box and C5 Bars"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        row = col.row(align=True)
        row.prop(s, "box", text="")
        row.operator("isouq.add_box", text="", icon="ADD")
        row = col.row(align=True)
        row.operator("isouq.select_box", icon="SELECT_SET")
        row.operator("isouq.plot_bars", icon="GRAPH")
        _draw_plot(col, "bars")


class VIEW3D_PT_isouq_methods(_Panel, bpy.types.Panel):
    bl_label = "C3 Methods"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        col.prop(s, "selection", expand=True)
        col.prop(s, "method_inside")
        col.prop(s, "method_outside")
        row = col.row(align=True)
        row.operator("isouq.apply_methods", icon="CHECKMARK")
        row.operator("isouq.reset_positions", text="", icon="LOOP_BACK")


class VIEW3D_PT_isouq_heatmap(_Panel, bpy.types.Panel):
    bl_label = "C4 Heat Map"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        row = col.row(align=True)
        row.prop(s, "heat_min")
        row.prop(s, "heat_max")
        obj = context.active_object
        if obj is not None and obj.type == "MESH" and obj.isouq.sequence:
            col.prop(s, "heat_range_scope", expand=True)
        col.operator("isouq.show_heatmap", icon="COLOR")
        _draw_plot(col, "legend", scale=3.0)


class VIEW3D_PT_isouq_compare(_Panel, bpy.types.Panel):
    bl_label = "C6 Compare"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        row = col.row(align=True)
        row.prop(s, "compare_method", text="")
        row.operator("isouq.compare_methods")
        col.operator("isouq.show_hidden", icon="MOD_OPACITY")
        col.operator("isouq.combined_view", icon="OVERLAY")


class VIEW3D_PT_isouq_summary(_Panel, bpy.types.Panel):
    bl_label = "C7 Summary"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        from . import views
        col = self.layout.column(align=True)
        try:
            rows = views.summary(context, views.isouq_object(context))
        except (views.ViewError, ValueError, json.JSONDecodeError) as e:
            col.label(text=str(e), icon="ERROR")
            return
        for label, value in rows:
            split = col.split(factor=0.45)
            split.label(text=str(label))
            split.label(text=str(value))
        col.operator("isouq.load_summary", icon="FILE")


class VIEW3D_PT_isouq_render(_Panel, bpy.types.Panel):
    bl_label = "Render"
    bl_parent_id = "VIEW3D_PT_isouq_overlays"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s, col = context.scene.isouq, self.layout.column()
        col.prop(s, "render_engine")
        col.prop(s, "render_size")
        col.prop(s, "render_path")
        col.prop(s, "render_exr")
        col.operator("isouq.render_view", icon="RENDER_STILL")


classes = (VIEW3D_PT_isouq_overlays, VIEW3D_PT_isouq_pipeline, VIEW3D_PT_isouq_threshold,
           VIEW3D_PT_isouq_box, VIEW3D_PT_isouq_methods, VIEW3D_PT_isouq_heatmap,
           VIEW3D_PT_isouq_compare, VIEW3D_PT_isouq_summary, VIEW3D_PT_isouq_render)


def register_previews():
    global _previews
    _previews = bpy.utils.previews.new()
    for key, path in _paths.items():
        if os.path.isfile(path):
            _previews.load(key, path, "IMAGE")


def unregister_previews():
    global _previews
    if _previews is not None:
        bpy.utils.previews.remove(_previews)
    _previews = None
