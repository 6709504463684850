"""Config -> render jobs: what to render once, what to derive, what to skip.

A *sequence* is one (trajectory, trial, condition) and becomes one directory of
the dataset. A *render job* is one Blender process rendering one trajectory's
frames once and writing every sequence that only differs in image space
(turbidity, depth light, noise) from the same clean passes. With the reference
fidelity the water is in the render, so each condition is its own job.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from blendgen import markers as mk
from blendgen.config import effective as eff
from blendgen.config.effective import SKY_FRACTION_PHYSICAL  # noqa: F401 - re-exported
from blendgen.config.models import (
    ConfigError,
    Experiment,
    ImageFormation,
    Lamp,
    Lens,
    Occlusion,
    Sensor,
    Strict,
    Vec3,
    Water,
)
from blendgen.geometry import intrinsics_from_hfov, make_T, rpy_to_R
from blendgen.physics.surface import optics as sf
from blendgen.pipeline import groundtruth, scene_check
from blendgen.render_spec import FramePlan, Marker, RenderScene, RenderSettings
from blendgen.vehicle import trajectories as tj
from datasets_spec.io import SEQUENCE_ENDS

INDEX_POOL, INDEX_DOCK, INDEX_MARKER0, INDEX_OBSTACLE0, INDEX_PARTICLES = 1, 2, 10, 100, 250
#: Version of :class:`JobRecord`, the file a render worker reads.
JOB_RECORD_VERSION = 1
#: The camera must stay this far (m) in front of the dock's marker plane: no frame from inside the dock.
MIN_CLEARANCE_M = 0.05
#: How a sequence's camera path ends (manifest ``sequences[].end``): ``path`` its own end (a
#: kinematic path's last sample, a docking trial's stop distance or time limit), ``dock`` the
#: camera at the marker plane (:func:`until_contact`), or the face of the water the hull touched
#: (:func:`until_wall`). The dataset contract's list.
PATH_ENDS = SEQUENCE_ENDS


class OcclusionPost(Occlusion):
    """Small obstacles of one sequence: the config's, with the region resolved and the flow."""

    region_min: Vec3
    region_max: Vec3
    v_flow: Vec3


class WorldPost(Strict):
    """The surface and caustics of one sequence, resolved from ``scene.world`` (fast path:
    ``pipeline/world_post.py``; physics: ``physics/surface/optics.py``). Radiances W/m^2/sr."""

    surface: bool
    caustics: bool
    wind_mps: float
    wave_seed: int
    sky_radiance: float = Field(ge=0.0, description="uniform sky radiance above the surface")
    ambient_radiance: float = Field(ge=0.0, description="the ambient term already in the clean render")
    sun_travel_dir: Vec3 = Field(
        description="direction the sunlight travels in (world, unit, in air): the "
        "scene's in-water sun direction unrefracted"
    )
    sun_irradiance: float = Field(
        0.0,
        ge=0.0,
        description="the sun's irradiance normal to its beam above the "
        "surface (W/m^2), seen as its disc through Snell's "
        "window; 0: no sun disc",
    )
    sun_lamp_w_m2: float = Field(
        0.0,
        ge=0.0,
        description="the clean render's sun in water (W/m^2 normal to its "
        "beam): a Lambertian pixel holds at most albedo E "
        "cos(i) / pi of its light, the part caustics refocus; "
        "0: not bounded",
    )


class SequencePost(Strict):
    """Image-space processing of one sequence (typed; recorded in the manifest as its
    ``conditions``). Depths in metres below the surface, world z up, irradiance W/m^2."""

    seed: int
    fps: float
    image_formation: ImageFormation
    water: Water
    water_effective: dict | None = Field(
        None,
        description="the water's coefficients in this image formation "
        "(per channel, 1/m), the preset they come from and their provenance",
    )
    light_depth_m: float = Field(ge=0.0, description="the dock's depth: its top below the surface (the article's d)")
    surface_z_m: float = Field(description="world z of the water surface for this condition")
    irradiance_w_m2: float = Field(ge=0.0, description="downwelling irradiance just below the surface")
    noise_std: float = 0.0
    sensor: Sensor = Sensor()
    distortion: list[float] | None = None
    occlusion: OcclusionPost | None = None
    lamps: list[Lamp] = Field(default_factory=list, description="the vehicle's lamps (camera frame)")
    sun_elevation_deg: float = Field(90.0, ge=0.0, le=90.0, description="the sun's elevation (physical veil)")
    sun_share: float = Field(1.0, ge=0.0, le=1.0, description="direct sun's share of the downwelling irradiance")
    veil: dict | None = Field(
        None, description="physical mode: the calibrated veil model's numbers (optics.veil_parameters), None: not used"
    )
    world: WorldPost | None = Field(None, description="surface and caustics (None: both off, no cost)")
    lamp_forward_kept: float | None = Field(None, description="fast lamp model's F (set with lamps)")
    lamp_shadows: bool | None = Field(None, description="fast lamp model's shadow test (set with lamps)")
    lens: Lens | None = Field(None, description="thin lens (particle defocus); null: pinhole")
    suns: list[tuple[Vec3, float]] = Field(
        default_factory=list,
        description="the render's directional lights (world travel direction, W/m^2), lighting fast particles",
    )
    ambient_w_m2_sr: float = Field(
        0.0,
        ge=0.0,
        description="the render's ambient light field (fast fidelity: plan.ambient_radiance), lighting fast particles",
    )

    @model_validator(mode="after")
    def _effective_sensor(self):
        """The sensor's mode-dependent nulls (noise, blooming) resolved once, here (config/effective.py):
        the image-space stages read the values and the manifest records them."""
        self.sensor = eff.effective_sensor(self.sensor, self.image_formation)
        return self


