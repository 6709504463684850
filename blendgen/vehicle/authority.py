"""Thruster authority: can the vehicle hold station (or a docking approach) against a steady current?

Pure numpy, no simulation: a steady state is solved directly. A vehicle holding a fixed pose in a
steady current ``v_c`` moves through the water at ``nu_r = -v_c`` (body axes), so the equations of
motion of :mod:`blendgen.vehicle.dynamics` (Fossen 2021, eq. 10.x) reduce to

    tau = D(nu_r) nu_r + C_A(nu_r) nu_r + g(eta),

with zero body rates. For this hull ``C_A(nu_r) nu_r`` vanishes at zero rates (equal sway and heave
added mass, Munk moments off: :class:`blendgen.vehicle.dynamics.VehicleParams`), ``D`` is diagonal
(linear + quadratic, ``d_i + d_q,i |v_i|``) and ``g`` at level attitude is the net weight
``W - B(rho)`` on heave. The required generalized force is allocated exactly as the autopilot does
(the least-norm pseudo-inverse on X Y Z M N, :meth:`blendgen.vehicle.thrusters.ThrusterSet.allocate`)
and each thruster's share is compared with its forward or reverse limit (reverse thrust is weaker:
``Thruster.reverse_ratio``). The *utilisation* of a thruster is share / limit; the vehicle can hold
the current when every utilisation is <= 1, and the *margin* is ``1 - max utilisation``.

For a docking approach the question is the same with the vehicle moving along the dock axis at the
final approach speed, its heading allowed anywhere within the capture's heading limit (crabbing into
the flow helps only as far as the capture geometry allows it): :func:`docking_authority` takes the
best heading of that range. A condition whose mean current fails this test is *beyond the vehicle's
authority*: no guidance law can dock it within the capture limits, so a failure there is not a
guidance or localization failure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blendgen.vehicle.dynamics import F_WORLD_NED, R_ned_frd, VehicleParams
from blendgen.vehicle.thrusters import F_FLU_FRD, GROUPS, ThrusterSet

# Directions of the flow in the vehicle's FLU body axes ("forward" pushes the vehicle forward).
FLOW_DIRECTIONS_FLU = {
    "forward": (1.0, 0.0, 0.0),
    "backward": (-1.0, 0.0, 0.0),
    "left": (0.0, 1.0, 0.0),
    "right": (0.0, -1.0, 0.0),
    "up": (0.0, 0.0, 1.0),
    "down": (0.0, 0.0, -1.0),
}
SPEED_SEARCH_MAX_MPS = 5.0  # bisection bracket for the largest holdable speed (m/s)


def required_force_frd(params: VehicleParams, rho: float, v_rel_frd) -> np.ndarray:
    """Steady generalized force (6,) FRD (N, N m) the thrusters must give to move through the water at
    ``v_rel_frd`` (3,) m/s (body FRD, vehicle relative to the water) level and without rotating:
    linear + quadratic damping plus the net weight on heave (module doc)."""
    v = np.asarray(v_rel_frd, float)
    dl, dq = params.linear_damping()[:3], np.asarray(params.quad_damping[:3], float)
    tau = np.zeros(6)
    tau[:3] = (dl + dq * np.abs(v)) * v
    tau[2] -= params.net_weight(rho)
    return tau


def thruster_utilisation(thrusters: ThrusterSet, rho: float, tau_frd) -> tuple[np.ndarray, np.ndarray]:
    """(thrusts (n,) N in FLU sign, utilisation (n,) = thrust / its forward or reverse limit, >= 0)."""
    T = thrusters.allocate(np.asarray(tau_frd, float))
    T = np.where(np.abs(T) < 1e-9, 0.0, T)  # allocation round-off on idle thrusters
    hi = thrusters.max_thrust(rho)
    lo = hi * thrusters.K_T_rev / thrusters.K_T
    return T, np.where(T >= 0.0, T / hi, -T / lo)


@dataclass(frozen=True)
class Hold:
    """Steady hold against one relative flow: group thrusts (N, mean of each pair, FLU sign), the
    largest thruster utilisation, whether it is <= 1, and which group limits it."""

    thrust_N: dict
    utilisation: float
    holds: bool
    limiting_group: str

    @property
    def margin(self) -> float:
        """Fraction of the limiting thruster's thrust left over (negative = short by that fraction)."""
        return 1.0 - self.utilisation


def hold(
    v_rel_frd, rho: float = 1025.0, params: VehicleParams | None = None, thrusters: ThrusterSet | None = None
) -> Hold:
    """The :class:`Hold` of the vehicle moving through the water at ``v_rel_frd`` (3,) m/s (FRD)."""
    params, thrusters = params or VehicleParams(), thrusters or ThrusterSet()
    T, u = thruster_utilisation(thrusters, rho, required_force_frd(params, rho, v_rel_frd))
    names = [t.name for t in thrusters.thrusters]
    worst = names[int(np.argmax(u))]
    group = next((g for g in GROUPS if worst.startswith(g)), worst)
    return Hold(
        {g: float(np.mean(T[list(idx)])) for g, idx in GROUPS.items()}, float(np.max(u)), bool(np.max(u) <= 1.0), group
    )


