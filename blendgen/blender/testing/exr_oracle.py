"""Oracle for the direct EXR reader: ``python -m blendgen.blender.testing.exr_oracle OUT.exr BORDER_JSON``.

Renders a 64x48 Cycles frame (a monkey with object index 3 under a sun in the "sun" light group
and a fill outside it, every pass the worker can ask for: albedo, normal and the sun's light
group too; ``BORDER_JSON`` null for the whole frame or [x0, x1, y0, y1] in 0..1 for an
ROI crop) to ``OUT.exr`` as the render worker writes it, then checks that
:func:`blendgen.blender.exr.read_channels` takes it and that :func:`render.read_passes` equals
OpenImageIO's read bit for bit, and that the sun's pass holds its light alone (lit where the
sun reaches, below the combined light by the fill's share). Prints OpenEXR's thread count
(``exr_threads N``), then ``same H W``; exits non-zero (AssertionError) otherwise.
Run by ``tests/test_exr_read.py`` in a subprocess, so bpy stays out of the test process."""

import json
import sys

import bpy
import numpy as np

from blendgen.blender import exr, render
from blendgen.blender import scene as scn


def main(argv: list[str]) -> int:
    path, border = argv[1], json.loads(argv[2])
    sc = scn.reset()
    bpy.ops.mesh.primitive_monkey_add(location=(0, 0, 0))
    bpy.context.active_object.pass_index = 3
    scn.add_sun("sun", (0.0, 0.0, 1.0), 3.0, lightgroup="sun")  # toward the camera's side of the monkey
    scn.add_sun("fill", (1.0, 0.0, 0.0), 1.0, shadows=False)
    cam = render.setup_camera(sc, {"width": 64, "height": 48, "hfov_rad": 1.0})
    render.setup_cycles(sc, {"samples": 1, "albedo_pass": True, "normal_pass": True, "sun_pass": True})
    if border:
        r = sc.render
        r.use_border = r.use_crop_to_border = True
        r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = border
    T = np.eye(4)
    T[:3, 3] = (0, 0, -4)
    render.render_frame(sc, cam, T, path)
    assert exr.read_channels(path) is not None, "direct reader not used"
    a, b = render.read_passes(path), render.read_passes_oiio(path)
    assert sorted(a) == sorted(b) == ["albedo", "depth_z", "index", "normal", "rgb", "sun"], sorted(a)
    for k in a:
        assert (a[k].dtype, a[k].shape) == (b[k].dtype, b[k].shape) and a[k].tobytes() == b[k].tobytes(), k
    assert a["index"].max() == 3 and np.isfinite(a["depth_z"]).any()
    sun, rgb, hit = a["sun"], a["rgb"], a["index"] == 3
    assert np.all(sun <= rgb + 1e-6), "the sun's light group holds more than the combined light"
    assert (sun[hit] > 0).any() and (rgb[hit] - sun[hit] > 1e-3).any(), "no sun alone / no fill in the pass"
    h, w = a["rgb"].shape[:2]
    print("exr_threads", render.exr_thread_count())  # setup_cycles: written in the calling thread
    print("same", h, w)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
