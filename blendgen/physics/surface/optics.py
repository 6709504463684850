"""The water surface seen from below and the sunlight it focuses: Snell's window and caustics.

Pure numpy. World frame: metres, +z up, the mean surface at ``z = surface_z``; time in s.

Surface waves: ``eta(x, y, t) = sum_i a_i sin(k_i . x - w_i t + phi_i)``, a seeded sum of
``n`` linear waves with wavelengths log-spaced in [``lambda_min``, ``lambda_max``], headings
spread +-60 deg about the wind, the capillary-gravity dispersion
``w^2 = g k + (gamma / rho) k^3`` (Lamb 1932, art. 267), and amplitudes set so the total
mean-square slope is Cox & Munk's (1954) clean-surface law
``<s^2> = 0.003 + 5.12e-3 U`` (U wind speed, m/s); ``U = 0`` with ``mss`` 0 is a flat mirror.

Snell's window (Born & Wolf, Principles of Optics, 1.5): a ray leaving the water upwards at
incidence ``theta_i`` to the local normal refracts into the air when ``sin theta_i < 1/n``
(``theta_c = asin(1/1.333) = 48.6 deg``), else it is totally reflected. Inside the window
the camera sees the sky radiance times the Fresnel transmittance times ``n^2`` (radiance is
``L / n^2`` invariant across an interface, Nicodemus 1963) plus the Fresnel-reflected
radiance of the water below; outside it only the reflected water.

Caustics (Schenck 1957, "On the focusing of sunlight by ocean waves"; the small-slope ray
map of Zaneveld, Boss & Barnard 2001): a sun ray refracted at a surface of slope
``grad eta`` is deflected by ``D grad eta`` (``D = (1 - 1/n) I`` at normal incidence; for an
oblique sun a matrix, larger along the sun's heading: :func:`sun_deflection`, Snell's law
differentiated), so after a slant beam path ``h`` it lands ``h D grad eta`` from its straight
path; ``1 / |det(I + h D Hess(eta))|`` is the ray tube's focusing and its first zero, at
:func:`focal_depth`, the first focus. The irradiance, all preimages summed, the sun's disc and
the light scattered on the way down: :mod:`blendgen.physics.surface.caustic_map`. Measured
irradiance fluctuations fall with depth the same way (Maritorena, Morel & Gentili 2000,
Limnol. Oceanogr. 45(6)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

N_WATER = 1.333  # refractive index of water (visible, 20 C)
G = 9.81  # m/s^2
GAMMA_OVER_RHO = 7.3e-5  # surface tension / density of water, m^3/s^2
SUN_RADIUS_RAD = math.radians(0.265)


def critical_angle_rad(n: float = N_WATER) -> float:
    """Half-angle of Snell's window (rad): ``asin(1/n)``; 48.6 deg for n = 1.333."""
    return math.asin(1.0 / n)


def cox_munk_mss(wind_mps: float) -> float:
    """Total mean-square slope of a clean sea surface at wind speed U (Cox & Munk 1954)."""
    return 0.003 + 5.12e-3 * float(wind_mps)


def fresnel_reflectance(cos_i, n1: float = N_WATER, n2: float = 1.0) -> np.ndarray:
    """Unpolarised Fresnel reflectance from medium n1 into n2 at incidence cosine ``cos_i``
    (array, in [0, 1]); 1 beyond the critical angle (total internal reflection)."""
    ci = np.clip(np.asarray(cos_i, np.float32), 0.0, 1.0)
    sin_t2 = (n1 / n2) ** 2 * (1.0 - ci * ci)
    tir = sin_t2 >= 1.0
    ct = np.sqrt(np.clip(1.0 - sin_t2, 0.0, 1.0))
    rs = ((n1 * ci - n2 * ct) / np.maximum(n1 * ci + n2 * ct, 1e-12)) ** 2
    rp = ((n1 * ct - n2 * ci) / np.maximum(n1 * ct + n2 * ci, 1e-12)) ** 2
    return np.where(tir, np.float32(1.0), 0.5 * (rs + rp)).astype(np.float32)


