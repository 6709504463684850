"""Six-DOF AUV model (Fossen 2021): rigid body + added mass + Coriolis + damping +
density-dependent restoring forces, relative-velocity current, RK4 integration.

Pure numpy/Python; no Blender. Units: metres, seconds, radians, newtons, kg.

Frames (read carefully)
-----------------------
*Internal* (Fossen, this module's state vector):
  - inertial NED: x north, y east, z DOWN (z = depth below the surface z = 0);
  - body FRD: x forward, y right (starboard), z down; origin at the centre of
    buoyancy (CB); the centre of gravity sits ``r_g`` below it.
  - state ``s = [x, y, z, phi, theta, psi, u, v, w, p, q, r]`` (12,):
    ``eta = s[:6]`` (NED position, ZYX Euler angles), ``nu = s[6:]`` (absolute body
    velocity, FRD).
*Public* (dockbench world, :mod:`blendgen.geometry`):
  - world: +z UP, water surface at z = 0 (depth h <=> z = -h);
  - body FLU: x forward, y left, z up.
  We identify world x with NED x (north). With ``F = diag(1, -1, -1)``:
      p_world = F p_ned,   v_world = F v_ned,
      R_world_bodyFLU = F R_ned_bodyFRD F,
  i.e. world roll = phi, world pitch = -theta, world yaw = -psi (for the ZYX Euler
  angles of :func:`blendgen.geometry.rpy_to_R`). A vehicle going deeper has larger
  NED z and more negative world z. :func:`eta_to_T_world_body` /
  :func:`T_world_body_to_eta` are the only public pose conversions.

Equations of motion (Fossen eq. 10.x, irrotational current):
    M nu_r_dot + C_RB(nu_r) nu_r + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau,
    nu_r = nu - nu_c,  nu_c = [R^T v_c_ned; 0],
    nu_dot = nu_r_dot - [omega x v_c_body; 0]   (current constant in NED over a step),
    eta_dot = J(eta) nu.
C_RB uses the linear-velocity-independent parametrisation, so the rigid-body terms
may be written in nu_r (Fossen Property 10.1). C_RB and C_A are skew-symmetric, so
with tau = 0, no current and g = 0 the kinetic energy 0.5 nu^T M nu can only decay
(damping), which tests/test_dynamics.py checks.

Vehicle (REMUS 100 hull, Prestero 2001, plus Fossen-style linear damping):
``VehicleParams`` documents every number. The displaced volume is chosen so that the
vehicle density is 1175 kg/m^3: it SINKS in all water of interest (975-1075 kg/m^3),
and the vertical thrusters must push up with ``(m - rho V) g``:
38.2 N at 1025, 25.4 N at 1075, 50.9 N at 975 kg/m^3 -- exactly in the ratio 6:4:8
of the article's Table 5 (normalised units).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from blendgen.geometry import R_to_rpy, rpy_to_R
from blendgen.vehicle.thrusters import ThrusterSet

GRAVITY = 9.81
F_WORLD_NED = np.diag([1.0, -1.0, -1.0])  # world(+z up) <-> NED, and FLU <-> FRD
DT_MAX = 0.1  # s; see check_dt


# ------------------------------------------------------------------ frames -------
def ned_to_world_vec(v) -> np.ndarray:
    """NED (or FRD) vector(s) (...,3) -> world (or FLU): flip y and z."""
    v = np.array(v, float)
    v[..., 1:] *= -1.0
    return v


world_to_ned_vec = ned_to_world_vec  # the map is an involution


def R_ned_frd(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body(FRD)->NED rotation for Fossen's ZYX Euler angles (rad)."""
    return rpy_to_R(phi, theta, psi)


def eta_to_T_world_body(eta) -> np.ndarray:
    """NED pose ``eta = [x, y, z, phi, theta, psi]`` -> ``T_world_body`` (4x4, world
    +z up, body FLU). p_world = F p_ned, R_world_flu = F R_ned_frd F, F = diag(1,-1,-1)."""
    eta = np.asarray(eta, float)
    T = np.eye(4)
    T[:3, :3] = F_WORLD_NED @ rpy_to_R(*eta[3:6]) @ F_WORLD_NED
    T[:3, 3] = F_WORLD_NED @ eta[:3]
    return T


