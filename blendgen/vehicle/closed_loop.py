"""Closed-loop docking: the vehicle steers on a localizer's estimate (or on ground truth).

Pure numpy; the camera is a callback. Each camera frame (``fps``) the true camera pose is
handed to ``observe(frame, t, T_world_cam) -> Observation`` (the tools layer renders the
frame and runs the localizer under test); the estimate becomes a :class:`DockFix`, the
:class:`RelativePoseFilter` (a constant-velocity Kalman filter, :mod:`blendgen.vehicle.visual_nav`) fuses it
with the depth and attitude sensors, and between frames the same LOS guidance law as the
ground-truth trials (:func:`blendgen.vehicle.docking.los_references` + the cross-track PID)
runs on the filtered relative pose at the control rate. With ``observe=None`` guidance uses
the true state: the baseline row (what perfect localization would give).

Latency (``TrialSetup.latency_s`` camera link + ``compute_latency`` localizer time, both 0 by
default): the estimate of a frame captured at ``t`` reaches the filter at ``t + latency``
and is processed as a delayed measurement stamped ``t``, then re-propagated to now
(:class:`DelayLine`); with both 0 the fix updates the filter at its capture time, as before.

Docking is judged by geometry. Every frame the hull (a capsule of the vehicle's length and
diameter) is tested against the dock's collision geometry (:mod:`blendgen.vehicle.contact`: the
body box with its face plate and sides, and the funnel cone through it): a touch ends the trial
as ``collision`` with ``contact_part`` and ``impact_speed_mps`` (the hull's contact point's speed
into the dock along the surface normal, m/s). With ``TrialSetup.water`` the hull is tested against
the water's solid faces as well (a pool's walls and floor, open water's seabed;
:class:`blendgen.vehicle.contact.WaterSolid`, world frame): a touch is a ``collision`` with
``contact_part`` ``pool_wall``, ``pool_floor`` or ``seabed``. When the camera (at the nose) crosses the dock's
entry plane the capture test (:func:`blendgen.vehicle.visual_nav.crossing_outcome`) decides:
inside the capture radius ``docked`` (or ``misaligned``); on the face plate grown by the hull
radius ``collision`` (when the frame-rate contact test missed it between frames); beside the
dock ``out_of_capture``. A trial also ends when the target is lost or at ``max_time_s``
(``timeout``).

Lost target (:class:`Recovery`), like a vehicle without a fix: for ``FilterParams.hold_s`` after
the last accepted fix guidance keeps steering on the navigation filter's dead-reckoned estimate
(mode ``dead_reckoning``); then it turns the nose to the last estimated bearing of the dock, holds
the dock's estimated depth and backs off along that bearing at ``backoff_speed_mps`` for
``backoff_s`` (``back_off``: the dock re-enters a wider part of the field of view), then holds
there facing the dock (``hold``). A fix accepted in any of these modes re-acquires the target
(the filter restarts on it; counted in ``reacquisitions``); none for ``FilterParams.lost_s`` aborts
the trial (``lost_target``, with ``lost_after_s``). Before the first fix the vehicle holds its start heading (the
prior bearing to the dock that
a homing stage, e.g. acoustic, hands over; the starts face the dock within their heading range)
and depth and creeps on at the final approach speed (``acquire``) until the camera sees the dock,
or ``lost_s`` after the start. This is the abort-and-retry pattern of
operational docking (the REMUS docking system backs out and re-tries a missed approach: Stokey
et al., "Enabling technologies for REMUS docking", IEEE J. Oceanic Eng. 26(4), 2001).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from blendgen.vehicle.contact import DockSolid, Hull, WaterSolid, hull_contact, impact_speed, water_contact
from blendgen.vehicle.control import Autopilot, Sensors
from blendgen.vehicle.docking import DockAxesNED, Gusts, LosGuidance, Turbulence, los_references, start_pose_world
from blendgen.vehicle.dynamics import (
    F_WORLD_NED,
    Plant,
    T_world_body_to_eta,
    VehicleParams,
    check_dt,
    eta_to_T_world_body,
    wrap_pi,
)
from blendgen.vehicle.visual_nav import (
    CaptureSpec,
    FilterParams,
    RelativePoseFilter,
    crossing_outcome,
    fix_from_estimate,
    interpolate_crossing,
)


@dataclass
class Observation:
    """What the camera + localizer gave for one frame: the estimate (``distance`` m, optional
    ``T_cam_dock`` 4x4) or None, and per-frame facts to log (``d_true``, ``in_view``, ``ms``,
    ``fail_reason``...)."""

    estimate: dict | None
    info: dict = field(default_factory=dict)


Observer = Callable[[int, float, np.ndarray], Observation]
RECOVERY_MODES = ("back_off", "hold")  # lost-target modes of :class:`_EstimateNav`


@dataclass(frozen=True)
class Recovery:
    """Lost-target behaviour after the dead-reckoning window (module doc): back off at
    ``backoff_speed_mps`` (m/s; default the final approach speed of
    :class:`blendgen.vehicle.docking.LosGuidance`, a speed the autopilot is tuned for) for
    ``backoff_s`` (s; 12 s: ~3 s to stop from the 0.5 m/s cruise through the autopilot's speed
    reference model, then ~9 s x 0.2 m/s = 1.8 m back, about the 1.5 m half-width of the start box),
    then hold until ``FilterParams.lost_s`` after the last fix."""

    backoff_speed_mps: float = 0.2
    backoff_s: float = 12.0

    def __post_init__(self):
        if not (0.0 <= self.backoff_speed_mps <= 2.0 and 0.0 <= self.backoff_s <= 600.0):
            raise ValueError(
                f"Recovery: need backoff_speed_mps in [0, 2] m/s and backoff_s in [0, 600] s, got "
                f"{self.backoff_speed_mps}, {self.backoff_s}"
            )


@dataclass(frozen=True)
class TrialSetup:
    """One closed-loop trial's physical settings (SI units; ``start`` as in
    :func:`blendgen.vehicle.docking.start_pose_world`; ``T_body_cam`` 4x4)."""

    T_world_dock: np.ndarray
    start: dict
    T_body_cam: np.ndarray
    capture: CaptureSpec
    current_world: tuple = (0.0, 0.0, 0.0)
    density: float = 1025.0
    fps: float = 10.0
    max_time_s: float = 120.0
    seed: int = 0
    dt: float = 0.02
    guidance: LosGuidance = LosGuidance()
    turbulence: Turbulence = Turbulence()
    filter: FilterParams = FilterParams()
    recovery: Recovery = Recovery()
    params: VehicleParams = VehicleParams()
    latency_s: float = 0.0
    compute_latency: float | str = 0.0
    dock_size_m: tuple = (1.0, 1.0, 0.4)  # the dock model's body (w, h, depth): config Dock.body_size_m
    water: WaterSolid | None = None  # the pool's walls and floor / the seabed (world frame); None: none

    def __post_init__(self):
        if not 0.0 <= self.latency_s <= 10.0:
            raise ValueError(f"latency_s must be in [0, 10] s, got {self.latency_s}")
        c = self.compute_latency
        if c != "measured" and not (isinstance(c, (int, float)) and 0.0 <= float(c) <= 10.0):
            raise ValueError(f"compute_latency must be 'measured' or in [0, 10] s, got {self.compute_latency!r}")

    @property
    def delayed(self) -> bool:
        """True when estimates reach guidance later than the frame's capture (latency path)."""
        return self.latency_s > 0 or self.compute_latency == "measured" or float(self.compute_latency) > 0


