"""Parametric camera trajectories and the world poses they sample.

Body frame: x forward, y left, z up (FLU). The camera is mounted at ``T_body_cam``;
with zero roll/pitch/yaw it looks straight ahead along body +x (OpenCV axes:
x_cam = -y_body, y_cam = -z_body, z_cam = +x_body).

Frames are sampled at the camera rate: image k is stamped ``t = k / fps`` and shows
the pose at ``t_pose = t - latency`` (clamped at 0), so a link latency makes each
image older than its stamp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blendgen.geometry import look_at_R, make_T, rpy_to_R

# OpenCV camera axes expressed in the FLU body frame (columns x_cam, y_cam, z_cam).
R_BODY_CAM_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class Sampled:
    """A sampled trajectory: stamps t (N,), pose times t_pose (N,), T_world_body (N,4,4)."""

    t: np.ndarray
    t_pose: np.ndarray
    T_world_body: np.ndarray


def T_body_cam_from_spec(pose) -> np.ndarray:
    """Camera mount (4x4) from a config Pose: xyz in the body frame; rpy rotates the
    camera from looking straight ahead (yaw left +, pitch down +... per ZYX in body axes)."""
    r, p, y = (math.radians(a) for a in pose.rpy_deg)
    return make_T(rpy_to_R(r, p, y) @ R_BODY_CAM_FORWARD, pose.xyz)


#: Half-side of a square marker's plate over the code's (quiet zone included): ISO/IEC 18004's
#: 4-module quiet zone around a 21-module QR code gives 29/21 = 1.38; 1.5 bounds it.
PLATE_HALF_FACTOR = 1.5


def dock_corners(dock) -> np.ndarray:
    """The 8 corners (8, 3) (dock frame, m) of a box holding the dock body and every marker."""
    sx, sy, sz = dock.body_size_m
    x, y = sx / 2, sy / 2
    for m in dock.markers:
        r = getattr(m, "led_radius_m", 0.0)
        side = max(m.size_m, getattr(m, "height_m", None) or 0.0)
        half = side / 2 * (PLATE_HALF_FACTOR if m.kind != "led_array" else 1.0) + r
        x = max(x, abs(m.center_m[0]) + half)
        y = max(y, abs(m.center_m[1]) + half)
    return np.array([[a, b, c] for a in (-x, x) for b in (-y, y) for c in (0.01, -sz - 0.01)])


def dock_top_m(dock) -> float:
    """Height (m) of the dock's top above its face centre: the top of :func:`dock_corners`'s
    box (body and markers, symmetric about the face centre)."""
    return float(dock_corners(dock)[:, 1].max())


def T_world_dock_from_spec(dock) -> np.ndarray:
    """Dock pose in the world (water surface at z = 0): face normal at yaw ``facing_deg``, the
    face vertical, and the dock's top (:func:`dock_top_m`) ``water_depth_m`` below the surface,
    so the face centre is at z = -(water_depth_m + dock_top_m) and 0 m is a dock just under the
    surface."""
    yaw = math.radians(dock.facing_deg)
    z_d = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    y_d = np.array([0.0, 0.0, 1.0])
    x_d = np.cross(y_d, z_d)
    x, y = dock.position_xy_m
    return make_T(np.column_stack([x_d, y_d, z_d]), [x, y, -(dock.water_depth_m + dock_top_m(dock))])


def _body_R_facing(forward_world: np.ndarray) -> np.ndarray:
    """FLU body rotation (3x3) with x along ``forward_world`` and z as close to up as possible."""
    R_cam = look_at_R(forward_world)  # columns: right, down, forward
    return np.column_stack([R_cam[:, 2], -R_cam[:, 0], -R_cam[:, 1]])


def frame_times(duration_s: float, fps: float, latency_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Image stamps covering [0, duration + latency] and the pose times they show (s)."""
    n = int(math.floor((duration_s + latency_s) * fps + 1e-9)) + 1
    t = np.arange(n) / fps
    return t, np.clip(t - latency_s, 0.0, duration_s)


