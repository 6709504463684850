"""Relative navigation on a vision estimate: the dock fix, the filter, and docking success by geometry.

Pure numpy. Frames as in :mod:`blendgen.vehicle.docking`: world +z up, body FLU, NED inside
the dynamics; the dock frame has its origin at the marker-face centre, +z out of the face
toward the vehicle, +y up, +x right seen from in front.

The filter (:class:`RelativePoseFilter`) is a **linear Kalman filter** on the vehicle's
horizontal position in the dock frame (x lateral and z range, each a constant-velocity
state [position, rate] driven by white acceleration noise ``accel_std``; one update per
camera frame; the two axes are decoupled, so each is an alpha-beta filter whose gains come
from the Kalman recursion instead of being fixed). The measurement noise grows with range as
marker PnP error does (docs/dynamics.md: error ~ Z^2): ``std = max(meas_std_min_m,
meas_std_per_m2 * z^2)``. A fix whose innovation exceeds ``gate_sigma`` standard deviations
is rejected as an outlier (counted as a dropout), except when the estimate is stale: then the
filter restarts on it. The vehicle's own sensors are fused as follows:

- the attitude sensor (heading/pitch/roll, 0.1 deg) turns each vision fix into the dock's
  approach heading in NED, ``psi_dock``; the depth sensor (0.01 m) turns it into the
  dock's depth. Both are constants of the scene: the heading is estimated as a constant
  by a scalar Kalman filter whose measurement std grows with range (``psi_std_per_m``:
  a planar target's rotation is poorly and ambiguously observed far away, so near fixes
  dominate and gated outliers -- mirrored IPPE solutions -- are dropped); the depth by a
  first-order low-pass (gain ``const_gain``). Between fixes the relative heading and
  depth come from the sensors at the control rate, not from the (older, noisier) fix;
- between fixes and through dropouts the position is dead-reckoned with the filter's
  velocity for at most ``hold_s``; after that the estimate is *stale* and guidance runs the
  lost-target recovery (:class:`blendgen.vehicle.closed_loop.Recovery`: face the last dock
  bearing, back off, hold) until a new fix re-acquires the target; a vehicle without an
  accepted fix for ``lost_s`` (including before the first one) has *lost the target*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from blendgen.geometry import invert_T, make_T
from blendgen.vehicle.dynamics import F_WORLD_NED, eta_to_T_world_body, wrap_pi


@dataclass(frozen=True)
class FilterParams:
    """Kalman filter settings: white-acceleration std ``accel_std`` (m/s^2), measurement std
    ``max(meas_std_min_m, meas_std_per_m2 * range^2)`` (m), innovation gate (sigmas), low-pass
    gain of the dock heading/depth, dropout hold and lost-target times (s).

    Defaults: 0.3 m/s^2 is about a quarter of the horizontal acceleration the lateral
    thrusters can give the vehicle (2 x 36.6 N / 66 kg sway mass = 1.1 m/s^2); 0.005 m^-1 is the order of the LED
    array's range error at 320x240 (the
    ``0.7 Z^2 sigma_px / (f s)`` rule with f = 277 px, s = 0.6 m, sigma_px = 1).
    ``hold_s`` = 3 s of dead reckoning: the filter's own position std grows as
    ``accel_std sqrt(t^3 / 3)`` without fixes, 0.9 m after 3 s, more than twice the 0.40 m capture
    radius: beyond that the estimate cannot steer into the mouth. ``lost_s`` = 20 s covers the dead
    reckoning, the 12 s back-off and 5 s of hold (:class:`blendgen.vehicle.closed_loop.Recovery`)."""

    accel_std: float = 0.3
    meas_std_per_m2: float = 0.005
    meas_std_min_m: float = 0.01
    gate_sigma: float = 4.0
    const_gain: float = 0.3
    psi_std_per_m: float = 0.02
    psi_std_min_rad: float = 0.005
    hold_s: float = 3.0
    lost_s: float = 20.0

    def __post_init__(self):
        if not 0.0 < self.const_gain <= 1.0:
            raise ValueError(f"const_gain must be in (0, 1], got {self.const_gain}")
        if min(self.accel_std, self.meas_std_per_m2, self.meas_std_min_m, self.gate_sigma) <= 0:
            raise ValueError("accel_std, meas_std_per_m2, meas_std_min_m and gate_sigma must be > 0")
        if not 0.0 <= self.hold_s <= self.lost_s:
            raise ValueError(f"need 0 <= hold_s <= lost_s, got hold_s={self.hold_s}, lost_s={self.lost_s}")

    def meas_std(self, range_m: float) -> float:
        """Measurement std (m) of a fix at ``range_m``."""
        return max(self.meas_std_min_m, self.meas_std_per_m2 * range_m**2)


@dataclass(frozen=True)
class DockFix:
    """One vision fix: body origin in the dock frame ``p_dock`` (3,) m from the full estimated pose
    (x lateral, y vertical, z range; x and y NaN for a distance-only estimate), the vector from
    the body origin to the dock origin in world axes ``to_dock_world`` (3,) m (estimated
    translation turned by the attitude sensor; NaN if unknown), the dock's approach heading in
    NED ``psi_dock`` rad (NaN if unknown) and the dock depth ``depth_dock`` m (NaN if unknown)."""

    p_dock: np.ndarray
    psi_dock: float
    depth_dock: float
    to_dock_world: np.ndarray = field(default_factory=lambda: np.full(3, math.nan))


def R_world_body_from_sensors(sens: dict) -> np.ndarray:
    """Body FLU -> world rotation (3x3) from the attitude sensor (deg)."""
    eta = [0.0, 0.0, 0.0] + [math.radians(sens[k]) for k in ("roll_deg", "pitch_deg", "heading_deg")]
    return eta_to_T_world_body(eta)[:3, :3]


def R_world_dock_of(psi_dock: float) -> np.ndarray:
    """Rotation (3x3) of an upright dock whose approach heading (NED, toward the face) is ``psi_dock``."""
    yaw_face = -psi_dock + math.pi  # world yaw of the face normal (+z_d)
    z_d = np.array([math.cos(yaw_face), math.sin(yaw_face), 0.0])
    y_d = np.array([0.0, 0.0, 1.0])
    return np.column_stack([np.cross(y_d, z_d), y_d, z_d])


def fix_from_estimate(estimate: dict, T_body_cam: np.ndarray, sens: dict) -> DockFix:
    """A localizer estimate (``distance`` m, optional ``T_cam_dock`` 4x4) -> :class:`DockFix`.

    With a pose: ``T_dock_body = inv(T_body_cam @ T_cam_dock)``; the dock's axes in the world
    come from the sensors' attitude times the estimated ``R_body_dock``. With a distance only,
    the range is ``distance`` plus the camera's forward offset and nothing else is known."""
    T = estimate.get("T_cam_dock")
    if T is None:
        z = float(estimate["distance"]) + float(T_body_cam[0, 3])
        return DockFix(np.array([math.nan, math.nan, z]), math.nan, math.nan)
    T_body_dock = np.asarray(T_body_cam, float) @ np.asarray(T, float)
    p = invert_T(T_body_dock)[:3, 3]
    R_wb = R_world_body_from_sensors(sens)
    R_wd = R_wb @ T_body_dock[:3, :3]
    axis_ned = F_WORLD_NED @ R_wd[:, 2]
    psi_dock = math.atan2(-axis_ned[1], -axis_ned[0])
    to_dock = R_wb @ T_body_dock[:3, 3]
    return DockFix(p, psi_dock, float(sens["depth_m"]) - float(to_dock[2]), to_dock)


