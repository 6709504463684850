"""Can the Cycles reference carry caustics? A far spot light with a light texture (a gobo) as the
sun: tested here on a pattern of known shape (docs/evidence/README.md).

Why: the reference's sun is a delta light under a refracting surface, so path tracing finds no
caustics, and Cycles' MNEE does not carry an absorbing medium. But the caustic
irradiance on a receiver is the flat-surface sun times a pattern ``M(xi)`` of the point ``xi``
where the receiver's sun ray crosses the surface plane (the coordinates ``physics/surface/caustic_map.py`` bins its
maps in;
for a planar receiver at fixed depth, the photon map of ``caustic_reference`` at that depth).
A spot light ``D`` = 1 km away along the refracted sun direction sends parallel rays (1 mrad
across a 12 m patch); its light texture, looked up with the Texture Coordinate node's
``Normal`` (the ray's direction in the light's frame: lateral offset ``D n_x / -n_z``), gives
each ray the pattern of the point where it crosses ``z = 0``. Its power ``4 pi E D^2`` gives
irradiance ``E`` normal to the beam. Light linking keeps the pattern on its receiver (the
floor): other receivers take a plain sun.

Scene: white Lambertian floor 2 m below the plane z = 0, beam 20 deg from vertical, E = 3 W/m^2,
pattern ``M = 1 + 0.8 sin(2 pi xi_x)``, optionally an absorbing water box (sigma_a 0.2 /m) up to
z = 0 and a step 0.5 m above the floor (x > 1 m) lit by a plain 5 W/m^2 sun only. Camera
orthographic from above, 128 px over 6 m, 16 spp. Expected radiance on the floor
``E cos(20 deg) / pi * M(x - H tan 20 deg) * exp(-sigma_a H (1/cos + 1))``.

It checks the building blocks of the reference's caustics (``caustic_sun.gobo_spot``,
``link_only``), which reference datasets use.

    python -m blendgen.blender.testing.caustic_gobo WORK_DIR  (~10 s; docs/evidence/caustic_gobo.txt)"""

import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from blendgen.physics.surface import caustic_beam as cb

H, TILT, E, SIGMA_A, N_GOBO, W_GOBO = 2.0, math.radians(20.0), 3.0, 0.2, 512, 12.0


def _grid() -> "cb.Grid":
    """The spot's grid: 512 bins over 12 m across a beam 20 deg from vertical, centred at the origin."""
    from blendgen.physics.surface import caustic_beam as cb

    t = np.array([math.sin(TILT), 0.0, -math.cos(TILT)])
    e1, e2 = cb.beam_axes(t)
    return cb.Grid(np.zeros(3), t, e1, e2, np.full(2, -W_GOBO / 2), W_GOBO / N_GOBO, (N_GOBO, N_GOBO))


def _pattern(grid) -> np.ndarray:
    """``M(xi) = 1 + 0.8 sin(2 pi xi_x)`` at each bin's ray, ``xi`` where it crosses z = 0."""
    from blendgen.physics.surface.caustic_beam import D_SPOT

    rows, cols = grid.shape
    p = grid.lo[0] + (np.arange(cols) + 0.5) * grid.bin_m
    q = grid.lo[1] + (np.arange(rows) + 0.5) * grid.bin_m
    P, Q = np.meshgrid(p, q)
    d = P[..., None] * grid.e1 + Q[..., None] * grid.e2 + D_SPOT * grid.t  # from the spot
    S = grid.c - D_SPOT * grid.t
    xi = S + (-S[2] / d[..., 2])[..., None] * d
    return (1.0 + 0.8 * np.sin(2 * np.pi * xi[..., 0])).astype(np.float32)