def linear_approach(spec, T_world_dock: np.ndarray, fps: float, latency_s: float = 0.0) -> Sampled:
    """``p(t) = p0 + v t d`` toward the dock face along its normal, heading along d.

    p0 = (lateral, vertical, start_range) in the dock frame; d = -z_dock; the run ends
    when the range to the face plane reaches ``end_range_m``."""
    duration = (spec.start_range_m - spec.end_range_m) / spec.speed_mps
    t, tp = frame_times(duration, fps, latency_s)
    R_wd, o = T_world_dock[:3, :3], T_world_dock[:3, 3]
    p0 = o + R_wd @ np.array([spec.lateral_m, spec.vertical_m, spec.start_range_m])
    d = -R_wd[:, 2]
    R_body = _body_R_facing(d)
    T = np.repeat(np.eye(4)[None], len(t), axis=0)
    T[:, :3, :3] = R_body
    T[:, :3, 3] = p0[None, :] + spec.speed_mps * tp[:, None] * d[None, :]
    return Sampled(t, tp, T)


def circle(spec, T_world_dock: np.ndarray, fps: float, latency_s: float = 0.0) -> Sampled:
    """``p(theta) = target + (R cos theta, R sin theta, h)`` around the dock face centre.

    theta is measured in the horizontal plane from the dock normal; the camera body
    always faces the target. theta runs from start_deg to end_deg at ``speed_mps``."""
    a0, a1 = math.radians(spec.start_deg), math.radians(spec.end_deg)
    duration = abs(a1 - a0) * spec.radius_m / spec.speed_mps
    t, tp = frame_times(duration, fps, latency_s)
    theta = a0 + (a1 - a0) * (tp / duration if duration > 0 else 0.0)
    target = T_world_dock[:3, 3]
    n = T_world_dock[:3, 2]
    base = math.atan2(n[1], n[0])
    T = np.repeat(np.eye(4)[None], len(t), axis=0)
    for i, th in enumerate(theta):
        p = target + np.array([spec.radius_m * math.cos(base + th), spec.radius_m * math.sin(base + th), spec.height_m])
        T[i, :3, :3] = _body_R_facing(target - p)
        T[i, :3, 3] = p
    return Sampled(t, tp, T)


def docking_trial(
    spec, T_world_dock: np.ndarray, fps: float, latency_s: float, seed: int, fluid
) -> tuple[Sampled, dict]:
    """Closed-loop docking of the 6-DOF vehicle from a random start drawn with ``seed``.

    The vehicle is guided by its controllers on ground-truth navigation through the
    fluid (density, current); poses are sampled at ``fps``. Returns the sampled poses
    and the trial's summary (start, stop reason, final offsets)."""
    from blendgen.vehicle import docking

    rng = np.random.default_rng(seed)
    st = spec.start
    start = docking.random_start(
        rng,
        {
            "range_m": tuple(st.range_m),
            "lateral_m": st.lateral_m,
            "vertical_m": st.vertical_m,
            "heading_error_deg": st.heading_error_deg,
        },
    )
    run = docking.simulate_docking_trial(
        T_world_dock,
        start,
        current_world=tuple(fluid.current_mps),
        density=fluid.density_kg_m3,
        fps=fps,
        stop_distance_m=spec.stop_distance_m,
        max_time_s=spec.max_time_s,
        seed=seed,
        guidance=docking.LosGuidance(cruise_speed=spec.cruise_speed_mps, final_speed=spec.final_speed_mps),
    )
    tp = np.asarray(run["t"], float)
    info = {
        "start": start,
        "stop_reason": run["stop_reason"],
        "final_distance_m": run["final_distance_m"],
        "final_lateral_m": run["final_lateral_m"],
        "final_vertical_m": run["final_vertical_m"],
    }
    return Sampled(tp + latency_s, tp, np.asarray(run["T_world_body"], float)), info


def sample(spec, T_world_dock: np.ndarray, fps: float, latency_s: float = 0.0, seed: int = 0, fluid=None) -> Sampled:
    """Dispatch on the trajectory kind (docking trials need the trial seed and the fluid)."""
    if spec.kind == "linear":
        return linear_approach(spec, T_world_dock, fps, latency_s)
    if spec.kind == "circle":
        return circle(spec, T_world_dock, fps, latency_s)
    if spec.kind == "docking":
        return docking_trial(spec, T_world_dock, fps, latency_s, seed, fluid)[0]
    raise ValueError(f"unknown trajectory kind {spec.kind!r}")