class JobCamera(Strict):
    width: int
    height: int
    hfov_rad: float
    K: list[list[float]]


class JobTruth(Strict):
    T_world_dock: list[list[float]]
    markers: list[Marker]


class JobOutput(Strict):
    seq_dir: str
    rel: str
    post: SequencePost


class JobPasses(Strict):
    """Where a job writes the passes it shares with every sequence it feeds (FORMAT.md 1.1):
    ``rel`` the dataset-relative ``renders/<key16>`` folder, ``dirs`` the absolute temp
    folders still to fill, ``depth``/``index`` which passes are written at all."""

    rel: str
    depth: bool
    index: bool
    dirs: list[str]


class JobRecord(Strict):
    """What a render worker process is given (JSON on disk, parsed once by the worker).
    ``scene``, ``render`` and ``frames`` are :func:`scene_description`, :func:`render_settings`
    and the camera path, typed (:mod:`blendgen.render_spec`): the planner's plain data is
    validated when the record is made, the file again when the worker reads it."""

    version: Literal[1] = JOB_RECORD_VERSION
    scene: RenderScene
    fidelity: Literal["fast", "reference"]
    render: RenderSettings
    frames: list[FramePlan]
    camera: JobCamera
    gt: JobTruth
    outputs: list[JobOutput]
    passes: JobPasses | None = None
    log: str | None = None
    timing_out: str | None = None
    raw_images: list[int] = []  # frame indices whose camera images a streaming run does not keep:
    # left as raw pixels (rgb/.<i>.npy), never PNG-encoded


@dataclass
class SequencePlan:
    """One output sequence: its id, condition and the image-space processing to apply."""

    id: str
    trajectory: str
    trial: int
    condition: str
    post: SequencePost


@dataclass
class RenderJob:
    """One Blender process: a scene, a camera path, and the sequences it feeds."""

    key: str
    scene: dict
    frames: list[dict]
    sequences: list[SequencePlan] = field(default_factory=list)
    end: str = "path"  # how the camera path ends: PATH_ENDS


def camera_K(exp: Experiment) -> np.ndarray:
    """Intrinsics (3x3) exactly as Blender renders them (see geometry.intrinsics_from_hfov)."""
    c = exp.camera
    return intrinsics_from_hfov(c.width, c.height, math.radians(c.hfov_deg))


def manifest_markers(exp: Experiment) -> list[dict]:
    """Manifest marker entries plus rendering fields (object index, plate size)."""
    out = []
    for i, spec in enumerate(exp.scene.dock.markers):
        m = mk.manifest_marker(spec)
        m["object_index"] = INDEX_MARKER0 + i
        tex = mk.texture_for(spec)
        if tex is not None:
            m["plate_size_m"] = tex.plane_size_m
        out.append(m)
    return out


def _sun_dir(elev_deg: float, azim_deg: float) -> list[float]:
    """Travel direction (unit, world) of light coming from elevation/azimuth (deg)."""
    e, a = math.radians(elev_deg), math.radians(azim_deg)
    return [-math.cos(e) * math.cos(a), -math.cos(e) * math.sin(a), -math.sin(e)]


def sun_lights(exp: Experiment) -> list[tuple[list[float], float]]:
    """The render's sun and fill as (world travel direction, strength W/m^2), strength > 0."""
    s = exp.scene
    out = [
        (_sun_dir(s.sun_elevation_deg, s.sun_azimuth_deg), s.sun_strength),
        (_sun_dir(0.0, s.sun_azimuth_deg), s.fill_strength),
    ]
    return [(d, float(e)) for d, e in out if e > 0]


