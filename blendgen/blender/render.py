"""Camera, Cycles settings and rendering one frame to in-memory passes.

A frame is rendered to an uncompressed multilayer EXR in a scratch directory
(``/dev/shm`` when present) and read back with OpenImageIO:
``rgb`` (H,W,3) float32 linear, ``depth_z`` (H,W) float32 planar depth in metres
(inf where no surface), ``index`` (H,W) uint8 object index.
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
import re

import bpy
import numpy as np
import OpenImageIO as oiio

from blendgen.geometry import blender_matrix_world_from_T_world_cam

NO_SURFACE_Z = 1e9  # Cycles writes ~1e10 where a ray escapes


def setup_camera(scene: bpy.types.Scene, cam: dict) -> bpy.types.Object:
    """Perspective camera, horizontal sensor fit, FOV and shift from the description."""
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.angle = float(cam["hfov_rad"])
    data.shift_x = float(cam.get("shift_x", 0.0))
    data.shift_y = float(cam.get("shift_y", 0.0))
    data.clip_start = float(cam.get("clip_start", 0.01))
    data.clip_end = float(cam.get("clip_end", 1000.0))
    obj = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(obj)
    scene.camera = obj
    scene.render.resolution_x = int(cam["width"])
    scene.render.resolution_y = int(cam["height"])
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    return obj


def setup_cycles(scene: bpy.types.Scene, r: dict) -> None:
    """Cycles on CPU: samples, bounces, threads, persistent data, only the passes read."""
    scene.render.engine = "CYCLES"
    exr_io_in_calling_thread()
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = int(r["samples"])
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    specular = int(r.get("specular_bounces", 0))  # the water surface (reference fidelity)
    cy.max_bounces = max(int(r.get("max_bounces", 0)), specular)
    cy.diffuse_bounces = int(r.get("diffuse_bounces", 0))  # light that bounces off walls and floor
    cy.glossy_bounces = cy.transmission_bounces = specular
    cy.volume_bounces = int(r.get("volume_bounces", 0))
    cy.caustics_reflective = cy.caustics_refractive = False
    cy.seed = int(r.get("seed", 0))
    # one sun and unsampled LEDs (fast fidelity): the light tree only adds work per sample
    # (same image; bench render-settings); reference fidelity samples LEDs and lamps with it
    cy.use_light_tree = bool(r.get("light_tree", True))
    # A box filter one pixel wide integrates each pixel's own area, as a sensor with
    # 100% fill factor does; Blackman-Harris 1.5 px blurs edges, and after the sRGB
    # encode that blur pulls dark-square corners ~0.3 px inward.
    cy.pixel_filter_type = "BOX"
    cy.filter_width = float(r.get("filter_width", 1.0))
    scene.render.use_persistent_data = True
    if r.get("threads"):
        scene.render.threads_mode = "FIXED"
        scene.render.threads = int(r["threads"])
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.use_pass_object_index = True
    vl.use_pass_diffuse_color = bool(r.get("albedo_pass"))  # the ambient and lamp terms' albedo
    vl.use_pass_normal = bool(r.get("normal_pass"))  # the fast lamp's incidence (world frame)
    if r.get("sun_pass") and "sun" not in vl.lightgroups:  # the sun's own light: what caustics refocus
        vl.lightgroups.add(name="sun")
    s = scene.render.image_settings
    s.media_type = "MULTI_LAYER_IMAGE"
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    s.exr_codec = "NONE"


def _loaded_libopenexr() -> str | None:
    """Path of the ``libOpenEXR`` shared library this process has loaded (Linux), or None."""
    if not os.path.exists("/proc/self/maps"):
        return None
    with open("/proc/self/maps") as fh:
        paths = {line.split()[-1] for line in fh if "/libOpenEXR" in line}
    return next((p for p in sorted(paths) if re.search(r"/libOpenEXR(-[\d_]+)?\.so", p)), None)


@functools.cache
def _openexr_function(mangled_tail: str):
    """The ctypes function ``Imf_3_<minor>::...`` of the loaded ``libOpenEXR`` whose Itanium
    mangled name ends with ``mangled_tail`` (the namespace carries the library's version,
    tried from 3.12 down), or None."""
    lib = _loaded_libopenexr()
    if lib is None:
        return None
    handle = ctypes.CDLL(lib)
    return next(
        (
            f
            for f in (getattr(handle, f"_ZN7Imf_3_{minor}{mangled_tail}", None) for minor in range(12, -1, -1))
            if f is not None
        ),
        None,
    )


def exr_io_in_calling_thread() -> bool:
    """Make OpenEXR read and write in the calling thread (its global thread count 0).

    Blender starts OpenEXR with a pool of one thread per core, and an uncompressed EXR is
    one task per scanline: each frame's write then hands ~250 tasks between the render
    thread and the pool (measured, one 320x240 frame: ~590 context switches and ~3 ms
    of kernel time, more when the workers share the cores). The pixels are identical.
    The call goes through ctypes to the ``libOpenEXR`` that bpy loaded. Returns False,
    changing nothing, when the library or the symbol is not found (another build of bpy)."""
    fn = _openexr_function("20setGlobalThreadCountEi")
    if fn is None:
        return False
    fn.argtypes = [ctypes.c_int]
    fn(0)
    return True


def exr_thread_count() -> int | None:
    """OpenEXR's global thread count in this process (None: library or symbol not found)."""
    fn = _openexr_function("17globalThreadCountEv")
    return None if fn is None else int(fn())


