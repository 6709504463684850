"""Artificial light sources in water: the vehicle's lamps and the dock's LEDs as point lights.

Pure numpy. Positions and directions are in the OpenCV camera frame (x right, y down,
z forward), metres. Radiometry per linear RGB channel:

- a point light has a radiant intensity ``I(theta) = I0 * profile(theta)`` (W/sr), theta
  the angle from its axis; ``profile`` is 1 inside ``half_angle - edge``, 0 outside
  ``half_angle``, a smoothstep in ``cos theta`` between (Cycles' spot blend,
  kernel/light/spot.h: ``smoothstep((cos t - cos a) / ((1 - cos a) blend))``, with
  :func:`blender_spot_blend` giving the blend);
- the irradiance it gives a point at distance ``d`` is ``I(theta) cos(incidence) / d^2 *
  exp(-c d)``: inverse square and beam attenuation ``c`` (1/m) along the light's path
  (Jaffe 1990's direct term; forward-scattered light near the beam is not added back).

A lamp of radiant flux ``P`` (W) spread evenly over a cone of half-angle ``a`` has
``I0 = P / (2 pi (1 - cos a))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PointLight:
    """One source. ``position_m`` (3,) and unit ``axis`` (3,) in the camera frame;
    ``intensity_w_sr`` (3,) on-axis radiant intensity per channel; ``half_angle_rad`` in
    (0, pi] (pi: isotropic); ``edge_rad`` the width of the soft edge inside it;
    ``cosine_power`` m multiplies the profile by ``cos(theta)^m`` (1 with half angle pi/2: a
    flat Lambertian emitter such as an LED disc, ``physics/light/leds.py``; 0: none)."""

    position_m: np.ndarray
    axis: np.ndarray
    intensity_w_sr: np.ndarray
    half_angle_rad: float = math.pi
    edge_rad: float = 0.0
    cosine_power: float = 0.0

    def profile(self, cos_theta: np.ndarray) -> np.ndarray:
        """Relative intensity (N,) at angles from the axis given by their cosines (N,)."""
        if self.cosine_power > 0:
            lam = np.clip(cos_theta, 0.0, None)
            if self.cosine_power != 1:
                lam = lam**self.cosine_power
            if self.half_angle_rad >= math.pi / 2 and self.edge_rad <= 0:
                return lam  # the cosine is already 0 behind the emitter
            base = PointLight(self.position_m, self.axis, self.intensity_w_sr, self.half_angle_rad, self.edge_rad)
            return base.profile(cos_theta) * lam
        if self.half_angle_rad >= math.pi:
            return np.ones_like(cos_theta)
        cos_half = math.cos(self.half_angle_rad)
        if self.edge_rad <= 0:
            return (cos_theta >= cos_half).astype(cos_theta.dtype)
        cos_inner = math.cos(max(self.half_angle_rad - self.edge_rad, 0.0))
        t = np.clip((cos_theta - cos_half) / (cos_inner - cos_half), 0.0, 1.0)
        return (t * t * (3.0 - 2.0 * t)).astype(cos_theta.dtype)


def cone_intensity(power_w: float, half_angle_rad: float) -> float:
    """On-axis radiant intensity (W/sr) of flux ``power_w`` (W) spread evenly over a cone."""
    return float(power_w) / (2.0 * math.pi * (1.0 - math.cos(half_angle_rad)))


def blender_spot_blend(half_angle_rad: float, edge_rad: float) -> float:
    """Cycles ``spot_blend`` whose mask is :meth:`PointLight.profile`: full intensity inside
    ``half_angle - edge``, 0 outside ``half_angle`` (smoothstep in cos between)."""
    cos_half = math.cos(half_angle_rad)
    cos_inner = math.cos(max(half_angle_rad - edge_rad, 0.0))
    return float(np.clip((cos_inner - cos_half) / (1.0 - cos_half), 0.0, 1.0)) if cos_half < 1.0 else 0.0


def irradiance(
    lights: list[PointLight],
    points_m: np.ndarray,
    c_per_m: np.ndarray,
    normals: np.ndarray | None = None,
    min_distance_m: float = 1e-3,
) -> np.ndarray:
    """Irradiance (N, 3) W/m^2 that ``lights`` give points ``points_m`` (N, 3), camera frame.

    ``c_per_m`` (3,) beam attenuation of the water along the light's path; ``normals`` (N, 3)
    unit surface normals (None: a sphere's mean, i.e. irradiance on a plane facing the
    light; ``cos(incidence)`` clipped at 0 otherwise). No shadows: use where the light's
    path is free (particles, surfaces the lamp faces)."""
    pts = np.asarray(points_m, np.float64).reshape(-1, 3)
    c = np.asarray(c_per_m, np.float64).reshape(1, 3)
    out = np.zeros((pts.shape[0], 3), np.float64)
    for light in lights:
        v = pts - np.asarray(light.position_m, np.float64)
        d = np.maximum(np.linalg.norm(v, axis=1), min_distance_m)
        u = v / d[:, None]
        gain = light.profile(u @ np.asarray(light.axis, np.float64)) / (d * d)
        if normals is not None:
            gain = gain * np.clip(-(u * np.asarray(normals, np.float64)).sum(axis=1), 0.0, None)
        out += gain[:, None] * np.asarray(light.intensity_w_sr, np.float64)[None, :] * np.exp(-c * d[:, None])
    return out


def lamp_lights(lamps) -> list[PointLight]:
    """Config lamps (``config.models.Lamp``-like: offset_m, yaw_deg, pitch_deg, half_angle_deg,
    edge_deg, power_w, color) -> point lights in the camera frame."""
    out = []
    for lamp in lamps:
        yaw, pitch = math.radians(lamp.yaw_deg), math.radians(lamp.pitch_deg)
        axis = np.array([math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
        half = math.radians(lamp.half_angle_deg)
        i0 = cone_intensity(lamp.power_w, half)
        out.append(
            PointLight(
                np.asarray(lamp.offset_m, float),
                axis / np.linalg.norm(axis),
                i0 * np.asarray(lamp.color, float),
                half,
                min(math.radians(lamp.edge_deg), half),
            )
        )
    return out