def scene_description(exp: Experiment, markers: list[dict], textures: dict[str, str]) -> dict:
    """Plain-data scene for the Blender builder (world frame, metres, linear colours)."""
    s = exp.scene
    T_wd = tj.T_world_dock_from_spec(s.dock)
    obstacles = []
    for i, o in enumerate(s.obstacles):
        R = rpy_to_R(*(math.radians(a) for a in o.pose.rpy_deg))
        obstacles.append(
            {
                "kind": o.kind,
                "T_world": make_T(R, o.pose.xyz).tolist(),
                "size_m": o.size_m,
                "color": o.color,
                "object_index": INDEX_OBSTACLE0 + i,
            }
        )
    desc = {
        "pool": s.pool.model_dump() if s.kind == "pool" else None,
        "dock": {"T_world_dock": T_wd.tolist(), "body_size_m": s.dock.body_size_m, "face_color": s.dock.face_color},
        "markers": [{**m, "texture": textures.get(m["id"])} for m in markers],
        "obstacles": obstacles,
        "object_index": {"pool": INDEX_POOL, "dock": INDEX_DOCK},
        "sun": {"direction": _sun_dir(s.sun_elevation_deg, s.sun_azimuth_deg), "strength": s.sun_strength},
        "fill": {"direction": _sun_dir(0.0, s.sun_azimuth_deg), "strength": s.fill_strength},
        "world_color": [0.0, 0.0, 0.0],
        "sky": sky_radiance(exp) if exp.render.fidelity == "reference" else None,
        "world": world_look(exp),
    }
    if exp.vehicle.lamps and exp.render.fidelity == "reference":  # Cycles spots on the camera
        desc["lamps"] = [lamp.model_dump(mode="json") for lamp in exp.vehicle.lamps]
    return desc


def sky_fraction(exp: Experiment) -> float:
    """Diffuse sky light as a fraction of the sun's horizontal irradiance (config, else by mode)."""
    return eff.value(exp, "scene.sky_fraction")


def sun_horizontal_irradiance(exp: Experiment) -> float:
    """Irradiance of the sun on a horizontal plane (W/m^2): strength x sin(elevation)."""
    return exp.scene.sun_strength * math.sin(math.radians(exp.scene.sun_elevation_deg))


def downwelling_irradiance(exp: Experiment) -> float:
    """E_d0 (W/m^2): sun plus sky on a horizontal plane just below the surface."""
    return sun_horizontal_irradiance(exp) * (1.0 + sky_fraction(exp))


def ambient_on(exp: Experiment) -> bool:
    return eff.value(exp, "scene.ambient")


def ambient_radiance(exp: Experiment) -> float:
    """Mean radiance of the diffuse light field just below the surface (W/m^2/sr):
    ``E_d0 / (4 pi mu_d)`` (the same light field as the fast model's veil,
    ``optics.light_field_veil``); 0 when the ambient light is off."""
    from blendgen.physics.water.optics import MEAN_COSINE_DOWN

    return downwelling_irradiance(exp) / (4.0 * math.pi * MEAN_COSINE_DOWN) if ambient_on(exp) else 0.0


def sky_radiance(exp: Experiment) -> dict | None:
    """Reference fidelity: a uniform environment (W/m^2/sr, hidden from the camera) standing
    in for the diffuse light field, the same isotropic-equivalent mean radiance the fast
    path's ambient term uses (attenuated by the medium on its way in, which the in-water
    light field is not: a known difference between the fidelities)."""
    if not ambient_on(exp):
        return None
    L = ambient_radiance(exp)
    return {"upper": L, "lower": L}


def object_index_names(markers: list[dict], exp: Experiment) -> dict[str, str]:
    """Manifest map object-index value -> name."""
    names = {"0": "background", str(INDEX_POOL): "pool", str(INDEX_DOCK): "dock"}
    names.update({str(m["object_index"]): m["id"] for m in markers})
    names.update({str(INDEX_OBSTACLE0 + i): f"obstacle_{i}" for i in range(len(exp.scene.obstacles))})
    names[str(INDEX_PARTICLES)] = "particles"
    return names


def until_contact(exp: Experiment, traj, T_wc: np.ndarray, T_wd: np.ndarray) -> int:
    """Number of leading frames with the camera at least ``MIN_CLEARANCE_M`` in front of the
    marker plane. A docking trial ends there (contact: the camera enters the dock); a
    kinematic path that gets there is a config error naming the trajectory and the fix."""
    z = (np.linalg.inv(T_wd) @ T_wc[:, :, 3].T)[2]  # camera centre, dock frame (+z out of the face)
    bad = np.flatnonzero(z < MIN_CLEARANCE_M)
    if bad.size == 0:
        return len(T_wc)
    if traj.kind == "docking":
        return int(bad[0])
    lead = exp.camera.T_body_cam.xyz[0]
    hint = (
        f"; end_range_m must be >= {lead + MIN_CLEARANCE_M:.2f} (camera {lead:g} m ahead of the body)"
        if traj.kind == "linear"
        else ""
    )
    raise ConfigError(
        f"trajectories: {traj.id!r}: the camera comes within {MIN_CLEARANCE_M} m of the dock's "
        f"marker plane (or behind it) at t = {bad[0] / exp.camera.fps:.2f} s{hint}"
    )


