"""The dock's LEDs as light sources with a physical power: radiance, point lights, light on surfaces.

Pure numpy. An LED is a flat Lambertian disc of radius ``a`` (m) whose on-axis radiant
intensity is ``I`` (W/sr) per unit colour weight: channel ``k`` emits ``I_k = I * color_k``
(the same convention as the vehicle's lamps, ``physics/lights.py``). Lambert's cosine law
for a flat emitter of area ``A = pi a^2`` and uniform radiance ``L`` gives
``I(theta) = L A cos(theta)`` (e.g. McCluney, *Introduction to Radiometry and Photometry*,
ch. 2), so the radiance both fidelities give the disc is

    L_k = I * color_k / (pi a^2)        (W m^-2 sr^-1, the render's linear units)

and its total flux over the front hemisphere is ``pi I_k``. Radiometric units are those of
``scene.sun_strength`` (W/m^2): the render is linear in both, so an LED and the sun keep
their ratio whatever the sensor does. The old ``strength`` key was this radiance per unit
colour weight: ``I = strength * pi a^2`` (exact).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from blendgen.physics.lights import PointLight


def led_radiance(intensity_w_sr: float, color, radius_m: float) -> list[float]:
    """Radiance (3,) W/m^2/sr of a Lambertian disc LED of on-axis intensity ``intensity_w_sr``
    (per unit colour weight), linear RGB ``color`` (3,) and radius ``radius_m``."""
    if not (intensity_w_sr > 0 and radius_m > 0):
        raise ValueError(f"intensity_w_sr and radius_m must be > 0, got {intensity_w_sr}, {radius_m}")
    area = math.pi * radius_m * radius_m
    return [float(intensity_w_sr) * float(c) / area for c in color]


def intensity_from_strength(strength: float, radius_m: float) -> float:
    """The on-axis intensity (W/sr per colour weight) of the old ``strength`` radiance scale."""
    return float(strength) * math.pi * radius_m * radius_m


def led_lights(marker: dict, T_cam_dock) -> list[PointLight]:
    """Point lights (camera frame) of one manifest LED-array ``marker``: Lambertian
    (``I(theta) = I_k cos(theta)``, nothing behind the face) on the dock's +z axis."""
    T = np.asarray(T_cam_dock, float)
    axis = T[:3, 2] / np.linalg.norm(T[:3, 2])
    I = float(marker["intensity_w_sr"])
    pts = np.asarray(marker["keypoints"], float) @ T[:3, :3].T + T[:3, 3]
    return [PointLight(p, axis, I * np.asarray(col, float), math.pi / 2, 0.0, cosine_power=1.0)
            for p, col in zip(pts, marker["colors"])]


def reach_m(lights: list[PointLight], min_irradiance: float) -> float:
    """Distance (m) beyond which no light gives more than ``min_irradiance`` (W/m^2) in clear
    water (inverse square of the brightest channel)."""
    if not lights:
        return 0.0
    i_max = max(float(np.max(li.intensity_w_sr)) for li in lights)
    return math.sqrt(i_max / max(min_irradiance, 1e-30))


def surface_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals (h, w, 3) of a grid of camera-frame surface points (h, w, 3), from the
    cross product of the grid's finite differences, turned toward the camera. At depth edges
    (a surface next to a farther one) the normal is that of the step between them: a few
    pixels along silhouettes get a wrong light (documented approximation)."""
    du = np.gradient(points, axis=1)
    dv = np.gradient(points, axis=0)
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
    flip = (n * points).sum(axis=-1, keepdims=True) > 0
    return np.where(flip, -n, n)


#: Below this radiance (linear render units; 1 fills the default sensor's well in 10 ms) the
#: LEDs' light on surfaces is not added (well under one electron at the default sensor).
MIN_LED_RADIANCE = 1e-4


@functools.lru_cache(maxsize=4)
def _upsample_maps(h: int, w: int, step: int):
    """cv2.remap maps from a grid sampled at every ``step``-th pixel (0, step, ...) to (h, w)."""
    mx, my = np.meshgrid(np.arange(w, dtype=np.float32) / step, np.arange(h, dtype=np.float32) / step)
    return mx, my


def surface_radiance(lights: list[PointLight], range_m: np.ndarray, rays: np.ndarray, albedo: np.ndarray,
                     c_per_m, step: int = 4, min_radiance: float = MIN_LED_RADIANCE) -> np.ndarray | None:
    """Radiance (H, W, 3) float32 that Lambertian surfaces of ``albedo`` (H, W, 3) reflect
    toward the camera under ``lights``: ``L = albedo * E / pi`` with E = ``lights.irradiance``
    (inverse square x exp(-c d) x cos(incidence), no shadows). Surface points are
    ``rays`` (H, W, 3 unit, camera frame) x ``range_m`` (H, W; inf: none). E varies slowly,
    so it is computed on every ``step``-th pixel and interpolated bilinearly. Returns None
    (nothing to add) when no light, or when the brightest result is below ``min_radiance``."""
    import cv2
    from blendgen.physics.lights import irradiance
    if not lights:
        return None
    h, w = range_m.shape
    r = np.asarray(range_m[::step, ::step], np.float64)
    ok = np.isfinite(r)
    if not ok.any():
        return None
    pts = rays[::step, ::step].astype(np.float64) * np.where(ok, r, 0.0)[..., None]
    nrm = surface_normals(pts)
    E = np.zeros(pts.shape, np.float64)
    E[ok] = irradiance(lights, pts[ok], np.asarray(c_per_m, float), nrm[ok])
    a_max = float(np.max(albedo[::step, ::step])) if albedo.size else 0.0   # albedo is piecewise flat
    if E.max() * a_max / math.pi < min_radiance:
        return None
    mx, my = _upsample_maps(h, w, step)
    E_full = cv2.remap(E.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return albedo.astype(np.float32) * E_full * np.float32(1.0 / math.pi)