def scratch_dir() -> str:
    """Fast scratch space for the per-frame EXR."""
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else "/tmp"


def read_passes(path: str) -> dict:
    """Read a multilayer EXR written by :func:`render_frame` into numpy arrays: numpy views
    over the file's bytes (:mod:`blendgen.blender.exr`, same values, ~4x less CPU than
    OpenImageIO) when it is the uncompressed float32 EXR the worker writes, else OpenImageIO."""
    from blendgen.blender import exr

    parts = exr.read_channels(path)
    if parts is None:
        return read_passes_oiio(path)
    out = {}
    for chans in parts:
        names = list(chans)
        _add_pass(
            out,
            names,
            lambda n, c: (
                np.stack([chans[names[i]] for i in range(n)], axis=-1)
                if c is None
                else np.stack([chans[_ending(names, e)] for e in c], axis=-1)
            ),
        )
    return out


def _ending(names: list[str], end: str) -> str:
    return next(n for n in names if n.endswith(end))


def _add_pass(out: dict, names: list[str], channels) -> None:
    """Add the pass held by one EXR part (channel ``names``) to ``out``. ``channels(n, ends)``
    gives (H, W, k) float32: the channels ending with ``ends`` in that order, or (``ends`` None)
    the first ``n`` channels."""
    if any(n.endswith("Combined.R") for n in names):
        out["rgb"] = np.ascontiguousarray(channels(3, (".R", ".G", ".B")), dtype=np.float32)
    elif any(n.endswith("Depth.Z") for n in names):
        z = channels(1, None)[:, :, 0].astype(np.float32)
        out["depth_z"] = np.where(z > NO_SURFACE_Z, np.inf, z).astype(np.float32)
    elif any(n.endswith("Object Index.X") for n in names):
        out["index"] = np.rint(channels(1, None)[:, :, 0]).clip(0, 255).astype(np.uint8)
    elif any(n.endswith("Combined_sun.R") for n in names):  # the "sun" light group
        out["sun"] = np.ascontiguousarray(channels(3, (".R", ".G", ".B")), dtype=np.float32)
    elif any(n.endswith(("DiffCol.R", "Diffuse Color.R")) for n in names):
        out["albedo"] = np.ascontiguousarray(channels(3, (".R", ".G", ".B")), dtype=np.float32)
    elif any(n.endswith("Normal.X") for n in names):
        out["normal"] = np.ascontiguousarray(channels(3, (".X", ".Y", ".Z")), dtype=np.float32)


def read_passes_oiio(path: str) -> dict:
    """:func:`read_passes` through OpenImageIO (any EXR it reads; the reference of the
    direct reader's test)."""
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError(f"cannot read render {path}: {oiio.geterror()}")
    out = {}
    try:
        sub = 0
        while inp.seek_subimage(sub, 0):
            names = list(inp.spec().channelnames)
            px = inp.read_image(sub, 0, 0, len(names), oiio.FLOAT)
            _add_pass(out, names, lambda n, c: px[:, :, :n])
            sub += 1
    finally:
        inp.close()
    return out


def render_frame(scene: bpy.types.Scene, cam_obj: bpy.types.Object, T_world_cam, path: str) -> None:
    """Place the camera (OpenCV pose, 4x4) and render the passes to ``path`` (EXR)."""
    from blendgen.blender.scene import set_matrix

    set_matrix(cam_obj, blender_matrix_world_from_T_world_cam(np.asarray(T_world_cam, float)))
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def hfov_rad_of(cam_obj: bpy.types.Object) -> float:
    """The horizontal FOV Blender uses (rad), for checking K."""
    d = cam_obj.data
    return 2 * math.atan(d.sensor_width / (2 * d.lens))


def _border(scene: bpy.types.Scene, box, width: int, height: int) -> None:
    """Render only the pixel box (x0, y0, x1, y1) (end-exclusive, OpenCV rows from the top);
    Blender's border is normalised with y from the bottom."""
    x0, y0, x1, y1 = box
    r = scene.render
    r.use_border = True
    r.use_crop_to_border = True
    # Blender truncates border * size to int: give whole pixels plus a small epsilon so
    # 1 - y/H = 0.99999... cannot lose a row
    frac = lambda n, size: min(1.0, (n + 1e-3) / size)  # noqa: E731
    r.border_min_x, r.border_max_x = frac(x0, width), frac(x1, width)
    r.border_min_y, r.border_max_y = frac(height - y1, height), frac(height - y0, height)


