"""Shader node trees for the two modalities.

RGB surfaces are Principled BSDFs with a procedural texture. Thermal surfaces are pure
emitters whose strength is the in-band radiance leaving them, `eps*L(T) + (1-eps)*L(T_sky)`,
precomputed by the generator as a curve over the texture factor (the texture also
modulates temperature). Cycles then adds nothing but geometry, occlusion and smoke
transmittance, so a thermal pixel is radiance in W m^-2 sr^-1.
"""
from __future__ import annotations

from typing import Any, Sequence

import bpy

from blender.job import MaterialJob, RgbSmokeJob, TextureJob, ThermalSmokeJob


def _tree(name: str) -> tuple[bpy.types.Material, bpy.types.NodeTree]:
    mat = bpy.data.materials.new(name)
    mat.use_fake_user = True  # unassigned between renders, yet must survive a save for resume
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    return mat, tree


#: Textures that read only the x and y of their vector: on a face whose normal lies in the
#: xy plane those coordinates degenerate to a line, and the pattern turns into stripes.
PLANAR_TEXTURES = ("brick",)


def _math(tree: bpy.types.NodeTree, operation: str, a: Any, b: Any) -> bpy.types.NodeSocket:
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = operation
    for socket, value in zip(node.inputs, (a, b)):
        if isinstance(value, float):
            socket.default_value = value
        else:
            tree.links.new(value, socket)
    return node.outputs["Value"]


def _box_coordinates(tree: bpy.types.NodeTree, coords: bpy.types.Node) -> bpy.types.NodeSocket:
    """Box (per-face planar) mapping in object space: a face takes the two object axes
    across it, (y, z), (x, z) or (x, y), chosen by the largest component of its normal, so
    2D patterns lie flat on every face and brick courses stay horizontal on vertical faces."""
    position = tree.nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(coords.outputs["Object"], position.inputs["Vector"])
    normal = tree.nodes.new("ShaderNodeVectorMath")
    normal.operation = "ABSOLUTE"
    tree.links.new(coords.outputs["Normal"], normal.inputs[0])
    n = tree.nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(normal.outputs["Vector"], n.inputs["Vector"])
    nx, ny, nz = n.outputs["X"], n.outputs["Y"], n.outputs["Z"]
    x_major = _math(tree, "MULTIPLY", _math(tree, "GREATER_THAN", nx, ny), _math(tree, "GREATER_THAN", nx, nz))
    y_major = _math(tree, "MULTIPLY", _math(tree, "SUBTRACT", 1.0, x_major), _math(tree, "GREATER_THAN", ny, nz))
    z_major = _math(tree, "SUBTRACT", _math(tree, "SUBTRACT", 1.0, x_major), y_major)
    px, py, pz = position.outputs["X"], position.outputs["Y"], position.outputs["Z"]
    u = _math(tree, "ADD", _math(tree, "MULTIPLY", x_major, py),
              _math(tree, "MULTIPLY", _math(tree, "SUBTRACT", 1.0, x_major), px))
    v = _math(tree, "ADD", _math(tree, "MULTIPLY", z_major, py),
              _math(tree, "MULTIPLY", _math(tree, "SUBTRACT", 1.0, z_major), pz))
    combine = tree.nodes.new("ShaderNodeCombineXYZ")
    tree.links.new(u, combine.inputs["X"])
    tree.links.new(v, combine.inputs["Y"])
    return combine.outputs["Vector"]


def _texture(tree: bpy.types.NodeTree, tex: TextureJob) -> bpy.types.Node | None:
    """The texture node driven by object coordinates (box-mapped for 2D textures), or None
    for a plain material."""
    kind = tex.kind
    if kind == "none":
        return None
    coords = tree.nodes.new("ShaderNodeTexCoord")
    node = tree.nodes.new({
        "noise": "ShaderNodeTexNoise", "checker": "ShaderNodeTexChecker", "brick": "ShaderNodeTexBrick",
        "wave": "ShaderNodeTexWave", "voronoi": "ShaderNodeTexVoronoi", "magic": "ShaderNodeTexMagic",
    }[kind])
    vector = _box_coordinates(tree, coords) if kind in PLANAR_TEXTURES else coords.outputs["Object"]
    tree.links.new(vector, node.inputs["Vector"])
    node.inputs["Scale"].default_value = tex.scale
    if "Detail" in node.inputs:
        node.inputs["Detail"].default_value = tex.detail
    return node