class RelativePoseFilter:
    """Kalman filter on the dock-relative horizontal position plus low-passed dock heading/depth
    (module doc). Time ``t`` in s; call :meth:`update` once per camera frame (``fix`` None on a
    dropout) and :meth:`state` at any control step."""

    def __init__(self, params: FilterParams = FilterParams()):
        self.p = params
        self.xz = np.zeros(2)  # lateral, range (m)
        self.v = np.zeros(2)  # their rates (m/s)
        self.P = np.zeros((2, 2, 2))  # per axis covariance of [position, rate]
        self.psi_dock = math.nan
        self.psi_var = math.nan  # rad^2
        self.depth_dock = math.nan
        self.t_fix = math.nan  # time of the last accepted fix
        self.t_upd = math.nan  # time the state refers to
        self.t0 = math.nan  # first call
        self.rejected = 0  # fixes refused by the gate

    @property
    def initialised(self) -> bool:
        return math.isfinite(self.t_fix) and math.isfinite(self.psi_dock)

    def _restart(self, t: float, meas: np.ndarray, fix: DockFix) -> None:
        r2 = self.p.meas_std(float(meas[1])) ** 2
        self.xz, self.v = meas.copy(), np.zeros(2)
        self.P = np.array([np.diag([r2, 0.5**2])] * 2)  # rate unknown: +-0.5 m/s
        if math.isfinite(self.psi_dock):  # re-acquired: the dock did not move
            self._update_constants(fix, float(meas[1]))
        else:
            self.psi_dock, self.depth_dock = fix.psi_dock, fix.depth_dock
            self.psi_var = self._psi_r(float(meas[1]))
        self.t_fix = self.t_upd = t

    def _psi_r(self, range_m: float) -> float:
        return max(self.p.psi_std_min_rad, self.p.psi_std_per_m * max(range_m, 0.0)) ** 2

    def _update_constants(self, fix: DockFix, range_m: float) -> None:
        """Scalar Kalman update of the dock heading (gated) and low-pass of the dock depth."""
        if math.isfinite(fix.psi_dock):
            r = self._psi_r(range_m)
            nu = wrap_pi(fix.psi_dock - self.psi_dock)
            if abs(nu) <= self.p.gate_sigma * math.sqrt(self.psi_var + r):
                k = self.psi_var / (self.psi_var + r)
                self.psi_dock = wrap_pi(self.psi_dock + k * nu)
                self.psi_var *= 1.0 - k
        g = self.p.const_gain
        if math.isfinite(fix.depth_dock):
            self.depth_dock += g * (fix.depth_dock - self.depth_dock)

    def _predict(self, dt: float) -> None:
        F = np.array([[1.0, dt], [0.0, 1.0]])
        q = self.p.accel_std**2
        Q = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        self.xz = self.xz + self.v * dt
        self.P = np.array([F @ P @ F.T + Q for P in self.P])
        self.t_upd += dt

    def _measurement(self, fix: DockFix) -> np.ndarray:
        """(lateral, range) of a fix: from its translation turned into the dock frame with the
        filtered dock heading when both exist (a planar target's PnP rotation is ambiguous at
        range, its translation is not), else from its own pose (or its distance alone)."""
        if math.isfinite(self.psi_dock) and np.all(np.isfinite(fix.to_dock_world)):
            p = -R_world_dock_of(self.psi_dock).T @ fix.to_dock_world
            return np.array([p[0], p[2]])
        return np.array([fix.p_dock[0], fix.p_dock[2]])

    def update(self, t: float, fix: DockFix | None) -> None:
        """Predict to ``t`` and, with a fix that passes the gate, correct."""
        if not math.isfinite(self.t0):
            self.t0 = t
        if fix is None:
            return
        meas = self._measurement(fix)
        if not self.initialised or not self.fresh(t):
            if (math.isfinite(fix.psi_dock) or self.initialised) and np.all(np.isfinite(meas)):
                self._restart(t, meas, fix)  # a distance alone cannot (re)start it
            return
        self._predict(t - self.t_upd)
        r2 = self.p.meas_std(float(meas[1])) ** 2
        innov = meas - self.xz
        S = self.P[:, 0, 0] + r2
        ok = np.isfinite(innov)  # a distance-only fix corrects the range alone
        if np.any(np.abs(np.where(ok, innov, 0.0)) > self.p.gate_sigma * np.sqrt(S)):
            self.rejected += 1
            return
        for i in np.flatnonzero(ok):
            K = self.P[i, :, 0] / S[i]
            self.xz[i] += K[0] * innov[i]
            self.v[i] += K[1] * innov[i]
            self.P[i] = self.P[i] - np.outer(K, self.P[i, 0, :])
        self.t_fix = t
        self._update_constants(fix, float(self.xz[1]))

    def since_fix(self, t: float) -> float:
        """Seconds since the last fix (since the start when there was none)."""
        return t - (self.t_fix if math.isfinite(self.t_fix) else self.t0)

    def fresh(self, t: float) -> bool:
        """True while the estimate may be used for guidance (a fix within ``hold_s``)."""
        return self.initialised and self.since_fix(t) <= self.p.hold_s

    def lost(self, t: float) -> bool:
        """True once no fix has arrived for ``lost_s``."""
        return math.isfinite(self.t0) and self.since_fix(t) > self.p.lost_s

    def state(self, t: float, depth_sensor_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(p_dock (3,) m, v (2,) m/s lateral/range rates) dead-reckoned to ``t``; the vertical
        offset is the estimated dock depth minus the depth sensor."""
        xz = self.xz + self.v * (t - self.t_upd)
        return np.array([xz[0], self.depth_dock - depth_sensor_m, xz[1]]), self.v.copy()

    def T_world_dock(self, origin_xy: np.ndarray) -> np.ndarray:
        """The estimated dock pose (4x4, world): horizontal origin anchored at ``origin_xy``
        (only relative positions matter), estimated depth and approach heading."""
        return make_T(R_world_dock_of(self.psi_dock), [origin_xy[0], origin_xy[1], -self.depth_dock])


# ------------------------------------------------------------ docking success -----
OUTCOMES = ("docked", "misaligned", "collision", "out_of_capture", "lost_target", "timeout")


@dataclass(frozen=True)
class CaptureSpec:
    """When a crossing of the dock's entry plane counts as docked.

    ``capture_radius_m``: the nose must cross within this distance of the face centre;
    ``max_heading_deg`` / ``max_lateral_speed_mps``: limits on the heading error and the
    speed across the dock axis at the crossing; ``frame_half_m`` (half width, half height):
    a crossing outside the capture radius but inside the dock face (grown by the hull radius)
    hits the dock frame (``collision``); beyond it the vehicle missed (``out_of_capture``).
    ``entry_plane_m``: the entry plane's distance in front of the marker face."""

    capture_radius_m: float
    frame_half_m: tuple[float, float]
    max_heading_deg: float = 15.0
    max_lateral_speed_mps: float = 0.25
    entry_plane_m: float = 0.0

    @classmethod
    def from_dock(cls, body_size_m, hull_radius_m: float, **kw) -> CaptureSpec:
        """Default from the dock face (width, height): the mouth is the face's inscribed circle
        and the hull must fit in it, so ``capture_radius = min(w, h) / 2 - hull_radius``
        (0.40 m for the 1 m dock and the 0.191 m REMUS hull)."""
        w, h = float(body_size_m[0]), float(body_size_m[1])
        r = min(w, h) / 2.0 - hull_radius_m
        if r <= 0:
            raise ValueError(f"dock face {w}x{h} m is too small for a hull of radius {hull_radius_m} m")
        return cls(kw.pop("capture_radius_m", r), (w / 2 + hull_radius_m, h / 2 + hull_radius_m), **kw)


def crossing_outcome(spec: CaptureSpec, nose_dock: np.ndarray, heading_err_deg: float, lateral_speed_mps: float) -> str:
    """Outcome of a crossing of the entry plane by the nose at ``nose_dock`` (3,) (dock frame)."""
    x, y = float(nose_dock[0]), float(nose_dock[1])
    if math.hypot(x, y) <= spec.capture_radius_m:
        ok = abs(heading_err_deg) <= spec.max_heading_deg and abs(lateral_speed_mps) <= spec.max_lateral_speed_mps
        return "docked" if ok else "misaligned"
    if abs(x) <= spec.frame_half_m[0] and abs(y) <= spec.frame_half_m[1]:
        return "collision"
    return "out_of_capture"


def interpolate_crossing(a: np.ndarray, b: np.ndarray, plane_z: float) -> np.ndarray:
    """Point (3,) where the segment a -> b (dock frame) crosses z = plane_z (a above, b at/below)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    s = (a[2] - plane_z) / max(a[2] - b[2], 1e-12)
    return a + min(max(s, 0.0), 1.0) * (b - a)


__all__ = [
    "FilterParams",
    "DockFix",
    "R_world_dock_of",
    "RelativePoseFilter",
    "fix_from_estimate",
    "CaptureSpec",
    "crossing_outcome",
    "interpolate_crossing",
    "OUTCOMES",
    "R_world_body_from_sensors",
]
