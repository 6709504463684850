"""The dock's LEDs as light sources with a physical power: radiance, point lights, light on surfaces.

Pure numpy. An LED is a flat Lambertian disc of radius ``a`` (m) whose on-axis radiant
intensity is ``I`` (W/sr) per unit colour weight: channel ``k`` emits ``I_k = I * color_k``
(the same convention as the vehicle's lamps, ``physics/light/sources.py``). Lambert's cosine law
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

import math

import numpy as np

from blendgen.physics.light.sources import PointLight
from blendgen.physics.light.surface_light import lambert_radiance


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
    return [
        PointLight(p, axis, I * np.asarray(col, float), math.pi / 2, 0.0, cosine_power=1.0)
        for p, col in zip(pts, marker["colors"])
    ]


def reach_m(lights: list[PointLight], min_irradiance: float) -> float:
    """Distance (m) beyond which no light gives more than ``min_irradiance`` (W/m^2) in clear
    water (inverse square of the brightest channel)."""
    if not lights:
        return 0.0
    i_max = max(float(np.max(li.intensity_w_sr)) for li in lights)
    return math.sqrt(i_max / max(min_irradiance, 1e-30))


#: Below this radiance (linear render units; 1 fills the default sensor's well in 10 ms) the
#: LEDs' light on surfaces is not added (well under one electron at the default sensor).
MIN_LED_RADIANCE = 1e-4


def surface_radiance(
    lights: list[PointLight],
    range_m: np.ndarray,
    rays: np.ndarray,
    albedo: np.ndarray,
    c_per_m,
    step: int = 4,
    min_radiance: float = MIN_LED_RADIANCE,
) -> np.ndarray | None:
    """Radiance (H, W, 3) float32 that Lambertian surfaces of ``albedo`` (H, W, 3) reflect
    toward the camera under the LEDs ``lights``: ``L = albedo * E / pi``, E inverse square x
    exp(-c d) x cos(incidence), no shadows (``surface_light.lambert_radiance``). Surface points are
    ``rays`` (H, W, 3 unit, camera frame) x ``range_m`` (H, W; inf: none), normals from the range
    pass. E varies slowly, so it is computed on every ``step``-th pixel and interpolated
    bilinearly. Returns None (nothing to add) when no light, or when the brightest result is
    below ``min_radiance``."""
    return lambert_radiance(lights, rays, range_m, albedo, c_per_m, None, step, None, min_radiance)