def _weighted_sum(a: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``a @ w`` for a (..., n) and w (n,), without BLAS: a multi-threaded BLAS spends ~20x
    the CPU of this on such thin products when the cores are shared (measured, OpenBLAS;
    einsum's row dot is also 4x cheaper than multiply-and-sum)."""
    return np.einsum("...j,j->...", a, w)


@dataclass(frozen=True)
class WaveField:
    """A seeded sum of linear waves. ``amp`` (n,) m, ``k`` (n, 2) rad/m, ``omega`` (n,) rad/s,
    ``phase`` (n,) rad."""

    amp: np.ndarray
    k: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    @classmethod
    def sample(
        cls,
        seed: int,
        wind_mps: float,
        n: int = 24,
        wind_dir_deg: float = 0.0,
        lambda_min_m: float = 0.25,
        lambda_max_m: float = 2.0,
        mss: float | None = None,
    ) -> WaveField:
        """``n`` waves, wavelengths log-uniform in [min, max] (equal slope variance per wave: a
        slope spectrum flat in log k, Phillips' saturation range), headings uniform within
        +-90 deg of the wind; total mean-square slope ``mss`` (default :func:`cox_munk_mss`).
        Short capillary ripples (< 0.25 m) are left out: they are damped in a pool and
        their focusing is blurred out within centimetres by the sun's disc."""
        rng = np.random.default_rng(seed)
        lam = np.exp(rng.uniform(math.log(lambda_min_m), math.log(lambda_max_m), n))
        kk = 2 * np.pi / lam
        head = math.radians(wind_dir_deg) + rng.uniform(-math.pi / 2, math.pi / 2, n)
        s2 = cox_munk_mss(wind_mps) if mss is None else float(mss)
        amp = np.sqrt(2 * s2 / n) / kk  # each wave: slope variance (a k)^2 / 2 = s2 / n
        return cls(
            amp=amp,
            k=np.column_stack([kk * np.cos(head), kk * np.sin(head)]),
            omega=np.sqrt(G * kk + GAMMA_OVER_RHO * kk**3),
            phase=rng.uniform(0, 2 * np.pi, n),
        )

    def _arg(self, x, y, t: float) -> np.ndarray:
        """Phases ``k_i . x - w_i t + phi_i`` (..., n) float32, built in one buffer."""
        k = self.k.astype(np.float32)
        a = np.multiply(np.asarray(x, np.float32)[..., None], k[:, 0])
        a += np.multiply(np.asarray(y, np.float32)[..., None], k[:, 1])
        a += (self.phase - float(t) * self.omega).astype(np.float32)
        return a

    def slope(self, x, y, t: float = 0.0):
        """(d eta/dx, d eta/dy) at points x, y (same shape), time t."""
        c = self._arg(x, y, t)
        np.cos(c, out=c)
        w = (self.amp[:, None] * self.k).astype(np.float32)
        return _weighted_sum(c, w[:, 0]), _weighted_sum(c, w[:, 1])


def waves_for(seed: int, wind_mps: float) -> WaveField:
    """The scene's surface waves: Cox-Munk slope for wind > 0; wind 0 is a flat mirror (a still
    indoor pool; the 0.003 intercept is the open sea's residual slope). Both fidelities use it."""
    return WaveField.sample(seed, wind_mps, mss=None if wind_mps > 0 else 0.0)


def window_radiance(cos_up, sky_radiance, below_radiance, n: float = N_WATER, reflectance=None) -> np.ndarray:
    """Radiance (..., 3) seen along rays meeting the surface from below at incidence cosine
    ``cos_up`` (...) to the local normal: ``T n^2 L_sky + R L_below`` (module docstring);
    ``sky_radiance`` and ``below_radiance`` per channel (3,); ``reflectance`` R (...) when
    already computed (:func:`fresnel_reflectance`)."""
    R = (fresnel_reflectance(cos_up, n, 1.0) if reflectance is None else reflectance)[..., None]
    sky = np.asarray(sky_radiance, np.float32) * np.float32(n * n)
    return (1.0 - R) * sky + R * np.asarray(below_radiance, np.float32)


def sun_disc_radiance(
    d_up, normal, cos_up, reflectance, to_sun, irradiance: float, px_rad: float, n: float = N_WATER
) -> np.ndarray:
    """Radiance (m,) of the sun's disc seen from below along rays ``d_up`` (m, 3) (world, unit)
    meeting the surface of unit ``normal`` (m, 3) at incidence cosine ``cos_up`` (m,) with
    Fresnel ``reflectance`` (m,) (1: total internal reflection, no sun): the ray refracted into
    the air (Snell, vector form) looks at the disc of radius ``SUN_RADIUS_RAD`` and radiance
    ``E / (pi r^2)``, seen through the surface as ``(1 - R) n^2 L`` (as the sky,
    :func:`window_radiance`). Anti-aliased over the pixel: ``px_rad`` the pixel's angle in
    water, stretched by refraction to ``p = px n cos_w / cos_a`` in air; the disc's edge is a
    linear ramp one ``p`` wide and a disc smaller than half a pixel is spread over it with
    its energy kept (radius ``max(r, p/2)``, radiance scaled by the area ratio)."""
    ci = np.clip(np.asarray(cos_up, np.float32), 0.0, 1.0)
    k = 1.0 - np.float32(n * n) * (1.0 - ci * ci)
    cos_a = np.sqrt(np.maximum(k, 0.0))
    t = np.float32(n) * d_up + (cos_a - np.float32(n) * ci)[:, None] * normal  # into the air
    s = np.asarray(to_sun, np.float32) / np.float32(np.linalg.norm(to_sun))
    delta = np.arccos(np.clip(np.einsum("ij,j->i", t, s), -1.0, 1.0))
    p = np.float32(px_rad * n) * ci / np.maximum(cos_a, np.float32(0.05))
    r = np.maximum(np.float32(SUN_RADIUS_RAD), p / 2)
    cover = np.clip((r - delta) / np.maximum(p, np.float32(1e-9)) + 0.5, 0.0, 1.0)
    L = np.float32(irradiance) / (np.float32(math.pi) * r * r)
    return np.where(k > 0, (1.0 - reflectance) * np.float32(n * n) * L * cover, 0.0).astype(np.float32)


def focal_depth(waves: WaveField, n: float = N_WATER) -> float:
    """Depth (m) of the first caustic focus, ``1 / (alpha rms(laplacian eta))``: where the ray
    map ``x + h alpha grad eta`` starts to fold (inf for a flat surface)."""
    lap = math.sqrt(float((waves.amp**2 * np.hypot(waves.k[:, 0], waves.k[:, 1]) ** 4).sum() / 2))
    return math.inf if lap == 0 else 1.0 / ((1.0 - 1.0 / n) * lap)


def sun_deflection(sun_travel_dir=None, n: float = N_WATER) -> np.ndarray:
    """(2, 2) matrix D: a sun ray refracted where the surface slope is ``grad eta`` lands,
    after a slant beam path L below the surface, displaced horizontally by ``L D grad eta``
    (first order in the slope). Snell's law in vector form, ``t = d/n + (cos_i/n - cos_t) N``
    with the normal ``N ~ (-eta_x, -eta_y, 1)``, differentiated at the flat surface, in the
    frame of the sun's heading (x along it): ``a_y = cos_t - cos_i / n`` (tilt across the plane
    of incidence) and ``a_x = a_y + sin_i sin_t (1 - cos_i / (n cos_t)) / (n cos_t)`` (along it:
    the change of the refracted angle and of the path to the depth). At the zenith both are
    ``1 - 1/n``; at 40 deg 0.39 / 0.30, at 60 deg 0.67 / 0.39. ``sun_travel_dir`` None: the
    zenith. Rotated to world x, y."""
    if sun_travel_dir is None:
        return np.eye(2) * (1.0 - 1.0 / n)
    d = np.asarray(sun_travel_dir, float)
    d = d / np.linalg.norm(d)
    cos_i, sin_i = -d[2], math.hypot(d[0], d[1])
    sin_t = sin_i / n
    cos_t = math.sqrt(1.0 - sin_t * sin_t)
    a_y = cos_t - cos_i / n
    a_x = a_y + sin_i * sin_t * (1.0 - cos_i / (n * cos_t)) / (n * cos_t)
    if sin_i < 1e-12:
        return np.eye(2) * a_y
    R = np.array([[d[0], -d[1]], [d[1], d[0]]]) / sin_i
    return R @ np.diag([a_x, a_y]) @ R.T


def refracted_sun(sun_travel_dir, n: float = N_WATER) -> np.ndarray:
    """Direction (3,) of the sun's beam below a flat surface (world, unit, pointing down)."""
    d = np.asarray(sun_travel_dir, float)
    d = d / np.linalg.norm(d)
    cos_i = -d[2]
    eta = 1.0 / n
    cos_t = math.sqrt(max(0.0, 1 - eta * eta * (1 - cos_i * cos_i)))
    t = eta * d + (eta * cos_i - cos_t) * np.array([0.0, 0.0, 1.0])
    return t / np.linalg.norm(t)


def sun_in_air(water_travel_dir, n: float = N_WATER) -> np.ndarray:
    """Direction (3,) in air of the sun whose beam travels along ``water_travel_dir`` below a
    flat surface (the inverse of :func:`refracted_sun`: horizontal part times ``n``). Raises
    ValueError when the beam is outside Snell's cone (zenith angle >= 48.6 deg in water), where
    no sun in the sky can send it."""
    t = np.asarray(water_travel_dir, float)
    t = t / np.linalg.norm(t)
    h = n * t[:2]
    s2 = float(h @ h)
    if t[2] >= 0 or s2 >= 1.0:
        raise ValueError(
            f"a beam at {math.degrees(math.acos(max(-1.0, min(1.0, -t[2])))):.1f} deg from the "
            f"vertical in water has no sun in the sky (at most {math.degrees(critical_angle_rad(n)):.1f})"
        )
    return np.array([h[0], h[1], -math.sqrt(1.0 - s2)])