def until_wall(exp: Experiment, T_world_body: np.ndarray) -> tuple[int, str]:
    """Number of leading frames (poses (N, 4, 4), world +z up, body FLU) before the hull first
    touches a solid face of the water (:func:`scene_check.water_solid`, the closed loop's
    collision geometry), and that face's part (``pool_wall``, ``pool_floor``, ``seabed``; ""
    when none is touched). A docking trial that a current carries into a wall ends there, as the
    closed loop's ``collision`` does; its last rendered frame is the one before the touch."""
    from blendgen.vehicle.contact import Hull
    from blendgen.vehicle.dynamics import VehicleParams
    from blendgen.vehicle.water_clearance import frame_clearance

    if len(T_world_body) == 0:
        return 0, ""
    p, water = VehicleParams(), scene_check.water_solid(exp)
    T = np.asarray(T_world_body, float)
    clear, face = frame_clearance(T[:, :3, 3], np.abs(T[:, :3, 0]), water, Hull.from_vehicle(p.length, p.diameter))
    touch = np.flatnonzero(clear <= 0.0)
    return (int(touch[0]), water.faces[int(face[touch[0]])][2]) if touch.size else (len(T), "")


def exposure_flow(exp: Experiment, T_wc: np.ndarray, T_wd: np.ndarray) -> np.ndarray:
    """(N, 2) image motion (px) of the dock's face centre during each frame's exposure.

    The pose at ``t + exposure_s`` is interpolated between consecutive samples (position
    linearly, attitude by slerp); the last frame repeats the previous motion. One vector per
    frame: a uniform blur, exact for rotation, approximate for motion toward the dock
    (whose flow is radial)."""
    from scipy.spatial.transform import Rotation, Slerp

    K = camera_K(exp)
    a = min(resolved_sensor(exp).exposure_s * exp.camera.fps, 1.0)
    centre = T_wd[:, 3]
    flow = np.zeros((len(T_wc), 2))
    for i in range(len(T_wc) - 1):
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix([T_wc[i][:3, :3], T_wc[i + 1][:3, :3]]))
        T1 = np.eye(4)
        T1[:3, :3] = slerp(a).as_matrix()
        T1[:3, 3] = (1 - a) * T_wc[i][:3, 3] + a * T_wc[i + 1][:3, 3]
        p0, p1 = (np.linalg.inv(T) @ centre for T in (T_wc[i], T1))
        if p0[2] > 0 and p1[2] > 0:
            flow[i] = (K @ p1[:3])[:2] / p1[2] - (K @ p0[:3])[:2] / p0[2]
    if len(T_wc) > 1:
        flow[-1] = flow[-2]
    return flow


def check_before_writing(exp: Experiment) -> None:
    """Raise ConfigError for what planning would refuse, before anything is written: the
    paths (:func:`check_paths`), the world's surface and sun (:func:`world_post`), and the dock,
    camera paths and docking starts inside the water (:func:`scene_check.check_scene`)."""
    scene_check.check_scene(exp)
    check_paths(exp)
    world_post(exp)


def check_paths(exp: Experiment) -> None:
    """Raise ConfigError before anything is written if a kinematic path (linear, circle) brings
    the camera to the dock's marker plane (:func:`until_contact`; docking trials end there) or
    yields no frame (:func:`scene_check.check_frames`)."""
    T_wd = tj.T_world_dock_from_spec(exp.scene.dock)
    T_bc = tj.T_body_cam_from_spec(exp.camera.T_body_cam)
    for i, traj in enumerate(exp.trajectories):
        if traj.kind != "docking":
            smp = tj.sample(traj, T_wd, exp.camera.fps, exp.camera.latency_s, seed=0, fluid=exp.fluid)
            T_wc = smp.T_world_body @ T_bc
            n = until_contact(exp, traj, T_wc, T_wd)
            nearest = min((groundtruth.d_true(T, T_wd) for T in T_wc[:n]), default=None)
            scene_check.check_frames(exp, i, None, *_frames(exp, traj, T_wd, T_bc, 0, exp.fluid), nearest)


