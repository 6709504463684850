"""Clean render passes -> what the camera delivers, plus per-frame ground truth.

Pure numpy/OpenCV (no Blender): runs inside the render worker right after each
frame, once per sequence that shares the clean render. Stages, in order:
water (fast fidelity only), lens distortion, 8-bit sRGB encode with Gaussian noise.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dataclasses import dataclass

from blendgen.pipeline import groundtruth

from blendgen.physics import particles as occlusion

from blendgen.physics import optics

from blendgen.physics import sensor
from blendgen.pipeline.plan import INDEX_PARTICLES
from blendgen.geometry import planar_depth_to_range, project, transform_points
from datasets_spec.io import save_image


def emissive_mask(index: np.ndarray, markers: list[dict]) -> np.ndarray:
    """(H,W) bool: pixels of self-lit objects (the LEDs) that depth light does not dim."""
    led = [m["object_index"] for m in markers if m["kind"] == "led_array"]
    return np.isin(index, led) if led else np.zeros(index.shape, bool)


@dataclass
class SequenceState:
    """What one output sequence carries from frame to frame: its random stream and
    its small-obstacle particles (world frame, drifting with the current)."""
    post: dict
    rng: np.random.Generator
    field: occlusion.ParticleField | None = None

    @classmethod
    def start(cls, post: dict) -> "SequenceState":
        rng = np.random.default_rng(post["seed"])
        occ = post.get("occlusion")
        field = None
        if occ:
            field = occlusion.ParticleField.sample(
                rng, occ["region_min"], occ["region_max"], n_total=occ["n_total"], r_min=occ["r_min_m"],
                r_max=occ["r_max_m"], count_dist=occ["count_dist"], n_max=occ["n_max"])
        return cls(post, rng, field)

    def advance(self) -> None:
        """Drift the particles by one frame: p += v_flow dt + eta, eta ~ N(0, sigma^2 I)."""
        if self.field is not None:
            occ = self.post["occlusion"]
            self.field = self.field.step(1.0 / self.post["fps"], occ["v_flow"], [occ["drift_sigma_m"]] * 3,
                                         self.rng)


def add_particles(passes: dict, state: SequenceState, K: np.ndarray, T_world_cam) -> tuple[dict, np.ndarray | None]:
    """Composite the sequence's particles over the clean passes, depth-tested against the
    range pass; returns passes with rgb/range of the nearest surface or particle, and
    the occluder mask (H,W) bool (None without particles)."""
    if state.field is None:
        return passes, None
    if state.post["occlusion"]["geometry"] == "blender":  # already in the render
        return passes, passes["index"] == INDEX_PARTICLES
    rgb, occ_mask, prange = occlusion.render_particles(
        passes["rgb"], passes["range_m"], state.field, K, np.asarray(T_world_cam, float),
        mode=state.post["occlusion"]["mode"])
    rng_eff = np.where(np.isfinite(prange), prange, passes["range_m"]).astype(np.float32)
    return {**passes, "rgb": rgb, "range_m": rng_eff}, occ_mask


def camera_image(passes: dict, post: dict, K: np.ndarray, markers: list[dict],
                 rng: np.random.Generator, fidelity: str, occluded: np.ndarray | None = None) -> np.ndarray:
    """Linear clean RGB (H,W,3) -> uint8 sRGB image (H,W,3) for one condition."""
    rgb = passes["rgb"]
    if fidelity == "fast":
        water, fo = optics.fast_water(post["water"], post.get("irradiance"))
        emissive = emissive_mask(passes["index"], markers)
        if occluded is not None:
            emissive &= ~occluded
        fx = float(K[0, 0])
        rgb = optics.apply_water(rgb, passes["range_m"], emissive, water, post["light_depth_m"],
                                 irradiance=fo["irradiance"], blur=fo["blur"],
                                 blur_px_per_tau=fo["blur_rad_per_tau"] * fx,
                                 blur_max_px=fo["blur_max_rad"] * fx)
    if post.get("distortion"):
        rgb = sensor.distort_image(rgb, K, post["distortion"])
    return sensor.to_uint8(rgb, post.get("noise_std", 0.0), rng)


def _polygon_area(uv: np.ndarray) -> float:
    x, y = uv[:, 0], uv[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def visible_fraction(marker: dict, T_cam_dock: np.ndarray, K: np.ndarray, index: np.ndarray,
                     occluded: np.ndarray | None = None) -> float:
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


def frame_record(frame: dict, T_world_dock: np.ndarray, markers: list[dict], K: np.ndarray,
                 width: int, height: int, index: np.ndarray) -> dict:
    """Ground truth of one frame (pose part + visible fractions from the index pass)."""
    T_wc = np.asarray(frame["T_world_cam"], float)
    gt = groundtruth.frame_truth(T_wc, T_world_dock, markers, K, width, height)
    rec = {"index": frame["index"], "t": frame["t"], "t_pose": frame["t_pose"], **gt}
    return with_visibility(rec, markers, K, index, None)


def with_visibility(rec: dict, markers: list[dict], K: np.ndarray, index: np.ndarray,
                    occluded: np.ndarray | None) -> dict:
    """Copy of a frame record with each in-view marker's visible_fraction (occluders hide)."""
    T_cd = np.asarray(rec["T_cam_dock"], float)
    out = {**rec, "markers": {k: dict(v) for k, v in rec["markers"].items()}}
    for m in markers:
        entry = out["markers"][m["id"]]
        if entry["in_fov"]:
            entry["visible_fraction"] = round(visible_fraction(m, T_cd, K, index, occluded), 6)
    return out


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
