"""After the fact: how close each trial of a closed-loop run came to the pool's walls and floor.

A run's ``frames.parquet`` (``dockbench dock``) logs per camera frame the body origin
(``x_world``, ``y_world``, ``z_world``; world frame, +z up, m) and the camera centre's
horizontal position (``x_cam_world``, ``y_cam_world``), not the full attitude.
:func:`trial_water_clearance` gives each trial's smallest clearance (m) between the hull
(:class:`blendgen.vehicle.contact.Hull`) and the solid faces of the water
(:class:`blendgen.vehicle.contact.WaterSolid`), at the logged frames:

* ``method="camera"`` (``cam_forward_m`` given: the camera sits on the body x axis,
  ``T_body_cam`` translation (a, 0, 0) with a = ``cam_forward_m``): the camera offset is
  a times the body x axis, so its horizontal part gives the heading and |cos(pitch)|, and the
  capsule's reach along each world axis, half axis x |x_body component|, is exact (the capsule is
  symmetric about its centre and about its axis, so neither the pitch's sign nor the roll
  matters). The clearance is then the same as :func:`blendgen.vehicle.contact.water_contact`'s.
* ``method="origin"`` (otherwise): the attitude is unknown, so the clearance is the conservative
  bound origin distance - half axis - radius (the hull pointing straight at each face): a lower
  bound of the true clearance, exact only for a hull pointing at the face.

Frames are 1/fps apart; the closed loop tests contact at the same frames.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from blendgen.vehicle.contact import Hull, WaterSolid

TRIAL_KEYS = ("localizer", "condition", "trial")


def frame_clearance(
    origin: np.ndarray, axis_abs: np.ndarray | None, water: WaterSolid, hull: Hull
) -> tuple[np.ndarray, np.ndarray]:
    """Clearance (N,) (m; negative = penetration) of the hull to the nearest solid face and that
    face's index (N,) into ``water.faces``, for body origins ``origin`` (N,3) (world, m) and
    ``axis_abs`` (N,3) = |body x axis components| in the world frame (None: unknown attitude, the
    conservative bound: every component taken as 1)."""
    o = np.atleast_2d(np.asarray(origin, float))
    reach = hull.half_axis * (np.ones_like(o) if axis_abs is None else np.asarray(axis_abs, float))
    per_face = []
    for axis, side, _ in water.faces:
        plane = water.hi[axis] if side > 0 else water.lo[axis]
        per_face.append(-side * (o[:, axis] - plane) - reach[:, axis] - hull.radius)
    if not per_face:
        return np.full(len(o), np.inf), np.full(len(o), -1)
    d = np.stack(per_face)  # (faces, N)
    k = np.argmin(d, axis=0)
    return d[k, np.arange(len(o))], k


def axis_from_camera(frames: pd.DataFrame, cam_forward_m: float) -> np.ndarray:
    """|body x axis components| (N,3) in the world frame from the camera's horizontal offset from the
    body origin (camera on the body x axis, ``cam_forward_m`` ahead of the origin, m)."""
    if not cam_forward_m > 0:
        raise ValueError(f"cam_forward_m must be positive, got {cam_forward_m}")
    dx = (frames["x_cam_world"].to_numpy(float) - frames["x_world"].to_numpy(float)) / cam_forward_m
    dy = (frames["y_cam_world"].to_numpy(float) - frames["y_world"].to_numpy(float)) / cam_forward_m
    h2 = dx * dx + dy * dy
    if np.any(h2 > 1 + 1e-6):
        raise ValueError(
            f"camera offset up to {np.sqrt(h2.max()) * cam_forward_m:.3f} m exceeds cam_forward_m = "
            f"{cam_forward_m} m: the camera is not on the body x axis that far ahead"
        )
    return np.column_stack([np.abs(dx), np.abs(dy), np.sqrt(np.clip(1.0 - h2, 0.0, 1.0))])


def trial_water_clearance(
    frames: pd.DataFrame, water: WaterSolid, hull: Hull | None = None, cam_forward_m: float | None = None
) -> pd.DataFrame:
    """Each trial's smallest hull clearance to the water's solid faces over its logged frames (module
    doc). ``frames``: a run's frames table; ``water``: e.g.
    :func:`blendgen.pipeline.scene_check.water_solid` of the run's experiment; ``hull``: default the
    vehicle's (:class:`blendgen.vehicle.dynamics.VehicleParams`); ``cam_forward_m``: the camera's body x
    (``camera.T_body_cam.xyz[0]`` when its y and z are 0), None: the conservative origin bound.

    Returns one row per trial (``localizer``, ``condition``, ``trial`` where present):
    ``min_clearance_m`` (m, negative = penetration), ``part`` (``pool_wall``, ``pool_floor``,
    ``seabed``), ``t_s`` (s) and ``x_world``/``y_world``/``z_world`` (m) of that frame, ``touched``
    (clearance <= 0) and ``method`` (``camera`` exact, ``origin`` a lower bound)."""
    if hull is None:
        from blendgen.vehicle.dynamics import VehicleParams

        p = VehicleParams()
        hull = Hull.from_vehicle(p.length, p.diameter)
    cam = cam_forward_m if {"x_cam_world", "y_cam_world"} <= set(frames.columns) else None
    use_cam = cam is not None
    axis_abs = None if cam is None else axis_from_camera(frames, float(cam))
    origin = frames[["x_world", "y_world", "z_world"]].to_numpy(float)
    clear, face = frame_clearance(origin, axis_abs, water, hull)
    names = np.array([f[2] for f in water.faces] + [""])
    df = frames.assign(min_clearance_m=clear, part=names[face]).reset_index(drop=True)
    keys = [k for k in TRIAL_KEYS if k in df.columns]
    best = (
        df.loc[df.groupby(keys, sort=False)["min_clearance_m"].idxmin()]
        if keys
        else df.loc[[df["min_clearance_m"].idxmin()]]
    )
    out = best[[*keys, "min_clearance_m", "part", "t", "x_world", "y_world", "z_world"]].rename(columns={"t": "t_s"})
    return out.assign(touched=out["min_clearance_m"] <= 0, method="camera" if use_cam else "origin").reset_index(
        drop=True
    )


__all__ = ["trial_water_clearance", "frame_clearance", "axis_from_camera"]
