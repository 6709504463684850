"""Beam spread of a lamp in forward-scattering water (small-angle multiple scattering).

Pure numpy/scipy. A lamp's light that reaches a point at distance ``d`` (m) and angle ``psi``
(rad) from its axis is, per colour channel (Jaffe 1990's direct beam and its
forward-scattered part; the small-angle picture of Mobley's Ocean Optics Web Book, "The
Beam Spread Function")

    I0 exp(-c d) [ P(psi) + sum_{n >= 1} lam^n / n! P_n(psi) ],     lam = F b d,

- ``P`` the lamp's sharp profile (``lights.PointLight.profile``), ``c`` the beam attenuation:
  the light never scattered;
- ``F`` (``lamp_water.FORWARD_KEPT``) the share of scattering that stays in the forward
  lobe ``theta <= theta_F`` of the phase function (31 deg for HG g = 0.9, F = 0.85); the
  rest (``(1 - F) b``) leaves the beam. Forward events along the path are Poisson of mean
  ``lam``, so the sum is ``exp(-c' d)`` in total with ``c' = c - F b`` (the mean the model
  had before, unchanged);
- ``P_n = P * K^(*n)``: the profile convolved ``n`` times with the **one-event kernel** ``K``,
  the distribution of the angle **seen from the lamp** of light deflected once by ``theta``
  (the lobe's own distribution) at a uniform distance ``s`` along the path: ``theta (1 - s/d)``.

Convolutions are radial (the profile and ``K`` are symmetric about the axis), done as
products of Hankel transforms (order 0): ``K`` transforms to
``K^(k) = E_theta[ int_0^1 J0(k theta u) du ] = E_theta[ Si0(k theta) / (k theta) ]`` with
``Si0(x) = int_0^x J0`` (``scipy.special.itj0y0``). No fitted constant beyond F: the phase
function fixes the spread.

Before this module the scattered light kept the sharp profile (``P exp(-c' d)``): no light
left the cone, and the veil outside the cone's edge was 71-76 % below a 32-bounce Cycles
render (docs/LAMP.md). Angles are treated as a plane (``psi`` as a radius): exact for small
angles, approximate for spreads beyond ~1 rad.
"""

from __future__ import annotations

import functools
import math

import numpy as np

#: Angle grid of the beam table (rad): psi in [0, PSI_MAX].
PSI_MAX, N_PSI = math.pi, 256
#: Distance grid of the beam table (m): geometric, D_MIN to D_MAX (1.4 % steps).
D_MIN, D_MAX, N_D = 0.05, 60.0, 512
#: Hankel grid: profile radius samples on [0, PSI_MAX] (K_MAX dr = 0.3: coarser samples alias
#: the high frequencies into a dip on the axis, 3 % at K_MAX dr = 1.2); frequencies up to K_MAX
#: (1/rad) in steps of 1/16 (coarser steps lose energy to a negative tail: 2.6 % at 1/4, 0.2 % at
#: 1/16); a Gaussian taper of TAPER_RAD (a 1-deg blur of the scattered light only; the lobe is
#: ~30 deg wide) that is exp(-6) at K_MAX, against ringing.
N_R, K_MAX, N_K, TAPER_RAD = 2048, 200.0, 3201, math.radians(1.0)


def psis() -> np.ndarray:
    return np.linspace(0.0, PSI_MAX, N_PSI)


def distances() -> np.ndarray:
    return np.geomspace(D_MIN, D_MAX, N_D)


def _lobe(phase, forward_kept: float) -> tuple[np.ndarray, np.ndarray]:
    """(theta (M,) rad, weights (M,)) of the forward lobe ``theta <= theta_F`` holding the share
    ``forward_kept`` of the phase function; weights sum to 1."""
    if not 0.0 < forward_kept < 1.0:
        raise ValueError(f"forward_kept must be in (0, 1), got {forward_kept}")
    theta = np.concatenate([[0.0], np.geomspace(1e-5, math.pi, 20000)])
    w = np.asarray(phase(np.cos(theta)), float) * 2.0 * math.pi * np.sin(theta)
    seg = 0.5 * (w[1:] + w[:-1]) * np.diff(theta)
    cum = np.cumsum(seg) / seg.sum()
    k = max(int(np.searchsorted(cum, forward_kept)), 1) + 1
    mid = 0.5 * (theta[1:k] + theta[: k - 1])
    return mid, seg[: k - 1] / seg[: k - 1].sum()


def kernel_transform(phase, forward_kept: float, k: np.ndarray) -> np.ndarray:
    """Hankel transform (order 0, unit integral) of the one-event kernel at frequencies
    ``k`` (1/rad): ``E_theta[Si0(k theta) / (k theta)]`` over the forward lobe (module doc)."""
    from scipy.special import itj0y0

    theta, w = _lobe(phase, forward_kept)
    idx = np.arange(0, w.size, 40)  # ~500 nodes: K^ is smooth in theta
    w_node = np.add.reduceat(w, idx)
    theta, w = np.add.reduceat(w * theta, idx) / np.maximum(w_node, 1e-300), w_node
    x = np.outer(k, theta)
    avg = np.where(x > 1e-9, itj0y0(np.maximum(x, 1e-9))[0] / np.maximum(x, 1e-9), 1.0)
    return avg @ w


def _frequencies() -> tuple[np.ndarray, np.ndarray]:
    """(k (N_K,) 1/rad, trapezoid weights (N_K,))."""
    k = np.linspace(0.0, K_MAX, N_K)
    wk = np.full(N_K, k[1] - k[0])
    wk[[0, -1]] *= 0.5
    return k, wk


