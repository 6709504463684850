"""Screen-space lamp shadows (physics/light/lamp_shadow.py) against the geometric projection of
known occluders, and their zero cost when off (no lamp, or ``lamp_shadows: false``)."""

import math

import cv2
import numpy as np
import pytest

from blendgen.geometry import intrinsics_from_hfov
from blendgen.physics.light import lamp_shadow, lamp_water
from blendgen.physics.light.sources import PointLight
from blendgen.physics.water import optics
from blendgen.pipeline.compose import _unit_rays
from blendgen.tools.bench import lamp_bench as lb

K3 = np.ones((3, 3), np.uint8)


def _plate_scene(size, lamp, plate_z, wall_z, rect):
    """Range pass of a thin plate ``rect`` (x0, x1, y0, y1) at depth plate_z in front of a wall
    at wall_z, and the geometric shadow on the wall: the segment wall point -> lamp crosses the
    plate's plane inside rect (written out here, independent of lamp_shadow)."""
    K = intrinsics_from_hfov(size[0], size[1], math.radians(60.0))
    rays = _unit_rays(tuple(K.ravel()), *size).astype(np.float64)
    P = rays * (plate_z / rays[..., 2])[..., None]
    on_plate = (P[..., 0] >= rect[0]) & (P[..., 0] <= rect[1]) & (P[..., 1] >= rect[2]) & (P[..., 1] <= rect[3])
    rng = np.where(on_plate, plate_z / rays[..., 2], wall_z / rays[..., 2]).astype(np.float32)
    X = rays * (wall_z / rays[..., 2])[..., None]
    S = np.asarray(lamp, float)
    t = (X[..., 2] - plate_z) / (X[..., 2] - S[2])
    Y = X + t[..., None] * (S - X)
    shadow = (
        ~on_plate & (Y[..., 0] >= rect[0]) & (Y[..., 0] <= rect[1]) & (Y[..., 1] >= rect[2]) & (Y[..., 1] <= rect[3])
    )
    return K, rays.astype(np.float32), rng, shadow, on_plate


@pytest.mark.parametrize(
    "size,lamp,px",
    [((160, 120), (0.0, 0.3, 0.0), 1), ((320, 240), (0.2, 0.25, 0.05), 1), ((640, 480), (-0.15, 0.3, -0.1), 1)],
)
def test_plate_shadow_edges_within_one_pixel_of_the_projection(size, lamp, px):
    """A thin plate 1 m ahead of a wall at 3 m: the fast shadow lies inside the geometric shadow
    dilated by ``px`` and covers it eroded by ``px`` (every edge within px), IoU > 0.85. At 640 px
    the edge cast by the plate's far rim lies 1.2 px out: the shadow of a THICKNESS_M thick plate."""
    K, rays, rng, geo, plate = _plate_scene(size, lamp, 1.0, 3.0, (-0.15, 0.15, 0.05, 0.15))
    fast = (lamp_shadow.visibility(lamp, K, rays, rng) < 0.5) & ~plate
    assert geo.sum() > 100
    g8 = geo.astype(np.uint8)
    assert not (fast & ~cv2.dilate(g8, K3, iterations=px).astype(bool)).any()
    assert not (cv2.erode(g8, K3, iterations=px).astype(bool) & ~fast).any()
    assert lb._iou(fast, geo) > 0.85


def test_moving_the_lamp_moves_the_shadow():
    """Property: with the lamp on the other side the shadow is on the other side (a test that a
    wrong march direction would fail)."""
    K, rays, rng, geo_dn, plate = _plate_scene((160, 120), (0.0, 0.3, 0.0), 1.0, 3.0, (-0.15, 0.15, -0.05, 0.05))
    _, _, _, geo_up, _ = _plate_scene((160, 120), (0.0, -0.3, 0.0), 1.0, 3.0, (-0.15, 0.15, -0.05, 0.05))
    dn = lamp_shadow.visibility((0.0, 0.3, 0.0), K, rays, rng) < 0.5
    up = lamp_shadow.visibility((0.0, -0.3, 0.0), K, rays, rng) < 0.5
    rows = np.arange(120)[:, None]
    assert rows[dn.any(axis=1)].max() < 60 < rows[up.any(axis=1)].min()  # lamp below: shadow above
    assert lb._iou(dn & ~plate, geo_dn) > 0.85 and lb._iou(up & ~plate, geo_up) > 0.85


@pytest.mark.parametrize("tilt_deg", [2.0, 10.0, 45.0, 80.0])
def test_no_self_shadow_on_an_open_plane(tilt_deg):
    """A floor below the camera seen from grazing (2 deg) to steep, lamp above it: nothing in shadow."""
    K = intrinsics_from_hfov(160, 120, math.radians(60.0))
    rays = _unit_rays(tuple(K.ravel()), 160, 120)
    n = np.array([0.0, -math.cos(math.radians(tilt_deg)), -math.sin(math.radians(tilt_deg))])  # faces up/back
    p0 = np.array([0.0, 1.0, 2.0])
    with np.errstate(divide="ignore"):
        t = (p0 @ n) / (rays @ n.astype(np.float32))
    rng = np.where(t > 0, t, np.inf).astype(np.float32)
    assert np.isfinite(rng).sum() > 1000
    assert (lamp_shadow.visibility((0.1, 0.3, 0.0), K, rays, rng) == 1.0).all()


