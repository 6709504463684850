"""Oracles for artificial light sources (physics/light/sources.py)."""

import math

import numpy as np
import pytest

from blendgen.config.models import Lamp
from blendgen.physics.light import sources as lights


def _lamp(**kw):
    return lights.lamp_lights([Lamp(**kw)])[0]


def test_inverse_square_times_attenuation():
    lamp = _lamp(offset_m=[0, 0, 0], power_w=10.0, half_angle_deg=30.0, edge_deg=0.0)
    c = np.array([0.1, 0.2, 0.4])
    d = np.array([1.0, 2.0, 4.0])
    E = lights.irradiance([lamp], np.c_[0 * d, 0 * d, d], c)
    i0 = 10.0 / (2 * math.pi * (1 - math.cos(math.radians(30))))
    assert np.allclose(E, i0 / d[:, None] ** 2 * np.exp(-np.outer(d, c)), rtol=1e-12)


def test_cone_holds_the_flux():
    """Integrating I over the sphere gives back the lamp's flux (uniform cone, hard edge)."""
    lamp = _lamp(half_angle_deg=40.0, edge_deg=0.0, power_w=7.0)
    th = np.linspace(0, math.pi, 200001)
    prof = lamp.profile(np.cos(th))
    flux = np.trapezoid(prof * np.sin(th), th) * 2 * math.pi * lamp.intensity_w_sr[0]
    assert flux == pytest.approx(7.0, rel=1e-3)


def test_outside_the_cone_is_dark_and_incidence_counts():
    lamp = _lamp(offset_m=[0, 0, 0], half_angle_deg=20.0, edge_deg=5.0)
    pts = np.array([[0.0, 0.0, 2.0], [2.0, 0.0, 2.0]])  # on axis, 45 deg off
    E = lights.irradiance([lamp], pts, np.zeros(3))
    assert E[1].max() == 0.0 and E[0].min() > 0
    n = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    tilted = np.array([[0.0, math.sin(0.5), -math.cos(0.5)]] * 2)
    Ef = lights.irradiance([lamp], pts[:1], np.zeros(3), normals=n[:1])
    Et = lights.irradiance([lamp], pts[:1], np.zeros(3), normals=tilted[:1])
    assert Et[0, 0] == pytest.approx(Ef[0, 0] * math.cos(0.5), rel=1e-12)


def test_aim_follows_pitch():
    lamp = _lamp(pitch_deg=30.0)
    assert np.allclose(lamp.axis, [0.0, 0.5, math.cos(math.radians(30))])
