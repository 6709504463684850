"""The vehicle lamp in water, fast fidelity: lamp-lit surfaces and the backscatter veil.

Pure numpy. Camera frame (OpenCV: x right, y down, z forward), metres, linear RGB
radiance (W/m^2/sr per channel). Lamps are :class:`physics.lights.PointLight` cones.
The Jaffe (1990) / McGlamery (1980) decomposition of an image under artificial light:

- **direct** (lamp-lit surface): a Lambertian surface of albedo ``rho`` at range ``r``
  along the pixel ray, at distance ``d`` from a lamp of intensity ``I(psi)`` (W/sr),
  reflects ``rho / pi * I(psi) cos(i) / d^2 * exp(-c' d)`` and the camera sees it times
  ``exp(-c r)`` (:func:`surface_radiance`). No shadow test: every surface the camera sees
  is assumed to see the lamp (true for the dock face and the pool seen from a camera-mounted
  lamp; wrong behind obstacles -- documented limitation).
- **backscatter** (the veil in front of the camera): the single-scattering integral along
  each pixel ray ``x = t u``, ``t`` in ``[0, r]``,

      V = int_0^r  b p(theta) I(psi) / d(t)^2 exp(-c' d(t)) exp(-c' t) dt

  with ``theta`` the scattering angle between the lamp's ray and the direction to the
  camera, ``p`` the water's phase function (1/sr; ``optics.hg_phase`` or ``ff_phase``),
  evaluated on a coarse grid of rays at geometric range nodes, accumulated (trapezoid)
  and interpolated per pixel bilinearly in the image and linearly at the pixel's own
  range (:func:`backscatter_table`, :func:`veil_at_range`).
- **multiple scattering**: ``c' = c - F b``, one documented factor ``F``
  (:data:`FORWARD_KEPT`): the share of scattered light that is not lost to a smooth light
  field because ocean scattering is forward-peaked (Petzold's mean cosine ~0.92; the
  "effective attenuation" of beam-spread models, Mobley's Ocean Optics Web Book, "The Beam
  Spread Function"). It applies where the light field is smooth on the scale of the
  forward-scattering angles: the lamp's beam (surfaces and veil) and the veil's way back
  to the camera. The image of a surface keeps ``c`` on its way to the camera (it is the
  beam transmittance; its forward-scattered part is blur/glow, not image). ``F = 0`` is
  single scattering, what the pipeline's 0-bounce reference renders.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from blendgen.physics.lights import PointLight

#: ``F``: share of scattered light kept by a smooth light field (forward-peaked water),
#: ``c' = c - F b``. 0 = pure single scattering. Fitted (one value for both waters) to
#: the mean backscatter veil of Cycles renders with 32 volume bounces, HG g = 0.9, waters
#: ``mild`` and ``moderate``, no surface (``dockbench bench lamp``): mean ratio fast/reference
#: 0.98 and 1.01, 12x12-px block error 8 % and 13 % (docs/LAMP.md).
FORWARD_KEPT = 0.85

#: Geometric range nodes of the veil integral (m): first node, last node, count.
T_MIN_M, T_MAX_M, N_NODES = 0.02, 60.0, 96
#: Coarse grid step (px) of the veil's rays.
GRID_PX = 16
#: Closest approach to a lamp counted (m): a ray grazing the source stays finite.
MIN_LAMP_DISTANCE_M = 0.05


@dataclass(frozen=True)
class LampWater:
    """What the fast lamp model needs: the lights and the water's coefficients (3,), 1/m.

    ``c_lamp`` is the effective attenuation ``c - F b`` of smooth light fields: on the
    lamp's path and on the veil's path to the camera; ``c`` stays on a surface's image."""
    lights: tuple[PointLight, ...]
    sigma_s: np.ndarray
    c: np.ndarray
    c_lamp: np.ndarray
    phase: object          # callable cos(theta) (N,) -> 1/sr (N,)

    @classmethod
    def build(cls, lights: list[PointLight], water, forward_kept: float | None = None) -> "LampWater":
        """From lights and an ``optics.WaterOptics`` (its phase function and coefficients);
        ``forward_kept`` F (None: :data:`FORWARD_KEPT`)."""
        forward_kept = FORWARD_KEPT if forward_kept is None else forward_kept
        from blendgen.physics import optics
        b, c = np.asarray(water.sigma_s, float), np.asarray(water.c, float)
        if water.phase == "ff":
            phase = functools.partial(_ff_of_cos, ior=water.ff_ior, backscatter=water.ff_backscatter)
        else:
            phase = functools.partial(optics.hg_phase, g=float(water.g))
        return cls(tuple(lights), b, c, c - float(forward_kept) * b, phase)