def T_world_body_to_eta(T) -> np.ndarray:
    """Inverse of :func:`eta_to_T_world_body`: 4x4 world/FLU pose -> NED eta (6,)."""
    T = np.asarray(T, float)
    R = F_WORLD_NED @ T[:3, :3] @ F_WORLD_NED
    phi, theta, psi = R_to_rpy(R)
    return np.concatenate([F_WORLD_NED @ T[:3, 3], [phi, theta, psi]])


def wrap_pi(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


# ------------------------------------------------------------------ params -------
@dataclass(frozen=True)
class VehicleParams:
    """REMUS-100-like hull (Prestero 2001 as transcribed in Fossen's
    PythonVehicleSimulator) made hover-capable with six thrusters.

    Geometry/inertia: m = 30.48 kg, L = 1.33 m, D = 0.191 m, origin at CB,
    r_g = (0, 0, 0.0196) m (FRD: CG below CB), Ixx = 0.177, Iyy = Izz = 3.45 kg m^2.
    Displaced volume V = m / vehicle_density with vehicle_density = 1175 kg/m^3
    (V = 0.02594 m^3): negatively buoyant at 975-1075 kg/m^3 (see module doc).
    Added mass (positive numbers = -X_udot, ...): 0.93, 35.5, 35.5, 0.0704, 4.88,
    4.88; couplings -Y_rdot = -1.93 (sway-yaw), -Z_qdot = +1.93 (heave-pitch).
    Quadratic damping (positive = -X_u|u| ...): 1.62, 131, 131, 0.13, 94, 94.
    Linear damping (Fossen style, not in Prestero): d = m_ii / T_i with time constants
    T_surge = 10 s, T_sway = T_heave = 5 s, T_yaw = 5 s; roll/pitch from damping ratios
    zeta = 0.3 / 0.8 of the restoring oscillation.
    Munk moments: the C_A entries coupling surge/sway/heave velocities into pitch and
    yaw ((0,4),(4,0),(2,4),(4,2),(0,5),(5,0),(1,5),(5,1)) are zeroed by default, as
    Fossen's REMUS 100 model does: without a hull/fin lift model they make pitch and yaw
    statically unstable (Munk pitch stiffness ~35 u^2 N m/rad exceeds the ~12 N m/rad
    of restoring + pitch control at 1 m/s relative flow; the vehicle tumbled in 1 m/s
    cross-current trials). Zeroing symmetric pairs keeps C_A skew-symmetric (energy
    conserving). ``munk_moments=True`` restores the full C_A.
    """

    mass: float = 30.48
    vehicle_density: float = 1175.0
    length: float = 1.33
    diameter: float = 0.191
    r_g: tuple[float, float, float] = (0.0, 0.0, 0.0196)  # FRD, CG w.r.t. CB (origin)
    inertia: tuple[float, float, float] = (0.177, 3.45, 3.45)
    added_mass: tuple[float, ...] = (0.93, 35.5, 35.5, 0.0704, 4.88, 4.88)
    added_mass_yr: float = -1.93  # M_A[1,5] = M_A[5,1] = -Y_rdot
    added_mass_zq: float = 1.93  # M_A[2,4] = M_A[4,2] = -Z_qdot
    quad_damping: tuple[float, ...] = (1.62, 131.0, 131.0, 0.13, 94.0, 94.0)
    T_surge: float = 10.0
    T_sway: float = 5.0
    T_heave: float = 5.0
    T_yaw: float = 5.0
    zeta_roll: float = 0.3
    zeta_pitch: float = 0.8
    linear_damping_override: tuple[float, ...] | None = None  # (6,) positive, N/(m/s)
    munk_moments: bool = False

    @property
    def volume(self) -> float:
        """Displaced volume (m^3)."""
        return self.mass / self.vehicle_density

    @property
    def weight(self) -> float:
        return self.mass * GRAVITY

    def buoyancy(self, rho: float) -> float:
        """Buoyant force (N) in water of density rho (kg/m^3)."""
        return rho * self.volume * GRAVITY

    def net_weight(self, rho: float) -> float:
        """W - B (N): the upward thrust needed to hover (positive = vehicle sinks)."""
        return self.weight - self.buoyancy(rho)

    def neutral(self, rho: float = 1025.0) -> VehicleParams:
        """Same vehicle trimmed neutrally buoyant in water of density rho."""
        return replace(self, vehicle_density=rho)

    def M_RB(self) -> np.ndarray:
        m = self.mass
        xg, yg, zg = self.r_g
        S = np.array([[0.0, -zg, yg], [zg, 0.0, -xg], [-yg, xg, 0.0]])
        M = np.zeros((6, 6))
        M[:3, :3] = m * np.eye(3)
        M[:3, 3:] = -m * S
        M[3:, :3] = m * S
        M[3:, 3:] = np.diag(self.inertia)
        return M

    def M_A(self) -> np.ndarray:
        M = np.diag(self.added_mass).astype(float)
        M[1, 5] = M[5, 1] = self.added_mass_yr
        M[2, 4] = M[4, 2] = self.added_mass_zq
        return M

    def M(self) -> np.ndarray:
        return self.M_RB() + self.M_A()

    def restoring_stiffness(self) -> tuple[float, float]:
        """Small-angle roll and pitch restoring stiffness (N m/rad) = z_g W (r_b = 0)."""
        k = self.r_g[2] * self.weight
        return k, k

    def linear_damping(self) -> np.ndarray:
        """Positive linear damping coefficients (6,)."""
        if self.linear_damping_override is not None:
            return np.asarray(self.linear_damping_override, float)
        Md = np.diag(self.M())
        k_roll, k_pitch = self.restoring_stiffness()
        d_roll = 2.0 * self.zeta_roll * math.sqrt(max(k_roll, 0.0) * Md[3])
        d_pitch = 2.0 * self.zeta_pitch * math.sqrt(max(k_pitch, 0.0) * Md[4])
        return np.array(
            [Md[0] / self.T_surge, Md[1] / self.T_sway, Md[2] / self.T_heave, d_roll, d_pitch, Md[5] / self.T_yaw]
        )


# ------------------------------------------------------------------ model --------
class AUVModel:
    """Equations of motion for one vehicle in water of density ``rho``.

    ``deriv`` works on plain Python floats (12-state), which is ~5x faster than
    small-array numpy for this size; M^-1 is precomputed.
    """

    def __init__(self, params: VehicleParams | None = None, rho: float = 1025.0, damping: bool = True):
        self.params = p = params or VehicleParams()
        self.rho = float(rho)
        if not (math.isfinite(self.rho) and self.rho >= 0.0):
            raise ValueError(f"water density must be finite and >= 0 kg/m^3, got {rho}")
        self.M = p.M()
        Minv = np.linalg.inv(self.M)
        self._Minv = [tuple(float(c) for c in row) for row in Minv]
        self._m = p.mass
        self._rg = tuple(float(c) for c in p.r_g)
        self._I = tuple(float(c) for c in p.inertia)
        ma = p.added_mass
        self._ma = tuple(float(c) for c in ma)
        self._myr = float(p.added_mass_yr)
        self._mzq = float(p.added_mass_zq)
        self._dl = tuple(float(c) for c in p.linear_damping()) if damping else (0.0,) * 6
        self._dq = tuple(float(c) for c in p.quad_damping) if damping else (0.0,) * 6
        self.W = p.weight
        self.B = p.buoyancy(self.rho)
        self.munk = bool(p.munk_moments)

    def kinetic_energy(self, nu) -> float:
        """0.5 nu^T M nu (rigid body + added mass), J."""
        nu = np.asarray(nu, float)
        return 0.5 * float(nu @ self.M @ nu)

    def restoring(self, eta) -> np.ndarray:
        """g(eta) (6,), FRD, CB at the origin."""
        phi, th = eta[3], eta[4]
        return np.array(self._g(math.cos(phi), math.sin(phi), math.cos(th), math.sin(th)))

    def _g(self, cph, sph, cth, sth):
        WB = self.W - self.B
        xg, yg, zg = self._rg
        W = self.W
        return (
            WB * sth,
            -WB * cth * sph,
            -WB * cth * cph,
            -yg * W * cth * cph + zg * W * cth * sph,
            zg * W * sth + xg * W * cth * cph,
            -xg * W * cth * sph - yg * W * sth,
        )

    def _coriolis_damping(self, ur, vr, wr, p, q, r):
        """Rigid-body and added-mass Coriolis plus damping forces (6 floats, FRD) for the
        velocity relative to the water (ur, vr, wr; m/s) and the body rates (p, q, r; rad/s).
        Unrolled scalar arithmetic: this is the inner loop of every RK4 stage."""
        m = self._m
        xg, yg, zg = self._rg
        Ix, Iy, Iz = self._I
        # rigid body: [m w x v_r - m w x (rg x w);  m rg x (w x v_r) + w x (I w)]
        wxv0 = q * wr - r * vr
        wxv1 = r * ur - p * wr
        wxv2 = p * vr - q * ur
        rgw0 = yg * r - zg * q
        rgw1 = zg * p - xg * r
        rgw2 = xg * q - yg * p
        f0 = m * (wxv0 - (q * rgw2 - r * rgw1))
        f1 = m * (wxv1 - (r * rgw0 - p * rgw2))
        f2 = m * (wxv2 - (p * rgw1 - q * rgw0))
        Iw0, Iw1, Iw2 = Ix * p, Iy * q, Iz * r
        f3 = m * (yg * wxv2 - zg * wxv1) + (q * Iw2 - r * Iw1)
        f4 = m * (zg * wxv0 - xg * wxv2) + (r * Iw0 - p * Iw2)
        f5 = m * (xg * wxv1 - yg * wxv0) + (p * Iw1 - q * Iw0)
        # added mass: a1 = A11 v_r + A12 w, a2 = A21 v_r + A22 w;
        # C_A nu_r = [w x a1; v_r x a1 + w x a2]
        ma = self._ma
        myr, mzq = self._myr, self._mzq
        a10 = ma[0] * ur
        a11 = ma[1] * vr + myr * r
        a12 = ma[2] * wr + mzq * q
        a20 = ma[3] * p
        a21 = ma[4] * q + mzq * wr
        a22 = ma[5] * r + myr * vr
        f1 -= p * a12
        f2 += p * a11
        f3 += vr * a12 - wr * a11 + q * a22 - r * a21
        f4 += r * a20 - p * a22
        f5 += p * a21 - q * a20
        if self.munk:  # C_A entries (0,4),(4,0),(2,4),(4,2),(0,5),(5,0),(1,5),(5,1)
            f0 += q * a12 - r * a11
            f1 += r * a10
            f2 -= q * a10
            f4 += wr * a10 - ur * a12
            f5 += ur * a11 - vr * a10
        # damping
        dl, dq = self._dl, self._dq
        f0 += (dl[0] + dq[0] * abs(ur)) * ur
        f1 += (dl[1] + dq[1] * abs(vr)) * vr
        f2 += (dl[2] + dq[2] * abs(wr)) * wr
        f3 += (dl[3] + dq[3] * abs(p)) * p
        f4 += (dl[4] + dq[4] * abs(q)) * q
        f5 += (dl[5] + dq[5] * abs(r)) * r
        return f0, f1, f2, f3, f4, f5

    def deriv(self, s, tau, vc):
        """State derivative. s: 12 floats (NED eta, FRD nu); tau: 6 floats (FRD);
        vc: NED current (3 floats, m/s)."""
        x, y, z, phi, th, psi, u, v, w, p, q, r = s
        cph, sph = math.cos(phi), math.sin(phi)
        cth, sth = math.cos(th), math.sin(th)
        cps, sps = math.cos(psi), math.sin(psi)
        R00 = cps * cth
        R01 = -sps * cph + cps * sth * sph
        R02 = sps * sph + cps * cph * sth
        R10 = sps * cth
        R11 = cps * cph + sph * sth * sps
        R12 = -cps * sph + sth * sps * cph
        R20 = -sth
        R21 = cth * sph
        R22 = cth * cph
        vcx, vcy, vcz = vc
        uc = R00 * vcx + R10 * vcy + R20 * vcz
        vcb = R01 * vcx + R11 * vcy + R21 * vcz
        wc = R02 * vcx + R12 * vcy + R22 * vcz
        ur, vr, wr = u - uc, v - vcb, w - wc

        f0, f1, f2, f3, f4, f5 = self._coriolis_damping(ur, vr, wr, p, q, r)
        g = self._g(cph, sph, cth, sth)
        fv = (
            tau[0] - f0 - g[0],
            tau[1] - f1 - g[1],
            tau[2] - f2 - g[2],
            tau[3] - f3 - g[3],
            tau[4] - f4 - g[4],
            tau[5] - f5 - g[5],
        )
        fv0, fv1, fv2, fv3, fv4, fv5 = fv
        acc = [c0 * fv0 + c1 * fv1 + c2 * fv2 + c3 * fv3 + c4 * fv4 + c5 * fv5 for c0, c1, c2, c3, c4, c5 in self._Minv]
        # nu_dot = nu_r_dot - w x v_c(body)
        acc[0] -= q * wc - r * vcb
        acc[1] -= r * uc - p * wc
        acc[2] -= p * vcb - q * uc
        # kinematics
        cth_safe = cth if abs(cth) > 1e-6 else math.copysign(1e-6, cth)
        tth = sth / cth_safe
        qs_rc = q * sph + r * cph
        return [
            R00 * u + R01 * v + R02 * w,
            R10 * u + R11 * v + R12 * w,
            R20 * u + R21 * v + R22 * w,
            p + qs_rc * tth,
            q * cph - r * sph,
            qs_rc / cth_safe,
            acc[0],
            acc[1],
            acc[2],
            acc[3],
            acc[4],
            acc[5],
        ]

    def rk4_step(self, s, tau, vc, dt):
        """One classical RK4 step (tau, vc held over the step). Returns a new list."""
        f = self.deriv
        k1 = f(s, tau, vc)
        h2 = 0.5 * dt
        k2 = f([a + h2 * b for a, b in zip(s, k1)], tau, vc)
        k3 = f([a + h2 * b for a, b in zip(s, k2)], tau, vc)
        k4 = f([a + dt * b for a, b in zip(s, k3)], tau, vc)
        h6 = dt / 6.0
        return [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]


def check_dt(dt: float) -> float:
    """Validate an integration/control step.

    Stability bound: dt must lie in (0, DT_MAX = 0.1 s]. RK4 is stable for
    |lambda| dt < 2.8; the fastest open-loop mode is the roll oscillation
    (sqrt(z_g W / (Ixx + K_pdot)) ~ 4.9 rad/s -> 0.57 s) and the controllers are
    sampled at dt with zero-order hold, which needs dt well below their
    ~1 rad/s bandwidth and the 0.2 s thruster lag. 0.1 s keeps both comfortable.
    """
    dt = float(dt)
    if not (0.0 < dt <= DT_MAX) or not math.isfinite(dt):
        raise ValueError(
            f"dt = {dt} s is outside the stable range (0, {DT_MAX}] s "
            "(RK4 + discrete controllers; see dynamics.check_dt)"
        )
    return dt


@dataclass
class Plant:
    """Vehicle + thrusters + current: the thing controllers drive.

    State ``s`` (NED/FRD list of 12), shaft speeds ``n`` (6,) rad/s.
    ``step(n_cmd, current_ned, dt)``: thrust from the *current* shaft speeds is held
    over the RK4 step, then the shafts move toward ``n_cmd`` through the lag.
    """

    params: VehicleParams = field(default_factory=VehicleParams)
    rho: float = 1025.0
    thrusters: ThrusterSet = field(default_factory=ThrusterSet)
    damping: bool = True

    def __post_init__(self):
        self.model = AUVModel(self.params, self.rho, damping=self.damping)
        self.s = [0.0] * 12
        self.n = np.zeros(self.thrusters.n)
        self.t = 0.0

    def set_pose_ned(self, eta, nu=None):
        self.s = [float(c) for c in eta] + ([float(c) for c in nu] if nu is not None else [0.0] * 6)

    @property
    def eta(self) -> np.ndarray:
        return np.array(self.s[:6])

    @property
    def nu(self) -> np.ndarray:
        return np.array(self.s[6:])

    def thrust(self) -> np.ndarray:
        """Per-thruster thrust (N, + along each thruster's FLU direction)."""
        return self.thrusters.speed_to_thrust(self.n, self.rho)

    def step(self, n_cmd, current_ned=(0.0, 0.0, 0.0), dt: float = 0.02):
        dt = check_dt(dt)
        tau = (self.thrusters.B @ self.thrust()).tolist()
        self.s = self.model.rk4_step(self.s, tau, tuple(current_ned), dt)
        self.n = self.thrusters.lag_step(self.n, n_cmd, dt)
        self.t += dt
        return self.s

    def T_world_body(self) -> np.ndarray:
        return eta_to_T_world_body(self.s[:6])


__all__ = [
    "VehicleParams",
    "AUVModel",
    "Plant",
    "eta_to_T_world_body",
    "T_world_body_to_eta",
    "ned_to_world_vec",
    "world_to_ned_vec",
    "R_ned_frd",
    "wrap_pi",
    "check_dt",
    "GRAVITY",
    "DT_MAX",
    "F_WORLD_NED",
]
