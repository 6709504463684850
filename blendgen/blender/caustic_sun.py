"""Reference caustics in datasets (docs/light.md): on every opaque surface the sun becomes a far
spot light whose light texture is this frame's photon map.

Why (``caustic_reference``, ``caustic_gobo``): the reference's sun is a delta light under a
refracting surface, so path tracing finds no caustics. But along the in-water beam ``t``
each straight line from the surface reaches exactly one first opaque point (floor, a wall,
the dock), and the caustic irradiance there is the plain sun's times a pattern ``M`` of that
line. So:

1. **Photon map** (a second Blender scene, rendered per frame): an orthographic camera in the
   air plays the sun (rays along the sun's direction in the sky, ``surface.sun_in_air``, each
   turned to a uniform direction within its disc by the camera's depth of field), the frame's wavy glass surface
   (the dataset's own object, same
   waves and time) refracts them, and every polygon of the receivers (pool floor and walls,
   dock body) records where they land: its emission is ``(u + OFFSET,
   v + OFFSET, id + 1)``, its own plane coordinates and number. Clear water (the dataset's
   medium then attenuates and scatters the spot's light as it did the sun's); a refracted ray
   keeps weight 1 (Fresnel chooses reflection or refraction, the reflected ray leaves to a
   black sky), which :meth:`CausticSun.photons` checks.
2. **Binning** (``physics/surface/caustic_beam.py``) across the in-water beam, at the projective
   coordinates the spot's light texture is looked up with (which also undo the spot's inverse
   square at the photon's receiver), over a flat surface's count: the plain sun's energy.
3. **The spots**: ``D`` upstream of the grid's centre along the beam, power ``4 pi S D^2``
   (``S``: the sun lamp's strength), texture ``1 + (M - 1)`` clipped to 1 outside the grid.
   Two of them, each with its own photon camera: one over the whole pool (2 cm bins,
   ``plan.REFERENCE_CAUSTICS`` says why) and one over the dock and its markers (1 cm bins:
   a camera at 1 m sees 2-4 mm pixels there, and the caustic lines of a shallow dock are
   1-3 cm wide). Light linking: the dock's spot
   lights the dock, its frame and markers; the pool's spot everything else but the water
   volume; the sun lamp lights only the volume (its in-scatter keeps the plain beam: ``M``
   belongs to the first receiver's depth, not to the water above it).

What is left out: the dock's frame bars and the markers are not recorders (they take the
pattern of the receiver behind them), photons are traced in clear water (the medium's
forward scattering does not blur the pattern, as it does in ``caustic_reference`` with a
medium), in open water the dock only (its 120 m seabed is beyond a photon budget: it keeps
the plain sun).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import bpy
import mathutils
import numpy as np

from blendgen.blender import render as rnd
from blendgen.blender.photon_scene import add_absorber, add_recorders, photon_scene, sun_camera
from blendgen.blender.world import _math
from blendgen.physics.surface import caustic_beam as cb
from blendgen.physics.surface import optics as sf
from blendgen.physics.surface.caustic_beam import D_SPOT, OFFSET, Grid

RECEIVERS = ("pool_floor", "pool_walls", "dock_body", "seabed")


def gobo_spot(sc: bpy.types.Scene, grid: Grid, strength: float) -> tuple[bpy.types.Object, bpy.types.Image]:
    """The spot ``D_SPOT`` upstream of the grid centre with irradiance ``strength`` (W/m^2)
    across its beam, its light colour ``1 + (M - 1)`` looked up at the ray's projective
    coordinates (0 outside the grid: the plain sun). Returns (object, pattern image)."""
    rows, cols = grid.shape
    size = grid.size()
    light = bpy.data.lights.new("caustic_sun", "SPOT")
    light.spot_size = 2.0 * math.atan(float(np.abs(np.concatenate([grid.lo, grid.lo + size])).max()) * 1.5 / D_SPOT)
    light.spot_blend, light.shadow_soft_size, light.energy = 0.0, 0.0, 4 * math.pi * strength * D_SPOT**2
    light.use_soft_falloff = False
    obj = bpy.data.objects.new("caustic_sun", light)
    sc.collection.objects.link(obj)
    obj.matrix_world = mathutils.Matrix(
        [[*grid.e1, 0], [*grid.e2, 0], [*(-grid.t), 0], [*(grid.c - D_SPOT * grid.t), 1]]
    ).transposed()
    img = bpy.data.images.new("caustic_pattern", cols, rows, float_buffer=True, alpha=False)
    img.colorspace_settings.name = "Non-Color"  # before the pixels: it regenerates the image
    nt = light.node_tree
    xyz = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(nt.nodes.new("ShaderNodeTexCoord").outputs["Normal"], xyz.inputs[0])
    uv = nt.nodes.new("ShaderNodeCombineXYZ")
    for axis, i in (("X", 0), ("Y", 1)):  # u = (D n / -n_z - lo) / size
        p = _math(nt, "DIVIDE", _math(nt, "MULTIPLY", xyz.outputs[axis], -D_SPOT / size[i]), xyz.outputs["Z"])
        nt.links.new(_math(nt, "SUBTRACT", p, float(grid.lo[i] / size[i])), uv.inputs[i])
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image, tex.extension, tex.interpolation = img, "CLIP", "Linear"
    nt.links.new(uv.outputs[0], tex.inputs["Vector"])
    one_plus = nt.nodes.new("ShaderNodeVectorMath")  # 1 + (M - 1); 1 outside the grid
    one_plus.operation = "ADD"
    one_plus.inputs[1].default_value = (1.0, 1.0, 1.0)
    nt.links.new(tex.outputs["Color"], one_plus.inputs[0])
    nt.links.new(one_plus.outputs["Vector"], nt.nodes["Emission"].inputs["Color"])
    return obj, img


def link_only(light_obj: bpy.types.Object, receivers, state: str) -> None:
    """Light linking: ``light_obj`` lights only ``receivers`` ("INCLUDE") or all but them ("EXCLUDE")."""
    coll = bpy.data.collections.new(f"{light_obj.name}_receivers")
    for r in receivers:
        coll.objects.link(r)
    for c in coll.collection_objects:
        c.light_linking.link_state = state
    light_obj.light_linking.receiver_collection = coll


DOCK_PARTS = ("dock_", "marker_", "led_")  # object name prefixes: the dock's fine layer


@dataclass
class Layer:
    """One caustic spot: its grid, its photon camera (framing the surface above its receivers
    with a margin for rays the waves bend in) and its light texture."""

    name: str
    grid: Grid
    cam: bpy.types.Object
    spot: bpy.types.Object
    image: bpy.types.Image


def dock_region(dock: list, t: np.ndarray, z: float, margin_m: float) -> dict | None:
    """The surface rectangle (``centre_xy``, ``half_xy``, ``z``) the dock's parts (mesh
    objects) are seen through along the beam ``t``, grown by ``margin_m``; None without them."""
    pts = [np.array(o.matrix_world) @ np.append(v.co, 1.0) for o in dock for v in o.data.vertices]
    if not pts:
        return None
    P = np.array(pts)[:, :3]
    xi = P - ((P[:, 2] - z) / t[2])[:, None] * t
    lo, hi = xi[:, :2].min(axis=0) - margin_m, xi[:, :2].max(axis=0) + margin_m
    return {"centre_xy": ((lo + hi) / 2).tolist(), "half_xy": ((hi - lo) / 2).tolist(), "z": z}


class CausticSun:
    """The dataset scene's sun replaced by caustic spots (module docstring): one over the pool
    (``bin_m``; not in open water, ``pool_spot`` false: its seabed keeps the plain sun), one
    finer over the dock and its markers (``dock_bin_m``: a camera at 1 m resolves millimetres
    there); call :meth:`update` each frame after the waves' time is set.

    ``desc``: the scene description (its ``sun``; its ``water_surface`` with ``caustics``:
    ``bin_m``, ``dock_bin_m`` (m), ``photons_per_bin``, ``renders`` (per spot and frame))."""

    def __init__(self, sc: bpy.types.Scene, desc: dict, threads: int = 0):
        surface, cfg = desc["water_surface"], desc["water_surface"]["caustics"]
        t = np.asarray(desc["sun"]["direction"], float)
        t /= np.linalg.norm(t)
        self.air, self.per_bin = sf.sun_in_air(t), float(cfg["photons_per_bin"])
        self.renders = int(cfg["renders"])
        self.ps = photon_scene(bpy.data.objects["water_surface"], threads)
        add_absorber(self.ps, surface)
        recorders = add_recorders(self.ps, [bpy.data.objects[n] for n in RECEIVERS if n in bpy.data.objects])
        self.planes = tuple(np.array([getattr(r, a) for r in recorders]) for a in ("o", "eu", "ev"))
        strength = float(desc["sun"]["strength"])
        dock = [o for o in sc.objects if o.type == "MESH" and o.name.startswith(DOCK_PARTS)]
        volume, sun = sc.objects.get("water_volume"), sc.objects.get("sun")
        self.layers = []
        if cfg.get("pool_spot", True):
            self.layers.append(self._layer(sc, "pool", surface, surface, t, float(cfg["bin_m"]), strength))
            link_only(self.layers[0].spot, dock + ([volume] if volume is not None else []), "EXCLUDE")
        region = dock_region(dock, t, float(surface["z"]), 0.05)
        if region is not None:
            framed = {**region, "half_xy": [h + 0.3 for h in region["half_xy"]]}  # bent rays from around it
            self.layers.append(self._layer(sc, "dock", region, framed, t, float(cfg["dock_bin_m"]), strength))
            link_only(self.layers[-1].spot, dock, "INCLUDE")
        if not cfg.get("pool_spot", True):
            link_only(sun, dock, "EXCLUDE")  # open water: seabed, rocks and water keep the plain sun
        elif volume is not None:
            link_only(sun, [volume], "INCLUDE")
        else:
            bpy.data.objects.remove(sun)

    def _layer(self, sc, name: str, region: dict, framed: dict, t: np.ndarray, bin_m: float, strength: float) -> Layer:
        grid = cb.grid_for(region, t, bin_m)
        cam = sun_camera(self.ps, framed, self.air, cb.photon_pitch(bin_m, self.per_bin, self.renders, self.air, t))
        return Layer(name, grid, cam, *gobo_spot(sc, grid, strength))

    def photons(self, layer: Layer, seed: int, path: str) -> np.ndarray:
        """(N, 3) world points where this frame's refracted sun rays through the layer's
        camera first land on a receiver."""
        O, EU, EV = self.planes
        self.ps.camera = layer.cam
        self.ps.render.resolution_x, self.ps.render.resolution_y = layer.cam["resolution"]
        out = []
        for i in range(self.renders):
            self.ps.cycles.seed = seed * 64 + i
            self.ps.render.filepath = path
            bpy.ops.render.render(write_still=True, scene=self.ps.name)
            rgb = rnd.read_passes(path)["rgb"].reshape(-1, 3)
            rgb = rgb[rgb[:, 2] > 0]
            k = np.rint(rgb[:, 2])
            if rgb.size and float(np.abs(rgb[:, 2] - k).max()) > 1e-3:
                raise RuntimeError(
                    "caustic photons: a refracted ray's weight is not 1 (medium or clamping in the photon scene?)"
                )
            ids = k.astype(int) - 1
            u, v = rgb[:, 0:1] - OFFSET, rgb[:, 1:2] - OFFSET
            out.append(O[ids] + u * EU[ids] + v * EV[ids])
        return np.concatenate(out) if out else np.zeros((0, 3))

    def update(self, seed: int) -> list[np.ndarray]:
        """Trace this frame's photons, load each layer's ``M - 1`` into its spot's texture;
        returns the layers' ``M``."""
        path = os.path.join(rnd.scratch_dir(), f"dockbench-photons-{os.getpid()}.exr")
        out = []
        try:
            for k, layer in enumerate(self.layers):
                pitch = layer.cam.data.ortho_scale / max(layer.cam["resolution"])
                M = cb.pattern(layer.grid, self.photons(layer, seed * 2 + k, path), pitch, self.renders, self.air)
                load_pattern(layer.image, M)
                out.append(M)
        finally:
            if os.path.exists(path):
                os.remove(path)
        return out


def load_pattern(img: bpy.types.Image, M: np.ndarray) -> None:
    """Put ``M - 1`` ((rows, cols), rows along e2) into the spot's light texture."""
    rgba = np.zeros(M.shape + (4,), np.float32)
    rgba[..., :3] = (M - 1.0)[..., None]
    rgba[..., 3] = 1.0
    img.pixels.foreach_set(rgba.ravel())
    img.update()