def _scene(water: bool, linking: bool):
    import bpy

    from blendgen.blender.caustic_sun import gobo_spot, link_only, load_pattern

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine, sc.cycles.samples, sc.cycles.device = "CYCLES", 16, "CPU"
    sc.render.resolution_x = sc.render.resolution_y = 128
    sc.cycles.diffuse_bounces = sc.cycles.glossy_bounces = sc.cycles.volume_bounces = 0
    floor = _plane(sc, "floor", 3.0, -H, (-3.0, 3.0))
    grid = _grid()
    spot, img = gobo_spot(sc, grid, E)
    load_pattern(img, _pattern(grid))
    if water:
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, -(H + 0.01) / 2))
        box = bpy.context.active_object
        box.scale = (7.0, 7.0, H + 0.01)
        mat = bpy.data.materials.new("water")
        nt = mat.node_tree
        nt.nodes.remove(nt.nodes["Principled BSDF"])
        ab = nt.nodes.new("ShaderNodeVolumeAbsorption")
        ab.inputs["Density"].default_value, ab.inputs["Color"].default_value = SIGMA_A, (0, 0, 0, 1)
        nt.links.new(ab.outputs[0], nt.nodes["Material Output"].inputs["Volume"])
        box.data.materials.append(mat)
    if linking:
        link_only(spot, [floor], "INCLUDE")
        sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
        sun.data.energy, sun.data.angle = 5.0, 0.0
        sun.rotation_euler = spot.rotation_euler
        sc.collection.objects.link(sun)
        link_only(sun, [floor], "EXCLUDE")
        _plane(sc, "step", 1.0, -H + 0.5, (1.0, 3.0))
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.data.type, cam.data.ortho_scale, cam.location = "ORTHO", 6.0, (0, 0, 5)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.world = bpy.data.worlds.new("black")
    sc.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    return sc


def _plane(sc, name, half_y, z, xs):
    import bpy

    me = bpy.data.meshes.new(name)
    me.from_pydata(
        [(xs[0], -half_y, z), (xs[1], -half_y, z), (xs[1], half_y, z), (xs[0], half_y, z)], [], [(0, 1, 2, 3)]
    )
    obj = bpy.data.objects.new(name, me)
    sc.collection.objects.link(obj)
    mat = bpy.data.materials.get("white") or bpy.data.materials.new("white")
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value, bsdf.inputs["Roughness"].default_value = (1, 1, 1, 1), 1.0
    me.materials.append(mat)
    return obj


def _render(work: Path, name: str, water: bool, linking: bool) -> np.ndarray:
    import bpy
    import OpenImageIO as oiio

    sc = _scene(water, linking)
    sc.render.image_settings.file_format, sc.render.filepath = "OPEN_EXR", str(work / f"{name}.exr")
    bpy.ops.render.render(write_still=True)
    return oiio.ImageBuf(str(work / f"{name}.exr")).get_pixels(oiio.FLOAT)[..., 0]


def main(work: Path) -> None:
    work.mkdir(parents=True, exist_ok=True)
    x = (np.arange(128) + 0.5) / 128 * 6 - 3
    for name, water, linking in (("air", False, False), ("water", True, False), ("water_linked", True, True)):
        row = _render(work, name, water, linking)[64]
        sig = SIGMA_A if water else 0.0
        want = (
            E
            * math.cos(TILT)
            / math.pi
            * (1 + 0.8 * np.sin(2 * np.pi * (x - H * math.tan(TILT))))
            * math.exp(-sig * H * (1 / math.cos(TILT) + 1))
        )
        fl = x < 0.9 if linking else np.ones(x.size, bool)
        err = np.abs(row[fl] / want[fl] - 1)
        print(
            f"{name:13s} floor vs M(xi): median |rel err| {np.median(err):.3f}, p90 {np.percentile(err, 90):.3f}, "
            f"mean ratio {row[fl].mean() / want[fl].mean():.4f}"
        )
        if linking:
            step = row[x > 1.1]
            want_step = 5.0 * math.cos(TILT) / math.pi * math.exp(-sig * (H - 0.5) * (1 / math.cos(TILT) + 1))
            print(
                f"{'':13s} step (plain sun, not linked to the gobo): mean {step.mean():.4f} vs {want_step:.4f}, "
                f"std/mean {step.std() / step.mean():.3f}"
            )


if __name__ == "__main__":
    main(Path(sys.argv[1]))
