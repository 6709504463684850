"""Clean render passes -> what the camera delivers, plus per-frame ground truth.

Pure numpy/OpenCV (no Blender): runs inside the render worker right after each
frame, once per sequence that shares the clean render. Stages, in order:
small-obstacle particles (lit by the light field, lamps and LEDs; depth-tested);
water and light with depth (fast fidelity only; ``physical`` or ``article`` mode;
in physical mode also caustics, the water surface seen from below, the calibrated veil
of the frame, the LEDs' light on nearby surfaces and the vehicle lamps' light and
backscatter, each skipped when off), motion blur over the exposure, lens distortion (of every written pass alike, so the
ground truth stays aligned), then the sensor (EMVA 1288: electrons, blooming, shot and
read noise, full well, gain, response curve, 8 bits).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from blendgen.geometry import planar_depth_to_range, project, transform_points
from blendgen.physics.camera import sensor
from blendgen.physics.light import lamp_water, leds
from blendgen.physics.light.sources import lamp_lights
from blendgen.physics.particles import field as occlusion
from blendgen.physics.water import optics
from blendgen.pipeline import groundtruth, particle_light
from blendgen.pipeline.frameshare import CLEAN
from blendgen.pipeline.plan import INDEX_PARTICLES, SequencePost
from blendgen.pipeline.stagetimer import term
from datasets_spec.io import save_image


def emissive_mask(index: np.ndarray, markers: list[dict]) -> np.ndarray:
    """(H,W) bool: pixels of self-lit objects (the LEDs) that depth light does not dim."""
    led = [m["object_index"] for m in markers if m["kind"] == "led_array"]
    if len(led) == 1:  # one array (the article's dock): a compare, ~8x cheaper than isin
        return index == led[0]
    return np.isin(index, led) if led else np.zeros(index.shape, bool)


@dataclass
class SequenceState:
    """What one output sequence carries from frame to frame: its typed processing, its
    random stream, its small-obstacle particles (world frame, drifting with the current)
    and its water model (built once, not per frame)."""

    post: SequencePost
    rng: np.random.Generator
    field: occlusion.ParticleField | None = None
    water: optics.WaterOptics | None = None
    water_opts: dict = dataclasses.field(default_factory=dict)
    camera: sensor.SensorModel = dataclasses.field(default_factory=sensor.SensorModel)
    auto_exposure: sensor.AutoExposure | None = None
    exposure_s: float | None = None  # the exposure of the last image (recorded with auto-exposure)
    lamp: lamp_water.LampWater | None = None
    prev_pose: tuple | None = None  # (t s, T_world_cam) of the last frame (particle streaks)

    @classmethod
    def start(cls, post: SequencePost) -> SequenceState:
        rng = np.random.default_rng(post.seed)
        occ = post.occlusion
        pfield = None
        if occ:
            pfield = occlusion.ParticleField.sample(
                rng,
                occ.region_min,
                occ.region_max,
                n_total=occ.n_total,
                r_min=occ.r_min_m,
                r_max=occ.r_max_m,
                count_dist=occ.count_dist,
                n_max=occ.n_max,
                size_dist=occ.size_dist,
                size_slope=occ.size_slope,
            )
        water, opts = optics.fast_water(post.water, post.image_formation, post.irradiance_w_m2, veil=post.veil)
        ae = post.sensor.auto_exposure
        auto = sensor.AutoExposure(**ae.model_dump()) if ae is not None else None
        lamp = (
            lamp_water.LampWater.build(
                lamp_lights(post.lamps), water, post.lamp_forward_kept, post.lamp_shadows is not False
            )
            if post.lamps
            else None
        )
        return cls(post, rng, pfield, water, opts, sensor_model(post), auto, lamp=lamp)

    def advance(self) -> None:
        """Drift the particles by one frame: p += v_flow dt + eta, eta ~ N(0, sigma^2 I)."""
        if self.field is not None:
            occ = self.post.occlusion
            self.field = self.field.step(1.0 / self.post.fps, occ.v_flow, [occ.drift_sigma_m] * 3, self.rng)


@term("particles")
def add_particles(
    passes: dict,
    state: SequenceState,
    K: np.ndarray,
    T_world_cam,
    markers: list[dict] | None = None,
    T_cam_dock=None,
    t_s: float | None = None,
    water_after: bool = True,
) -> tuple[dict, np.ndarray | None]:
    """Composite the sequence's particles over the clean passes, depth-tested against the
    range pass; returns passes with rgb/range of the nearest surface or particle, and
    the occluder mask (H,W) bool (None without particles). ``lit`` particles take their
    radiance from the light field (the LEDs need ``markers`` and ``T_cam_dock``) and are
    blurred by defocus and motion relative to the camera's pose at the previous call, ``t_s``
    the frame time (s; None: one frame period later) (pipeline/particle_light.py).
    ``water_after``: the fast water model runs on the result (fast fidelity): partly covered
    pixels then get the exact two-layer composite (particle_light.background_transfer)."""
    if state.field is None:
        return passes, None
    if state.post.occlusion.geometry == "blender":  # already in the render
        return passes, passes["index"] == INDEX_PARTICLES
    T = np.asarray(T_world_cam, float)
    kw = {"mode": state.post.occlusion.mode}
    if state.post.occlusion.mode == "lit":
        kw = {
            "shade": particle_light.shader(state.post, state.water, T, markers, T_cam_dock, state.lamp),
            "blur": particle_light.shaper(state.post, K, T, state.prev_pose, t_s),
        }
    if water_after:
        kw["background"] = _particle_background(state, K, T)
    rgb, occ_mask, rng_eff = occlusion.render_particles(
        passes["rgb"], passes["range_m"], state.field, K, T, merged_range=True, **kw
    )
    state.prev_pose = (t_s, T)
    return {**passes, "rgb": rgb, "range_m": rng_eff}, occ_mask


def _particle_background(state: SequenceState, K: np.ndarray, T: np.ndarray):
    """particle_light.background_transfer with the water, veil and depth that :func:`water_image`
    will use on this frame (same frame veil, same per-pixel depth along each ray)."""
    post, water = state.post, state.water
    physical = post.image_formation == "physical"
    if not physical:
        return particle_light.background_transfer(water, water.B_inf, False)
    cam_depth = max(float(post.surface_z_m - T[2, 3]), 0.0)
    veil_depth = cam_depth
    if state.water_opts.get("veil"):
        water, veil_depth = frame_veil(state, T, cam_depth), 0.0
    B = water.B_inf * state.water_opts["irradiance"] * optics.depth_light(water, veil_depth)
    return particle_light.background_transfer(water, B, True, K, T, cam_depth)


@functools.lru_cache(maxsize=4)
def _unit_rays(K_t: tuple, width: int, height: int) -> np.ndarray:
    """(H, W, 3) float32 unit ray directions (camera frame) through each pixel centre."""
    K = np.array(K_t).reshape(3, 3)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    d = np.dstack([x, y, np.ones_like(x)])
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    d = d.astype(np.float32)
    d.setflags(write=False)
    return d


def surface_depth(range_m: np.ndarray, K: np.ndarray, T_world_cam, surface_z_m: float) -> tuple[np.ndarray, float]:
    """Depth below the water surface (m, >= 0) of the surface each pixel sees, and the camera's.

    range_m (H, W) along the ray (inf: nothing hit -> the camera's depth); T_world_cam
    4x4 (OpenCV camera, world z up); surface_z_m the world z of the water surface.
    Returns ((H, W) float32, camera depth float)."""
    T = np.asarray(T_world_cam, float)
    h, w = range_m.shape
    rays = _unit_rays(tuple(np.asarray(K, float).ravel()), w, h)
    dir_z = rays @ T[2, :3].astype(np.float32)  # world z of each unit ray
    cam_depth = max(float(surface_z_m - T[2, 3]), 0.0)
    r = np.where(np.isfinite(range_m), range_m, 0.0).astype(np.float32)
    depth = np.float32(surface_z_m - T[2, 3]) - r * dir_z
    return np.maximum(depth, np.float32(0.0)), cam_depth


@term("led_light")
def led_light(
    passes: dict, state: SequenceState, K: np.ndarray, T_world_cam, markers: list[dict], T_world_dock
) -> np.ndarray | None:
    """Fast fidelity, physical mode: radiance (H,W,3) the dock's LEDs put on the surfaces the
    camera sees (``physics/light/leds.surface_radiance``), before the view path's attenuation; None
    (no cost) without LEDs, without the albedo pass, in article mode or when it is negligible."""
    arrays = [m for m in markers if m["kind"] == "led_array" and "intensity_w_sr" in m]
    if not arrays or T_world_dock is None or "albedo" not in passes or state.post.image_formation != "physical":
        return None
    T_cd = np.linalg.inv(np.asarray(T_world_cam, float)) @ np.asarray(T_world_dock, float)
    lights = [li for m in arrays for li in leds.led_lights(m, T_cd)]
    h, w = passes["range_m"].shape
    rays = _unit_rays(tuple(np.asarray(K, float).ravel()), w, h)
    return leds.surface_radiance(lights, passes["range_m"], rays, passes["albedo"], state.water.c)


@term("water")
def water_image(
    passes: dict,
    state: SequenceState,
    K: np.ndarray,
    T_world_cam,
    markers: list[dict],
    occluded: np.ndarray | None = None,
    T_world_dock=None,
    t: float = 0.0,
    memo: dict | None = None,
) -> np.ndarray:
    """Fast fidelity: the clean linear render (H,W,3) seen through the condition's water
    with light at depth, in the sequence's image-formation mode (optics module docstring);
    in physical mode plus the LEDs' light on nearby surfaces (:func:`led_light`), attenuated
    along the view ray only. ``memo``: the frame's water-independent parts, shared by the
    sequences that see these very passes (``FrameShare.memo``; None: nothing shared)."""
    post = state.post
    emissive = emissive_all = emissive_mask(passes["index"], markers)
    if occluded is not None:
        emissive = emissive & ~occluded
        if "sun" in passes:  # a particle in front hides the sunlit surface behind it
            passes = {**passes, "sun": np.where(occluded[..., None], np.float32(0), passes["sun"])}
    fx = float(K[0, 0])
    water = state.water
    if post.image_formation == "physical":
        depth, veil_depth = surface_depth(passes["range_m"], K, T_world_cam, post.surface_z_m)
        if state.water_opts.get("veil"):  # calibrated veil at this camera depth and view elevation
            water, veil_depth = frame_veil(state, T_world_cam, veil_depth), 0.0
    else:
        depth, veil_depth = post.light_depth_m, None
    rgb, range_m = passes["rgb"], passes["range_m"]
    if post.world is not None and post.image_formation == "physical":
        rgb, range_m, depth = _world(
            passes, state, water, K, T_world_cam, depth, veil_depth, t, emissive, memo, (occluded, emissive_all)
        )
    img = optics.apply_water(
        rgb,
        range_m,
        emissive,
        water,
        depth,
        model=post.image_formation,
        veil_depth_m=veil_depth,
        irradiance=state.water_opts["irradiance"],
        blur=state.water_opts["blur"],
        blur_px_per_tau=optics.BLUR_RAD_PER_TAU * fx,
        blur_max_px=optics.BLUR_MAX_RAD * fx,
        glow_fx=fx if state.water_opts.get("glow", True) else None,
    )
    lit = led_light(passes, state, K, T_world_cam, markers, T_world_dock)
    if lit is not None:
        lit *= optics.transmittance(state.water, passes["range_m"]).reshape(lit.shape)
        img += lit
    if state.lamp is not None:  # no lamp: no call, no cost
        img += lamp_image(passes, state.lamp, K, T_world_cam)
    return img


def frame_veil(state: SequenceState, T_world_cam, cam_depth_m: float) -> optics.WaterOptics:
    """The sequence's water with ``B_inf`` = the calibrated veil (per unit ``E_d0``) of a camera
    at ``cam_depth_m`` whose optical axis (OpenCV +z, world z up) has the frame's elevation."""
    import math

    axis_z = float(np.asarray(T_world_cam, float)[2, 2])
    elev = math.asin(max(-1.0, min(1.0, axis_z)))
    post = state.post
    B = optics.veil_radiance_at(
        state.water, state.water_opts["veil"], cam_depth_m, elev, post.sun_elevation_deg, post.sun_share
    )
    return state.water.replace(B_inf=np.clip(B, *optics.B_INF_RANGE))


def _world(
    passes: dict,
    state: SequenceState,
    w: optics.WaterOptics,
    K,
    T_world_cam,
    depth,
    veil_depth: float,
    t: float,
    emissive=None,
    memo: dict | None = None,
    occluders: tuple | None = None,
):
    """Caustics (not on the ``emissive`` pixels: an LED's light is not sunlight), then the
    surface seen from below (``pipeline/world_post.py``) in water ``w`` (the frame's veil);
    (rgb, range, depth). ``memo``: the frame's dict of water-independent parts (shared by the
    sequences that see the frame's own passes; None: nothing shared). ``occluders``: (mask
    (H, W) bool or None, emitter mask of the frame's own passes) of a sequence with particles,
    whose ``memo`` is the frame's (:meth:`FrameShare.frame_memo`): it shares the caustic and
    surface geometry made from the frame's own passes, applied where no particle is in front."""
    from blendgen.pipeline import world_post

    wp, z = state.post.world, state.post.surface_z_m
    memo = {} if memo is None else memo
    occluded = None if occluders is None else occluders[0]
    clean = memo.get(CLEAN) if occluded is not None else None  # the frame's own passes (particles)
    # where the water-independent geometry is kept: the frame's memo, unless it would be made
    # from this sequence's particle-composited passes (no frame memo to take the clean ones from)
    geo_memo = {} if occluded is not None and clean is None else memo
    rgb, range_m = passes["rgb"], passes["range_m"]
    h, wd = range_m.shape
    if "rays" not in memo:  # world directions of the pixels: the frame's pose
        memo["rays"] = np.einsum(
            "ijk,lk->ijl",
            _unit_rays(tuple(np.asarray(K, float).ravel()), wd, h),
            np.asarray(T_world_cam, float)[:3, :3].astype(np.float32),
        )  # einsum: @ is slower here
    rays = memo["rays"]
    if wp.caustics:
        key = ("caustics", z, wp.model_dump_json(), t)
        if key not in geo_memo:  # the same for every water of this frame
            if clean is None:  # this sequence's own passes (those of the frame, or no frame memo)
                p, d, em = passes, depth, emissive
            else:  # the frame's own passes, as every sequence without particles makes them
                p, em, d = clean, occluders[1], _clean_depth(memo, K, T_world_cam, z)
            geo_memo[key] = world_post.caustic_geometry(
                p["rgb"], p.get("albedo"), p["range_m"], d, wp, rays, K, T_world_cam, t, em, p.get("sun")
            )
        rgb = world_post.shade_caustics(rgb, geo_memo[key], float(np.mean(w.sigma_s)), float(w.g), occluded)
    if wp.surface:
        veil = w.B_inf * state.water_opts["irradiance"] * optics.depth_light(w, veil_depth)
        below = mirror_fill(rgb, range_m, depth, w, veil)
        key = ("surface", z, wp.model_dump_json(), t)
        if key not in geo_memo:  # the same for every water of this frame
            r, d = (range_m, depth) if clean is None else (clean["range_m"], _clean_depth(memo, K, T_world_cam, z))
            geo_memo[key] = world_post.surface_geometry(r, d, wp, rays, K, T_world_cam, z, t)
        geo = geo_memo[key] if clean is None or geo_memo[key] is None else geo_memo[key].seen_past(range_m)
        rgb, range_m, depth = world_post.shade_surface(rgb, range_m, depth, geo, wp, below)
    return rgb, range_m, depth


def _clean_depth(memo: dict, K, T_world_cam, surface_z_m: float) -> np.ndarray:
    """(H, W) :func:`surface_depth` of the frame's own range pass (``memo[CLEAN]``), made once
    per frame and surface height (kept in ``memo``)."""
    key = ("clean_depth", surface_z_m)
    if key not in memo:
        memo[key] = surface_depth(memo[CLEAN]["range_m"], K, T_world_cam, surface_z_m)[0]
    return memo[key]


@term("surface")
def mirror_fill(rgb: np.ndarray, range_m: np.ndarray, depth, w: optics.WaterOptics, veil) -> np.ndarray:
    """Radiance (3,) the surface reflects where its mirror image is not in the frame: the
    scene below seen through water. The frame's surfaces (clean ``rgb`` (H,W,3) dimmed by the
    depth light at their own ``depth`` (H,W) m), averaged, carried over their median range L
    and veiled: ``mean(J_lit) exp(-c L) + veil (1 - exp(-c L))``. Only the ``veil`` (3,) when
    the frame holds no surface (open water looking up): the depths below are dark water.
    Without it a pool's total reflection showed black blotches in clear water. The mean and
    median are taken over every 4th pixel in x and y (a frame-wide statistic)."""
    rgb, depth, range_m = rgb[::4, ::4], np.broadcast_to(depth, range_m.shape)[::4, ::4], range_m[::4, ::4]
    hit = np.isfinite(range_m)
    if not hit.any():
        return np.asarray(veil, np.float32)
    lit = rgb[hit] * optics.depth_light(w, depth[hit])
    tr = np.exp(-np.asarray(w.c, float) * float(np.median(range_m[hit])))
    return (lit.mean(axis=0) * tr + np.asarray(veil, float) * (1.0 - tr)).astype(np.float32)


@term("lamp")
def lamp_image(passes: dict, lamp: lamp_water.LampWater, K: np.ndarray, T_world_cam) -> np.ndarray:
    """Fast fidelity: what the vehicle's lamps add to the camera image (H, W, 3): lamp-lit
    surfaces (albedo pass, normal pass rotated into the camera frame) and the backscatter
    veil (:mod:`blendgen.physics.light.lamp_water`)."""
    rng = passes["range_m"]
    h, w = rng.shape
    rays = _unit_rays(tuple(np.asarray(K, float).ravel()), w, h)
    albedo = passes.get("albedo")
    if albedo is None:
        albedo = np.zeros((h, w, 3), np.float32)
    normals = passes.get("normal")
    if normals is not None:  # world -> camera: n_cam = R^T n_world
        normals = normals @ np.asarray(T_world_cam, float)[:3, :3].astype(np.float32)
    return lamp_water.lamp_radiance(lamp, K, rays, rng, albedo, normals)


def sensor_model(post: SequencePost) -> sensor.SensorModel:
    """The sequence's camera sensor, the same in both image-formation modes (noise and blooming
    as resolved in ``post.sensor``: config/effective.py); a null exposure (a post built without
    ``plan.resolved_sensor``) as the exposure of a dock without LEDs."""
    s = post.sensor
    exposure = (
        s.exposure_s
        if s.exposure_s is not None
        else sensor.beacon_exposure_s(0.0, s.full_well_e, s.responsivity_e_per_s)
    )
    return sensor.SensorModel(
        exposure_s=exposure,
        responsivity_e_per_s=s.responsivity_e_per_s,
        full_well_e=s.full_well_e,
        read_noise_e=s.read_noise_e,
        gain=s.gain,
        noise=s.noise,
        response=s.response,
        bloom_fraction=s.bloom_fraction,
        bloom_sigma_px=s.bloom_sigma_px,
        noise_std=post.noise_std,
        dark_current_e_per_s=s.dark_current_e_per_s,
    )


def camera_image(
    passes: dict,
    state: SequenceState,
    K: np.ndarray,
    frame: dict,
    markers: list[dict],
    fidelity: str,
    occluded: np.ndarray | None = None,
    T_world_dock=None,
    memo: dict | None = None,
) -> np.ndarray:
    """Linear clean RGB (H,W,3) -> uint8 image (H,W,3) for one condition; ``frame`` is the
    planned frame (``T_world_cam``, optional ``blur_px`` motion over the exposure);
    ``T_world_dock`` places the LEDs that light nearby surfaces (None: they light nothing);
    ``memo``: :func:`water_image`'s."""
    rgb = passes["rgb"]
    if fidelity == "fast":
        rgb = water_image(
            passes, state, K, frame["T_world_cam"], markers, occluded, T_world_dock, float(frame.get("t", 0.0)), memo
        )
    with term("sensor"):
        if frame.get("blur_px") is not None:
            rgb = sensor.motion_blur(rgb, frame["blur_px"])
        if state.post.distortion:
            rgb = sensor.distort_image(rgb, K, state.post.distortion)
        img = state.camera.apply(rgb, state.rng)
        state.exposure_s = state.camera.exposure_s
        if state.auto_exposure is not None:  # the AE loop sets the next frame's exposure
            t = state.auto_exposure.next_exposure(rgb, state.camera.exposure_s, state.camera, 1.0 / state.post.fps)
            state.camera = dataclasses.replace(state.camera, exposure_s=t)
    return img


def output_passes(passes: dict, K: np.ndarray, distortion) -> dict:
    """The passes as written next to a distorted image: index and range remapped with the
    same lens map (nearest: labels and depths are not blended), so every pass stays aligned
    with the RGB image. Without distortion, the passes themselves."""
    if not distortion:
        return passes
    out = dict(passes)
    for k in ("index", "range_m"):
        if k in passes:
            out[k] = sensor.distort_image(passes[k], K, distortion, interpolation=cv2.INTER_NEAREST)
    return out


def _polygon_area(uv: np.ndarray) -> float:
    x, y = uv[:, 0], uv[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def visible_fraction(
    marker: dict, T_cam_dock: np.ndarray, K: np.ndarray, index: np.ndarray, occluded: np.ndarray | None = None
) -> float:
    """Share of a marker the camera sees (FORMAT.md); occluded (H,W) bool hides pixels.

    LED arrays: share of LEDs whose centre pixel shows the array and is not occluded;
    square markers: visible plate pixels over the plate's projected area."""
    occluded = np.zeros(index.shape, bool) if occluded is None else occluded
    kp = np.asarray(marker["keypoints"], float)
    pts = transform_points(T_cam_dock, kp)
    if np.any(pts[:, 2] <= 0):
        return 0.0
    if marker["kind"] == "led_array":
        return occlusion.led_visible_fraction(project(K, pts), index, marker["object_index"], occluded)
    centre = kp.mean(axis=0)
    plate = centre + (kp - centre) * (marker["plate_size_m"] / marker["size_m"])
    area = _polygon_area(project(K, transform_points(T_cam_dock, plate)))
    return occlusion.visible_fraction_from_masks(index == marker["object_index"], occluded, max(area, 0.0))


@term("truth")
def frame_record(
    frame: dict,
    T_world_dock: np.ndarray,
    markers: list[dict],
    K: np.ndarray,
    width: int,
    height: int,
    index: np.ndarray,
) -> dict:
    """Ground truth of one frame (pose part + visible fractions from the index pass)."""
    T_wc = np.asarray(frame["T_world_cam"], float)
    gt = groundtruth.frame_truth(T_wc, T_world_dock, markers, K, width, height)
    rec = {"index": frame["index"], "t": frame["t"], "t_pose": frame["t_pose"], **gt}
    return with_visibility(rec, markers, K, index, None)


@term("truth")
def with_visibility(
    rec: dict, markers: list[dict], K: np.ndarray, index: np.ndarray, occluded: np.ndarray | None
) -> dict:
    """Copy of a frame record with each in-view marker's visible_fraction (occluders hide)."""
    T_cd = np.asarray(rec["T_cam_dock"], float)
    out = {**rec, "markers": {k: dict(v) for k, v in rec["markers"].items()}}
    for m in markers:
        entry = out["markers"][m["id"]]
        if entry["in_fov"]:
            entry["visible_fraction"] = round(visible_fraction(m, T_cd, K, index, occluded), 6)
    return out


def add_ambient(passes: dict, ambient_radiance: float) -> dict:
    """Fast fidelity: light of the water's diffuse light field on every surface.

    A Lambertian surface of albedo rho (the render's diffuse-colour pass, (H,W,3)) under
    a uniform radiance L reflects ``rho L``; added to the sun-lit render before the water
    model dims both by the surface's depth. Ignores occlusion of the light field (no
    ambient occlusion) and interreflection. No-op (no cost) when 0 or without the pass."""
    if ambient_radiance > 0 and "albedo" in passes:
        rgb = passes["albedo"] * np.float32(ambient_radiance)
        rgb += passes["rgb"]
        passes["rgb"] = rgb
    return passes


def add_range(passes: dict, K: np.ndarray) -> dict:
    """Add ``range_m`` (H,W) float32 along each ray from the planar depth pass."""
    passes["range_m"] = planar_depth_to_range(passes["depth_z"], K).astype(np.float32)
    return passes


def write_image(seq_dir: Path, rel: str, i: int, img: np.ndarray) -> dict:
    """Write the sequence's camera image (H,W,3) uint8 RGB as ``rgb/<i>.png``; returns the
    record's ``image`` path. Range and index passes are shared per render
    (:mod:`blendgen.pipeline.passstore`), not written per sequence."""
    name = f"{i:06d}.png"
    save_image(seq_dir / "rgb" / name, img)
    return {"image": f"{rel}/rgb/{name}"}
