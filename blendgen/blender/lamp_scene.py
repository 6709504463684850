"""Reference renders of the vehicle lamp: a pinhole camera with its lamps in a water box.

``python -m blendgen.blender.lamp_scene SPEC.json OUT.npy`` renders the camera at the world
origin looking along +x (OpenCV camera frame: x_cam = -y, y_cam = -z, z_cam = +x world), its
config lamps (:mod:`blendgen.blender.lamps`) parented to it, inside a water box
(``plan.water_volume``-style ``water`` dict, or null for no medium), optionally facing a
Lambertian ``card`` (a large plane at ``z_cam = distance_m`` of albedo ``albedo``) and
optional Lambertian ``occluders`` in front of it (axis-aligned boxes in the camera frame, the
lamp's shadow test, ``blendgen.tools.bench.lamp_bench.shadow_table``), and nothing else (the world
is black). OUT.npy holds the linear RGB (H, W, 3) float32.
SPEC keys: ``water``, ``lamps`` (list of ``Lamp`` dicts), ``card`` ({distance_m, albedo} or
null), ``occluders`` (optional list of {min, max (3,) camera frame m, albedo}), ``hfov_deg``,
``width``, ``height``, ``samples``, ``volume_bounces``, ``seed``.
"""

from __future__ import annotations

import math
import sys

BOX = {"box_min": [-2.0, -30.0, -30.0], "box_max": [60.0, 30.0, 30.0]}


def build(spec: dict):
    import bpy

    from blendgen.blender import lamps, materials, render, water
    from blendgen.blender import scene as scn

    sc = scn.reset()
    world = bpy.data.worlds.new("black")
    sc.world = world
    materials.world_color(world, [0.0, 0.0, 0.0])
    if spec.get("water"):
        water.add_water_volume({**spec["water"], **BOX})
    card = spec.get("card")
    if card:
        x, h, a = float(card["distance_m"]), 40.0, float(card["albedo"])
        plane = scn.mesh_object("card", [(x, -h, -h), (x, h, -h), (x, h, h), (x, -h, h)], [(0, 3, 2, 1)], index=1)
        plane.data.materials.append(materials.diffuse("card", [a, a, a]))
    for i, box in enumerate(spec.get("occluders") or []):
        add_box(f"occluder_{i}", box["min"], box["max"], float(box["albedo"]))
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
    lamps.add_lamps(cam, spec["lamps"])
    bounces = int(spec.get("volume_bounces", 0))
    render.setup_cycles(
        sc, {"samples": spec["samples"], "seed": spec.get("seed", 0), "max_bounces": bounces, "volume_bounces": bounces}
    )
    water.reference_settings(sc, bounces)
    return sc


def _world(p_cam) -> tuple[float, float, float]:
    """OpenCV camera frame -> this scene's world (camera at the origin looking along +x)."""
    return float(p_cam[2]), -float(p_cam[0]), -float(p_cam[1])


def add_box(name: str, lo, hi, albedo: float):
    """A Lambertian axis-aligned box between camera-frame corners ``lo`` and ``hi`` (m)."""
    from blendgen.blender import materials
    from blendgen.blender import scene as scn

    verts = [_world((x, y, z)) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    obj = scn.mesh_object(name, verts, faces, index=2)
    obj.data.materials.append(materials.diffuse(name, [albedo] * 3))
    return obj


def main(argv: list[str]) -> int:
    from blendgen.blender import render

    return render.oracle_main(build, argv, "lamp")


if __name__ == "__main__":
    sys.exit(main(sys.argv))