class DelayLine:
    """Estimates in flight between the camera and guidance (camera link + localizer compute).

    A frame captured at ``t_capture`` reaches guidance at ``t_capture + latency_s + compute``
    (``compute`` = the configured seconds, or the localizer's measured time of that frame when
    ``compute_latency == "measured"``); arrivals are kept in capture order (a localizer works
    on one frame at a time, so a frame cannot overtake the one before it). The filter is then
    updated with the fix *stamped at its capture time* and guidance reads the state
    dead-reckoned to now: delayed-measurement processing by re-propagation (exact for this
    filter, whose only inputs are the fixes; Bar-Shalom, Li & Kirubarajan, *Estimation with
    Applications to Tracking and Navigation*, 2001, sec. 10.5 and the out-of-sequence
    measurement literature, here with in-sequence arrivals). The fix uses the attitude and
    depth sensors of the capture instant."""

    def __init__(self, latency_s: float, compute_latency: float | str):
        self.latency_s, self.compute = latency_s, compute_latency
        self.queue: list[tuple[float, float, object]] = []  # (t_arrive, t_capture, fix)
        self.last_arrival = -math.inf

    def push(self, t_capture: float, fix, measured_ms: float) -> None:
        extra = (
            (measured_ms / 1e3 if math.isfinite(measured_ms) else 0.0)
            if self.compute == "measured"
            else float(self.compute)
        )
        self.last_arrival = max(self.last_arrival, t_capture + self.latency_s + extra)
        self.queue.append((self.last_arrival, t_capture, fix))

    def deliver(self, filt: RelativePoseFilter, t: float) -> None:
        """Update ``filt`` with every fix that has arrived by ``t`` (capture order)."""
        while self.queue and self.queue[0][0] <= t + 1e-9:
            _, t_cap, fix = self.queue.pop(0)
            filt.update(t_cap, fix)