def _largest_speed(ok, tol: float) -> float:
    """Largest speed (m/s) in [0, SPEED_SEARCH_MAX_MPS] for which the monotone test ``ok``
    holds, by bisection to ``tol``; 0 when it fails at rest."""
    if not ok(0.0):
        return 0.0
    lo, hi = 0.0, SPEED_SEARCH_MAX_MPS
    if ok(hi):
        return hi
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def max_holdable_speed(
    direction_flu,
    rho: float = 1025.0,
    params: VehicleParams | None = None,
    thrusters: ThrusterSet | None = None,
    tol: float = 1e-4,
) -> float:
    """Largest steady flow speed (m/s) along the FLU unit ``direction_flu`` the vehicle can hold
    (bisection on the utilisation, which grows monotonically with speed; capped at
    :data:`SPEED_SEARCH_MAX_MPS`). 0 when even still water cannot be held."""
    d = np.asarray(direction_flu, float)
    d = d / np.linalg.norm(d)

    def ok(speed: float) -> bool:
        return hold(-(F_FLU_FRD @ d) * speed, rho, params, thrusters).holds

    return _largest_speed(ok, tol)


def station_keeping_authority(
    speeds=(0.5, 1.0), rho: float = 1025.0, params: VehicleParams | None = None
) -> list[dict]:
    """One row per (flow direction, speed): group thrusts (N), max utilisation, margin, holds, the
    limiting group and the largest holdable speed in that direction (m/s)."""
    params, thr = params or VehicleParams(), ThrusterSet()
    rows = []
    for name, d in FLOW_DIRECTIONS_FLU.items():
        v_max = max_holdable_speed(d, rho, params, thr)
        for s in speeds:
            h = hold(-(F_FLU_FRD @ np.asarray(d)) * float(s), rho, params, thr)
            rows.append(
                {
                    "flow": name,
                    "speed_mps": float(s),
                    "density_kg_m3": float(rho),
                    "main_N": h.thrust_N["main"],
                    "lateral_N": h.thrust_N["lateral"],
                    "vertical_N": h.thrust_N["vertical"],
                    "utilisation": h.utilisation,
                    "margin": h.margin,
                    "holds": h.holds,
                    "limiting": h.limiting_group,
                    "max_speed_mps": v_max,
                }
            )
    return rows


def docking_authority(
    current_world,
    approach_world,
    final_speed_mps: float,
    max_heading_deg: float,
    rho: float = 1025.0,
    params: VehicleParams | None = None,
    n_headings: int = 61,
) -> dict:
    """Can the vehicle cross the dock's entry plane at ``final_speed_mps`` along the horizontal unit
    ``approach_world`` (3,) (toward the face, world +z up) with a heading within +-``max_heading_deg``
    of it, against the steady ``current_world`` (3,) m/s? Returns ``holds``, the best heading offset
    (deg, + = nose left), its utilisation and margin and the limiting group."""
    params, thr = params or VehicleParams(), ThrusterSet()
    a = np.asarray(approach_world, float)
    a = a / np.linalg.norm(a)
    v_rel_w = final_speed_mps * a - np.asarray(current_world, float)  # vehicle through the water, world
    v_rel_ned = F_WORLD_NED @ v_rel_w
    psi0 = math.atan2(-a[1], a[0])  # NED heading of the approach
    best = None
    offsets = np.linspace(-max_heading_deg, max_heading_deg, n_headings)
    for off in sorted(offsets, key=abs):  # ties: the smallest crab angle
        R = R_ned_frd(0.0, 0.0, psi0 - math.radians(off))  # + offset = nose left = NED psi smaller
        h = hold(R.T @ v_rel_ned, rho, params, thr)
        if best is None or h.utilisation < best[1].utilisation:
            best = (float(off), h)
    off, h = best
    return {
        "holds": h.holds,
        "heading_offset_deg": off,
        "utilisation": h.utilisation,
        "margin": h.margin,
        "limiting": h.limiting_group,
    }


def max_docking_current(
    cross_dir_world,
    approach_world,
    final_speed_mps: float,
    max_heading_deg: float,
    rho: float = 1025.0,
    params: VehicleParams | None = None,
    tol: float = 1e-3,
) -> float:
    """Largest steady current speed (m/s) along the unit ``cross_dir_world`` for which
    :func:`docking_authority` holds (bisection up to :data:`SPEED_SEARCH_MAX_MPS`)."""
    d = np.asarray(cross_dir_world, float)
    d = d / np.linalg.norm(d)

    def ok(c: float) -> bool:
        return docking_authority(c * d, approach_world, final_speed_mps, max_heading_deg, rho, params)["holds"]

    return _largest_speed(ok, tol)


__all__ = [
    "FLOW_DIRECTIONS_FLU",
    "Hold",
    "docking_authority",
    "hold",
    "max_docking_current",
    "max_holdable_speed",
    "required_force_frd",
    "station_keeping_authority",
    "thruster_utilisation",
]