def _frames(
    exp: Experiment, traj, T_wd: np.ndarray, T_body_cam: np.ndarray, seed: int, fluid
) -> tuple[list[dict], str]:
    """Camera frames of one path up to contact (:func:`until_contact`, :func:`until_wall`) and
    how the path ends (:data:`PATH_ENDS`); frames farther than ``render.max_distance_m`` from
    the marker plane are skipped (they are outside the evaluation window). Indices keep the
    trajectory's sample numbering, so ``t`` stays ``index / fps``."""
    smp = tj.sample(traj, T_wd, exp.camera.fps, exp.camera.latency_s, seed=seed, fluid=fluid)
    T_wc = smp.T_world_body @ T_body_cam
    n = until_contact(exp, traj, T_wc, T_wd)
    end = "dock" if n < len(T_wc) else "path"
    if traj.kind == "docking":
        n_wall, part = until_wall(exp, smp.T_world_body[:n])
        n, end = (n_wall, part) if n_wall < n else (n, end)
    d_max = exp.render.max_distance_m
    flow = exposure_flow(exp, T_wc[:n], T_wd) if exp.camera.sensor.motion_blur else None
    frames = [
        {"index": i, "t": float(t), "t_pose": float(tp), "T_world_cam": T.tolist()}
        | ({} if flow is None else {"blur_px": flow[i].tolist()})
        for i, (t, tp, T) in enumerate(zip(smp.t[:n], smp.t_pose[:n], T_wc[:n]))
        if d_max is None or groundtruth.d_true(T, T_wd) <= d_max
    ]
    if exp.render.roi and exp.render.fidelity == "fast":
        regions = RenderRegions.of(exp)
        for f in frames:
            f.update(regions.boxes(np.asarray(f["T_world_cam"]), T_wd))
    return frames, end


@dataclass(frozen=True)
class RenderRegions:
    """Where a fast-fidelity frame spends its samples (``render.roi_regions``): one box around the
    dock, or a box per marker plate / code square and LED disc. Datasets and the closed loop both
    ask this for each frame, so a frame at the same pose renders the same boxes."""

    K: np.ndarray
    width: int
    height: int
    box: np.ndarray  # dock_corners (8,3), used for roi_regions "dock"
    regions: list | None  # marker_regions, None for roi_regions "dock"
    max_boxes: int

    @classmethod
    def of(cls, exp: Experiment) -> RenderRegions:
        regions = (
            None
            if exp.render.roi_regions == "dock"
            else marker_regions(manifest_markers(exp), quiet_zone=exp.render.roi_regions == "markers")
        )
        return cls(
            camera_K(exp), exp.camera.width, exp.camera.height, dock_corners(exp), regions, exp.render.roi_max_boxes
        )

    def boxes(self, T_world_cam: np.ndarray, T_world_dock: np.ndarray) -> dict:
        """``{"roi": box or None}`` or ``{"rois": [boxes]}`` (pixel boxes x0, y0, x1, y1) of one frame."""
        T_cd = np.linalg.inv(np.asarray(T_world_cam, float)) @ T_world_dock
        if self.regions is None:
            return {"roi": groundtruth.dock_roi(T_cd, self.K, self.width, self.height, self.box)}
        return {
            "rois": [
                list(b)
                for b in groundtruth.marker_rois(
                    T_cd, self.K, self.width, self.height, self.regions, max_boxes=self.max_boxes
                )
            ]
        }


def marker_regions(markers: list[dict], quiet_zone: bool = True) -> list[np.ndarray]:
    """What the localizers read, as boxes of corners (8,3 each, dock frame, m): each
    square marker's plate (code plus quiet zone; without ``quiet_zone`` the code square
    alone, its uniform white surround left to the background render), each LED disc
    (radius ``led_radius_m``). The glow around an LED is added in image space (compose),
    not rendered."""
    out = []
    for m in markers:
        T = np.asarray(m["T_dock_marker"], float)
        if m["kind"] == "led_array":
            r = float(m["led_radius_m"])
            centres = np.asarray(m["keypoints"], float)
            out += [
                np.array([[x, y, z] for x in (cx - r, cx + r) for y in (cy - r, cy + r) for z in (-r, r)])
                for cx, cy, _ in centres
            ]
            continue
        h = float((m.get("plate_size_m") if quiet_zone else None) or m["size_m"]) / 2
        local = np.array([[x, y, z, 1.0] for x in (-h, h) for y in (-h, h) for z in (-0.01, 0.01)])
        out.append((local @ T.T)[:, :3])
    return out


def dock_corners(exp: Experiment) -> np.ndarray:
    """The 8 corners (dock frame, m) of a box holding the dock body and every marker."""
    return tj.dock_corners(exp.scene.dock)


def trial_seed(exp: Experiment, trial: int) -> int:
    """Seed of one trial: same config seed and trial index -> same start, noise, particles."""
    return int(np.random.SeedSequence([exp.seed, trial]).generate_state(1)[0])