class _TruthNav:
    """Ground-truth navigation: LOS on the true pose, true lateral rate."""

    mode = "truth"

    def __init__(self, axes: DockAxesNED, guidance: LosGuidance, stop_m: float):
        self.axes, self.guidance, self.stop_m = axes, guidance, stop_m

    def references(self, ap: Autopilot, t: float, eta, nu, sens: dict, dt: float):
        psi_ref, depth_ref, u_ref, e_lat = los_references(self.axes, self.guidance, eta, self.stop_m)
        v_lat = float((ap._R(eta) @ np.asarray(nu[:3])) @ self.axes.lateral_h)
        f = ap.sway_pid.update(-e_lat, -v_lat, dt)
        return psi_ref, depth_ref, u_ref, f * self.axes.lateral_h


class _EstimateNav:
    """LOS on the filtered relative pose (dead-reckoned between fixes for ``hold_s``); then the
    :class:`Recovery` manoeuvre: face the last estimated dock bearing, back off, hold. Before the
    first fix: ``acquire``. ``mode`` is the current one (``acquire``, ``tracking``,
    ``dead_reckoning``, ``back_off``, ``hold``)."""

    def __init__(
        self,
        filt: RelativePoseFilter,
        origin_xy: np.ndarray,
        guidance: LosGuidance,
        stop_m: float,
        recovery: Recovery = Recovery(),
        frame_s: float = 0.1,
    ):
        self.filt, self.origin_xy, self.guidance, self.stop_m = filt, origin_xy, guidance, stop_m
        self.recovery, self.frame_s = recovery, frame_s  # frame_s: camera frame period (s)
        self._axes_key, self._axes, self._held, self.mode = None, None, None, "acquire"

    def _axes_hat(self) -> DockAxesNED:
        key = (self.filt.psi_dock, self.filt.depth_dock)
        if key != self._axes_key:
            self._axes_key, self._axes = key, DockAxesNED(self.filt.T_world_dock(self.origin_xy))
        return self._axes

    def _recover(self, t: float, sens: dict):
        """References while the target is lost (after the dead-reckoning window), or not yet seen."""
        if not self.filt.initialised:  # never seen: creep on along the start (prior) bearing
            if self._held is None:
                self._held = (math.radians(sens["heading_deg"]), sens["depth_m"])
            self.mode = "acquire"
            return self._held[0], self._held[1], self.guidance.final_speed, None
        if self._held is None or self.mode == "acquire":  # freeze the last dock estimate: bearing, depth
            p, _ = self.filt.state(self.filt.t_fix + self.filt.p.hold_s, sens["depth_m"])
            to_dock = -(self._axes_hat().R_dock_ned.T @ p)  # NED, vehicle -> dock origin
            depth = self.filt.depth_dock if math.isfinite(self.filt.depth_dock) else sens["depth_m"]
            self._held = (math.atan2(to_dock[1], to_dock[0]), depth)
        lost_for = self.filt.since_fix(t) - self.filt.p.hold_s
        backing = lost_for <= self.recovery.backoff_s
        self.mode = "back_off" if backing else "hold"
        return self._held[0], self._held[1], -self.recovery.backoff_speed_mps if backing else 0.0, None

    def references(self, ap: Autopilot, t: float, eta, nu, sens: dict, dt: float):
        if not self.filt.fresh(t):
            return self._recover(t, sens)
        self._held = None
        self.mode = "tracking" if self.filt.since_fix(t) <= self.frame_s + 1e-9 else "dead_reckoning"
        p, v = self.filt.state(t, sens["depth_m"])
        axes = self._axes_hat()
        pos = axes.origin + axes.R_dock_ned.T @ p
        att = [math.radians(sens[k]) for k in ("roll_deg", "pitch_deg", "heading_deg")]
        psi_ref, depth_ref, u_ref, e_lat = los_references(axes, self.guidance, np.r_[pos, att], self.stop_m)
        f = ap.sway_pid.update(-e_lat, -float(v[0]), dt)
        return psi_ref, depth_ref, u_ref, f * axes.lateral_h


