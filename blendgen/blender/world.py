"""The world around the dock in Blender (docs/light.md): textured pool, dock materials, seabed,
and (reference fidelity) the refracting water surface with the sky above it.

Procedural Cycles shader nodes only (nothing is downloaded or bundled). Texture
randomisation is seeded from ``scene.world.texture_seed``: the seed shifts the texture
coordinates (Blender's brick/noise hashes are position-based), picks rock shapes and
tile tints. Every albedo below is a linear diffuse colour; the render's diffuse-colour
pass (the fast path's ambient term, ``compose.add_ambient``) carries it.

Albedos (linear, visible): ceramic pool tile 0.5-0.7 and grout ~0.3 (pool finishes are
light-coloured), sand 0.25-0.45 (dry quartz sand ~0.4; wet darker), basalt/granite rock
0.08-0.2, painted steel 0.3-0.6 by colour, aluminium diffuse part 0.24 plus a rough
specular lobe (metals reflect ~0.6-0.9 specularly; Principled metallic).
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from blendgen.blender.materials import _fresh
from blendgen.blender.meshes import mesh_object
from blendgen.physics.surface.optics import N_WATER, waves_for


def _node(nt, kind: str, **inputs):
    n = nt.nodes.new(kind)
    for k, v in inputs.items():
        n.inputs[k].default_value = v
    return n


def _offset_coords(nt, seed: int, swizzle: str):
    """Object coordinates (m), swizzled to a 2-D texture plane ('xy' floor, 'wall': (x + y, z)),
    shifted by a seeded offset. Returns the vector socket."""
    rng = np.random.default_rng(seed)
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Object"], sep.inputs["Vector"])
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    ox, oy = (float(v) for v in rng.uniform(0, 100, 2))
    if swizzle == "wall":
        add = nt.nodes.new("ShaderNodeMath")
        add.operation = "ADD"
        nt.links.new(sep.outputs["X"], add.inputs[0])
        nt.links.new(sep.outputs["Y"], add.inputs[1])
        u, v = add.outputs["Value"], sep.outputs["Z"]
    else:
        u, v = sep.outputs["X"], sep.outputs["Y"]
    nt.links.new(u, comb.inputs["X"])
    nt.links.new(v, comb.inputs["Y"])
    shift = nt.nodes.new("ShaderNodeVectorMath")
    shift.operation = "ADD"
    shift.inputs[1].default_value = (ox, oy, 0.0)
    nt.links.new(comb.outputs["Vector"], shift.inputs[0])
    return shift.outputs["Vector"]


def _grime(nt, vec, color_socket, strength: float, scale: float):
    """Multiply a colour by ``1 - strength * dirt``, dirt a fractal noise in [0, 1] (smoothstep
    of Perlin fBm, ~``1/scale`` m blotches). Returns the colour socket."""
    noise = _node(nt, "ShaderNodeTexNoise", Scale=scale, Detail=6.0, Roughness=0.6)
    nt.links.new(vec, noise.inputs["Vector"])
    ramp = nt.nodes.new("ShaderNodeMapRange")
    ramp.interpolation_type = "SMOOTHSTEP"
    ramp.inputs["From Min"].default_value = 0.45
    ramp.inputs["From Max"].default_value = 0.75
    ramp.inputs["To Min"].default_value = 1.0
    ramp.inputs["To Max"].default_value = 1.0 - float(strength)
    nt.links.new(noise.outputs["Factor"], ramp.inputs["Value"])
    mul = nt.nodes.new("ShaderNodeVectorMath")
    mul.operation = "MULTIPLY"
    nt.links.new(color_socket, mul.inputs[0])
    nt.links.new(ramp.outputs["Result"], mul.inputs[1])
    return mul.outputs["Vector"]


def tiles(name: str, color, look: dict, swizzle: str) -> bpy.types.Material:
    """Ceramic tiles of edge ``tile_size_m`` with grout lines (5 % of a tile) and per-tile
    tint (+-8 %), dirt by ``grime``; diffuse (tile glaze gloss is left out: the fast path has
    no glossy pass, and both fidelities share this scene)."""
    mat, nt = _fresh(name)
    vec = _offset_coords(nt, look["texture_seed"] + (0 if swizzle == "xy" else 1), swizzle)
    c = np.asarray(color, float)
    s = float(look["tile_size_m"])
    brick = _node(
        nt,
        "ShaderNodeTexBrick",
        **{
            "Color1": (*(c * 1.08).clip(0, 0.95), 1.0),
            "Color2": (*(c * 0.92), 1.0),
            "Mortar": (*(c * 0.55), 1.0),
            "Scale": 1.0,
            "Mortar Size": 0.05 * s,
            "Mortar Smooth": 0.2,
            "Bias": 0.0,
            "Brick Width": s,
            "Row Height": s,
        },
    )
    brick.offset, brick.squash = 0.0, 1.0
    nt.links.new(vec, brick.inputs["Vector"])
    col = _grime(nt, vec, brick.outputs["Color"], look["grime"], 0.6)
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    nt.links.new(col, bsdf.inputs["Color"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def painted(name: str, color, look: dict) -> bpy.types.Material:
    """Painted metal: the paint colour with dirt, roughness 0.5 (Principled, dielectric)."""
    mat, nt = _fresh(name)
    vec = _offset_coords(nt, look["texture_seed"] + 2, "xy")
    base = _node(nt, "ShaderNodeCombineXYZ", X=float(color[0]), Y=float(color[1]), Z=float(color[2]))
    col = _grime(nt, vec, base.outputs["Vector"], 0.6 * look["grime"], 4.0)
    bsdf = _node(nt, "ShaderNodeBsdfPrincipled", Roughness=0.5)
    bsdf.inputs["Specular IOR Level"].default_value = 0.3
    nt.links.new(col, bsdf.inputs["Base Color"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def metal(name: str) -> bpy.types.Material:
    """Anodised/brushed aluminium frame: Principled metallic 0.6 (a diffuse share stays for
    the ambient term's albedo pass), base 0.6 grey, roughness 0.35."""
    mat, nt = _fresh(name)
    bsdf = _node(nt, "ShaderNodeBsdfPrincipled", Metallic=0.6, Roughness=0.35)
    bsdf.inputs["Base Color"].default_value = (0.6, 0.6, 0.62, 1.0)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def sand(name: str, look: dict) -> bpy.types.Material:
    """Sand with ripples (wave texture, ~0.1 m wavelength) and patches (noise): albedo 0.25-0.45."""
    mat, nt = _fresh(name)
    vec = _offset_coords(nt, look["texture_seed"] + 3, "xy")
    wave = _node(nt, "ShaderNodeTexWave", Scale=1.6, Distortion=4.0, Detail=3.0)
    nt.links.new(vec, wave.inputs["Vector"])
    noise = _node(nt, "ShaderNodeTexNoise", Scale=0.3, Detail=4.0)
    nt.links.new(vec, noise.inputs["Vector"])
    mix = nt.nodes.new("ShaderNodeMath")
    mix.operation = "MULTIPLY_ADD"
    nt.links.new(wave.outputs["Factor"], mix.inputs[0])
    mix.inputs[1].default_value = 0.25
    nt.links.new(noise.outputs["Factor"], mix.inputs[2])
    ramp = nt.nodes.new("ShaderNodeMapRange")
    ramp.inputs["From Min"].default_value, ramp.inputs["From Max"].default_value = 0.3, 1.0
    ramp.inputs["To Min"].default_value, ramp.inputs["To Max"].default_value = 0.25, 0.45
    nt.links.new(mix.outputs["Value"], ramp.inputs["Value"])
    tint = nt.nodes.new("ShaderNodeVectorMath")
    tint.operation = "SCALE"
    tint.inputs[0].default_value = (1.0, 0.9, 0.72)  # quartz-and-shell sand is yellowish
    nt.links.new(ramp.outputs["Result"], tint.inputs["Scale"])
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    nt.links.new(tint.outputs["Vector"], bsdf.inputs["Color"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def rock(name: str, look: dict) -> bpy.types.Material:
    """Dark rock with lighter encrustation: albedo 0.08-0.2 by noise."""
    mat, nt = _fresh(name)
    vec = _offset_coords(nt, look["texture_seed"] + 4, "xy")
    noise = _node(nt, "ShaderNodeTexNoise", Scale=3.0, Detail=8.0, Roughness=0.7)
    nt.links.new(vec, noise.inputs["Vector"])
    ramp = nt.nodes.new("ShaderNodeMapRange")
    ramp.inputs["To Min"].default_value, ramp.inputs["To Max"].default_value = 0.08, 0.2
    nt.links.new(noise.outputs["Factor"], ramp.inputs["Value"])
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    nt.links.new(ramp.outputs["Result"], bsdf.inputs["Color"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def add_water_surface(desc: dict) -> bpy.types.Object:
    """Reference fidelity: the water surface as a refracting interface (Glass BSDF, IOR 1.333,
    normal up: a ray from below meets its back face and leaves water into air, so Cycles
    applies Snell's law with total internal reflection beyond 48.6 deg and Fresnel weights).

    It sits 1 mm above the water volume's top face (coplanar faces flicker). It does not cast
    shadows and is invisible to diffuse rays: sunlight and the ambient environment reach the
    pool as without it; camera, glossy and transmission rays see it. Above it the world
    returns the sky radiance to transmission rays (:func:`world_sky_through_surface`)."""
    z = float(desc["z"]) + 1e-3
    (cx, cy), (hx, hy) = desc["centre_xy"], desc["half_xy"]
    v = [(cx - hx, cy - hy, z), (cx + hx, cy - hy, z), (cx + hx, cy + hy, z), (cx - hx, cy + hy, z)]
    obj = mesh_object("water_surface", v, [(0, 1, 2, 3)], index=0)
    mat, nt = _fresh("water_surface")
    glass = _node(nt, "ShaderNodeBsdfGlass", Roughness=0.0, IOR=N_WATER)
    glass.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    waves = waves_for(int(desc.get("wave_seed", 0)), float(desc.get("wind_mps", 0.0)))
    if np.any(waves.amp > 0):
        bump = _node(nt, "ShaderNodeBump", Strength=1.0, Distance=1.0)
        # Cycles bumps a back face along its own (downward) normal, which mirrors the waves
        # (measured: normal pass from below (-sx, -sy, -1) instead of (sx, sy, -1)); seen
        # from below (the camera's side) the height is negated so both sides see eta.
        side = _math(nt, "MULTIPLY_ADD", nt.nodes.new("ShaderNodeNewGeometry").outputs["Backfacing"], -2.0, 1.0)
        nt.links.new(_math(nt, "MULTIPLY", _wave_height(nt, waves), side), bump.inputs["Height"])
        nt.links.new(bump.outputs["Normal"], glass.inputs["Normal"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(glass.outputs["BSDF"], out.inputs["Surface"])
    obj.data.materials.append(mat)
    obj.visible_shadow = False
    obj.visible_diffuse = False
    obj.visible_volume_scatter = False
    return obj


def _math(nt, op: str, a, b, c=None):
    n = nt.nodes.new("ShaderNodeMath")
    n.operation = op
    for i, x in enumerate((a, b, c)[: 3 if c is not None else 2]):
        if isinstance(x, (int, float)):
            n.inputs[i].default_value = float(x)
        else:
            nt.links.new(x, n.inputs[i])
    return n.outputs["Value"]


def _wave_height(nt, waves) -> bpy.types.NodeSocket:
    """Shader nodes of ``eta(x, y, t)`` (:class:`physics.surface.optics.WaveField`, world = object
    coordinates of the unrotated surface); time is the Value node ``wave_time`` (s), set per
    frame by :func:`set_wave_time`."""
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Object"], sep.inputs["Vector"])
    time = nt.nodes.new("ShaderNodeValue")
    time.name = time.label = "wave_time"
    time.outputs[0].default_value = 0.0
    total = None
    for a, (kx, ky), w, ph in zip(waves.amp, waves.k, waves.omega, waves.phase):
        arg = _math(
            nt,
            "MULTIPLY_ADD",
            sep.outputs["X"],
            float(kx),
            _math(
                nt,
                "MULTIPLY_ADD",
                sep.outputs["Y"],
                float(ky),
                _math(nt, "MULTIPLY_ADD", time.outputs[0], -float(w), float(ph)),
            ),
        )
        term = _math(nt, "MULTIPLY", _math(nt, "SINE", arg, 0.0), float(a))
        total = term if total is None else _math(nt, "ADD", total, term)
    return total


def set_wave_time(t: float) -> None:
    """Move the reference surface's waves to time ``t`` (s); no-op without a wavy surface."""
    mat = bpy.data.materials.get("water_surface")
    node = mat.node_tree.nodes.get("wave_time") if mat is not None else None
    if node is not None:
        node.outputs[0].default_value = float(t)


def world_sky_through_surface(world: bpy.types.World, sky_radiance: float, sun: dict | None = None) -> None:
    """Make the world return ``n^2 sky_radiance`` (``sky_radiance`` the uniform sky's, W/m^2/sr)
    to rays that left the water through the surface (transmission rays), keeping its other
    radiance for the rest. The ``n^2``: radiance over n^2 is invariant across an interface
    (Nicodemus 1963), and Cycles' refraction does not apply it (measured: a sky of radiance L
    seen from below renders as ``T L``), so the sky carries it. ``sun`` (``to_sun`` (3,)
    world unit vector, ``irradiance`` W/m^2 normal to the beam): the sun's disc, radius
    ``SUN_RADIUS_RAD``, radiance ``E / (pi r^2)`` (times n^2), for those rays too: the scene's
    sun lamp is a delta light that a refracted camera ray cannot hit."""
    nt = world.node_tree
    out = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeOutputWorld")
    old = out.inputs["Surface"].links[0].from_socket if out.inputs["Surface"].links else None
    path = nt.nodes.new("ShaderNodeLightPath")
    sky = _node(nt, "ShaderNodeBackground", Strength=float(sky_radiance) * N_WATER**2)
    sky.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    if sun is not None and float(sun["irradiance"]) > 0:
        nt.links.new(_sun_disc_strength(nt, sun, float(sky_radiance)), sky.inputs["Strength"])
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(path.outputs["Is Transmission Ray"], mix.inputs["Fac"])
    if old is not None:
        nt.links.new(old, mix.inputs[1])
    nt.links.new(sky.outputs["Background"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])


def _sun_disc_strength(nt, sun: dict, sky_radiance: float):
    """``n^2 (L_sky + L_sun [angle(ray, to_sun) < SUN_RADIUS_RAD])`` as a world-shader value."""
    from blendgen.physics.surface.optics import SUN_RADIUS_RAD

    coord = nt.nodes.new("ShaderNodeTexCoord")  # world: Generated = ray direction
    to_sun = np.asarray(sun["to_sun"], float)
    dot = nt.nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    dot.inputs[1].default_value = tuple(to_sun / np.linalg.norm(to_sun))
    nt.links.new(coord.outputs["Generated"], dot.inputs[0])
    inside = _math(nt, "GREATER_THAN", dot.outputs["Value"], math.cos(SUN_RADIUS_RAD))
    l_sun = float(sun["irradiance"]) / (math.pi * SUN_RADIUS_RAD**2)
    return _math(nt, "MULTIPLY_ADD", inside, l_sun * N_WATER**2, sky_radiance * N_WATER**2)
