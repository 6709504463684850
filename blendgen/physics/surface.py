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
``grad eta`` is deflected by ``alpha grad eta`` (``alpha = 1 - 1/n`` at normal incidence),
so the point it reaches at depth ``h`` moves by ``h alpha grad eta`` and the irradiance is
``E / E_0 = 1 / |det(I + h alpha Hess(eta))|`` (ray-tube area; bright lines where the
determinant vanishes: the caustic network). The pattern's contrast
falls with depth because (i) the sun's disc (radius 0.265 deg in air) blurs a wave of
wavenumber ``k`` at depth ``h`` by ``exp(-(k h theta_sun / n)^2 / 2)``, and (ii) only the
unscattered beam ``exp(-b h)`` carries it (``b`` the scattering coefficient): scattered
light arrives from all directions. Measured irradiance fluctuations fall with depth the
same way (Maritorena, Morel & Gentili 2000, Limnol. Oceanogr. 45(6)). Beyond the first
focal depth the ray map folds; we evaluate one preimage per point (the point itself),
clip the factor at folds to ``CAUSTIC_MAX`` and renormalise its area mean to 1 per depth
(energy conservation), an approximation of summing over all preimages.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

N_WATER = 1.333                     # refractive index of water (visible, 20 C)
G = 9.81                            # m/s^2
GAMMA_OVER_RHO = 7.3e-5             # surface tension / density of water, m^3/s^2
SUN_RADIUS_RAD = math.radians(0.265)
CAUSTIC_MAX = 8.0                   # clip of the ray-tube factor at a fold (before renormalising)


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
    the CPU of this on such thin products when the cores are shared (measured, OpenBLAS)."""
    return np.multiply(a, w).sum(axis=-1)


@dataclass(frozen=True)
class WaveField:
    """A seeded sum of linear waves. ``amp`` (n,) m, ``k`` (n, 2) rad/m, ``omega`` (n,) rad/s,
    ``phase`` (n,) rad."""
    amp: np.ndarray
    k: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    @classmethod
    def sample(cls, seed: int, wind_mps: float, n: int = 24, wind_dir_deg: float = 0.0,
               lambda_min_m: float = 0.25, lambda_max_m: float = 2.0, mss: float | None = None) -> "WaveField":
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
        amp = np.sqrt(2 * s2 / n) / kk              # each wave: slope variance (a k)^2 / 2 = s2 / n
        return cls(amp=amp, k=np.column_stack([kk * np.cos(head), kk * np.sin(head)]),
                   omega=np.sqrt(G * kk + GAMMA_OVER_RHO * kk ** 3), phase=rng.uniform(0, 2 * np.pi, n))

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

    def hessian(self, x, y, t: float = 0.0, damping=None):
        """(eta_xx, eta_xy, eta_yy) at x, y, t; ``damping`` (..., n) or (n,) multiplies each wave."""
        s = self._arg(x, y, t)
        np.sin(s, out=s)
        if damping is not None:
            s *= np.asarray(damping, np.float32)
        kx, ky = self.k[:, 0], self.k[:, 1]
        return tuple(_weighted_sum(s, (-self.amp * kk).astype(np.float32)) for kk in (kx * kx, kx * ky, ky * ky))


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


def sun_disc_damping(k_abs: np.ndarray, path_m, n: float = N_WATER) -> np.ndarray:
    """Share of each wave's focusing left at beam path ``path_m`` (...) -> (..., n): the sun's
    disc (angular radius ``SUN_RADIUS_RAD / n`` in water) blurs a wave of wavenumber k by
    ``exp(-(k h theta_sun / n)^2 / 2)``."""
    h = np.asarray(path_m, np.float32)[..., None]
    blur = np.float32(SUN_RADIUS_RAD / n) * h * np.asarray(k_abs, np.float32)
    return np.exp(-0.5 * blur * blur)


#: Fixed-point iterations of :func:`preimage` (0: evaluate the ray tube at the point itself).
PREIMAGE_ITERS = 2


def preimage(waves: WaveField, x, y, path_m, t: float, n: float = N_WATER, iters: int | None = None):
    """Where the sun ray that reaches (x, y) at beam path ``path_m`` crossed the surface:
    the fixed point of ``xi = x - h alpha grad eta(xi)`` (the small-slope ray map inverted),
    ``iters`` iterations from ``xi = x``. It converges before the first focal depth
    (``h alpha |H| < 1``); beyond it the map folds and the iterate is one of the preimages
    or none of them (the renormalised statistics still hold, the pattern's phase does not).
    Checked against the Cycles photon map (``bench caustics``): evaluating the ray tube at
    the point itself (``iters = 0``) overstates the contrast at 1 m by ~40 %."""
    s = np.float32(1.0 - 1.0 / n) * np.maximum(np.asarray(path_m, np.float32), 0)
    px, py = np.asarray(x, np.float32), np.asarray(y, np.float32)
    for _ in range(PREIMAGE_ITERS if iters is None else iters):
        gx, gy = waves.slope(px, py, t)
        px, py = x - s * gx, y - s * gy
    return px, py


def _ray_tube_factor(waves: WaveField, x, y, path_m, t: float, n: float) -> np.ndarray:
    """``1 / |det(I + h alpha H)|`` at the ray's :func:`preimage`, clipped to [0, CAUSTIC_MAX]
    (single-preimage ray map), H the Hessian with each wave damped by the sun's disc."""
    h = np.maximum(np.asarray(path_m, np.float32), 0)
    damp = sun_disc_damping(np.hypot(waves.k[:, 0], waves.k[:, 1]), h, n)
    x, y = preimage(waves, x, y, h, t, n)
    hxx, hxy, hyy = waves.hessian(x, y, t, damp)
    s = np.float32(1.0 - 1.0 / n) * h
    det = (1 + s * hxx) * (1 + s * hyy) - (s * hxy) ** 2
    return np.minimum(1.0 / np.maximum(np.abs(det), np.float32(1.0 / CAUSTIC_MAX)), np.float32(CAUSTIC_MAX))


#: Beam paths (m) of the energy table of :func:`mean_ray_tube_factor`.
MEAN_TABLE_PATHS = np.concatenate([[0.0], np.geomspace(0.05, 200.0, 47)]).astype(np.float32)


def mean_ray_tube_factor(waves: WaveField, n: float = N_WATER, grid: int = 128) -> np.ndarray:
    """Area mean of the ray-tube factor at each of ``MEAN_TABLE_PATHS`` (48,), over a patch
    three longest wavelengths wide. Beyond the first focal depth the single-preimage map
    counts the folded sheets wrongly and its mean leaves 1; dividing by this table restores
    energy conservation (mean irradiance = the flat-surface value) depth by depth."""
    side = 3 * 2 * np.pi / float(np.hypot(waves.k[:, 0], waves.k[:, 1]).min())
    x, y = np.meshgrid(*(np.linspace(0, side, grid, endpoint=False, dtype=np.float32),) * 2)
    return np.array([float(_ray_tube_factor(waves, x, y, h, 0.0, n).mean()) for h in MEAN_TABLE_PATHS],
                    np.float32)


def caustic_factor(waves: WaveField, x, y, path_m, t: float, scattering: float = 0.0,
                   n: float = N_WATER, mean_table: np.ndarray | None = None) -> np.ndarray:
    """Sun irradiance at points over its flat-surface value (module docstring), (x.shape):
    ``1 + exp(-b h) (m / <m>(h) - 1)`` with ``m`` the ray-tube factor of the sun-disc-damped
    surface, ``<m>(h)`` its area mean (:func:`mean_ray_tube_factor`: energy conservation) and
    ``exp(-b h)`` the unscattered share of the beam, the only one that carries the pattern.
    ``x``, ``y``: where each point's sun ray crosses the surface; ``path_m`` its beam path
    below the surface (m); ``mean_table`` the cached table of these waves (else computed)."""
    h = np.maximum(np.asarray(path_m, np.float32), 0)
    table = mean_ray_tube_factor(waves, n) if mean_table is None else mean_table
    mean = np.interp(h, MEAN_TABLE_PATHS, table).astype(np.float32)
    m = _ray_tube_factor(waves, x, y, h, t, n) / mean
    return 1 + np.exp(-np.float32(scattering) * h) * (m - 1)


def refracted_sun(sun_travel_dir, n: float = N_WATER) -> np.ndarray:
    """Direction (3,) of the sun's beam below a flat surface (world, unit, pointing down)."""
    d = np.asarray(sun_travel_dir, float)
    d = d / np.linalg.norm(d)
    cos_i = -d[2]
    eta = 1.0 / n
    cos_t = math.sqrt(max(0.0, 1 - eta * eta * (1 - cos_i * cos_i)))
    t = eta * d + (eta * cos_i - cos_t) * np.array([0.0, 0.0, 1.0])
    return t / np.linalg.norm(t)