def occlusion_region(exp: Experiment, occ) -> tuple[list[float], list[float]]:
    """Region of the small obstacles: the config's, else the pool (15x5x8 m = the article's
    600 m^3), else 600 m^3 in front of the dock in open water."""
    if occ.region_min is not None:
        return list(occ.region_min), list(occ.region_max)
    s = exp.scene
    if s.kind == "pool":
        p = s.pool
        return [-p.length_m / 2, -p.width_m / 2, -p.depth_m], [p.length_m / 2, p.width_m / 2, 0.0]
    T = tj.T_world_dock_from_spec(s.dock)
    c = T[:3, 3] + 7.5 * T[:3, 2]
    return list(c - [7.5, 2.5, 4.0]), list(c + [7.5, 2.5, 4.0])


def resolved_sensor(exp: Experiment):
    """The camera's sensor with every default resolved (config/effective.py: noise and blooming,
    the same in both image-formation modes, and the exposure for the dock's beacons), so every
    sequence's manifest entry records the values used."""
    return eff.effective(exp).camera.sensor


def condition_post(exp: Experiment, cond, seed: int) -> SequencePost:
    """Image-space processing of one condition: water, depth light, particles, sensor.

    A depth condition moves the water surface (``surface_z_m``), not the geometry, so the
    clean render is shared: the surface sits ``light_depth_m`` above the dock's top
    (``trajectories.dock_top_m``), which the scene puts at z = -scene.dock.water_depth_m."""
    depth = cond.dock_water_depth_m if cond.dock_water_depth_m is not None else exp.scene.dock.water_depth_m
    occ = cond.occlusion or exp.occlusion
    fluid = cond.fluid or exp.fluid
    occ_post = None
    if occ is not None and occ.n_total > 0:
        lo, hi = occlusion_region(exp, occ)
        occ_post = OcclusionPost(
            **occ.model_dump(exclude={"region_min", "region_max"}),
            region_min=lo,
            region_max=hi,
            v_flow=list(fluid.current_mps),
        )
    from blendgen.physics.water import optics

    water = cond.water or exp.water
    return SequencePost(
        seed=seed,
        fps=exp.camera.fps,
        image_formation=exp.image_formation,
        water=water,
        water_effective=effective_water(water, exp.image_formation),
        light_depth_m=depth,
        surface_z_m=-exp.scene.dock.water_depth_m + depth,
        irradiance_w_m2=downwelling_irradiance(exp),
        noise_std=exp.camera.noise_std,
        sensor=resolved_sensor(exp),
        distortion=exp.camera.distortion,
        occlusion=occ_post,
        lamps=exp.vehicle.lamps,
        sun_elevation_deg=exp.scene.sun_elevation_deg,
        sun_share=1.0 / (1.0 + sky_fraction(exp)),
        veil=optics.veil_parameters(cond.water or exp.water, exp.image_formation),
        world=world_post(exp),
        lamp_forward_kept=exp.vehicle.lamp_forward_kept if exp.vehicle.lamps else None,
        lamp_shadows=exp.vehicle.lamp_shadows if exp.vehicle.lamps else None,
        lens=exp.camera.lens,
        suns=sun_lights(exp),
        ambient_w_m2_sr=ambient_radiance(exp),
    )


def effective_water(water: Water, mode: str) -> dict:
    """The manifest's record of a condition's water in an image formation: the coefficients
    used (1/m, R/G/B; ``B_inf`` before the veil model), ``c``, the preset they come from
    (in physical mode an article level is its Jerlov type) and their provenance."""
    from blendgen.physics.water import optics

    w = optics.water_for_mode(water, mode)
    return {**w.to_dict(), "c": w.c.tolist(), "preset": optics.effective_preset(water, mode)}


def world_on(exp: Experiment, what: str) -> bool:
    """``scene.world.<what>`` (surface, caustics, textures, sun_glint) of the effective config."""
    return eff.value(exp, f"scene.world.{what}")


def world_post(exp: Experiment) -> WorldPost | None:
    """Surface and caustics of the fast path, None when both are off (zero cost)."""
    surface, caustics = world_on(exp, "surface"), world_on(exp, "caustics")
    if not (surface or caustics):
        return None
    if exp.image_formation != "physical":
        raise ConfigError(
            "scene.world: surface and caustics need image_formation: physical "
            "(the article's formulas have no surface light); set them false or null"
        )
    w, s = exp.scene.world, exp.scene
    sky = sky_fraction(exp) * sun_horizontal_irradiance(exp) / math.pi  # uniform sky: E = pi L
    low = 90.0 - math.degrees(sf.critical_angle_rad())
    if s.sun_elevation_deg <= low:
        raise ConfigError(
            f"scene.sun_elevation_deg: {s.sun_elevation_deg:g} is the sun's elevation in water, where "
            f"sunlight below a surface stays above {low:.1f} deg (Snell's window); allowed "
            f"{low:.1f} < elevation <= 90 while scene.world.surface or caustics is on"
        )
    return WorldPost(
        surface=surface,
        caustics=caustics,
        wind_mps=w.wind_mps,
        wave_seed=eff.value(exp, "scene.world.wave_seed"),
        sky_radiance=sky,
        ambient_radiance=ambient_radiance(exp) if exp.render.fidelity == "fast" else 0.0,
        sun_travel_dir=sf.sun_in_air(_sun_dir(s.sun_elevation_deg, s.sun_azimuth_deg)).tolist(),
        sun_irradiance=s.sun_strength if surface and world_on(exp, "sun_glint") else 0.0,
        sun_lamp_w_m2=s.sun_strength,
    )


