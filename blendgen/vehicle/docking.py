"""Docking trials and station keeping with the 6-DOF vehicle (pure numpy).

Public frames (see :mod:`blendgen.vehicle.dynamics` for the internal NED/FRD ones):
- world: +z up, water surface z = 0; body: FLU (x forward, y left, z up).
- dock frame ``T_world_dock``: origin at the centre of the marker face, +z out of the
  face toward the approaching vehicle, +y up, +x right as seen from in front.
- A start ``{"range_m", "lateral_m", "vertical_m", "heading_error_deg"[, "speed_mps"]}``
  places the body origin at ``range * z_d + lateral * x_d + vertical * y_d`` in the
  dock frame, heading along -z_d (toward the face) rotated by ``heading_error_deg``
  about world +z (positive = nose turned LEFT / counter-clockwise seen from above),
  level, with surge speed ``speed_mps`` (default 0).

Guidance (ground-truth navigation): line-of-sight toward the dock axis point
``lookahead_m`` ahead of the vehicle's projection on the axis (heading), a cross-track
PID on the lateral offset driving the lateral thrusters, depth hold on the axis depth,
and a speed schedule slowing from ``cruise_speed`` to ``final_speed`` inside
``slow_zone_m`` of the face. The current acts physically (relative-velocity drag,
added mass, Coriolis); a steady cross current beyond the lateral thrusters' authority
(~0.6 m/s toward the vehicle's left, ~0.7 m/s toward its right: reverse thrust is
weaker) saturates them, the vehicle drifts, LOS turns the nose into the flow, and
turbulent gusts (Ornstein-Uhlenbeck, :class:`Turbulence`: intensity x |current|,
time scale; seeded) make the heading oscillate. Thrust is
allocated with moment priority (:meth:`ThrusterSet.allocate_prioritized`): when a
group saturates, its force (sway/surge/heave) is given up before the yaw/pitch moment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blendgen.vehicle.control import Autopilot, Sensors
from blendgen.vehicle.dynamics import (
    F_WORLD_NED,
    Plant,
    T_world_body_to_eta,
    VehicleParams,
    check_dt,
    eta_to_T_world_body,
    wrap_pi,
)
from blendgen.vehicle.thrusters import GROUPS, THRUSTER_NAMES

BENCHMARK_DENSITY = 1025.0


def thrust_unit_N(params: VehicleParams | None = None) -> float:
    """Newtons per normalised thrust unit: the benchmark (1025 kg/m^3, no flow) mean
    vertical thrust per thruster, (W - B(1025)) / 2, is mapped to 6 units (as in the
    article's Table 5). For the default vehicle: 38.17 N / 2 / 6 = 3.181 N per unit."""
    params = params or VehicleParams()
    return params.net_weight(BENCHMARK_DENSITY) / 2.0 / 6.0


# ------------------------------------------------------------ station keeping ----
_FLOWS_FLU = {
    "up": (0.0, 0.0, 1.0),
    "down": (0.0, 0.0, -1.0),
    "forward": (1.0, 0.0, 0.0),
    "backward": (-1.0, 0.0, 0.0),
    "left": (0.0, 1.0, 0.0),
    "right": (0.0, -1.0, 0.0),
}


def station_keep_run(
    density: float = 1025.0,
    flow_flu=(0.0, 0.0, 0.0),
    duration_s: float = 60.0,
    dt: float = 0.02,
    params: VehicleParams | None = None,
    depth_m: float = 3.0,
    average_last_s: float = 10.0,
) -> dict:
    """Hold position/heading/depth for ``duration_s`` with a steady current given in the
    vehicle's initial FLU body axes (m/s; the vehicle heads along world +x). Returns
    mean per-thruster thrust (N, FLU sign) over the last ``average_last_s`` seconds,
    the mean position error norm (m) and heading error (deg) over the same window."""
    dt = check_dt(dt)
    params = params or VehicleParams()
    plant = Plant(params, density)
    ap = Autopilot(params, density, plant.thrusters)
    plant.set_pose_ned([0.0, 0.0, depth_m, 0.0, 0.0, 0.0])
    plant.n = ap.hover_speeds()
    vc_ned = tuple(float(c) for c in F_WORLD_NED @ np.asarray(flow_flu, float))
    sensors = Sensors()
    ref = (0.0, 0.0, depth_m)
    n_steps = int(round(duration_s / dt))
    n_avg = max(1, int(round(average_last_s / dt)))
    T_acc = np.zeros(plant.thrusters.n)
    e_acc = 0.0
    h_acc = 0.0
    for k in range(n_steps):
        eta, nu = plant.s[:6], plant.s[6:]
        sens = sensors.read(eta)
        tau = ap.station_keep(eta, nu, sens, ref, 0.0, dt)
        plant.step(ap.thruster_command(tau), vc_ned, dt)
        if k >= n_steps - n_avg:
            T_acc += plant.thrust()
            s = plant.s
            e_acc += math.sqrt(s[0] ** 2 + s[1] ** 2 + (s[2] - depth_m) ** 2)
            h_acc += abs(math.degrees(wrap_pi(s[5])))
    return {
        "thrust_N": T_acc / n_avg,
        "pos_error_m": e_acc / n_avg,
        "heading_error_deg": h_acc / n_avg,
        "final_T_world_body": plant.T_world_body(),
    }


def station_keeping_table(
    densities=(1025, 1075, 975),
    flow_speed: float = 0.5,
    duration_s: float = 60,
    dt: float = 0.02,
    params: VehicleParams | None = None,
):
    """The article's Table 5 as a pandas DataFrame.

    Rows: ``benchmark`` (densities[0], no flow), ``density <rho>`` for the others (no
    flow), then flows ``up/down/forward/backward/left/right`` of ``flow_speed`` m/s at
    densities[0] (directions in the vehicle's FLU body axes: "forward" pushes the
    vehicle forward). Columns: ``main_N``, ``lateral_N``, ``vertical_N`` (mean of each
    thruster pair over the last 10 s; + = forward / left / up), the same in normalised
    units ``main``, ``lateral``, ``vertical`` (1 unit = :func:`thrust_unit_N` =
    3.181 N for the default vehicle, so the benchmark vertical is ~6), ``pos_error_m``
    (mean distance from the held point over the last 10 s) and ``heading_error_deg``.
    """
    import pandas as pd

    params = params or VehicleParams()
    unit = thrust_unit_N(params)
    rho0 = float(densities[0])
    cases = [("benchmark", rho0, "none", (0.0, 0.0, 0.0))]
    cases += [(f"density {float(r):g}", float(r), "none", (0.0, 0.0, 0.0)) for r in densities[1:]]
    cases += [(f"flow {name}", rho0, name, tuple(flow_speed * c for c in v)) for name, v in _FLOWS_FLU.items()]
    rows = []
    for label, rho, flow_name, flow in cases:
        res = station_keep_run(rho, flow, duration_s, dt, params)
        g = {k: float(np.mean(res["thrust_N"][list(idx)])) for k, idx in GROUPS.items()}
        rows.append(
            {
                "condition": label,
                "density_kg_m3": rho,
                "flow": flow_name,
                "flow_speed_mps": 0.0 if flow_name == "none" else float(flow_speed),
                "main_N": g["main"],
                "lateral_N": g["lateral"],
                "vertical_N": g["vertical"],
                "main": g["main"] / unit,
                "lateral": g["lateral"] / unit,
                "vertical": g["vertical"] / unit,
                "pos_error_m": res["pos_error_m"],
                "heading_error_deg": res["heading_error_deg"],
            }
        )
    df = pd.DataFrame(rows).set_index("condition")
    df.attrs["unit_N"] = unit
    df.attrs["unit_note"] = f"normalised thrust: 1 unit = {unit:.3f} N (benchmark vertical mean per thruster = 6 units)"
    return df


def station_keeping_signs_ok(df) -> dict[str, bool]:
    """The qualitative checks of Table 5 on a :func:`station_keeping_table` frame."""
    b = df.loc["benchmark"]
    out: dict[str, bool] = {"benchmark_vertical_up": bool(b["vertical_N"] > 0)}
    for cond, row in df.iterrows():
        if cond.startswith("density "):
            rho = row["density_kg_m3"]
            if rho > b["density_kg_m3"]:
                out[f"{cond}: less vertical"] = bool(row["vertical_N"] < b["vertical_N"])
            elif rho < b["density_kg_m3"]:
                out[f"{cond}: more vertical"] = bool(row["vertical_N"] > b["vertical_N"])
    tol = 0.05  # N: "no demand" in the unaffected groups
    checks = {
        "flow up": lambda r: r["vertical_N"] < b["vertical_N"],
        "flow down": lambda r: r["vertical_N"] > b["vertical_N"],
        "flow forward": lambda r: r["main_N"] < -tol,
        "flow backward": lambda r: r["main_N"] > tol,
        "flow left": lambda r: r["lateral_N"] < -tol,  # flow pushes left -> thrust right
        "flow right": lambda r: r["lateral_N"] > tol,
    }
    for cond, fn in checks.items():
        if cond in df.index:
            out[cond] = bool(fn(df.loc[cond]))
    return out


# ------------------------------------------------------------ docking trials -----
DEFAULT_START_RANGES = {
    "range_m": (6.0, 12.0),
    "lateral_m": (-1.5, 1.5),
    "vertical_m": (-0.5, 0.5),
    "heading_error_deg": (-15.0, 15.0),
}


def random_start(rng: np.random.Generator, cfg: dict | None = None) -> dict:
    """Draw a start uniformly from ranges. ``cfg`` maps the keys of
    :data:`DEFAULT_START_RANGES` (plus optional ``speed_mps``) to ``(lo, hi)`` or to a
    number ``a`` meaning ``(-a, a)``; missing keys use the defaults (range [6, 12] m,
    lateral +-1.5 m, vertical +-0.5 m, heading error +-15 deg, speed 0)."""
    cfg = dict(cfg or {})
    out = {}
    for key, default in list(DEFAULT_START_RANGES.items()) + [("speed_mps", (0.0, 0.0))]:
        v = cfg.get(key, default)
        lo, hi = (-abs(float(v)), abs(float(v))) if np.isscalar(v) else map(float, v)
        out[key] = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
    return out


def _dock_axes(T_world_dock: np.ndarray):
    T = np.asarray(T_world_dock, float)
    if T.shape != (4, 4):
        raise ValueError("T_world_dock must be 4x4")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("T_world_dock rotation is not a proper rotation (orthonormal, det +1)")
    return T[:3, 3], R[:, 0], R[:, 1], R[:, 2]


def start_pose_world(T_world_dock: np.ndarray, start: dict) -> np.ndarray:
    """T_world_body (4x4) of a start dict (see module doc)."""
    o, xd, yd, zd = _dock_axes(T_world_dock)
    p = (
        o
        + float(start.get("range_m", 8.0)) * zd
        + float(start.get("lateral_m", 0.0)) * xd
        + float(start.get("vertical_m", 0.0)) * yd
    )
    f = -zd.copy()
    f[2] = 0.0
    if np.linalg.norm(f) < 1e-6:
        raise ValueError("dock +z axis is vertical: no horizontal approach direction")
    yaw_w = math.atan2(f[1], f[0]) + math.radians(float(start.get("heading_error_deg", 0.0)))
    # level vehicle, world yaw yaw_w -> NED psi = -yaw_w
    return eta_to_T_world_body([p[0], -p[1], -p[2], 0.0, 0.0, -yaw_w])


@dataclass(frozen=True)
class LosGuidance:
    """Line-of-sight guidance along the dock axis: speeds in m/s, distances in m."""

    cruise_speed: float = 0.5
    final_speed: float = 0.2
    slow_zone_m: float = 4.0
    lookahead_m: float = 2.5


@dataclass(frozen=True)
class Turbulence:
    """Ornstein-Uhlenbeck gusts: std = ``intensity`` x |mean current| (m/s), time scale ``time_s``."""

    intensity: float = 0.15
    time_s: float = 2.0


class DockAxesNED:
    """The dock frame seen in NED: origin (3,), lateral/vertical/out-of-face axes, approach heading."""

    def __init__(self, T_world_dock: np.ndarray):
        o_w, xd_w, yd_w, zd_w = _dock_axes(T_world_dock)
        F = F_WORLD_NED
        self.origin, self.axis = F @ o_w, F @ zd_w  # axis: +z_d, out of the face
        self.R_dock_ned = np.vstack([F @ xd_w, F @ yd_w, self.axis])  # rows: dock axes in NED
        lat = F @ xd_w
        lat[2] = 0.0
        self.lateral_h = lat / max(np.linalg.norm(lat), 1e-9)  # horizontal lateral unit vector
        self.approach_psi = math.atan2(-self.axis[1], -self.axis[0])  # NED heading toward the face

    def p_dock(self, p_ned: np.ndarray) -> np.ndarray:
        """NED position (3,) -> dock frame (x lateral, y vertical, z range), metres."""
        return self.R_dock_ned @ (np.asarray(p_ned, float) - self.origin)


def los_references(
    axes: DockAxesNED, guidance: LosGuidance, eta: np.ndarray, stop_distance_m: float
) -> tuple[float, float, float, float]:
    """(psi_ref rad, depth_ref m, u_ref m/s, lateral error m) for the NED pose ``eta`` (6,).

    Aim at the axis point ``lookahead_m`` beyond the vehicle's projection on the axis; hold the
    axis depth; slow from cruise to final speed inside the slow zone, and turn first when way off."""
    p_n = np.asarray(eta[:3], float)
    rel = p_n - axes.origin
    along = float(rel @ axes.axis)
    q = axes.origin + axes.axis * (along - guidance.lookahead_m)
    psi_ref = math.atan2(q[1] - p_n[1], q[0] - p_n[0])
    depth_ref = float(axes.origin[2] + axes.axis[2] * along)
    span = max(guidance.slow_zone_m - stop_distance_m, 1e-6)
    frac = min(max((along - stop_distance_m) / span, 0.0), 1.0)
    u_ref = guidance.final_speed + (guidance.cruise_speed - guidance.final_speed) * frac
    u_ref *= max(math.cos(wrap_pi(psi_ref - eta[5])), 0.0)
    return psi_ref, depth_ref, u_ref, float(rel @ axes.lateral_h)


class Gusts:
    """Seeded current with OU turbulence about a mean NED current (3,) m/s, one draw per step."""

    def __init__(self, rng: np.random.Generator, mean_ned: np.ndarray, turbulence: Turbulence, dt: float, n_steps: int):
        self.mean = np.asarray(mean_ned, float)
        self.sigma = turbulence.intensity * float(np.linalg.norm(self.mean))
        self.a = math.exp(-dt / turbulence.time_s)
        self.noise = (
            rng.standard_normal((n_steps + 1, 3)) * (self.sigma * math.sqrt(1 - self.a**2)) if self.sigma > 0 else None
        )
        self.gust = rng.standard_normal(3) * self.sigma if self.sigma > 0 else np.zeros(3)
        self.k = 0

    def next(self) -> tuple[float, float, float]:
        """Current (NED, m/s) for the next integration step."""
        if self.noise is not None:
            self.gust = self.a * self.gust + self.noise[self.k]
        self.k += 1
        vc = self.mean + self.gust
        return float(vc[0]), float(vc[1]), float(vc[2])


class _TrialLog:
    """Per-frame records of a docking trial."""

    def __init__(self):
        self.rows: list[tuple] = []

    def add(self, t: float, plant: Plant, sens: dict, p_dock: np.ndarray, heading_err_deg: float):
        eta = plant.s[:6]
        self.rows.append((t, eta_to_T_world_body(eta), plant.thrust(), plant.n.copy(), sens, p_dock, heading_err_deg))

    def arrays(self) -> dict:
        t, T, thr, n, sens, pd, he = zip(*self.rows)
        return {
            "t": np.array(t),
            "T_world_body": np.array(T),
            "thrust": np.array(thr),
            "n_rad_s": np.array(n),
            "sensors": {k: np.array([s[k] for s in sens]) for k in sens[0]},
            "p_dock": np.array(pd),
            "heading_error_deg": np.array(he),
        }


@dataclass
class _ClosedLoop:
    """Plant, autopilot and guidance of one trial; ``advance`` integrates one frame period."""

    plant: Plant
    autopilot: Autopilot
    sensors: Sensors
    axes: DockAxesNED
    guidance: LosGuidance
    gusts: Gusts
    n_sub: int  # integration steps per frame
    dt: float  # s per step
    stop_distance_m: float

    def advance(self) -> None:
        """``n_sub`` steps of LOS guidance + cross-track PID (lateral thrusters) on the true state."""
        ap, plant = self.autopilot, self.plant
        for _ in range(self.n_sub):
            eta, nu = plant.s[:6], plant.s[6:]
            sens = self.sensors.read(eta)
            psi_ref, depth_ref, u_ref, e_lat = los_references(self.axes, self.guidance, eta, self.stop_distance_m)
            v_n = ap._R(eta) @ np.asarray(nu[:3])
            f_lat = ap.sway_pid.update(-e_lat, -float(v_n @ self.axes.lateral_h), self.dt)
            tau = ap.track(
                eta, nu, sens, depth_ref, psi_ref, u_ref, self.dt, cross_force_ned=f_lat * self.axes.lateral_h
            )
            plant.step(ap.thruster_command(tau), self.gusts.next(), self.dt)


def simulate_docking_trial(
    T_world_dock: np.ndarray,
    start: dict,
    current_world=(0.0, 0.0, 0.0),
    density: float = 1025.0,
    fps: float = 10.0,
    stop_distance_m: float = 0.5,
    max_time_s: float = 120,
    seed=None,
    dt: float = 0.02,
    params: VehicleParams | None = None,
    guidance: LosGuidance = LosGuidance(),
    turbulence: Turbulence = Turbulence(),
) -> dict:
    """Closed-loop docking approach on ground-truth navigation; frames sampled at ``fps``.

    Twelve keyword parameters (a reason): they are the trial's independent physical settings
    (fluid, sampling, vehicle, guidance, turbulence) with documented defaults, and callers name them.
    The integration step is ``dt`` shrunk (if needed) to divide the frame period
    exactly: ``dt_eff = 1 / (fps * ceil(1 / (fps * dt)))``. The stop test
    (body origin within ``stop_distance_m`` of the face plane, i.e. dock-frame z <=
    stop distance) is evaluated at frame times; the last frame is the one where it holds
    (``stop_reason = "reached"``) or ``max_time_s`` (``"timeout"``).

    Returns a dict:
      ``t`` (N,) s; ``T_world_body`` (N,4,4) world +z up, body FLU;
      ``thrust`` (N,6) N per thruster (order :data:`THRUSTER_NAMES`; + = forward /
      left / up); ``n_rad_s`` (N,6); ``sensors``: dict of (N,) arrays ``depth_m``,
      ``heading_deg``, ``pitch_deg``, ``roll_deg`` (quantised readings);
      ``p_dock`` (N,3) body origin in the dock frame (x lateral, y vertical, z range);
      ``heading_error_deg`` (N,) body heading minus the approach direction (+ = left);
      ``stop_reason``, ``final_distance_m``, ``final_lateral_m``, ``final_vertical_m``,
      ``dt``, ``seed``, ``start``, ``current_world``, ``density``, ``thruster_names``.
    """
    check_dt(dt)
    if fps <= 0:
        raise ValueError("fps must be positive")
    n_sub = max(1, math.ceil((1.0 / fps) / dt - 1e-9))
    dt = 1.0 / (fps * n_sub)
    params = params or VehicleParams()
    rng = np.random.default_rng(seed)
    axes = DockAxesNED(T_world_dock)
    plant = Plant(params, density)
    ap = Autopilot(params, density, plant.thrusters)
    plant.set_pose_ned(
        T_world_body_to_eta(start_pose_world(T_world_dock, start)), [float(start.get("speed_mps", 0.0)), 0, 0, 0, 0, 0]
    )
    plant.n = ap.hover_speeds()
    sensors = Sensors()
    n_frames_max = int(math.floor(max_time_s * fps + 1e-9)) + 1
    gusts = Gusts(rng, F_WORLD_NED @ np.asarray(current_world, float), turbulence, dt, (n_frames_max - 1) * n_sub)
    loop = _ClosedLoop(plant, ap, sensors, axes, guidance, gusts, n_sub, dt, stop_distance_m)
    log, stop_reason = _TrialLog(), "timeout"
    for frame in range(n_frames_max):
        eta = plant.s[:6]
        p_dock = axes.p_dock(eta[:3])
        log.add(frame / fps, plant, sensors.read(eta), p_dock, -math.degrees(wrap_pi(eta[5] - axes.approach_psi)))
        if p_dock[2] <= stop_distance_m:
            stop_reason = "reached"
            break
        if frame == n_frames_max - 1:
            break
        loop.advance()
        if not all(map(math.isfinite, plant.s)):
            raise FloatingPointError("docking simulation diverged")
    out = log.arrays()
    pd_arr = out["p_dock"]
    return {
        **out,
        "stop_reason": stop_reason,
        "final_distance_m": float(pd_arr[-1, 2]),
        "final_lateral_m": float(pd_arr[-1, 0]),
        "final_vertical_m": float(pd_arr[-1, 1]),
        "dt": dt,
        "seed": seed,
        "start": dict(start),
        "current_world": tuple(float(c) for c in current_world),
        "density": float(density),
        "thruster_names": THRUSTER_NAMES,
    }


__all__ = [
    "station_keeping_table",
    "station_keeping_signs_ok",
    "station_keep_run",
    "thrust_unit_N",
    "random_start",
    "start_pose_world",
    "simulate_docking_trial",
    "DEFAULT_START_RANGES",
    "LosGuidance",
    "Turbulence",
    "DockAxesNED",
    "los_references",
]
