# Scene.isouq (the analysis views' settings, SPEC §7) and Object.isouq (what an object is).
#
# The measure and method menus list the vocabulary of `isouq nodes --json` (its `columns` and
# `methods` tables) from the binary that pipeline.find_binary() finds. Without one (or with one
# too old to print them) they list what the scene's isouq meshes' own columns tell
# (pipeline.mesh_vocabulary). Enum numbers are a hash of the token, so a saved choice keeps its
# meaning whichever list is shown; the defaults are the only tokens spelled here.

import json
import zlib

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, PointerProperty, StringProperty)

from . import pipeline


def vocabulary(context=None, columns=None):
    """The binary's vocabulary (pipeline.vocabulary), else that of `columns` (name -> numpy
    type string), by default the vertex columns of the scene's isouq meshes."""
    context = context or bpy.context
    addon = context.preferences.addons.get(__package__)
    binary, _ = pipeline.find_binary(addon.preferences.binary if addon else "")
    found = pipeline.vocabulary(binary)
    if found is not None:
        return found
    return pipeline.mesh_vocabulary(_scene_columns(context) if columns is None else columns)


def _scene_columns(context):
    """name -> PLY type of the vertex columns of the scene's isouq meshes (attributes.py keeps
    the types in mesh["isouq_ply_types"])."""
    columns = {}
    for obj in getattr(getattr(context, "scene", None), "objects", ()):
        if obj.type != "MESH" or obj.isouq.role == "NONE":
            continue
        for name, ply in json.loads(obj.data.get("isouq_ply_types", "{}")).items():
            attr = obj.data.attributes.get(name)
            if attr is not None and attr.domain == "POINT":
                columns.setdefault(name, ply["dtype"])
    return columns


def number(token):
    """The enum number of `token`: the same in every list that holds it."""
    return zlib.crc32(token.encode()) & 0x7FFFFFFF


_items = {}   # Blender keeps pointers into the items' strings: every list stays alive here


def _enum(entries):
    key = tuple(entries)
    return _items.setdefault(key, list(key))


def measure_items(self, context):
    v = vocabulary(context)
    return _enum((name, name, v.description(name), number(name)) for name in v.measures())


def method_items(self, context):
    v = vocabulary(context)
    return _enum((m["token"], m["label"], v.description(m["column"]), number(m["token"]))
                 for m in v.methods)


def _update_threshold(self, context):
    from . import materials
    materials.set_threshold(self.threshold_value, self.colour_below, self.colour_above)


def _update_heat_range(self, context):
    from . import materials
    materials.set_heat_range(self.heat_min, self.heat_max)


SEQUENCE_MODES = [
    ("CLIP", "Clip", "Before the first and after the last frame the mesh is empty"),
    ("EXTEND", "Extend", "Before the first and after the last frame hold the nearest one"),
    ("REPEAT", "Repeat", "Loop the sequence"),
    ("PING_PONG", "Ping-Pong", "Loop the sequence forward and back")]
NO_FRAME = -(2 ** 31) + 1       # Object.isouq.sequence_frame when the mesh shows no frame


def _update_sequence(self, context):
    from . import sequence
    obj = self.id_data
    if isinstance(obj, bpy.types.Object) and self.sequence:
        sequence.update_object(context.scene, obj, force=True)


def _update_pattern(self, context):
    """A new pattern (or the same one again): its frames are looked up on disk again."""
    from . import sequence
    obj = self.id_data
    if isinstance(obj, bpy.types.Object) and self.sequence:
        sequence.rescan(obj)
        sequence.update_object(context.scene, obj, force=True)


class ISOUQ_SceneSettings(bpy.types.PropertyGroup):
    measure: EnumProperty(name="Measure", items=measure_items, default=number("err_est"))
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
    method_inside: EnumProperty(name="Inside", items=method_items, default=number("weno"))
    method_outside: EnumProperty(name="Outside", items=method_items, default=number("linear"))
    # C4 heat map
    heat_min: FloatProperty(name="Min", default=0.0, precision=6, update=_update_heat_range)
    heat_max: FloatProperty(name="Max", default=1.0, precision=6, update=_update_heat_range)
    heat_range_scope: EnumProperty(name="Range over", items=[
        ("SEQUENCE", "Sequence", "Heat Map takes the range over every frame of a sequence, so "
                                 "frames are comparable"),
        ("FRAME", "Frame", "Heat Map takes the range of the frame shown")], default="SEQUENCE")
    # C6 comparison
    compare_method: EnumProperty(name="Compare with", items=method_items,
                                 default=number("linear"))
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
    method: EnumProperty(name="Method", items=method_items, default=number("weno"))
    hidden_features: BoolProperty(name="Hidden features", default=False)
    subdivisions: IntProperty(name="Subdivisions", default=4, min=2, max=16)
    grid: StringProperty(name="Grid", description="Grid name (--grid); empty: first float grid")
    whole_sequence: BoolProperty(
        name="Whole sequence", default=True,
        description="A Volume that is a sequence: mesh every frame and import the mesh "
                    "sequence (else the current frame only)")
    sequence_dir: StringProperty(
        name="Sequence folder", subtype="DIR_PATH", default="//isouq_sequences/",
        description="Where the frames of a Volume sequence are written (NAME.####.ply and "
                    "NAME.json); '//' is the .blend's folder (unsaved: the temporary folder)")
    resume: BoolProperty(name="Resume", default=False,
                         description="Keep frames already written in the sequence folder "
                                     "(--resume)")
    skip_missing: BoolProperty(name="Skip missing", default=False,
                               description="Mesh the frames that exist when some of the "
                                           "range are missing (--skip-missing)")
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
    # a mesh sequence (sequence.py): the mesh follows the scene frame
    sequence: StringProperty(name="Sequence", subtype="FILE_PATH", update=_update_pattern,
                             description="The frames' files, '#' for the frame number; "
                                         "empty: not a sequence. Setting it (again) looks the "
                                         "frames up on disk")
    sequence_offset: IntProperty(name="Frame offset", default=0, update=_update_sequence,
                                 description="File frame = scene frame + offset")
    sequence_mode: EnumProperty(name="Outside the frames", items=SEQUENCE_MODES,
                                default="EXTEND", update=_update_sequence)
    sequence_summary: StringProperty(name="Sequence summary", subtype="FILE_PATH",
                                     description="The sequence summary JSON (per-frame C7)")
    sequence_frame: IntProperty(name="File frame", default=NO_FRAME,
                                description="The file frame the mesh holds")


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
