"""Cycles materials: diffuse surfaces, printed marker textures, LED emitters, world, water volume."""

from __future__ import annotations

import bpy

PRINT_BLACK = 0.04  # albedo of printed black
PRINT_WHITE = 0.85  # albedo of white plastic / paper


def _fresh(name: str) -> tuple[bpy.types.Material, bpy.types.NodeTree]:
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    return mat, nt


def diffuse(name: str, color) -> bpy.types.Material:
    """Lambertian surface of linear albedo ``color`` (3,)."""
    mat, nt = _fresh(name)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*color, 1.0)
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _cell_texture(nt: bpy.types.NodeTree, path: str, black: float, white: float):
    """Nodes reading a black/white cell texture nearest (sharp cell edges exactly on the cell
    boundaries) and mapping cell 0/1 to ``black``/``white``; returns the value socket."""
    tex = nt.nodes.new("ShaderNodeTexImage")
    img = bpy.data.images.load(path, check_existing=True)
    img.colorspace_settings.name = "Non-Color"
    tex.image = img
    tex.interpolation = "Closest"
    tex.extension = "EXTEND"
    scale = nt.nodes.new("ShaderNodeMath")
    scale.operation = "MULTIPLY_ADD"
    scale.inputs[1].default_value = float(white - black)
    scale.inputs[2].default_value = float(black)
    nt.links.new(tex.outputs["Color"], scale.inputs[0])
    return scale.outputs["Value"]


def printed_texture(name: str, path: str) -> bpy.types.Material:
    """Diffuse print of a black/white cell texture: albedo PRINT_BLACK .. PRINT_WHITE."""
    mat, nt = _fresh(name)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    nt.links.new(_cell_texture(nt, path, PRINT_BLACK, PRINT_WHITE), bsdf.inputs["Color"])
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def emissive_texture(name: str, path: str, black: float, white: float) -> bpy.types.Material:
    """Self-lit cell texture (radiance black .. white): needs no light, renders noise-free."""
    mat, nt = _fresh(name)
    mat.cycles.emission_sampling = "NONE"  # lights nothing: never sampled as a light
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1.0
    nt.links.new(_cell_texture(nt, path, black, white), em.inputs["Color"])
    nt.links.new(em.outputs["Emission"], out.inputs["Surface"])
    return mat


def emission(name: str, color, strength: float, sampled: bool = False) -> bpy.types.Material:
    """Self-lit LED: emission of linear colour (3,) times ``strength``.

    Not sampled as a light unless ``sampled`` (reference fidelity: the LEDs light the water
    and what faces them; front side only, the side that faces out of the dock). Unsampled,
    the LEDs are seen but light nothing (no Monte Carlo noise at the few samples of the fast
    path, which adds their light itself)."""
    mat, nt = _fresh(name)
    mat.cycles.emission_sampling = "FRONT" if sampled else "NONE"
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*color, 1.0)
    em.inputs["Strength"].default_value = float(strength)
    nt.links.new(em.outputs["Emission"], out.inputs["Surface"])
    return mat


def world_color(world: bpy.types.World, color) -> None:
    """Constant background radiance (what a ray that hits nothing returns)."""
    nt = world.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputWorld")
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])


def world_sky(world: bpy.types.World, upper: float, lower: float) -> None:
    """Uniform grey environment hidden from the camera: radiance ``upper`` (W/m^2/sr) from
    directions above the horizon (diffuse sky and in-water scattered light), ``lower`` from
    below (upwelling). Lights every surface a few bounces can reach; camera rays that hit
    nothing still return 0 (the water model paints those)."""
    nt = world.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputWorld")
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    above = nt.nodes.new("ShaderNodeMath")
    above.operation = "GREATER_THAN"
    above.inputs[1].default_value = 0.0
    mix = nt.nodes.new("ShaderNodeMapRange")  # 0 -> lower, 1 -> upper
    mix.inputs["To Min"].default_value = float(lower)
    mix.inputs["To Max"].default_value = float(upper)
    bg = nt.nodes.new("ShaderNodeBackground")
    nt.links.new(coord.outputs["Generated"], sep.inputs["Vector"])
    nt.links.new(sep.outputs["Z"], above.inputs[0])
    nt.links.new(above.outputs["Value"], mix.inputs["Value"])
    nt.links.new(mix.outputs["Result"], bg.inputs["Strength"])
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    world.cycles_visibility.camera = False
