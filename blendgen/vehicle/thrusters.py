"""Six-thruster layout, propeller model, first-order lag and thrust allocation.

Pure numpy. Conventions:
- Thruster positions/directions are *specified* in the public FLU body frame
  (x forward, y left, z up; origin at the centre of buoyancy). The dynamics integrate
  in Fossen's FRD body frame (x forward, y right, z down), so every geometric vector
  is mapped with ``F = diag(1, -1, -1)`` before building the allocation matrix.
- A thruster's positive thrust acts along its FLU ``direction``: main -> forward,
  lateral -> left (+y), vertical -> up (+z). Reported thrusts (N) use this sign.
- Propeller: ``T = rho K_T D^4 |n| n`` with the shaft speed n in rad/s, |n| <= n_max
  (100 rad/s); reverse thrust uses ``K_T * reverse_ratio`` (weaker, default 0.7).
- Shaft dynamics: first-order lag ``n_dot = (n_cmd - n) / time_constant_s``
  (0.1-0.3 s), discretised exactly for a step dt (zero-order hold on n_cmd).
- Allocation: ``tau = B T`` with B (6x6, rows X Y Z K M N in FRD) and T (6,) thrusts.
  The roll row K is identically zero for this layout (all thrust lines pass through
  the body x axis or are parallel to it), so B has rank 5: commands are allocated with
  the Moore-Penrose pseudo-inverse of the 5 controllable rows (X Y Z M N).
  :meth:`ThrusterSet.allocate_prioritized` adds saturation handling that keeps the
  moments and scales down the forces of a saturating group.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

F_FLU_FRD = np.diag([1.0, -1.0, -1.0])  # maps FLU vectors to FRD vectors (and back)
CONTROLLED_DOFS = (0, 1, 2, 4, 5)  # X, Y, Z, M, N (roll K uncontrolled)

THRUSTER_NAMES = ("main_left", "main_right", "lateral_bow", "lateral_stern", "vertical_fore", "vertical_aft")
GROUPS = {"main": (0, 1), "lateral": (2, 3), "vertical": (4, 5)}


@dataclass(frozen=True)
class Thruster:
    """One thruster. Geometry in the FLU body frame (metres), propeller diameter D (m),
    thrust coefficient K_T for n in rad/s (dimensionless with n in rad/s)."""

    name: str
    position_flu: tuple[float, float, float]
    direction_flu: tuple[float, float, float]
    diameter_m: float
    K_T: float = 0.0125  # ~0.49 per (rev/s)^2 expressed per (rad/s)^2
    reverse_ratio: float = 0.7  # reverse K_T = reverse_ratio * K_T
    time_constant_s: float = 0.2
    n_max: float = 100.0  # rad/s

    def max_thrust(self, rho: float) -> float:
        """Forward thrust (N) at n = n_max in water of density rho."""
        return rho * self.K_T * self.diameter_m**4 * self.n_max**2

    def max_reverse_thrust(self, rho: float) -> float:
        """Magnitude (N) of reverse thrust at n = -n_max."""
        return self.reverse_ratio * self.max_thrust(rho)


def default_thrusters() -> tuple[Thruster, ...]:
    """The dockbench layout (FLU, origin at the centre of buoyancy), ~1.33 m hull:

    - 2 main (aft, y = +-0.10 m, push forward; D = 0.10 m -> 12.8 N each at 1025),
    - 2 lateral tunnel thrusters (bow x = +0.45, stern x = -0.45; push left;
      D = 0.13 m -> 36.6 N each, 25.6 N in reverse),
    - 2 vertical tunnel thrusters (fore x = +0.35, aft x = -0.35; push up;
      D = 0.14 m -> 49 N each).
    Maximum thrust at 1025 kg/m^3 is quoted; reverse is 0.7x. Lateral capacity
    (~73 N forward, 51 N reverse per pair) holds a 0.5 m/s cross current (~39 N of
    sway drag) but not 1.0 m/s (~144 N): the vehicle drifts and must turn into the flow.
    """
    return (
        Thruster("main_left", (-0.60, 0.10, 0.0), (1.0, 0.0, 0.0), 0.10),
        Thruster("main_right", (-0.60, -0.10, 0.0), (1.0, 0.0, 0.0), 0.10),
        Thruster("lateral_bow", (0.45, 0.0, 0.0), (0.0, 1.0, 0.0), 0.13),
        Thruster("lateral_stern", (-0.45, 0.0, 0.0), (0.0, 1.0, 0.0), 0.13),
        Thruster("vertical_fore", (0.35, 0.0, 0.0), (0.0, 0.0, 1.0), 0.14),
        Thruster("vertical_aft", (-0.35, 0.0, 0.0), (0.0, 0.0, 1.0), 0.14),
    )


def allocation_matrix(thrusters, frame: str = "frd") -> np.ndarray:
    """B (6, n_thr): generalized force [F; r x F] per newton of each thruster.

    ``frame='frd'`` (Fossen body, used by the dynamics) or ``'flu'`` (public body frame).
    """
    cols = []
    for th in thrusters:
        r = np.asarray(th.position_flu, float)
        d = np.asarray(th.direction_flu, float)
        d = d / np.linalg.norm(d)
        if frame == "frd":
            r, d = F_FLU_FRD @ r, F_FLU_FRD @ d
        elif frame != "flu":
            raise ValueError(f"frame must be 'frd' or 'flu', got {frame!r}")
        cols.append(np.concatenate([d, np.cross(r, d)]))
    return np.column_stack(cols)


@dataclass
class ThrusterSet:
    """Vectorised thruster bank: allocation, thrust <-> shaft speed, lag, saturation."""

    thrusters: tuple[Thruster, ...] = field(default_factory=default_thrusters)

    def __post_init__(self):
        th = self.thrusters
        self.n = len(th)
        self.B = allocation_matrix(th, "frd")  # (6, n) FRD
        self.B_flu = allocation_matrix(th, "flu")
        B5 = self.B[list(CONTROLLED_DOFS), :]
        if np.linalg.matrix_rank(B5) != 5:
            raise ValueError("thruster layout does not control X Y Z M N")
        self.B5_pinv = np.linalg.pinv(B5)  # (n, 5)
        self.D4 = np.array([t.diameter_m**4 for t in th])
        self.K_T = np.array([t.K_T for t in th])
        self.K_T_rev = np.array([t.K_T * t.reverse_ratio for t in th])
        self.n_max = np.array([t.n_max for t in th])
        self.time_constant = np.array([t.time_constant_s for t in th])
        self._lag_cache: dict[float, np.ndarray] = {}
        names = [t.name for t in th]
        self._group_idx = [
            np.array([i for i, nm in enumerate(names) if nm.startswith(g)]) for g in ("main", "lateral", "vertical")
        ]
        self._group_idx = [g.tolist() for g in self._group_idx if len(g)]
        self._P_rows = [tuple(float(c) for c in row) for row in self.B5_pinv]
        self._limits: dict[float, tuple[list, list]] = {}

    # --- allocation -------------------------------------------------------------
    def allocate(self, tau_frd: np.ndarray) -> np.ndarray:
        """Thrusts (N, n) realising the X Y Z M N part of a 6-DOF FRD command
        (least-norm solution; the K entry is ignored: roll is uncontrolled)."""
        tau = np.asarray(tau_frd, float)
        return self.B5_pinv @ tau[list(CONTROLLED_DOFS)]

    def allocate_prioritized(self, tau_frd: np.ndarray, rho: float) -> np.ndarray:
        """Saturation-aware allocation that keeps the MOMENTS (pitch M, yaw N) and gives
        up force first: thrusts = T_moment + s_g * T_force with, per thruster group
        (main: X, lateral: Y, vertical: Z), the largest s_g in [0, 1] that keeps every
        thruster of the group within its forward/reverse limits; the moment part is
        itself scaled down uniformly if it alone exceeds a limit. With no saturation this
        equals :meth:`allocate`. (Main thrusters carry only X and N, lateral only Y and N,
        vertical only Z and M, so the groups decouple.)"""
        X, Y, Z, _, M, N = (float(c) for c in tau_frd)
        lim = self._limits.get(rho)
        if lim is None:
            hi = self.max_thrust(rho)
            lim = self._limits[rho] = (hi.tolist(), (-hi * self.K_T_rev / self.K_T).tolist())
        hi, lo = lim
        T_f, T_m = [], []
        for a0, a1, a2, a3, a4 in self._P_rows:
            T_f.append(a0 * X + a1 * Y + a2 * Z)
            T_m.append(a3 * M + a4 * N)
        if all(l <= tm + tf <= h for tm, tf, h, l in zip(T_m, T_f, hi, lo)):
            return np.array([tm + tf for tm, tf in zip(T_m, T_f)])
        over = max((tm / h if tm > 0 else tm / l if tm < 0 else 0.0) for tm, h, l in zip(T_m, hi, lo))
        if over > 1.0:
            T_m = [tm / over for tm in T_m]
        s_i = []
        for tf, tm, h, l in zip(T_f, T_m, hi, lo):
            if tf > 0:
                s_i.append(min(max((h - tm) / tf, 0.0), 1.0))
            elif tf < 0:
                s_i.append(min(max((l - tm) / tf, 0.0), 1.0))
            else:
                s_i.append(1.0)
        s = [1.0] * self.n
        for idx in self._group_idx:
            sg = min(s_i[i] for i in idx)
            for i in idx:
                s[i] = sg
        return np.array([tm + sg * tf for tm, sg, tf in zip(T_m, s, T_f)])

    # --- propeller ---------------------------------------------------------------
    def thrust_to_speed(self, thrust: np.ndarray, rho: float) -> np.ndarray:
        """Shaft speeds (rad/s) giving ``thrust`` (N), saturated at +-n_max."""
        T = np.asarray(thrust, float)
        kt = np.where(T >= 0.0, self.K_T, self.K_T_rev)
        n = np.sign(T) * np.sqrt(np.abs(T) / (rho * kt * self.D4))
        return np.clip(n, -self.n_max, self.n_max)

    def speed_to_thrust(self, n: np.ndarray, rho: float) -> np.ndarray:
        """Thrust (N) from shaft speeds (rad/s): rho K_T D^4 |n| n (reverse weaker)."""
        n = np.asarray(n, float)
        kt = np.where(n >= 0.0, self.K_T, self.K_T_rev)
        return rho * kt * self.D4 * np.abs(n) * n

    def max_thrust(self, rho: float) -> np.ndarray:
        """Per-thruster forward thrust limit (N)."""
        return rho * self.K_T * self.D4 * self.n_max**2

    def lag_step(self, n: np.ndarray, n_cmd: np.ndarray, dt: float) -> np.ndarray:
        """Exact first-order lag update of shaft speeds over dt (n_cmd held)."""
        a = self._lag_cache.get(dt)
        if a is None:
            a = 1.0 - np.exp(-dt / self.time_constant)
            self._lag_cache[dt] = a
        return n + a * (np.clip(n_cmd, -self.n_max, self.n_max) - n)

    def generalized_force(self, thrust: np.ndarray) -> np.ndarray:
        """6-DOF FRD force/moment (N, N m) produced by thrusts (N)."""
        return self.B @ np.asarray(thrust, float)


def group_means(thrust: np.ndarray) -> dict[str, np.ndarray]:
    """Mean thrust of each pair (main, lateral, vertical) along the last axis."""
    T = np.asarray(thrust, float)
    return {g: T[..., list(idx)].mean(axis=-1) for g, idx in GROUPS.items()}


__all__ = [
    "Thruster",
    "ThrusterSet",
    "default_thrusters",
    "allocation_matrix",
    "group_means",
    "THRUSTER_NAMES",
    "GROUPS",
    "CONTROLLED_DOFS",
    "F_FLU_FRD",
]