def world_look(exp: Experiment) -> dict:
    """Blender side of ``scene.world``: textures (both fidelities share the scene)."""
    w = exp.scene.world
    return {
        "textures": world_on(exp, "textures"),
        "texture_seed": eff.value(exp, "scene.world.texture_seed"),
        "tile_size_m": w.tile_size_m,
        "grime": w.grime,
        "seabed_depth_m": w.seabed_depth_m,
    }


# Reference caustics (blender/caustic_sun.py): the frame's photon map, binned across the
# in-water beam. Over the pool 2 cm bins: no wider than a 320 x 240 pixel's footprint at the
# far end of an approach (60 deg / 320 px x 10 m = 3.3 cm), so the pattern's bright cusps are
# not blurred below what the camera resolves. 4 cm bins did blur them: on the held-in clear
# approach (bench fidelity's set, 12 frames) the LED localizer succeeded in 0.92 of the frames
# with 4 cm and 0.67 with 2 cm, where the cusps on the sunlit end wall outshine the far LEDs
# (the fast path, binned at the pixel's footprint: 0.58). Over the dock 1 cm bins (the camera
# comes within 1 m of it). 100 photons per bin: 10 % shot noise per bin, ~19 M photons over
# the pool; one render per spot and frame (the sun's disc is the sun camera's depth of field).
REFERENCE_CAUSTICS = {"bin_m": 0.02, "dock_bin_m": 0.01, "photons_per_bin": 100.0, "renders": 1}


def water_surface(exp: Experiment, post: SequencePost) -> dict | None:
    """Reference fidelity: the refracting surface (glass, IOR 1.333) at the condition's surface
    height with the sky above it; None when the surface is off."""
    wp = post.world
    if wp is None or not wp.surface:
        return None
    s = exp.scene
    if s.kind == "pool":
        half = [s.pool.length_m / 2, s.pool.width_m / 2]
        centre = [0.0, 0.0]
    else:
        half, centre = [60.0, 60.0], list(s.dock.position_xy_m)
    sun = (
        {"to_sun": [-v for v in wp.sun_travel_dir], "irradiance": wp.sun_irradiance} if wp.sun_irradiance > 0 else None
    )
    out = {
        "z": post.surface_z_m,
        "centre_xy": centre,
        "half_xy": half,
        "sky_radiance": wp.sky_radiance,
        "wind_mps": wp.wind_mps,
        "wave_seed": wp.wave_seed,
        "sun": sun,
    }
    if wp.caustics and s.sun_strength > 0:  # open water: the dock only (the seabed is beyond a photon budget)
        out["caustics"] = {**REFERENCE_CAUSTICS, "pool_spot": s.kind == "pool"}
    return out