def _factor(node: bpy.types.Node) -> bpy.types.NodeSocket:
    """The texture's scalar output: mortar mask for bricks, Fac or Distance otherwise."""
    for name in ("Fac", "Distance"):
        if name in node.outputs:
            return node.outputs[name]
    raise KeyError(f"texture node {node.bl_idname} has no scalar output")


def _curve(tree: bpy.types.NodeTree, points: Sequence[Sequence[float]], source: bpy.types.NodeSocket,
           ) -> bpy.types.NodeSocket:
    """A piecewise-linear lookup y(x) on x in [0,1] (the radiance tabulation), scaled back up."""
    ys = [p[1] for p in points]
    scale = max(max(ys), 1e-30)
    node = tree.nodes.new("ShaderNodeFloatCurve")
    mapping = node.mapping
    mapping.use_clip = False
    curve = mapping.curves[0]
    while len(curve.points) > 2:
        curve.points.remove(curve.points[-1])
    curve.points[0].location = (points[0][0], points[0][1] / scale)
    curve.points[1].location = (points[-1][0], points[-1][1] / scale)
    for x, y in points[1:-1]:
        curve.points.new(x, y / scale)
    for pt in curve.points:
        pt.handle_type = "VECTOR"
    mapping.update()
    tree.links.new(source, node.inputs["Value"])
    node.inputs["Factor"].default_value = 1.0
    mul = tree.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    tree.links.new(node.outputs["Value"], mul.inputs[0])
    mul.inputs[1].default_value = scale
    return mul.outputs["Value"]


def rgb_surface(spec: MaterialJob) -> bpy.types.Material:
    mat, tree = _tree(f"{spec.name}.rgb")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Roughness"].default_value = spec.roughness
    bsdf.inputs["Metallic"].default_value = spec.metallic
    base = (*spec.base_color, 1.0)
    tex_spec = spec.texture
    tex = _texture(tree, tex_spec)
    if tex is None:
        bsdf.inputs["Base Color"].default_value = base
    elif tex_spec.kind == "brick":
        tex.inputs["Color1"].default_value = base
        tex.inputs["Color2"].default_value = (*tex_spec.color2, 1.0)
        tex.inputs["Mortar"].default_value = (*tex_spec.mortar_color, 1.0)
        tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        mix = tree.nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        tree.links.new(_factor(tex), mix.inputs["Factor"])
        mix.inputs["A"].default_value = base
        mix.inputs["B"].default_value = (*tex_spec.color2, 1.0)
        tree.links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def thermal_surface(spec: MaterialJob) -> bpy.types.Material:
    """Emission = tabulated radiance over the texture factor (constant without a texture)."""
    mat, tree = _tree(f"{spec.name}.thermal")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    points = spec.thermal_curve
    tex = _texture(tree, spec.texture)
    if tex is None or len(points) == 1:
        emission.inputs["Strength"].default_value = points[0][1]
    else:
        tree.links.new(_curve(tree, points, _factor(tex)), emission.inputs["Strength"])
    tree.links.new(emission.outputs["Emission"], out.inputs["Surface"])
    return mat


SMOKE_WEIGHT = "smoke_weight"  # object property: this domain's share of the interpolated smoke state


def _multiply(tree: bpy.types.NodeTree, a: bpy.types.NodeSocket, b: bpy.types.NodeSocket | float,
              ) -> bpy.types.NodeSocket:
    mul = tree.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    tree.links.new(a, mul.inputs[0])
    if isinstance(b, float):
        mul.inputs[1].default_value = b
    else:
        tree.links.new(b, mul.inputs[1])
    return mul.outputs["Value"]


def _domain_weight(tree: bpy.types.NodeTree) -> bpy.types.NodeSocket:
    """The domain object's interpolation weight: two domains showing consecutive baked frames,
    weighted (1-w) and w, sum to the linearly interpolated coefficients (volumes add in Cycles)."""
    attr = tree.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "OBJECT"
    attr.attribute_name = SMOKE_WEIGHT
    return attr.outputs["Fac"]


def _density(tree: bpy.types.NodeTree, per_unit: float) -> bpy.types.NodeSocket:
    attr = tree.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "density"
    return _multiply(tree, _multiply(tree, attr.outputs["Fac"], float(per_unit)), _domain_weight(tree))


def _add(tree: bpy.types.NodeTree, a: bpy.types.NodeSocket, b: bpy.types.NodeSocket) -> bpy.types.NodeSocket:
    node = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(a, node.inputs[0])
    tree.links.new(b, node.inputs[1])
    return node.outputs["Shader"]