def _ff_of_cos(cos_theta, ior: float, backscatter: float):
    from blendgen.physics import optics
    return optics.ff_phase(np.arccos(np.clip(cos_theta, -1.0, 1.0)), ior, backscatter)


def range_nodes() -> np.ndarray:
    """(N_NODES + 1,) range nodes (m): 0, then geometric from T_MIN_M to T_MAX_M."""
    return np.concatenate([[0.0], np.geomspace(T_MIN_M, T_MAX_M, N_NODES)])


def _light_terms(light: PointLight, x: np.ndarray, c_lamp: np.ndarray):
    """For points x (..., 3): unit direction lamp->x (..., 3) and I(psi) exp(-c' d) / d^2 (..., 3)."""
    v = x - np.asarray(light.position_m, x.dtype)
    d = np.maximum(np.linalg.norm(v, axis=-1), MIN_LAMP_DISTANCE_M)
    w = v / d[..., None]
    prof = light.profile(w @ np.asarray(light.axis, x.dtype)) / (d * d)
    gain = prof[..., None] * np.asarray(light.intensity_w_sr, x.dtype) * np.exp(-d[..., None] * c_lamp.astype(x.dtype))
    return w, gain


def backscatter_table(model: LampWater, rays: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cumulative single-scatter veil (N, T, 3) along unit rays (N, 3) up to each node t (T,)."""
    x = rays[:, None, :] * t[None, :, None]                       # (N, T, 3)
    f = np.zeros(x.shape, np.float64)
    for light in model.lights:
        w, gain = _light_terms(light, x, model.c_lamp)
        cos_scatter = -(w * rays[:, None, :]).sum(axis=-1)        # lamp ray vs direction to camera
        f += gain * model.phase(cos_scatter)[..., None]
    f *= model.sigma_s * np.exp(-t[None, :, None] * model.c_lamp)
    dt = np.diff(t)[None, :, None]
    steps = 0.5 * (f[:, 1:] + f[:, :-1]) * dt
    return np.concatenate([np.zeros_like(f[:, :1]), np.cumsum(steps, axis=1)], axis=1)


@functools.lru_cache(maxsize=4)
def _grid(K_t: tuple, width: int, height: int, step: int):
    """Coarse rays (gh*gw, 3) and, per pixel (H*W,), the 4 cell indices and bilinear weights."""
    K = np.array(K_t).reshape(3, 3)
    gu = np.linspace(0.0, width - 1.0, max(2, math.ceil((width - 1) / step) + 1))
    gv = np.linspace(0.0, height - 1.0, max(2, math.ceil((height - 1) / step) + 1))
    u, v = np.meshgrid(gu, gv)
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    rays = np.dstack([x, y, np.ones_like(x)]).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    fu = np.arange(width) / (gu[1] - gu[0])
    fv = np.arange(height) / (gv[1] - gv[0])
    iu = np.minimum(fu.astype(int), len(gu) - 2)
    iv = np.minimum(fv.astype(int), len(gv) - 2)
    au, av = (fu - iu).astype(np.float32), (fv - iv).astype(np.float32)
    c00 = (iv[:, None] * len(gu) + iu[None, :]).ravel()
    cells = np.stack([c00, c00 + 1, c00 + len(gu), c00 + len(gu) + 1])
    wts = np.stack([np.outer(1 - av, 1 - au), np.outer(1 - av, au), np.outer(av, 1 - au), np.outer(av, au)])
    return rays, cells, wts.reshape(4, -1).astype(np.float32)


def veil_at_range(table: np.ndarray, t: np.ndarray, cells: np.ndarray, wts: np.ndarray,
                  range_m: np.ndarray) -> np.ndarray:
    """Per-pixel veil (H, W, 3): the table (N, T, 3) at the pixel's range (H, W) (inf: last
    node), bilinear over the 4 coarse rays ``cells`` (4, H*W) with weights ``wts`` (4, H*W)."""
    h, w = range_m.shape
    r = np.nan_to_num(range_m.reshape(-1).astype(np.float64), nan=t[-1], posinf=t[-1])
    r = np.clip(r, 0.0, t[-1])
    k = np.clip(np.searchsorted(t, r, side="right") - 1, 0, len(t) - 2)
    frac = ((r - t[k]) / (t[k + 1] - t[k])).astype(np.float32)[:, None]
    flat = table.astype(np.float32).reshape(-1, 3)
    nt = len(t)
    out = np.zeros((h * w, 3), np.float32)
    for cell, wt in zip(cells, wts):
        base = cell * nt + k
        out += wt[:, None] * (flat[base] * (1 - frac) + flat[base + 1] * frac)
    return out.reshape(h, w, 3)


def backscatter(model: LampWater, K: np.ndarray, range_m: np.ndarray, step: int = GRID_PX) -> np.ndarray:
    """The lamps' backscatter veil (H, W, 3) in front of surfaces at ``range_m`` (H, W)."""
    h, w = range_m.shape
    step = int(min(step, max(4, min(w, h) // 24)))      # at least ~24 rays across small images
    rays, cells, wts = _grid(tuple(np.asarray(K, float).ravel()), w, h, step)
    t = range_nodes()
    return veil_at_range(backscatter_table(model, rays, t), t, cells, wts, range_m)


def surface_radiance(model: LampWater, rays: np.ndarray, range_m: np.ndarray, albedo: np.ndarray,
                     normals: np.ndarray | None) -> np.ndarray:
    """Lamp light reflected by Lambertian surfaces, as seen by the camera (H, W, 3):
    ``albedo / pi * sum I(psi) cos(i) exp(-c' d) / d^2 * exp(-c r)``.

    rays (H, W, 3) unit pixel rays; range_m (H, W) (inf/NaN: no surface, 0); albedo (H, W, 3);
    normals (H, W, 3) unit, camera frame (None: the surface faces the lamp, cos(i) = 1)."""
    hit = np.isfinite(range_m) & (range_m > 0)
    out = np.zeros(albedo.shape, np.float32)
    if not hit.any():
        return out
    r = range_m[hit].astype(np.float32)
    x = rays[hit] * r[:, None]
    e = np.zeros(x.shape, np.float32)
    for light in model.lights:
        wdir, gain = _light_terms(light, x, model.c_lamp)
        if normals is not None:
            gain = gain * np.clip(-(wdir * normals[hit]).sum(axis=1), 0.0, None)[:, None]
        e += gain
    e *= albedo[hit] * np.float32(1.0 / math.pi) * np.exp(-r[:, None] * model.c.astype(np.float32))
    out[hit] = e
    return out


def lamp_radiance(model: LampWater, K: np.ndarray, rays: np.ndarray, range_m: np.ndarray,
                  albedo: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
    """Everything the lamps add to the camera image (H, W, 3): lit surfaces + backscatter."""
    out = surface_radiance(model, rays, range_m, albedo, normals)
    if np.any(model.sigma_s > 0):
        out += backscatter(model, K, range_m)
    return out
