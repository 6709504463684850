"""Point lights (the vehicle's lamps, the dock's LEDs) on the Lambertian surfaces the camera sees.

numpy (+ cv2 for one resampling; the normals in one compiled pass, ``surface_kernels``).
Camera frame (OpenCV), metres, linear RGB. The clean radiance (before the camera path's
attenuation, which the caller applies) of a Lambertian surface of albedo ``rho`` lit by point
lights of intensity ``I(psi)`` (W/sr, ``lights.PointLight``) at distance ``d`` (Jaffe 1990's
direct term; McCluney, *Introduction to Radiometry and Photometry*, ch. 2, for the Lambertian
reflection ``L = rho E / pi``):

    L = rho / pi * sum_lights I(psi) cos(i) / d^2 * exp(-c d) * visible

with ``c`` (3,) the attenuation along the light's path (the beam's ``c - F b`` for the lamps,
``c`` for the LEDs) and ``visible`` the light's shadow test (``lamp_shadow``; none: 1).
``cos(i)`` comes from the normal pass when there is one, else from the range pass (the cross
product of the surface points' finite differences, ``leds.surface_normals``: a few pixels
along silhouettes get the normal of the step between two surfaces).
"""

from __future__ import annotations

import functools
import math

import numpy as np

#: Closest approach to a light counted (m): a surface touching the source stays finite.
MIN_LIGHT_DISTANCE_M = 0.05


def surface_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals (h, w, 3) of a grid of camera-frame surface points (h, w, 3), from the
    cross product of the grid's finite differences, turned toward the camera; 0 where a
    neighbour is missing (nan points: nothing hit) or the grid is degenerate. At depth edges
    (a surface next to a farther one) the normal is that of the step between them: a few
    pixels along silhouettes get a wrong light (documented approximation)."""
    from blendgen.physics.surface.kernels import normals

    P = np.ascontiguousarray(points)
    if P.ndim != 3 or P.shape[2] != 3 or min(P.shape[:2]) < 2:
        raise ValueError(f"surface points must be a grid (h, w, 3) with h, w >= 2, got {P.shape}")
    out = np.empty_like(P)
    normals(P, out)  # one compiled pass (surface_kernels)
    return out


def lit_pixels(img) -> np.ndarray:
    """(H, W) bool: some channel of the light image ``img`` (H, W, C) is > 0, compared channel
    by channel (a reduction over the last axis, ``max(axis=-1) > 0``, takes ~20x as long on a
    640x480 frame: 11 ms against 0.5)."""
    img = np.asarray(img)
    out = img[..., 0] > 0
    for c in range(1, img.shape[-1]):
        out |= img[..., c] > 0
    return out


@functools.lru_cache(maxsize=4)
def _upsample_maps(h: int, w: int, step: int):
    """cv2.remap maps from a grid sampled at every ``step``-th pixel (0, step, ...) to (h, w)."""
    mx, my = np.meshgrid(np.arange(w, dtype=np.float32) / step, np.arange(h, dtype=np.float32) / step)
    return mx, my


def _light_gain(light, x: np.ndarray, normals: np.ndarray, sharp: bool = True):
    """(h, w) float32 ``I(psi)/I0 cos(i) / d^2`` (``sharp`` False: without ``I(psi)/I0``), the
    distances d (h, w) of surface points x (h, w, 3) and the cosines of psi (h, w)."""
    v = x - np.asarray(light.position_m, np.float32)
    d = np.maximum(np.sqrt(np.einsum("hwk,hwk->hw", v, v)), np.float32(MIN_LIGHT_DISTANCE_M))
    v /= d[..., None]
    cos_psi = v @ np.asarray(light.axis, np.float32)
    gain = (light.profile(cos_psi) if sharp else np.float32(1.0)) / (d * d)
    gain *= np.clip(-np.einsum("hwk,hwk->hw", v, normals), 0.0, None)
    return gain.astype(np.float32), d, cos_psi


def lambert_radiance(
    lights,
    rays: np.ndarray,
    range_m: np.ndarray,
    albedo: np.ndarray,
    c_light,
    normals: np.ndarray | None = None,
    step: int = 1,
    visible=None,
    min_radiance: float = 0.0,
    beam=None,
) -> np.ndarray | None:
    """Clean radiance (H, W, 3) float32 that ``lights`` put on the surfaces of the range pass (module doc).

    rays (H, W, 3) unit pixel rays; range_m (H, W) (inf/NaN/0: no surface); albedo (H, W, 3);
    c_light (3,) 1/m; normals (H, W, 3) unit, camera frame (None: from the range pass, on the
    ``step`` grid); ``step`` > 1: the light computed on every step-th pixel and interpolated
    bilinearly (smooth light fields); ``visible``: callable(light, lit (H, W) bool) -> (H, W)
    visibility, applied at full resolution; ``beam``: None (the sharp profile times ``exp(-c_light d)``)
    or callable(light, cos_psi (h, w), d (h, w)) -> (h, w, 3), the light's relative beam (the
    lamp's spread in water, ``lamp_water.LampWater.beam``). Returns None when no light or when
    the brightest result is below ``min_radiance`` (nothing worth adding)."""
    import cv2

    if not lights:
        return None
    h, w = range_m.shape
    hit = np.isfinite(range_m) & (range_m > 0)
    r = np.where(hit, range_m, 0.0).astype(np.float32)[::step, ::step]
    x = rays[::step, ::step].astype(np.float32) * r[..., None]
    nrm = (
        surface_normals(x.astype(np.float64)).astype(np.float32)
        if normals is None
        else np.asarray(normals, np.float32)[::step, ::step]
    )
    c = np.asarray(c_light, np.float32).reshape(3)
    grid = []
    for light in lights:
        gain, d, cos_psi = _light_gain(light, x, nrm, sharp=beam is None)
        e = (gain * hit[::step, ::step])[..., None] * (
            np.exp(-d[..., None] * c) if beam is None else beam(light, cos_psi, d)
        )
        grid.append(e * np.asarray(light.intensity_w_sr, np.float32))
    a_max = float(np.max(albedo)) if albedo.size else 0.0
    if min_radiance > 0 and sum(float(e.max()) for e in grid) * a_max / math.pi < min_radiance:
        return None  # before any full-resolution work
    if visible is None and step > 1:  # no per-light shadow: one resampling of the summed light (it is linear)
        grid = [np.sum(grid, axis=0, dtype=np.float32)] if len(grid) > 1 else grid
    E = np.zeros((h, w, 3), np.float32)
    for light, e in zip(lights, grid):
        if step > 1:
            e = cv2.remap(e, *_upsample_maps(h, w, step), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if visible is not None:
            e *= visible(light, lit_pixels(e))[..., None]
        E += e
    E *= albedo
    E *= np.float32(1.0 / math.pi)
    return E
