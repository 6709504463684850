"""Veiling light of the ``physical`` mode: a beam + diffuse path-radiance model.

Pure numpy (+ scipy for the fit). Per RGB channel, radiance per unit downwelling irradiance
just below the surface ``E_d0`` (W/m^2 on a horizontal plane), for a camera at depth ``h``
(m) looking at elevation ``theta`` (rad, > 0 up) along an unobstructed ray. Radiative
transfer along the ray (Mobley 1994, *Light and Water*, eq. 5.24: ``dL/ds = -c L + J``)
with the path function ``J`` of two light fields:

* the **unscattered sun beam**, irradiance ``E_d0 exp(-c h / mu_s) / mu_s`` normal to the
  beam (``mu_s`` the sine of the sun's in-water elevation), scattered by the phase function
  at the angle ``psi`` between the beam and the ray to the camera: exact single scattering,
  no fitted number (the Cycles medium with 0 volume bounces checks it);
* the **diffuse field**, everything the water has already scattered, taken in its
  asymptotic form (Preisendorfer's asymptotic radiance distribution: a fixed angular shape
  that decays with depth at one rate): ``J_diff = kappa b E_d0 exp(-K_v h) / (4 pi mu_d)``.
  ``kappa = 1, K_v = Kd`` is the isotropic-equivalent estimate of the previous model
  (``(b/c) E_d / (4 pi mu_d)``, 4-5x too bright for the forward-peaked waters);
  ``kappa`` (the in-scattering of the diffuse field into the ray relative to an isotropic
  field of mean cosine ``mu_d``) and ``K_v`` (1/m, the rate at which it dims with depth)
  are the TWO numbers fitted per preset and channel, plus one per preset, ``eta``, the
  elevation dependence of the diffuse path function (``1 + eta sin(theta)``: the first two
  terms of its expansion in the cosine from the vertical, as in the Eddington approximation),
  to Cycles references with multiple
  volume bounces (``dockbench calibrate-veil``; stored in
  ``blendgen/data/water_calibration.json`` under ``"veil"``).

Each term's source changes along a slanted ray as its light field does with depth
(``exp(-c h/mu_s)`` for the beam, ``exp(-K_v h)`` for the diffuse field), so integrating
``exp(-c s) J(h - s sin theta)`` over the path gives ``(1 - exp(-x L)) / x`` with
``x = c - k_term sin(theta)``; ``L = h / sin(theta)`` up to the surface when looking up,
``inf`` otherwise (nothing above the surface contributes: the reference box has no sky seen
through it). The veil goes to 0 as ``b -> 0``; at fixed ``a``, ``kappa`` and ``K_v`` its
diffuse term grows monotonically with ``b``; the beam term only while ``b h < a / c`` (deeper,
more scattering also dims the beam that feeds it).
"""

from __future__ import annotations

import math

import numpy as np

#: Mean cosine of the downwelling diffuse light (Kirk 2011: about 0.7-0.9 near the surface).
MEAN_COSINE_DOWN = 0.75
#: kappa used when a preset has no calibration: the isotropic-equivalent field.
KAPPA_ISOTROPIC = 1.0


def _path_integral(x: np.ndarray, length: float) -> np.ndarray:
    """``int_0^L exp(-x s) ds`` per channel; ``L = inf`` needs ``x > 0`` (else inf)."""
    x = np.asarray(x, float)
    if math.isinf(length):
        return np.where(x > 0, 1.0 / np.where(x > 0, x, 1.0), np.inf)
    small = np.abs(x) < 1e-12
    safe = np.where(small, 1.0, x)
    return np.where(small, length, -np.expm1(-x * length) / safe)


def scatter_cosine(sun_elevation_rad: float, view_elevation_rad: float, rel_azimuth_rad: float) -> float:
    """cos of the scattering angle between the sun's beam (travelling down at elevation
    ``e``) and the light going to the camera (opposite to a view ray at elevation ``theta``,
    azimuth ``phi`` from the sun's): ``sin e sin theta - cos e cos theta cos phi``."""
    e, t = sun_elevation_rad, view_elevation_rad
    return math.sin(e) * math.sin(t) - math.cos(e) * math.cos(t) * math.cos(rel_azimuth_rad)