def _fire_glow(tree: bpy.types.NodeTree, table: Sequence[Sequence[float]]) -> bpy.types.NodeSocket:
    """Blackbody glow: per-channel emission tabulated over the flame grid by the generator
    (colour and relative luminance of T(flame)), scaled by the domain's interpolation weight."""
    flame = tree.nodes.new("ShaderNodeAttribute")
    flame.attribute_name = "flame"
    combine = tree.nodes.new("ShaderNodeCombineColor")
    weight = _domain_weight(tree)
    for channel, socket in enumerate(("Red", "Green", "Blue"), start=1):
        column = _curve(tree, [[row[0], row[channel]] for row in table], flame.outputs["Fac"])
        tree.links.new(_multiply(tree, column, weight), combine.inputs[socket])
    glow = tree.nodes.new("ShaderNodeEmission")
    glow.inputs["Strength"].default_value = 1.0
    tree.links.new(combine.outputs["Color"], glow.inputs["Color"])
    return glow.outputs["Emission"]


def rgb_smoke(spec: RgbSmokeJob) -> bpy.types.Material:
    """Mie-derived per-channel scattering and absorption, Henyey-Greenstein with Mie's g.

    Volume Scatter's coefficient is colour*density and Volume Absorption's is
    (1-colour)*density, so the two colours encode the per-channel coefficients exactly.
    """
    mat, tree = _tree("smoke.rgb")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    scatter = tree.nodes.new("ShaderNodeVolumeScatter")
    scatter.inputs["Color"].default_value = (*spec.scatter_color, 1.0)
    scatter.inputs["Anisotropy"].default_value = spec.anisotropy
    tree.links.new(_density(tree, spec.scatter_density), scatter.inputs["Density"])
    absorb = tree.nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (*spec.absorb_color, 1.0)
    tree.links.new(_density(tree, spec.absorb_density), absorb.inputs["Density"])
    shader = _add(tree, scatter.outputs["Volume"], absorb.outputs["Volume"])
    if spec.fire is not None:
        shader = _add(tree, shader, _fire_glow(tree, spec.fire.glow_table))
    tree.links.new(shader, out.inputs["Volume"])
    return mat


def rgb_smoke_extinction(spec: RgbSmokeJob) -> bpy.types.Material:
    """The RGB smoke's per-channel extinction (scattering plus absorption) as pure absorption,
    for the smoke opacity pass. Cycles ends a camera sample that scatters, so through the
    scattering material each sample's transparency is all or nothing and a pixel's opacity is
    quantised in steps of 1/samples; through this one every sample carries the ray's exact
    transmittance, and the expected opacity is the same."""
    extinction = [spec.scatter_density * s + spec.absorb_density * (1.0 - a)
                  for s, a in zip(spec.scatter_color, spec.absorb_color)]
    top = max(extinction)
    mat, tree = _tree("smoke.rgb.extinction")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    absorb = tree.nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (*[1.0 - e / top if top > 0 else 1.0 for e in extinction], 1.0)
    tree.links.new(_density(tree, top), absorb.inputs["Density"])
    tree.links.new(absorb.outputs["Volume"], out.inputs["Volume"])
    return mat


def thermal_smoke(spec: ThermalSmokeJob) -> bpy.types.Material:
    """LWIR: absorption with the Mie extinction and Kirchhoff emission sigma_a * L_band(T).

    With fire, T comes from the flame grid through the generator's radiance tabulation;
    without fire the smoke is at the ambient temperature. Emitting in the same render as
    the transmitted surface radiance keeps the two consistent path by path, so their Monte
    Carlo noise cancels where surface and smoke are at similar temperatures.
    """
    mat, tree = _tree("smoke.thermal")
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    absorb = tree.nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    sigma = _density(tree, spec.absorption_per_density)
    tree.links.new(sigma, absorb.inputs["Density"])
    if spec.fire is not None:
        flame = tree.nodes.new("ShaderNodeAttribute")
        flame.attribute_name = "flame"
        strength = _multiply(tree, sigma, _curve(tree, spec.fire.radiance_curve, flame.outputs["Fac"]))
    else:
        strength = _multiply(tree, sigma, float(spec.ambient_radiance))
    glow = tree.nodes.new("ShaderNodeEmission")
    glow.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(strength, glow.inputs["Strength"])
    shader = _add(tree, absorb.outputs["Volume"], glow.outputs["Emission"])
    tree.links.new(shader, out.inputs["Volume"])
    return mat


def world(name: str, color: Sequence[float], strength: float) -> bpy.types.World:
    w = bpy.data.worlds.new(name)
    w.use_fake_user = True
    w.use_nodes = True
    bg = w.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    return w