def test_box_scene_matches_geometry_except_hidden_edges():
    """The bench's shadow scene (a 5 cm slab and a 5 cm post, lamp right and below): IoU with the
    segment-box oracle > 0.9 at 320x240; no pixel shadowed more than 1 px outside it."""
    spec = lb.shadow_spec(optics.get_preset("clear"), (320, 240))
    K, rays = lb.camera(spec)
    rng, _, _, obj = lb.scene_passes(spec, rays)
    geo = lb.geometric_shadow(spec, rays)
    fast = (lamp_shadow.visibility(lb.SHADOW_LAMP["offset_m"], K, rays, rng) < 0.5) & (obj == 1)
    assert lb._iou(fast, geo) > 0.9
    assert not (fast & ~cv2.dilate(geo.astype(np.uint8), K3).astype(bool)).any()


def test_coarse_grid_equals_full_resolution():
    K, rays, rng, _, _ = _plate_scene((640, 480), (0.2, 0.3, 0.0), 1.0, 3.0, (-0.15, 0.15, 0.05, 0.15))
    assert np.array_equal(
        lamp_shadow.visibility((0.2, 0.3, 0.0), K, rays, rng, step=4),
        lamp_shadow.visibility((0.2, 0.3, 0.0), K, rays, rng, step=1),
    )


def test_shadow_darkens_lamp_light_and_switch_skips_it(monkeypatch):
    """Clear water: the lamp's light on the wall is 0 in the shadow and unchanged elsewhere;
    ``shadows=False`` never calls the test."""
    K, rays, rng, geo, plate = _plate_scene((160, 120), (0.0, 0.3, 0.0), 1.0, 3.0, (-0.15, 0.15, 0.05, 0.15))
    light = PointLight(np.array([0.0, 0.3, 0.0]), np.array([0.0, 0.0, 1.0]), np.ones(3))
    clear = optics.get_preset("clear")
    alb = np.full((120, 160, 3), 0.5, np.float32)
    nrm = np.broadcast_to(np.array([0, 0, -1.0], np.float32), (120, 160, 3))
    on = lamp_water.surface_radiance(lamp_water.LampWater.build([light], clear), rays, rng, alb, nrm, K)
    calls = []
    monkeypatch.setattr(lamp_shadow, "visibility", lambda *a, **k: calls.append(1))
    off = lamp_water.surface_radiance(lamp_water.LampWater.build([light], clear, shadows=False), rays, rng, alb, nrm, K)
    assert not calls
    shadowed = on[..., 1] < 0.5 * off[..., 1]
    assert lb._iou(shadowed, geo) > 0.85
    assert np.allclose(on[~shadowed], off[~shadowed])


def test_veil_in_the_shadow_volume_matches_quadrature():
    """Single scattering, isotropic lamp and phase: the veil in front of the wall inside the plate's
    shadow is b/(4 pi) int I/d^2 exp(-c (d + t)) vis(t) dt with vis 0 where the segment from the
    water point to the lamp crosses the plate (written out here; dense trapezoid). The cut is 5 % of
    this pixel's veil (most of it is near the camera); the fast veil gets it within 20 % of the cut."""
    size, lamp, rect = (96, 72), (0.0, 0.3, 0.0), (-0.3, 0.3, 0.05, 0.25)
    K, rays, rng, geo, plate = _plate_scene(size, lamp, 1.0, 3.0, rect)
    b = 0.1
    w = optics.WaterOptics(name="t", sigma_a=[0.0] * 3, sigma_s=[b] * 3, Kd=[0.1] * 3, B_inf=[0.0] * 3, g=0.0)
    light = PointLight(np.asarray(lamp, float), np.array([0.0, 0.0, 1.0]), np.ones(3))
    on = lamp_water.LampWater.build([light], w, forward_kept=0.0)
    off = lamp_water.LampWater.build([light], w, forward_kept=0.0, shadows=False)
    v, u = 31, 48
    assert geo[v, u]
    ray = rays[v, u].astype(np.float64)
    t = np.linspace(0.0, float(rng[v, u]), 200001)
    x = t[:, None] * ray[None, :]
    d = np.linalg.norm(x - np.asarray(lamp), axis=1)
    s = np.clip((x[:, 2] - 1.0) / np.maximum(x[:, 2] - lamp[2], 1e-9), 0.0, 1.0)
    y = x + s[:, None] * (np.asarray(lamp) - x)
    cut = (x[:, 2] > 1.0) & (y[:, 0] >= rect[0]) & (y[:, 0] <= rect[1]) & (y[:, 1] >= rect[2]) & (y[:, 1] <= rect[3])
    f = b / (4 * math.pi) / d**2 * np.exp(-b * (d + t)) * ~cut
    exact = float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t)))
    got = lamp_water.backscatter(on, K, rng)[v, u, 1]
    free = lamp_water.backscatter(off, K, rng)[v, u, 1]
    assert free > 1.03 * exact  # the shadow volume holds 5 % of this veil
    assert abs(got - exact) < 0.2 * (free - exact)  # measured: 0.4 % off, 8 % of the cut
