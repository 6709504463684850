"""Tiny physics-oracle scenes built with the project's scene builder and water module.

``python -m blendgen.blender.oracle_scenes SPEC.json`` renders one scene and prints
one JSON line: the image mean/std (linear RGB) and the medium's coefficients as
read back from the material. SPEC keys:

- ``water``: a ``plan.water_volume``-style dict (sigma_a, sigma_s, phase, g, ...,
  box_min, box_max), or null for no medium;
- ``camera``: ``{"ortho_scale": m, "z": m, "clip_start": m, "pitch_deg": 0}`` -- an
  orthographic camera at (0, 0, z) looking along +x, tilted ``pitch_deg`` up (negative: down);
- ``target``: ``{"kind": "emitter"|"black"|"grey", "x": m, "radiance": 1, "albedo": 0.5}`` -- a large plane
  at x facing -x; the emitter is seen by the camera only (hidden from scatter rays,
  never sampled as a light);
- ``sun``: ``{"direction": [..], "strength": E}`` or null;
- ``render``: ``{"width", "height", "samples", "volume_bounces", "seed"}``.
"""

from __future__ import annotations

import json
import math
import os
import sys


def build(spec: dict):
    import bpy

    from blendgen.blender import materials, render, water
    from blendgen.blender import scene as scn

    sc = scn.reset()
    world = bpy.data.worlds.new("black")
    sc.world = world
    materials.world_color(world, [0.0, 0.0, 0.0])
    mat = None
    if spec.get("water"):
        obj = water.add_water_volume(spec["water"])
        mat = obj.data.materials[0]
    t = spec["target"]
    h = 50.0
    x = float(t["x"])
    plane = scn.mesh_object("target", [(x, -h, -h), (x, h, -h), (x, h, h), (x, -h, h)], [(0, 3, 2, 1)], index=1)
    if t["kind"] == "emitter":
        plane.data.materials.append(materials.emission("target", [1.0, 1.0, 1.0], float(t.get("radiance", 1.0))))
        scn.camera_only(plane)
    else:  # "black" or "grey" (albedo t["albedo"])
        a = float(t.get("albedo", 0.0))
        plane.data.materials.append(materials.diffuse("target", [a, a, a]))
    if spec.get("sun"):
        scn.add_sun("sun", spec["sun"]["direction"], spec["sun"]["strength"])
    c = spec["camera"]
    data = bpy.data.cameras.new("camera")
    data.type = "ORTHO"
    data.ortho_scale = float(c.get("ortho_scale", 0.1))
    data.clip_start = float(c.get("clip_start", 0.001))
    data.clip_end = 1000.0
    cam = bpy.data.objects.new("camera", data)
    sc.collection.objects.link(cam)
    sc.camera = cam
    cam.location = (0.0, 0.0, float(c.get("z", 0.0)))
    pitch = math.radians(float(c.get("pitch_deg", 0.0)))
    cam.rotation_euler = (math.pi / 2 + pitch, 0.0, -math.pi / 2)  # -Z view axis -> (cos p, 0, sin p)
    r = spec["render"]
    sc.render.resolution_x, sc.render.resolution_y = int(r["width"]), int(r["height"])
    sc.render.resolution_percentage = 100
    render.setup_cycles(
        sc,
        {
            "samples": r["samples"],
            "seed": r.get("seed", 0),
            "threads": r.get("threads", 0),
            "max_bounces": 0,
            "volume_bounces": 0,
        },
    )
    water.reference_settings(sc, int(r.get("volume_bounces", 0)))
    return sc, mat


def run(spec: dict) -> dict:
    import bpy
    import numpy as np

    from blendgen.blender import render, water

    sc, mat = build(spec)
    path = os.path.join(render.scratch_dir(), f"dockbench-oracle-{os.getpid()}.exr")
    sc.render.filepath = path
    try:
        bpy.ops.render.render(write_still=True)
        rgb = render.read_passes(path)["rgb"].astype(np.float64)
    finally:
        if os.path.exists(path):
            os.remove(path)
    px = rgb.reshape(-1, 3)
    return {
        "mean": px.mean(axis=0).tolist(),
        "std": px.std(axis=0).tolist(),
        "n_px": int(px.shape[0]),
        "coefficients": water.coefficients_of(mat) if mat is not None else None,
        "volume_bounces": sc.cycles.volume_bounces,
    }


def main(argv: list[str]) -> int:
    spec = json.loads(open(argv[1]).read())
    fd = os.dup(1)  # keep our stdout; Blender's render log -> /dev/null
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    try:
        out = run(spec)
    finally:
        os.dup2(fd, 1)
    sys.stdout.write(json.dumps(out) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
