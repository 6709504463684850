"""Oracle scene for the reference water surface: a camera under water looking straight up.

``python -m blendgen.blender.testing.surface_oracle SPEC.json OUT.npy`` renders the refracting
surface of :func:`blendgen.blender.world.add_water_surface` (flat, at z = 0, with the sky
above it; optional water volume) seen from ``depth_m`` below by a pinhole camera of
horizontal field ``hfov_deg``, and saves the linear RGB (H, W, 3) float32.
SPEC: ``{"depth_m", "hfov_deg", "size", "samples", "sky_radiance", "water": null|dict}``, optional
``"tilt_deg"`` (view axis from the zenith towards +x), ``"wind_mps"``, ``"wave_seed"`` (the waves) and ``"sun"``
(``to_sun``, ``irradiance``:
the sun's disc in the sky, :func:`blendgen.blender.world.world_sky_through_surface`);
with ``"kind": "albedo"`` (``{"size", "height_m", "seed"}``) it saves the albedo pass of the
tiled pool floor instead (:func:`render_albedo`).
"""

from __future__ import annotations

import json
import math
import sys


def render(spec: dict, out: str) -> None:
    import bpy

    from blendgen.blender import materials, water, world
    from blendgen.blender import render as rnd
    from blendgen.blender import scene as scn

    sc = scn.reset()
    wo = bpy.data.worlds.new("w")
    sc.world = wo
    materials.world_color(wo, [0.0, 0.0, 0.0])
    world.world_sky_through_surface(wo, float(spec["sky_radiance"]), spec.get("sun"))
    world.add_water_surface(
        {
            "z": 0.0,
            "centre_xy": [0.0, 0.0],
            "half_xy": [500.0, 500.0],
            "sky_radiance": spec["sky_radiance"],
            "wave_seed": int(spec.get("wave_seed", 0)),
            "wind_mps": float(spec.get("wind_mps", 0.0)),
        }
    )
    if spec.get("water"):
        water.add_water_volume(spec["water"])
    n = int(spec["size"])
    cam = rnd.setup_camera(sc, {"hfov_rad": math.radians(spec["hfov_deg"]), "width": n, "height": n})
    rnd.setup_cycles(sc, {"samples": int(spec["samples"]), "specular_bounces": 2, "threads": 1})
    rnd.save_pass(sc, out, "surface-oracle", "rgb", cam, looking_up(spec["depth_m"], spec.get("tilt_deg", 0.0)))


def looking_up(depth_m: float, tilt_deg: float = 0.0):
    """OpenCV camera ``depth_m`` below z = 0 looking up, its axis tilted ``tilt_deg`` from the
    zenith towards +x (4x4 T_world_cam)."""
    import numpy as np

    a = math.radians(tilt_deg)
    T = np.eye(4)
    T[:3, :3] = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]) @ np.diag(
        [1.0, -1.0, 1.0]
    )  # z_cam = (sin a, 0, cos a): up, towards +x
    T[2, 3] = -float(depth_m)
    return T


def render_albedo(spec: dict, out: str) -> None:
    """The diffuse-colour pass (the fast path's ambient albedo) of the tiled pool floor seen
    from ``height_m`` above it, looking down; saves (H, W, 3) float32."""
    import numpy as np

    from blendgen.blender import render as rnd
    from blendgen.blender import scene as scn

    look = {
        "textures": True,
        "texture_seed": int(spec.get("seed", 0)),
        "tile_size_m": 0.25,
        "grime": 0.35,
        "seabed_depth_m": 12.0,
    }
    desc = {
        "pool": {
            "length_m": 15.0,
            "width_m": 5.0,
            "depth_m": 8.0,
            "walls": True,
            "wall_color": [0.55, 0.62, 0.66],
            "floor_color": [0.5, 0.55, 0.55],
        },
        "dock": {"T_world_dock": np.eye(4).tolist(), "body_size_m": [0.1, 0.1, 0.1], "face_color": [0.5] * 3},
        "markers": [],
        "object_index": {"pool": 1, "dock": 2},
        "world_color": [0.0] * 3,
        "world": look,
        "sun": {"direction": [0.0, 0.0, -1.0], "strength": 3.0},
        "fill": {"direction": [1, 0, 0], "strength": 0},
    }
    sc = scn.build(desc)
    n = int(spec["size"])
    cam = rnd.setup_camera(sc, {"hfov_rad": math.radians(40.0), "width": n, "height": n})
    rnd.setup_cycles(sc, {"samples": 4, "threads": 1, "albedo_pass": True})
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV camera looking down
    T[:3, 3] = [3.0, 1.0, -8.0 + float(spec["height_m"])]
    rnd.save_pass(sc, out, "albedo-oracle", "albedo", cam, T)


if __name__ == "__main__":
    spec = json.loads(open(sys.argv[1]).read())
    (render_albedo if spec.get("kind") == "albedo" else render)(spec, sys.argv[2])
