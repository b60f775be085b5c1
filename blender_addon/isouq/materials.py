# Get-or-create ISOUQ_ materials for the views of paper sec. 4.3 (SPEC §7): a heat map of a
# measure (C4), a binary map above/below a threshold (C1), opaque blue / transparent orange for
# standard MC under hidden features (C6), and one combined view of heat map and hidden features.
# Every tree reads mesh attributes with ShaderNodeAttribute, so it follows C3 and re-imports.

import bpy

HEAT_COLORMAP = "plasma"        # matplotlib name; the legend uses the same one
STANDARD_BLUE = (0.05, 0.25, 0.85, 1.0)
HIDDEN_ORANGE = (1.0, 0.45, 0.0, 1.0)
HIDDEN_ALPHA = 0.5
# combined view: refined faces in a green that the heat map's plasma never reaches (its top
# is orange-yellow, which would read as a large error)
REFINED_GREEN = (0.02, 0.45, 0.12, 1.0)


def _srgb_to_linear(c):
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def colormap_stops(name=HEAT_COLORMAP, count=9):
    """(position, linear RGBA) samples of a matplotlib colormap for a ColorRamp."""
    import matplotlib
    cmap = matplotlib.colormaps[name]
    stops = []
    for i in range(count):
        x = i / (count - 1)
        r, g, b, _ = cmap(x)
        stops.append((x, (_srgb_to_linear(r), _srgb_to_linear(g), _srgb_to_linear(b), 1.0)))
    return stops


def _fresh(name):
    """The material `name`, emptied, so rebuilding it is idempotent."""
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.use_nodes = True
    mat.node_tree.nodes.clear()
    return mat, mat.node_tree.nodes, mat.node_tree.links


def _surface(nodes, links, colour_socket, emission=0.25):
    """Principled surface whose base and emission colour come from `colour_socket`: shaded
    for shape, bright enough that colours read as the legend's."""
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Roughness"].default_value = 0.6
    bsdf.inputs["Specular"].default_value = 0.2
    bsdf.inputs["Emission Strength"].default_value = emission
    links.new(colour_socket, bsdf.inputs["Base Color"])
    links.new(colour_socket, bsdf.inputs["Emission"])
    out = nodes.new("ShaderNodeOutputMaterial")
    links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return bsdf, out


def _attribute(nodes, name, label):
    node = nodes.new("ShaderNodeAttribute")
    node.attribute_type = "GEOMETRY"
    node.attribute_name = name
    node.name = node.label = label
    return node


def _aov(nodes, links, socket, name):
    aov = nodes.new("ShaderNodeOutputAOV")
    aov.name = name            # Blender 3.4: the AOV output's node name is the AOV's name
    aov.label = f"AOV {name}"
    links.new(socket, aov.inputs["Value"])


def _heat_colour(nodes, links, measure, vmin, vmax):
    """Attribute -> Map Range [vmin, vmax] -> ColorRamp; returns (colour socket, value socket)."""
    attr = _attribute(nodes, measure, "Measure")
    rng = nodes.new("ShaderNodeMapRange")
    rng.name = rng.label = "Range"
    rng.clamp = True
    rng.inputs["From Min"].default_value = vmin
    rng.inputs["From Max"].default_value = vmax if vmax > vmin else vmin + 1e-12
    links.new(attr.outputs["Fac"], rng.inputs["Value"])
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.name = ramp.label = "Colormap"
    elements = ramp.color_ramp.elements
    stops = colormap_stops()
    while len(elements) < len(stops):
        elements.new(0.5)
    for element, (pos, rgba) in zip(elements, stops):
        element.position, element.color = pos, rgba
    links.new(rng.outputs["Result"], ramp.inputs["Fac"])
    return ramp.outputs["Color"], attr.outputs["Fac"]


def heatmap_material(measure, vmin=0.0, vmax=1.0):
    """C4: `measure` through the colormap; AOV `measure` carries the raw value."""
    mat, nodes, links = _fresh("ISOUQ_heatmap")
    colour, value = _heat_colour(nodes, links, measure, vmin, vmax)
    _surface(nodes, links, colour)
    _aov(nodes, links, value, measure)
    _aov(nodes, links, _hidden_mask(nodes, links), "hidden")
    return mat


def set_heat_range(vmin, vmax):
    for name in ("ISOUQ_heatmap", "ISOUQ_combined"):
        mat = bpy.data.materials.get(name)
        if mat and mat.node_tree and "Range" in mat.node_tree.nodes:
            rng = mat.node_tree.nodes["Range"]
            rng.inputs["From Min"].default_value = vmin
            rng.inputs["From Max"].default_value = vmax if vmax > vmin else vmin + 1e-12