@functools.lru_cache(maxsize=256)
def _file_sha(path: str, mtime_ns: int, size: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _texture_sha(path: str | None) -> str | None:
    """Content hash of a texture file (cached per path, modification time and size)."""
    if path is None:
        return None
    st = os.stat(path)
    return _file_sha(path, st.st_mtime_ns, st.st_size)


def job_key(exp: Experiment, scene: dict, frames: list[dict]) -> str:
    """What determines a clean render, whichever dataset asks for it: scene (texture files
    by content, not path), poses, camera, fidelity and render settings (not thread count)."""
    scene = {**scene, "markers": [{**m, "texture": _texture_sha(m.get("texture"))} for m in scene["markers"]]}
    render = {k: v for k, v in render_settings(exp, 1).items() if k != "threads"}
    c = exp.camera
    blob = json.dumps(
        {
            "scene": scene,
            "frames": frames,
            "render": render,
            "fidelity": exp.render.fidelity,
            "camera": [c.width, c.height, c.hfov_deg],
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def water_volume(exp: Experiment, post: SequencePost) -> dict | None:
    """Reference-fidelity medium for one condition, or None when the water is clear.

    A box whose top face is the water surface (a World volume would kill sunlight).
    The surface sits ``light_depth_m`` above the dock, so a depth condition moves the
    surface, not the geometry, and the clean renders stay comparable."""
    from blendgen.physics.water import optics

    w = optics.water_for_mode(post.water, post.image_formation)
    if w.is_clear:
        return None
    s = exp.scene
    dock_z = float(tj.T_world_dock_from_spec(s.dock)[2, 3])
    surface_z = post.surface_z_m
    if s.kind == "pool":
        lo = [-s.pool.length_m / 2, -s.pool.width_m / 2, -s.pool.depth_m]
        hi = [s.pool.length_m / 2, s.pool.width_m / 2, surface_z]
    else:
        x, y = s.dock.position_xy_m
        lo, hi = [x - 60.0, y - 60.0, dock_z - 60.0], [x + 60.0, y + 60.0, surface_z]
    return {
        "sigma_a": list(map(float, w.sigma_a)),
        "sigma_s": list(map(float, w.sigma_s)),
        "phase": w.phase,
        "g": float(w.g),
        "ff_ior": float(w.ff_ior),
        "ff_backscatter": float(w.ff_backscatter),
        "box_min": lo,
        "box_max": hi,
    }


def _motion(exp: Experiment, traj, cond):
    """What makes a condition's camera path differ: the fluid, for dynamic trials only."""
    if traj.kind != "docking":
        return None
    return cond.fluid or exp.fluid


def plan_jobs(exp: Experiment, scene: dict) -> list[RenderJob]:
    """Every render job; sequences with identical clean renders share one job.

    A job is keyed by :func:`job_key` (scene and camera path), so kinematic trajectories
    render once for all trials and conditions (trials differ only in image-space
    seeds), docking trials render once per (trial, fluid), and with the reference
    fidelity the water makes every condition its own render."""
    T_wd = np.asarray(scene["dock"]["T_world_dock"], float)
    T_bc = tj.T_body_cam_from_spec(exp.camera.T_body_cam)
    jobs: dict[str, RenderJob] = {}
    paths: dict[tuple, list[dict]] = {}
    for traj in exp.trajectories:
        for trial in range(exp.trials):
            seed = trial_seed(exp, trial)
            for c in exp.conditions:
                fluid = _motion(exp, traj, c)
                mkey = (
                    traj.id,
                    trial if traj.kind == "docking" else None,
                    None if fluid is None else json.dumps(fluid.model_dump(), sort_keys=True),
                )
                if mkey not in paths:
                    paths[mkey] = _frames(exp, traj, T_wd, T_bc, seed, fluid or exp.fluid)
                    scene_check.check_frames(exp, exp.trajectories.index(traj), trial, *paths[mkey])
                frames, end = paths[mkey]
                post = condition_post(exp, c, seed)
                sq = SequencePlan(f"{traj.id}-t{trial:03d}-{c.label}", traj.id, trial, c.label, post)
                sc = (
                    scene
                    if exp.render.fidelity == "fast"
                    else {
                        **scene,
                        "water_volume": water_volume(exp, post),
                        "led_lights": True,
                        "water_surface": water_surface(exp, post),
                    }
                )
                if post.occlusion and post.occlusion.geometry == "blender":
                    # real geometry is part of the render: keyed by its config and seed
                    sc = {
                        **sc,
                        "particles": {
                            **post.occlusion.model_dump(),
                            "seed": seed,
                            "fps": exp.camera.fps,
                            "object_index": INDEX_PARTICLES,
                        },
                    }
                key = job_key(exp, sc, frames)
                jobs.setdefault(key, RenderJob(key, sc, frames, end=end)).sequences.append(sq)
    return list(jobs.values())


def render_settings(exp: Experiment, threads: int) -> dict:
    """Cycles settings for the chosen fidelity."""
    r = exp.render
    samples = r.samples if r.fidelity == "fast" else r.reference_samples
    vb = r.volume_bounces if r.fidelity == "reference" else 0
    # the refracting surface: camera -> surface (transmission or total reflection) -> sky or wall
    spec = 2 if r.fidelity == "reference" and world_on(exp, "surface") else 0
    lamps = bool(exp.vehicle.lamps) and r.fidelity == "fast"  # fast lamp: albedo and normal passes
    out = {
        "samples": samples,
        "threads": threads,
        "max_bounces": max(r.diffuse_bounces, vb, spec),
        "diffuse_bounces": r.diffuse_bounces,
        "volume_bounces": vb,
        "seed": exp.seed,
        "specular_bounces": spec,
        "ambient_radiance": ambient_radiance(exp) if r.fidelity == "fast" else 0.0,
        "albedo_pass": r.fidelity == "fast" and (ambient_on(exp) or lamps),
        "write_depth": r.write_depth,
        "write_index": r.write_index,
        "roi": r.roi and r.fidelity == "fast",
        "background_scale": r.background_scale,
        "background_samples": r.background_samples,
        "roi_max_fraction": r.roi_max_fraction,
        "light_tree": eff.value(exp, "render.light_tree"),
    }
    if lamps:
        out["normal_pass"] = True
    if r.fidelity == "fast" and exp.image_formation == "physical" and world_on(exp, "caustics"):
        out["sun_pass"] = True  # the sun's own light (a Cycles light group): what caustics refocus
    return out