def profile_transform(light) -> np.ndarray:
    """``F(k) = 2 pi int P(r) J0(k r) r dr`` (N_K,) of a light's profile on the r grid
    (trapezoid; in blocks of frequencies, no N_K x N_R matrix is kept)."""
    from scipy.special import j0

    r = np.linspace(0.0, PSI_MAX, N_R)
    wr = np.full(N_R, r[1] - r[0])
    wr[[0, -1]] *= 0.5
    f = 2.0 * math.pi * light.profile(np.cos(r)) * r * wr
    k = _frequencies()[0]
    return np.concatenate([j0(np.outer(k[i : i + 256], r)) @ f for i in range(0, N_K, 256)])


@functools.lru_cache(maxsize=1)
def _inverse_matrix() -> np.ndarray:
    """(N_PSI, N_K): ``f(psi) = 1/(2 pi) int F(k) J0(k psi) k dk`` with the Gaussian taper."""
    from scipy.special import j0

    k, wk = _frequencies()
    taper = np.exp(-0.5 * (k * TAPER_RAD) ** 2)
    return j0(np.outer(psis(), k)) * (k * wk * taper)[None, :] / (2.0 * math.pi)


@functools.lru_cache(maxsize=16)
def spread_profiles(light_key: tuple, phase_key: tuple, forward_kept: float, n_max: int) -> np.ndarray:
    """(n_max, N_PSI) float32: ``P_n`` for n = 1..n_max of a profile (``light_key`` =
    (half_angle_rad, edge_rad, cosine_power)) and a phase function (``phase_key`` = ("hg", g)
    or ("ff", ior, backscatter))."""
    from blendgen.physics.light.sources import PointLight

    light = PointLight(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.ones(3), *light_key)
    k = _frequencies()[0]
    K_hat = kernel_transform(phase_of(phase_key), forward_kept, k)
    powers = K_hat[None, :] ** np.arange(1, n_max + 1)[:, None]
    return ((powers * profile_transform(light)[None, :]) @ _inverse_matrix().T).astype(np.float32)


def phase_of(phase_key: tuple):
    """Callable cos(theta) (N,) -> 1/sr (N,) for ("hg", g) or ("ff", ior, backscatter) (the
    water's phase function, ``optics.hg_phase`` / ``optics.ff_phase``)."""
    from blendgen.physics.water import optics

    if phase_key[0] == "hg":
        return functools.partial(optics.hg_phase, g=float(phase_key[1]))
    return lambda mu: optics.ff_phase(np.arccos(np.clip(mu, -1.0, 1.0)), float(phase_key[1]), float(phase_key[2]))


def light_key(light) -> tuple:
    """The profile parameters of a ``lights.PointLight`` (cache key of :func:`spread_profiles`)."""
    return (float(light.half_angle_rad), float(light.edge_rad), float(light.cosine_power))


def beam_table(light, c: np.ndarray, sigma_s: np.ndarray, forward_kept: float, phase_key: tuple) -> np.ndarray:
    """(N_D, N_PSI, 3) float32 relative beam ``exp(-c d) [P + sum lam^n/n! P_n]``, ``lam = F b d``
    (module doc), of ``light`` on the grid (:func:`distances`, :func:`psis`); ``c``, ``sigma_s``
    = b: (3,) 1/m; ``forward_kept`` F in (0, 1); ``phase_key`` as in :func:`spread_profiles`.
    Times ``I0 / d^2`` it is the irradiance normal to the light's ray."""
    from scipy.special import gammaln

    d = distances()
    c = np.asarray(c, float)
    fb = float(forward_kept) * np.asarray(sigma_s, float)
    lam_max = float(np.max(fb)) * D_MAX
    n_max = int(min(640, 32 * math.ceil((lam_max + 8.0 * math.sqrt(lam_max) + 12) / 32)))  # cache buckets
    profiles = spread_profiles(light_key(light), phase_key, float(forward_kept), n_max)
    sharp = light.profile(np.cos(psis()))
    n = np.arange(1, n_max + 1)
    out = np.empty((N_D, N_PSI, 3), np.float32)
    for ch in range(3):
        logw = n[None, :] * np.log(np.maximum(fb[ch] * d, 1e-300))[:, None] - gammaln(n + 1)[None, :]
        logw -= (c[ch] * d)[:, None]
        out[..., ch] = np.exp(-c[ch] * d)[:, None] * sharp[None, :] + np.exp(logw) @ profiles
    return np.maximum(out, 0.0, out=out)  # the transforms' ringing leaves ~-1e-4 far out


def lookup(table: np.ndarray, cos_psi: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The beam table (:func:`beam_table`) at angles ``cos_psi`` (h, w) and distances ``d``
    (h, w, m; clipped to [D_MIN, D_MAX]) -> (h, w, 3) float32, bilinear (``cv2.remap``)."""
    import cv2

    if np.size(cos_psi) == 0:  # cv2.remap rejects an empty map (a frame with no particle)
        return np.zeros((*np.shape(cos_psi), 3), np.float32)
    x = np.arccos(np.clip(cos_psi, -1.0, 1.0)).astype(np.float32) * np.float32((N_PSI - 1) / PSI_MAX)
    y = np.log(np.clip(d, D_MIN, D_MAX).astype(np.float32) * np.float32(1.0 / D_MIN))
    y *= np.float32((N_D - 1) / math.log(D_MAX / D_MIN))
    return cv2.remap(table, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
