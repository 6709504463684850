"""The one Lambertian point-light function (physics/light/surface_light.py) used by the LEDs (range-pass
normals, 1/4 grid) and the vehicle lamp (normal pass, every pixel, shadows)."""

import math

import numpy as np
import pytest

from blendgen.geometry import intrinsics_from_hfov
from blendgen.physics.light.sources import PointLight
from blendgen.physics.light.surface_light import lambert_radiance, lit_pixels
from blendgen.pipeline.compose import _unit_rays


def _tilted_wall(tilt_deg=35.0, size=(96, 72)):
    """A plane through (0, 0, 3) tilted about the y axis: rays, range, its unit normal (facing the camera)."""
    K = intrinsics_from_hfov(*size, math.radians(60.0))
    rays = _unit_rays(tuple(K.ravel()), *size)
    a = math.radians(tilt_deg)
    n = np.array([math.sin(a), 0.0, -math.cos(a)])
    rng = ((np.array([0.0, 0.0, 3.0]) @ n) / (rays @ n.astype(np.float32))).astype(np.float32)
    return rays, rng, n


@pytest.mark.parametrize("normals_from", ["pass", "range"])
@pytest.mark.parametrize("step", [1, 4])
def test_tilted_wall_matches_lambert_law(normals_from, step):
    """rho/pi I cos(i)/d^2 exp(-c d) written out per pixel with the plane's exact normal: the normal
    pass and the range-derived normals agree with it (0.5 %; 1 % on the 1/4 grid, away from the border)."""
    rays, rng, n = _tilted_wall()
    light = PointLight(np.array([0.3, 0.2, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 2.0, 3.0]))
    c = np.array([0.1, 0.2, 0.3])
    albedo = np.full(rng.shape + (3,), 0.4, np.float32)
    normals = np.broadcast_to(n.astype(np.float32), rays.shape) if normals_from == "pass" else None
    got = lambert_radiance([light], rays, rng, albedo, c, normals, step)
    x = rays.astype(np.float64) * rng[..., None]
    v = x - light.position_m
    d = np.linalg.norm(v, axis=-1)
    cos_i = -(v / d[..., None]) @ n
    want = 0.4 / math.pi * light.intensity_w_sr * (cos_i / d**2)[..., None] * np.exp(-c * d[..., None])
    inner = (slice(4, -8), slice(4, -8))
    np.testing.assert_allclose(got[inner], want[inner], rtol=0.005 if step == 1 else 0.01)


def test_visibility_multiplies_each_light_and_nothing_is_none():
    rays, rng, n = _tilted_wall()
    lights = [PointLight(np.array([s, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.ones(3)) for s in (-0.2, 0.2)]
    albedo = np.full(rng.shape + (3,), 0.5, np.float32)
    both = lambert_radiance(lights, rays, rng, albedo, np.zeros(3))
    one = lambert_radiance(lights[:1], rays, rng, albedo, np.zeros(3))
    half = lambert_radiance(
        lights,
        rays,
        rng,
        albedo,
        np.zeros(3),
        visible=lambda light, lit: np.full(lit.shape, float(light.position_m[0] < 0), np.float32),
    )
    np.testing.assert_allclose(half, one, rtol=1e-6)
    assert (both > one).all()
    assert lambert_radiance([], rays, rng, albedo, np.zeros(3)) is None


def _normals_oracle(P):
    """The law written with np.gradient-free slices and np.cross: du x dv of central differences
    (one-sided at the border), unit, turned toward the origin, 0 where not finite or degenerate."""
    du = np.concatenate([P[:, 1:2] - P[:, :1], P[:, 2:] - P[:, :-2], P[:, -1:] - P[:, -2:-1]], axis=1)
    dv = np.concatenate([P[1:2] - P[:1], P[2:] - P[:-2], P[-1:] - P[-2:-1]], axis=0)
    n = np.cross(du.astype(np.float64), dv.astype(np.float64))
    norm = np.linalg.norm(n, axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / norm * np.where(np.sum(n * P, axis=2, keepdims=True) > 0, -1.0, 1.0)
    return np.where(np.isfinite(n) & (norm > 0), n, 0.0)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_surface_normals_are_the_cross_product_of_the_grid(dtype):
    """The compiled normals (physics/surface/kernels) against the law written with np.cross: a
    tilted wall (its exact normal inside), nan holes (0 around them), a curved patch (every
    orientation, turned toward the camera) and the one-sided borders; 1e-6."""
    from blendgen.physics.light.surface_light import surface_normals

    rays, rng, n_wall = _tilted_wall(size=(40, 30))
    P = (rays * rng[..., None]).astype(dtype)
    got = surface_normals(P)
    assert got.dtype == dtype
    assert np.allclose(got[3:-3, 3:-3], n_wall, atol=1e-5)
    rs = np.random.default_rng(4)
    bumpy = (P * (1.0 + 0.2 * rs.random(P.shape[:2]))[..., None]).astype(dtype)  # every orientation
    bumpy[rs.random(P.shape[:2]) < 0.05] = np.nan  # nothing hit there
    got = surface_normals(bumpy)
    want = _normals_oracle(bumpy)
    assert np.count_nonzero(np.all(want == 0, axis=2)) > 100  # the holes' neighbours are 0
    assert np.max(np.abs(got - want)) < 1e-5
    assert np.all(np.sum(got * np.nan_to_num(bumpy), axis=2) <= 1e-6)  # toward the camera


def test_several_lights_on_the_coarse_grid_are_the_sum_of_each_alone():
    """Without shadows the lights' grids are summed before the one (linear) resampling: four
    LEDs on the 1/4 grid give the sum of each LED's own radiance (float32 rounding)."""
    rays, rng, n = _tilted_wall()
    lights = [
        PointLight(np.array([sx, sy, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 2.0, 3.0]))
        for sx in (-0.3, 0.3)
        for sy in (-0.2, 0.2)
    ]
    albedo = np.random.default_rng(1).uniform(0.1, 0.9, rng.shape + (3,)).astype(np.float32)
    c = np.array([0.1, 0.2, 0.3])
    together = lambert_radiance(lights, rays, rng, albedo, c, step=4)
    alone = sum(lambert_radiance([li], rays, rng, albedo, c, step=4) for li in lights)
    np.testing.assert_allclose(together, alone, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_lit_pixels_is_any_channel_above_zero(channels):
    """The mask the lamp shadow test and the caustics take: the same as ``max(axis=-1) > 0``
    for zeros, negatives, tiny and huge values, and -0.0."""
    rng = np.random.default_rng(5)
    img = rng.choice(np.array([0.0, -0.0, -1.0, 1e-30, 3.0, 1e30], np.float32), size=(37, 23, channels))
    np.testing.assert_array_equal(lit_pixels(img), img.max(axis=-1) > 0)
