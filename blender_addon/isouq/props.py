# Scene.isouq (the analysis views' settings, SPEC §7) and Object.isouq (what an object is).

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, PointerProperty, StringProperty)

MEASURES = [(m, m, f"Per-vertex {m} (SPEC §6)") for m in (
    "err_est", "err_bound", "d_lc", "d_lw", "d_cw", "max_var",
    "err_true_linear", "err_true_cubic", "err_true_weno")]
VIEW_METHODS = [("linear", "Linear", "Linear crossing (t_linear)"),
                ("cubic", "Cubic", "4-point Lagrange cubic crossing (t_cubic)"),
                ("weno", "WENO", "WENO crossing (t_weno)")]
RUN_METHODS = VIEW_METHODS + [("weno-paper", "WENO (paper)", "Paper's constant weights")]


def _update_threshold(self, context):
    from . import materials
    materials.set_threshold(self.threshold_value, self.colour_below, self.colour_above)


def _update_heat_range(self, context):
    from . import materials
    materials.set_heat_range(self.heat_min, self.heat_max)


class ISOUQ_SceneSettings(bpy.types.PropertyGroup):
    measure: EnumProperty(name="Measure", items=MEASURES, default="err_est")
    # C1 threshold
    threshold_mode: EnumProperty(name="Threshold by", items=[
        ("VALUE", "Value", "Threshold in world units"),
        ("PERCENTILE", "Percentile", "Threshold at a percentile of the measure")], default="VALUE")
    threshold_value: FloatProperty(name="Threshold", default=0.0, min=0.0, precision=6,
                                   update=_update_threshold)
    threshold_percentile: FloatProperty(name="Percentile", default=90.0, min=0.0, max=100.0,
                                        subtype="PERCENTAGE")
    colour_below: FloatVectorProperty(name="Below", subtype="COLOR", size=3, min=0, max=1,
                                      default=(0.2, 0.35, 0.8), update=_update_threshold)
    colour_above: FloatVectorProperty(name="Above", subtype="COLOR", size=3, min=0, max=1,
                                      default=(0.95, 0.3, 0.05), update=_update_threshold)
    # C2 box
    box: PointerProperty(name="Box", type=bpy.types.Object,
                         description="Cube or empty whose [-1, 1]^3 box selects vertices")
    # C3 methods
    selection: EnumProperty(name="Selection", items=[
        ("THRESHOLD", "Threshold", "Vertices whose measure is above the threshold"),
        ("BOX", "Box", "Vertices inside the box")], default="THRESHOLD")
    method_inside: EnumProperty(name="Inside", items=VIEW_METHODS, default="weno")
    method_outside: EnumProperty(name="Outside", items=VIEW_METHODS, default="linear")
    # C4 heat map
    heat_min: FloatProperty(name="Min", default=0.0, precision=6, update=_update_heat_range)
    heat_max: FloatProperty(name="Max", default=1.0, precision=6, update=_update_heat_range)
    # C6 comparison
    compare_method: EnumProperty(name="Compare with", items=VIEW_METHODS, default="linear")
    # pipeline
    input_path: StringProperty(name="Input", subtype="FILE_PATH",
                               description="A .vdb or .raw file, or field:NAME / formula:EXPR (SPEC §8)")
    resolution: IntProperty(name="Resolution", default=0, min=0, max=4096,
                            description="field:/formula: samples per axis (--resolution); 0: the CLI's")
    volume: PointerProperty(name="Volume", type=bpy.types.Object,
                            poll=lambda self, obj: obj.type == "VOLUME")
    use_isovalue: BoolProperty(name="Isovalue", default=False,
                               description="Pass --isovalue (else the CLI's default)")
    isovalue: FloatProperty(name="Isovalue", default=0.0, precision=6)
    method: EnumProperty(name="Method", items=RUN_METHODS, default="weno")
    hidden_features: BoolProperty(name="Hidden features", default=False)
    subdivisions: IntProperty(name="Subdivisions", default=4, min=2, max=16)
    grid: StringProperty(name="Grid", description="Grid name (--grid); empty: first float grid")
    # render
    render_engine: EnumProperty(name="Engine", items=[
        ("BLENDER_EEVEE", "Eevee", ""), ("CYCLES", "Cycles (CPU)", "")], default="BLENDER_EEVEE")
    render_path: StringProperty(name="Output", subtype="FILE_PATH", default="//isouq_view.png")
    render_exr: BoolProperty(name="Multilayer EXR with AOVs", default=False)
    render_size: IntProperty(name="Size", default=800, min=16, max=8192)


class ISOUQ_ObjectSettings(bpy.types.PropertyGroup):
    role: EnumProperty(name="Role", items=[
        ("NONE", "None", ""), ("MESH", "isouq mesh", "Standard MC mesh"),
        ("HIDDEN", "Hidden-feature mesh", "MC with hidden features"),
        ("COMPARE", "Comparison copy", "Another method's positions (C6)")], default="NONE")
    source: StringProperty(name="Source", subtype="FILE_PATH")
    summary: StringProperty(name="Summary JSON", description="The --summary JSON text")
    method_shown: StringProperty(name="Shown method", default="")
    partner: PointerProperty(name="Partner", type=bpy.types.Object,
                             description="The standard / hidden-feature mesh of the same run")


class ISOUQ_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    binary: StringProperty(
        name="isouq binary", subtype="FILE_PATH", default="",
        description="Path of the isouq command line; empty: $ISOUQ_CLI, else `isouq` on PATH, "
                    "else the repo's build*/houdini_style_nodes/isouq")

    def draw(self, context):
        self.layout.prop(self, "binary")


classes = (ISOUQ_SceneSettings, ISOUQ_ObjectSettings, ISOUQ_AddonPreferences)


def register_properties():
    bpy.types.Scene.isouq = PointerProperty(type=ISOUQ_SceneSettings)
    bpy.types.Object.isouq = PointerProperty(type=ISOUQ_ObjectSettings)


def unregister_properties():
    del bpy.types.Object.isouq
    del bpy.types.Scene.isouq