def _upsample(passes: dict, width: int, height: int) -> dict:
    """Background passes to full size: colour bilinear, depth and index nearest."""
    import cv2

    linear = {"rgb", "albedo", "normal", "sun"}
    return {
        k: cv2.resize(v, (width, height), interpolation=cv2.INTER_LINEAR if k in linear else cv2.INTER_NEAREST)
        for k, v in passes.items()
    }


def frame_boxes(frame: dict, cfg: dict) -> list | None:
    """The frame's ROI boxes (x0, y0, x1, y1), or None when the frame renders whole at
    ``samples`` (ROIs off). ``rois`` (per-marker boxes, disjoint) wins over ``roi`` (one box
    around the dock); an empty list means nothing worth samples is in view."""
    if not cfg.get("roi"):
        return None
    if "rois" in frame:
        return [tuple(b) for b in frame["rois"]]
    return [] if frame.get("roi") is None else [tuple(frame["roi"])]


def render_roi_frame(
    scene: bpy.types.Scene, cam_obj: bpy.types.Object, frame: dict, cfg: dict, width: int, height: int, path: str
) -> dict:
    """Render one frame, spending samples where the localizers look.

    Without ROIs, or when they cover more than ``roi_max_fraction`` of the image, the full
    frame is rendered at ``samples``. Otherwise the background is rendered at
    ``background_scale`` resolution with ``background_samples`` and upsampled, and each
    ROI box (:func:`frame_boxes`) at full resolution with ``samples`` is pasted over it
    (same pixel grid: the border is whole pixels). Returns full-size passes."""
    r = scene.render
    boxes = frame_boxes(frame, cfg)
    area = 0.0 if not boxes else sum((b[2] - b[0]) * (b[3] - b[1]) for b in boxes) / (width * height)
    r.use_border, r.resolution_percentage = False, 100
    scene.cycles.samples = int(cfg["samples"])
    if boxes is None or area > cfg["roi_max_fraction"]:
        render_frame(scene, cam_obj, frame["T_world_cam"], path)
        return read_passes(path)
    r.resolution_percentage = max(1, int(round(100 * cfg["background_scale"])))
    scene.cycles.samples = int(cfg["background_samples"])
    render_frame(scene, cam_obj, frame["T_world_cam"], path)
    passes = _upsample(read_passes(path), width, height)
    r.resolution_percentage = 100
    scene.cycles.samples = int(cfg["samples"])
    for x0, y0, x1, y1 in boxes:
        _border(scene, (x0, y0, x1, y1), width, height)
        render_frame(scene, cam_obj, frame["T_world_cam"], path)
        for k, v in read_passes(path).items():
            if v.shape[:2] != (y1 - y0, x1 - x0):
                raise RuntimeError(f"ROI render {v.shape[:2]} does not match the box {(x0, y0, x1, y1)}")
            passes[k][y0:y1, x0:x1] = v
    r.use_border = False
    return passes


def oracle_main(build, argv: list[str], tag: str) -> int:
    """Entry point of a one-frame oracle scene: ``python -m MODULE SPEC.json OUT.npy``.

    ``build(spec) -> scene`` builds it from the JSON spec; the linear RGB pass (H, W, 3)
    float32 is saved to OUT.npy. Blender's render log goes to /dev/null; the scratch EXR
    is removed whatever happens."""
    import json

    spec = json.loads(open(argv[1]).read())
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    save_pass(build(spec), argv[2], tag)
    return 0


def save_pass(scene: bpy.types.Scene, out: str, tag: str, key: str = "rgb", cam_obj=None, T_world_cam=None) -> None:
    """Render ``scene`` once (placing ``cam_obj`` at ``T_world_cam`` (4x4, OpenCV) when given)
    to a scratch EXR and save its pass ``key`` ((H, W, 3) float32) to ``out`` (.npy); the
    scratch file is removed whatever happens."""
    path = os.path.join(scratch_dir(), f"dockbench-{tag}-{os.getpid()}.exr")
    try:
        if cam_obj is None:
            scene.render.filepath = path
            bpy.ops.render.render(write_still=True)
        else:
            render_frame(scene, cam_obj, T_world_cam, path)
        np.save(out, read_passes(path)[key])
    finally:
        if os.path.exists(path):
            os.remove(path)


def scratch_exr(path: str, width: int, height: int, every_pass: bool) -> None:
    """Render a monkey (object index 3) at 1 spp to ``path`` as the worker's EXR (albedo and
    normal passes with ``every_pass``): input of ``bench io``."""
    from blendgen.blender import scene as scn

    sc = scn.reset()
    bpy.ops.mesh.primitive_monkey_add(location=(0, 0, 0))
    bpy.context.active_object.pass_index = 3
    cam = setup_camera(sc, {"width": width, "height": height, "hfov_rad": 1.0})
    setup_cycles(sc, {"samples": 1, "albedo_pass": every_pass, "normal_pass": every_pass})
    T = np.eye(4)
    T[:3, 3] = (0, 0, -4)
    render_frame(sc, cam, T, path)
