"""Reference glow of a point emitter seen through the Cycles medium (for the fast model's PSF).

``python -m blendgen.blender.glow_scene SPEC.json OUT.npy`` renders a small point light
(radius ``light_radius_m``, never seen directly: Cycles point lights are invisible to camera
rays) at ``range_m`` straight ahead of a pinhole camera, both inside a water box
(``plan.water_volume``-style ``water`` dict, 0 volume bounces: single scattering, the light
reached by next-event estimation). The image then holds only the forward-scattered glow;
OUT.npy is its linear RGB (H, W, 3) float32. SPEC keys: ``water``, ``range_m``, ``power_w``,
``light_radius_m``, ``hfov_deg``, ``width``, ``height``, ``samples``, ``seed``; optional ``led``
(``{"radiance": [3], "radius_m": a, "lights_scene": bool}``: the dataset's disc LED instead of
the point light), ``water`` null (no medium) and ``volume_bounces`` (default 0: single
scattering; > 0: multiple scattering).
"""

from __future__ import annotations

import math
import sys


def build(spec: dict):
    import bpy

    from blendgen.blender import materials, render, water
    from blendgen.blender import scene as scn

    sc = scn.reset()
    world = bpy.data.worlds.new("black")
    sc.world = world
    materials.world_color(world, [0.0, 0.0, 0.0])
    r = float(spec["range_m"])
    if spec.get("water"):
        water.add_water_volume({**spec["water"], "box_min": [-2.0, -20.0, -20.0], "box_max": [r + 5.0, 20.0, 20.0]})
    if spec.get("led"):
        add_disc_led(spec["led"], r)
    else:
        light = bpy.data.lights.new("led", type="POINT")
        light.energy = float(spec.get("power_w", 1.0))
        light.shadow_soft_size = float(spec.get("light_radius_m", 0.005))
        obj = bpy.data.objects.new("led", light)
        sc.collection.objects.link(obj)
        obj.location = (r, 0.0, 0.0)
    cam = render.setup_camera(
        sc,
        {
            "width": spec["width"],
            "height": spec["height"],
            "hfov_rad": math.radians(spec["hfov_deg"]),
            "clip_start": 0.001,
        },
    )
    cam.rotation_euler = (math.pi / 2, 0.0, -math.pi / 2)  # Blender -Z view axis -> world +x
    render.setup_cycles(sc, {"samples": spec["samples"], "seed": spec.get("seed", 0), "max_bounces": 0})
    water.reference_settings(sc, int(spec.get("volume_bounces", 0)))
    return sc


def add_disc_led(led: dict, r: float) -> None:
    """The dataset's LED (``scene.add_led_array``'s disc and material): radiance ``led["radiance"]``
    (3,), radius ``led["radius_m"]``, at x = r facing the camera; ``led["lights_scene"]`` as there."""
    import numpy as np

    from blendgen.blender import materials
    from blendgen.blender import scene as scn

    v, f = scn.disc(float(led["radius_m"]))
    obj = scn.mesh_object("led_disc", v, f, index=1)
    sampled = bool(led.get("lights_scene"))
    obj.data.materials.append(materials.emission("led_disc", led["radiance"], 1.0, sampled=sampled))
    if not sampled:
        scn.camera_only(obj)
    T = np.array([[0, 0, -1, r], [0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]], float)  # disc +z -> world -x
    scn.set_matrix(obj, T)


def main(argv: list[str]) -> int:
    from blendgen.blender import render

    return render.oracle_main(build, argv, "glow")


if __name__ == "__main__":
    sys.exit(main(sys.argv))
