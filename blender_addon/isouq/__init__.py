# isouq for Blender: import isouq meshes with every attribute (SPEC §6), run the isouq pipeline on
# a VDB, and show where the surface can be trusted (paper sec. 4.3, SPEC §7 C1..C7).

bl_info = {
    "name": "isouq: isosurface uncertainty",
    "author": "isouq developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "File > Import > isouq mesh (.ply), isouq mesh sequence; View3D > Sidebar > isouq",
    "description": "Isosurfaces from VDB volumes with per-vertex error estimates",
    "category": "Import-Export",
}

if "bpy" in locals():
    import importlib
    for _module in (ply_io, frames, analysis, plots, pipeline, attributes, materials, props,
                    views, sequence, render, ui, operators):
        importlib.reload(_module)
else:
    from . import (ply_io, frames, analysis, plots, pipeline, attributes, materials, props,
                   views, sequence, render, ui, operators)

import bpy

classes = props.classes + operators.classes + ui.classes


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    props.register_properties()
    ui.register_previews()
    sequence.register_handlers()
    bpy.types.TOPBAR_MT_file_import.append(operators.menu_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(operators.menu_import)
    sequence.unregister_handlers()
    ui.unregister_previews()
    props.unregister_properties()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
