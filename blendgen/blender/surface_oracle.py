"""Oracle scene for the reference water surface: a camera under water looking straight up.

``python -m blendgen.blender.surface_oracle SPEC.json OUT.npy`` renders the refracting
surface of :func:`blendgen.blender.world.add_water_surface` (flat, at z = 0, with the sky
above it; optional water volume) seen from ``depth_m`` below by a pinhole camera of
horizontal field ``hfov_deg``, and saves the linear RGB (H, W, 3) float32.
SPEC: ``{"depth_m", "hfov_deg", "size", "samples", "sky_radiance", "water": null|dict}``.
"""
from __future__ import annotations

import json
import math
import os
import sys


def render(spec: dict, out: str) -> None:
    import bpy
    import numpy as np
    from blendgen.blender import materials, render as rnd, scene as scn, water, world

    sc = scn.reset()
    wo = bpy.data.worlds.new("w")
    sc.world = wo
    materials.world_color(wo, [0.0, 0.0, 0.0])
    world.world_sky_through_surface(wo, float(spec["sky_radiance"]))
    world.add_water_surface({"z": 0.0, "centre_xy": [0.0, 0.0], "half_xy": [500.0, 500.0],
                             "sky_radiance": spec["sky_radiance"]})
    if spec.get("water"):
        water.add_water_volume(spec["water"])
    n = int(spec["size"])
    cam = rnd.setup_camera(sc, {"hfov_rad": math.radians(spec["hfov_deg"]), "width": n, "height": n})
    rnd.setup_cycles(sc, {"samples": int(spec["samples"]), "specular_bounces": 2, "threads": 1})
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, 1.0])          # OpenCV camera looking up (+z world)
    T[2, 3] = -float(spec["depth_m"])
    path = os.path.join(rnd.scratch_dir(), f"surface-oracle-{os.getpid()}.exr")
    try:
        rnd.render_frame(sc, cam, T, path)
        np.save(out, rnd.read_passes(path)["rgb"])
    finally:
        if os.path.exists(path):
            os.remove(path)


if __name__ == "__main__":
    render(json.loads(open(sys.argv[1]).read()), sys.argv[2])
