"""Chessboard calibration renders: ``python -m blendgen.blender.calibration_scene JOB.json``.

One process per (resolution, trial) builds an empty scene holding one emissive
chessboard plate (no lights, black world: a noise-free render whose only Monte
Carlo error is the anti-aliasing of the cell edges) and renders every pose of the
job with persistent data. Each frame is written as an 8-bit sRGB grey PNG (what a
dataset image is) and one line is appended to the job's ``frames.jsonl`` (the
parent counts them for progress). Blender's own chatter goes to the job's log.

JOB keys (written by :func:`blendgen.tools.calibration.camera.write_job`):
``board``: {texture (PNG path, one pixel per cell), plate_size_m [w, h], black, white}
(linear radiance of the dark and light cells); ``camera``: {width, height, hfov_rad};
``render``: {samples, threads, seed}; ``frames``: [{index, T_world_cam, path}];
``progress``: jsonl path; ``log``: log path. The board frame is the world frame.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path


def build(board: dict):
    """Empty scene with a black world and the board plate in the world z = 0 plane
    (facing +z, texture top row at +y); returns the scene."""
    import bpy

    from blendgen.blender import materials
    from blendgen.blender import scene as scn

    sc = scn.reset()
    world = bpy.data.worlds.new("black")
    sc.world = world
    materials.world_color(world, [0.0, 0.0, 0.0])
    w, h = (float(x) / 2 for x in board["plate_size_m"])
    v = [(-w, h, 0), (w, h, 0), (w, -h, 0), (-w, -h, 0)]
    uvs = [(0, 1), (1, 1), (1, 0), (0, 0)]
    obj = scn.mesh_object("chessboard", v, [(0, 3, 2, 1)], uvs=[uvs[i] for i in (0, 3, 2, 1)], index=1)
    obj.data.materials.append(
        materials.emissive_texture("chessboard", board["texture"], board["black"], board["white"])
    )
    return sc


def run(job: dict) -> dict:
    import cv2

    from blendgen.blender import render
    from blendgen.physics.camera import sensor

    t0 = time.perf_counter()
    sc = build(job["board"])
    cam = render.setup_camera(sc, job["camera"])
    render.setup_cycles(sc, {**job["render"], "max_bounces": 0})
    vl = sc.view_layers[0]
    vl.use_pass_z = vl.use_pass_object_index = False
    times = {"scene_build": time.perf_counter() - t0, "render": []}
    exr = os.path.join(render.scratch_dir(), f"dockbench-calib-{os.getpid()}.exr")
    try:
        with open(job["progress"], "w") as fh:
            for fr in job["frames"]:
                t1 = time.perf_counter()
                render.render_frame(sc, cam, fr["T_world_cam"], exr)
                rgb = render.read_passes(exr)["rgb"]
                gray = sensor.to_uint8(rgb[:, :, 1])
                Path(fr["path"]).parent.mkdir(parents=True, exist_ok=True)
                if not cv2.imwrite(fr["path"], gray):
                    raise RuntimeError(f"cannot write {fr['path']}")
                dt = time.perf_counter() - t1
                times["render"].append(dt)
                fh.write(json.dumps({"index": fr["index"], "path": fr["path"], "seconds": dt}) + "\n")
                fh.flush()
    finally:
        if os.path.exists(exr):
            os.remove(exr)
    return times


def main(argv: list[str]) -> int:
    from blendgen.workerio import quiet_stdout

    job = json.loads(Path(argv[1]).read_text())
    quiet_stdout(job.get("log", os.devnull))
    times = run(job)
    if job.get("timing_out"):
        Path(job["timing_out"]).write_text(json.dumps(times))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