def veil_radiance(
    sigma_a,
    sigma_s,
    K_v,
    phase_fn,
    kappa,
    depth_m: float,
    view_elevation_rad: float = 0.0,
    eta: float = 0.0,
    sun_elevation_rad: float = math.pi / 2,
    rel_azimuth_rad: float = math.pi / 2,
    mean_cosine_down: float = MEAN_COSINE_DOWN,
    parts: bool = False,
):
    """Path radiance of an unobstructed ray per unit ``E_d0`` (3,), 1/sr (module docstring).

    ``sigma_a``, ``sigma_s``, ``K_v`` (3,) 1/m; ``phase_fn(psi_rad) -> 1/sr``; ``kappa`` scalar
    or (3,); ``depth_m`` the camera's depth >= 0; elevations/azimuth in radians (default: sun
    overhead, horizontal view); ``eta`` the diffuse path function's elevation dependence
    ``J_diff(theta) ~ 1 + eta sin(theta)`` (two-term expansion of the light field about the
    vertical: more light scattered into a ray looking up than down). ``parts=True`` returns ``(beam, diffuse)``
    instead of the sum."""
    a = np.broadcast_to(np.asarray(sigma_a, float), (3,))
    b = np.broadcast_to(np.asarray(sigma_s, float), (3,))
    K = np.broadcast_to(np.asarray(K_v, float), (3,))
    c = a + b
    h = max(float(depth_m), 0.0)
    mu_s = max(math.sin(sun_elevation_rad), 1e-3)
    st = math.sin(view_elevation_rad)
    length = h / st if st > 1e-9 else math.inf
    beam_e = np.exp(-c * h / mu_s)  # unscattered beam share of E_d0 at h
    psi = math.acos(max(-1.0, min(1.0, scatter_cosine(sun_elevation_rad, view_elevation_rad, rel_azimuth_rad))))
    beam = b * float(phase_fn(psi)) * beam_e / mu_s * _path_integral(c - c / mu_s * st, length)
    tilt = max(1.0 + float(eta) * st, 0.0)  # two-term angular shape of J_diff
    diffuse = (
        np.asarray(kappa, float)
        * tilt
        * b
        * np.exp(-K * h)
        / (4.0 * math.pi * float(mean_cosine_down))
        * _path_integral(c - K * st, length)
    )
    beam, diffuse = np.nan_to_num(beam, posinf=0.0), np.nan_to_num(diffuse, posinf=0.0)
    return (beam, diffuse) if parts else beam + diffuse


def fit_channel(beam: np.ndarray, ref: np.ndarray, shape_fn, k_bounds: tuple[float, float]) -> tuple[float, float]:
    """``(kappa, K_v)`` of one channel minimising the RELATIVE residual of
    ``ref ~ beam + kappa * shape_fn(K_v)`` ((N,) arrays; ``shape_fn(K) -> (N,)`` the diffuse
    term at kappa 1). For a given K_v the best kappa is linear; K_v is scanned over
    ``k_bounds`` (1/m) then refined (scipy's bounded scalar minimiser)."""
    from scipy.optimize import minimize_scalar

    w = 1.0 / np.maximum(ref, 1e-12)
    y = (ref - beam) * w

    def best(K):
        x = shape_fn(K) * w
        den = float(x @ x)
        k = max(float(x @ y) / den, 0.0) if den > 1e-30 else 0.0
        return k, float(np.sum((y - k * x) ** 2))

    grid = np.linspace(*k_bounds, 41)
    K0 = grid[int(np.argmin([best(K)[1] for K in grid]))]
    step = (k_bounds[1] - k_bounds[0]) / 40
    r = minimize_scalar(
        lambda K: best(K)[1],
        bounds=(max(k_bounds[0], K0 - step), min(k_bounds[1], K0 + step)),
        method="bounded",
        options={"xatol": 1e-5},
    )
    K = float(r.x) if r.fun <= best(K0)[1] else float(K0)
    return best(K)[0], K