def _nose_dock(axes: DockAxesNED, eta, T_body_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T_world_cam 4x4, camera centre in the dock frame (3,))."""
    T_wc = eta_to_T_world_body(eta) @ T_body_cam
    return T_wc, axes.p_dock(F_WORLD_NED @ T_wc[:3, 3])


def _start(setup: TrialSetup):
    """Plant, autopilot, sensors and the frame-period split of one trial."""
    check_dt(setup.dt)
    if setup.fps <= 0:
        raise ValueError(f"fps must be positive, got {setup.fps}")
    n_sub = max(1, math.ceil((1.0 / setup.fps) / setup.dt - 1e-9))
    dt = 1.0 / (setup.fps * n_sub)
    plant = Plant(setup.params, setup.density)
    ap = Autopilot(setup.params, setup.density, plant.thrusters)
    plant.set_pose_ned(
        T_world_body_to_eta(start_pose_world(setup.T_world_dock, setup.start)),
        [float(setup.start.get("speed_mps", 0.0)), 0, 0, 0, 0, 0],
    )
    plant.n = ap.hover_speeds()
    return plant, ap, Sensors(), n_sub, dt


def _crossing(setup: TrialSetup, axes: DockAxesNED, prev: np.ndarray, nose: np.ndarray, plant: Plant) -> dict:
    """Outcome record of the frame where the nose passed the entry plane."""
    eta, nu = plant.s[:6], plant.s[6:]
    pt = interpolate_crossing(prev, nose, setup.capture.entry_plane_m)
    head = -math.degrees(wrap_pi(eta[5] - axes.approach_psi))
    R = Autopilot._R(eta)
    v_lat = float((R @ np.asarray(nu[:3])) @ axes.R_dock_ned[0])
    outcome = crossing_outcome(setup.capture, pt, head, v_lat)
    out = {
        "outcome": outcome,
        "cross_lateral_m": float(pt[0]),
        "cross_vertical_m": float(pt[1]),
        "cross_heading_deg": head,
        "cross_lateral_speed_mps": v_lat,
    }
    if outcome == "collision":
        out["impact_speed_mps"] = nose_closing_speed(axes, eta, nu, setup.T_body_cam)
        inside_mouth = math.hypot(pt[0], pt[1]) <= min(setup.dock_size_m[:2]) / 2
        out["contact_part"] = "funnel" if inside_mouth else "face_plate"
    return out


class HullContact:
    """The hull against the dock's collision geometry and the water's solid faces (``setup.water``:
    the pool's walls and floor, or the seabed; :mod:`blendgen.vehicle.contact`) at the plant's state;
    ``hit(plant)`` -> collision record or None."""

    MARGIN_M = 0.05  # skip the exact test while the body origin is this far beyond any reach

    def __init__(self, setup: TrialSetup):
        p = setup.params
        self.solid = DockSolid.from_dock(setup.dock_size_m, p.diameter / 2)
        self.hull = Hull.from_vehicle(p.length, p.diameter)
        self.T_dock_world = np.linalg.inv(np.asarray(setup.T_world_dock, float))
        self.reach = self.hull.half_axis + self.hull.radius + self.MARGIN_M
        self.water = setup.water

    def hit(self, plant: Plant) -> dict | None:
        """Collision record (``outcome``, ``contact_part``, ``impact_speed_mps``, ``contact_*_m``: the
        point touched in the dock frame, m) if the hull touches or penetrates the dock or a solid face
        of the water, else None; both touching: the deeper one."""
        eta, nu = plant.s[:6], plant.s[6:]
        T_wb = eta_to_T_world_body(eta)  # world (+z up), body FLU
        R_wb = F_WORLD_NED @ Autopilot._R(eta)  # body FRD -> NED -> world (F: a rotation, det +1)
        v_w, w_w = R_wb @ np.asarray(nu[:3], float), R_wb @ np.asarray(nu[3:6], float)  # world, m/s, rad/s
        hits = [h for h in (self._dock_hit(T_wb, v_w, w_w), self._water_hit(T_wb, v_w, w_w)) if h is not None]
        return min(hits, key=lambda h: h[0])[1] if hits else None

    def _dock_hit(self, T_wb: np.ndarray, v_w: np.ndarray, w_w: np.ndarray) -> tuple[float, dict] | None:
        """(clearance m, record) of a touch of the dock, else None; velocities in the world frame."""
        T_db = self.T_dock_world @ T_wb
        o, sd = T_db[:3, 3], self.solid
        centre = np.array([0.0, 0.0, -sd.depth / 2])  # of the dock's box
        gap = np.maximum(np.abs(o - centre) - [sd.half_w, sd.half_h, sd.depth / 2], 0.0)  # origin to box
        if np.linalg.norm(gap) > self.reach:
            return None
        c = hull_contact(sd, self.hull, T_db)
        if c.clearance_m > 0:
            return None
        R_dw = self.T_dock_world[:3, :3]
        speed = impact_speed(c, self.hull, R_dw @ v_w, R_dw @ w_w, T_db)
        return c.clearance_m, self._record(c.part, speed, c.point_dock)

    def _water_hit(self, T_wb: np.ndarray, v_w: np.ndarray, w_w: np.ndarray) -> tuple[float, dict] | None:
        """(clearance m, record) of a touch of a wall, the floor or the seabed, else None."""
        if self.water is None:
            return None
        c = water_contact(self.water, self.hull, T_wb)
        if c.clearance_m > 0:
            return None
        p_dock = self.T_dock_world[:3, :3] @ c.point_world + self.T_dock_world[:3, 3]
        return c.clearance_m, self._record(c.part, impact_speed(c, self.hull, v_w, w_w, T_wb), p_dock)

    @staticmethod
    def _record(part: str, speed: float, p_dock: np.ndarray) -> dict:
        """The collision record: part, impact speed (m/s), the point touched (dock frame, m)."""
        return {
            "outcome": "collision",
            "contact_part": part,
            "impact_speed_mps": speed,
            "contact_lateral_m": float(p_dock[0]),
            "contact_vertical_m": float(p_dock[1]),
            "contact_range_m": float(p_dock[2]),
        }


def _judge(setup: TrialSetup, axes: DockAxesNED, touch: HullContact, prev, nose, plant: Plant) -> dict | None:
    """The trial's end at this frame, or None: the capture test when the nose crossed the entry
    plane (a docked/misaligned crossing stands; otherwise a hull touch names the part hit), else
    a hull touch."""
    if prev is not None and prev[2] > setup.capture.entry_plane_m >= nose[2]:
        res = _crossing(setup, axes, prev, nose, plant)
        if res["outcome"] in ("docked", "misaligned"):
            return res
        hit = touch.hit(plant)
        return res if hit is None else {**res, **hit}
    return touch.hit(plant)


def nose_closing_speed(axes: DockAxesNED, eta, nu, T_body_cam: np.ndarray) -> float:
    """Speed (m/s) of the nose (the camera centre, ``T_body_cam``) toward the dock face, along the face
    normal: the impact speed of a hit on the dock's frame. Rigid body: v_nose = v + omega x r (FRD)."""
    r = F_WORLD_NED @ np.asarray(T_body_cam, float)[:3, 3]  # FLU -> FRD (same diag flip)
    v = np.asarray(nu[:3], float) + np.cross(np.asarray(nu[3:6], float), r)
    return float(-(axes.R_dock_ned @ (Autopilot._R(eta) @ v))[2])


def simulate_closed_loop(setup: TrialSetup, observe: Observer | None = None) -> dict:
    """Run one trial; ``observe`` None = ground-truth guidance (no camera needed).

    Returns ``{"outcome": str (visual_nav.OUTCOMES), "t_end": s, "time_to_dock_s": s or NaN,
    "cross_*": crossing offsets (m), heading (deg), lateral speed (m/s) or NaN, "impact_speed_mps"
    (collision only, else NaN), "contact_part" (collision: :data:`blendgen.vehicle.contact.PARTS`, the
    dock's parts or the water's ``pool_wall``/``pool_floor``/``seabed``, else ""),
    "contact_lateral_m"/"contact_vertical_m"/"contact_range_m" (the dock, wall or floor point touched,
    dock frame, m, else NaN), "lost_after_s" (lost_target only: s since the last fix, else NaN),
    "reacquisitions" (fixes that ended a back_off/hold),
    "final_lateral_m", "final_vertical_m", "final_range_m", "final_heading_deg" (body origin
    at the last frame), "frames": list of per-frame dicts}`` with frame keys ``t``,
    ``x_world``, ``y_world``, ``z_world`` (body origin, m), ``lateral_m``, ``vertical_m``,
    ``range_m`` (body origin, dock frame), ``x_cam_world``, ``y_cam_world`` (camera = nose), ``heading_err_deg``,
    ``fix`` (bool), ``est_lateral_m``,
    ``est_range_m`` (filtered, NaN if none), ``nav_mode`` (truth, tracking, dead_reckoning, back_off,
    hold) and the observer's ``info``."""
    plant, ap, sensors, n_sub, dt = _start(setup)
    rng = np.random.default_rng(setup.seed)
    axes = DockAxesNED(setup.T_world_dock)
    n_max = int(math.floor(setup.max_time_s * setup.fps + 1e-9)) + 1
    gusts = Gusts(rng, F_WORLD_NED @ np.asarray(setup.current_world, float), setup.turbulence, dt, (n_max - 1) * n_sub)
    stop_m = float(setup.T_body_cam[0, 3]) + setup.capture.entry_plane_m
    filt = RelativePoseFilter(setup.filter)
    nav = (
        _TruthNav(axes, setup.guidance, stop_m)
        if observe is None
        else _EstimateNav(
            filt, np.asarray(setup.T_world_dock)[:2, 3], setup.guidance, stop_m, setup.recovery, 1.0 / setup.fps
        )
    )
    reacquired, touch = 0, HullContact(setup)
    delay = DelayLine(setup.latency_s, setup.compute_latency) if setup.delayed and observe is not None else None
    frames, res, prev = [], {"outcome": "timeout"}, None
    for k in range(n_max):
        t, eta = k / setup.fps, plant.s[:6].copy()
        T_wc, nose = _nose_dock(axes, eta, setup.T_body_cam)
        end = _judge(setup, axes, touch, prev, nose, plant)
        if end is not None:
            res = end
            break
        prev = nose
        sens = sensors.read(eta)
        row = _frame_row(t, eta, axes)
        row.update(x_cam_world=float(T_wc[0, 3]), y_cam_world=float(T_wc[1, 3]))
        if observe is not None:
            _observe_frame(observe, setup, filt, delay, k, t, T_wc, sens, row)
            if nav.mode in RECOVERY_MODES and filt.fresh(t):
                reacquired, nav.mode = reacquired + 1, "tracking"
            if filt.lost(t):
                frames.append({**row, "nav_mode": nav.mode})
                res = {"outcome": "lost_target", "lost_after_s": filt.since_fix(t)}
                break
        frames.append({**row, "nav_mode": nav.mode})
        if k == n_max - 1:
            break
        for j in range(n_sub):
            if delay is not None and j:
                delay.deliver(filt, t + j * dt)
            eta, nu = plant.s[:6], plant.s[6:]
            s = sensors.read(eta)
            psi_ref, depth_ref, u_ref, f_ned = nav.references(ap, t + j * dt, eta, nu, s, dt)
            tau = ap.track(eta, nu, s, depth_ref, psi_ref, u_ref, dt, cross_force_ned=f_ned)
            plant.step(ap.thruster_command(tau), gusts.next(), dt)
        if not all(map(math.isfinite, plant.s)):
            raise FloatingPointError("closed-loop docking simulation diverged")
    return _summary({**res, "reacquisitions": reacquired}, frames, setup.fps, k)


def _observe_frame(
    observe: Observer,
    setup: TrialSetup,
    filt: RelativePoseFilter,
    delay: DelayLine | None,
    k: int,
    t: float,
    T_wc: np.ndarray,
    sens: dict,
    row: dict,
) -> None:
    """Frame ``k``: capture + localize, then update the filter now (no latency) or queue the fix
    (:class:`DelayLine`); log the estimate guidance holds at ``t`` into ``row``."""
    obs = observe(k, t, T_wc)
    fix = None if obs.estimate is None else fix_from_estimate(obs.estimate, setup.T_body_cam, sens)
    if delay is None:
        filt.update(t, fix)
    else:
        filt.update(t, None)  # starts the lost-target clock at the first frame
        if fix is not None:
            delay.push(t, fix, float(obs.info.get("ms", math.nan)))
        delay.deliver(filt, t)
    p_hat = filt.state(t, sens["depth_m"])[0] if filt.initialised else np.full(3, math.nan)
    row.update(obs.info, fix=fix is not None, est_lateral_m=float(p_hat[0]), est_range_m=float(p_hat[2]))


def _frame_row(t: float, eta, axes: DockAxesNED) -> dict:
    p_w = F_WORLD_NED @ np.asarray(eta[:3])
    p_d = axes.p_dock(eta[:3])
    return {
        "t": t,
        "x_world": float(p_w[0]),
        "y_world": float(p_w[1]),
        "z_world": float(p_w[2]),
        "lateral_m": float(p_d[0]),
        "vertical_m": float(p_d[1]),
        "range_m": float(p_d[2]),
        "heading_err_deg": -math.degrees(wrap_pi(eta[5] - axes.approach_psi)),
    }


def _summary(res: dict, frames: list[dict], fps: float, k_end: int) -> dict:
    nan = math.nan
    last = frames[-1] if frames else dict.fromkeys(("lateral_m", "vertical_m", "range_m", "heading_err_deg"), nan)
    out = {
        "cross_lateral_m": nan,
        "cross_vertical_m": nan,
        "cross_heading_deg": nan,
        "cross_lateral_speed_mps": nan,
        "impact_speed_mps": nan,
        "contact_part": "",
        "contact_lateral_m": nan,
        "contact_vertical_m": nan,
        "contact_range_m": nan,
        "lost_after_s": nan,
        **res,
        "t_end": k_end / fps,
        "final_lateral_m": last["lateral_m"],
        "final_vertical_m": last["vertical_m"],
        "final_range_m": last["range_m"],
        "final_heading_deg": last["heading_err_deg"],
        "frames": frames,
    }
    out["time_to_dock_s"] = out["t_end"] if out["outcome"] == "docked" else nan
    return out


__all__ = [
    "Observation",
    "Observer",
    "TrialSetup",
    "Recovery",
    "DelayLine",
    "simulate_closed_loop",
    "nose_closing_speed",
    "HullContact",
    "RECOVERY_MODES",
]
