"""Does the reference's caustic spot (``caustic_sun``) put the frame's photon map where it
belongs, with the plain sun's energy? One frame of a reference job rendered three times
with one seed: the plain sun, no sun, the caustic spot.

    python -m blendgen.blender.testing.caustic_sun_check SPEC.json OUT.npz

SPEC: ``scene`` (a reference job's scene description, its ``water_surface`` with
``caustics``), ``camera`` (``plan.JobCamera`` fields), ``render`` (``plan.render_settings``),
``frame`` (``T_world_cam`` 4x4 OpenCV pose, ``t`` s, ``index``). OUT: ``plain``, ``nosun``,
``caustic`` (H, W, 3) linear radiance, ``depth_z`` (H, W) planar depth (m, inf: nothing),
``index`` (H, W) object index, and per spot (``pool_``, ``dock_``) its photon map ``M`` (rows,
cols) and grid ``c``, ``t``, ``e1``, ``e2``, ``lo``, ``bin_m``.
The test (``tests/test_caustic_sun.py``) predicts ``caustic = plain + (plain - nosun) (M(P) - 1)``
at every pixel's world point ``P``.
"""

import json
import os
import sys

import numpy as np


def _render(sc, cam, T, path: str) -> dict:
    from blendgen.blender import render

    render.render_frame(sc, cam, T, path)
    return render.read_passes(path)


def main(spec_path: str, out: str) -> None:
    from blendgen.blender import render, world
    from blendgen.blender import scene as scn
    from blendgen.blender.caustic_sun import CausticSun

    spec = json.loads(open(spec_path).read())
    sc = scn.build(spec["scene"])
    cam = render.setup_camera(sc, spec["camera"])
    render.setup_cycles(sc, spec["render"])
    fr = spec["frame"]
    world.set_wave_time(float(fr["t"]))
    path = os.path.join(render.scratch_dir(), f"dockbench-caustic-check-{os.getpid()}.exr")
    try:
        plain = _render(sc, cam, fr["T_world_cam"], path)
        sun = sc.objects["sun"]
        strength, sun.data.energy = sun.data.energy, 0.0
        nosun = _render(sc, cam, fr["T_world_cam"], path)["rgb"]
        sun.data.energy = strength
        cs = CausticSun(sc, spec["scene"], int(spec["render"].get("threads") or 0))
        Ms = cs.update(int(fr["index"]))
        caustic = _render(sc, cam, fr["T_world_cam"], path)["rgb"]
    finally:
        if os.path.exists(path):
            os.remove(path)
    layers = {}
    for layer, M in zip(cs.layers, Ms):
        g, name = layer.grid, layer.name
        layers.update(
            {
                f"{name}_{k}": v
                for k, v in (
                    ("M", M),
                    ("c", g.c),
                    ("t", g.t),
                    ("e1", g.e1),
                    ("e2", g.e2),
                    ("lo", g.lo),
                    ("bin_m", g.bin_m),
                )
            }
        )
    np.savez(
        out, plain=plain["rgb"], nosun=nosun, caustic=caustic, depth_z=plain["depth_z"], index=plain["index"], **layers
    )


if __name__ == "__main__":
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    main(sys.argv[1], sys.argv[2])