def threshold_material(measure, threshold, below, above):
    """C1: binary colour map, `above` where measure > threshold (analysis.above)."""
    mat, nodes, links = _fresh("ISOUQ_threshold")
    attr = _attribute(nodes, measure, "Measure")
    cmp = nodes.new("ShaderNodeMath")
    cmp.operation = "GREATER_THAN"
    cmp.name = cmp.label = "Threshold"
    cmp.inputs[1].default_value = threshold
    links.new(attr.outputs["Fac"], cmp.inputs[0])
    mix = nodes.new("ShaderNodeMixRGB")
    mix.name = mix.label = "Above"
    mix.inputs["Color1"].default_value = tuple(below) + (1.0,)
    mix.inputs["Color2"].default_value = tuple(above) + (1.0,)
    links.new(cmp.outputs["Value"], mix.inputs["Fac"])
    _surface(nodes, links, mix.outputs["Color"])
    _aov(nodes, links, attr.outputs["Fac"], measure)
    return mat


def set_threshold(threshold, below=None, above=None):
    mat = bpy.data.materials.get("ISOUQ_threshold")
    if not (mat and mat.node_tree and "Threshold" in mat.node_tree.nodes):
        return
    mat.node_tree.nodes["Threshold"].inputs[1].default_value = threshold
    mix = mat.node_tree.nodes["Above"]
    if below is not None:
        mix.inputs["Color1"].default_value = tuple(below) + (1.0,)
    if above is not None:
        mix.inputs["Color2"].default_value = tuple(above) + (1.0,)


def solid_material(name, rgba, alpha=1.0):
    """Opaque (alpha 1) or alpha-blended flat colour: ISOUQ_standard, ISOUQ_hidden."""
    mat, nodes, links = _fresh(name)
    rgb = nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = rgba
    bsdf, _ = _surface(nodes, links, rgb.outputs[0], emission=0.2)
    bsdf.inputs["Alpha"].default_value = alpha
    mat.blend_method = "OPAQUE" if alpha >= 1.0 else "BLEND"
    mat.shadow_method = "OPAQUE" if alpha >= 1.0 else "NONE"
    mat.use_backface_culling = False
    mat.show_transparent_back = False
    mat.diffuse_color = rgba[:3] + (alpha,)
    return mat


def standard_material():
    return solid_material("ISOUQ_standard", STANDARD_BLUE)


def hidden_material():
    return solid_material("ISOUQ_hidden", HIDDEN_ORANGE, HIDDEN_ALPHA)


def _hidden_mask(nodes, links):
    """1 on refined faces: the face attribute `hidden_face` (or a vertex `hidden` if the file
    has no face flags; a missing attribute reads 0)."""
    face = _attribute(nodes, "hidden_face", "Hidden face")
    vertex = _attribute(nodes, "hidden", "Hidden vertex")
    both = nodes.new("ShaderNodeMath")
    both.operation = "MAXIMUM"
    both.name = both.label = "Hidden"
    links.new(face.outputs["Fac"], both.inputs[0])
    links.new(vertex.outputs["Fac"], both.inputs[1])
    return both.outputs["Value"]


def combined_material(measure, vmin=0.0, vmax=1.0):
    """Heat map of `measure`, green where the face comes from hidden-feature refinement."""
    mat, nodes, links = _fresh("ISOUQ_combined")
    colour, value = _heat_colour(nodes, links, measure, vmin, vmax)
    hidden = _hidden_mask(nodes, links)
    mix = nodes.new("ShaderNodeMixRGB")
    mix.name = mix.label = "Hidden mix"
    mix.inputs["Color2"].default_value = REFINED_GREEN
    links.new(hidden, mix.inputs["Fac"])
    links.new(colour, mix.inputs["Color1"])
    _surface(nodes, links, mix.outputs["Color"])
    _aov(nodes, links, value, measure)
    _aov(nodes, links, hidden, "hidden")
    return mat


def assign(obj, mat):
    """Makes `mat` the object's only material."""
    obj.data.materials.clear()
    obj.data.materials.append(mat)


def ensure_aovs(view_layer, names):
    """Registers shader AOV passes (VALUE) so multilayer EXR renders carry them."""
    existing = {a.name for a in view_layer.aovs}
    for name in names:
        if name not in existing:
            aov = view_layer.aovs.add()
            aov.name, aov.type = name, "VALUE"
