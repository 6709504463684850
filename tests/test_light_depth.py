"""Natural light with depth (physical mode): each surface dims by exp(-Kd h) of its OWN depth,
per channel; the veil by the camera's depth; emitters only along their path. The article mode
scales every pixel by exp(-k d) of the dock's depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.config.models import Water
from blendgen.geometry import planar_depth_to_range
from blendgen.physics.water import optics
from blendgen.pipeline import compose
from blendgen.pipeline.plan import SequencePost

W, H = 64, 48
K = np.array([[50.0, 0, (W - 1) / 2], [0, 50.0, (H - 1) / 2], [0, 0, 1]])
DOCK_ID = 2


def _post(water: Water, mode="physical", surface_z=0.0, light_depth=1.0) -> SequencePost:
    return SequencePost(
        seed=0,
        fps=10,
        image_formation=mode,
        water=water,
        light_depth_m=light_depth,
        surface_z_m=surface_z,
        irradiance_w_m2=3.0,
    )


def _image(post, depth_z, rgb, T_world_cam, index=None):
    passes = {
        "rgb": rgb.astype(np.float32),
        "depth_z": depth_z.astype(np.float32),
        "index": np.full((H, W), DOCK_ID, np.uint8) if index is None else index,
    }
    compose.add_range(passes, K)
    state = compose.SequenceState.start(post)
    return compose.water_image(passes, state, K, T_world_cam, [{"kind": "led_array", "object_index": 10}])


def _looking_down(cam_z: float) -> np.ndarray:
    """OpenCV camera at (0, 0, cam_z) looking straight down (world z up): z_cam = -z_world."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = cam_z
    return T


def _looking_along_x(cam_z: float) -> np.ndarray:
    """Horizontal camera at (0, 0, cam_z) looking along +x: x_cam = -y_w, y_cam = -z_w, z_cam = x_w."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    T[2, 3] = cam_z
    return T


# clear-beam water (c = 0: no transmission loss, no veil) with Jerlov II's per-channel Kd
JERLOV_II = optics.get_preset("jerlov_II")
NO_BEAM = Water(preset="jerlov_II", sigma_a=0.0, sigma_s=0.0, B_inf=0.0)


@pytest.mark.parametrize("h", [0.5, 2.0, 7.0])
def test_grey_card_at_depth_dims_by_exp_minus_kd_h_per_channel(h):
    """Oracle: a horizontal grey card h metres below the surface, seen from 1 m above it."""
    grey = np.full((H, W, 3), 0.18)
    out = _image(_post(NO_BEAM), np.full((H, W), 1.0), grey, _looking_down(-(h - 1.0)))
    ratio = out.reshape(-1, 3) / 0.18
    np.testing.assert_allclose(ratio, np.broadcast_to(np.exp(-JERLOV_II.Kd * h), ratio.shape), rtol=0.02)
    assert ratio[:, 0].mean() < ratio[:, 1].mean()  # red fades first in oceanic water


def test_vertical_wall_dims_row_by_row_with_its_own_depth():
    """A wall 4 m ahead of a horizontal camera 2 m deep: row v shows world depth
    2 + (v - cy) / fy * 4 (derived by hand, not by the code under test)."""
    grey = np.full((H, W, 3), 0.5)
    out = _image(_post(NO_BEAM), np.full((H, W), 4.0), grey, _looking_along_x(-2.0))
    v = np.arange(H)
    depth = np.maximum(2.0 + (v - K[1, 2]) / K[1, 1] * 4.0, 0.0)
    expected = 0.5 * np.exp(-np.outer(depth, JERLOV_II.Kd))  # (H, 3)
    np.testing.assert_allclose(out[:, W // 2], expected, rtol=1e-4)
    np.testing.assert_allclose(out[:, 0], expected, rtol=1e-4)  # same row, same depth


def test_veil_dims_with_camera_depth_and_emitters_only_along_their_path():
    water = Water(preset="jerlov_II")
    w = optics.water_for_mode(water, "physical")
    rgb = np.full((H, W, 3), 0.3)
    index = np.full((H, W), DOCK_ID, np.uint8)
    index[21, 31] = 10  # an LED (one pixel: no glow onto itself)
    depth_z = np.full((H, W), 3.0)
    depth_z[:4] = np.inf  # open water above the dock
    outs = {}
    for cam_depth in (1.0, 5.0):
        outs[cam_depth] = _image(_post(water), depth_z, rgb, _looking_along_x(-cam_depth), index)
    veil = optics.light_field_veil(w) * 3.0
    for cam_depth, out in outs.items():
        np.testing.assert_allclose(out[0, 0], veil * np.exp(-w.Kd * cam_depth), rtol=1e-4)
    r = planar_depth_to_range(np.full((H, W), 3.0), K)[21, 31]
    t = np.exp(-w.c * r)
    for cam_depth, out in outs.items():  # LED: same direct part at any depth
        np.testing.assert_allclose(out[21, 31], 0.3 * t + veil * np.exp(-w.Kd * cam_depth) * (1 - t), rtol=1e-4)


def test_article_mode_scales_every_pixel_by_exp_minus_k_d():
    water = Water(preset="mild", glow=False)  # the LEDs' forward-scattered glow adds light: off for this oracle
    rgb = np.full((H, W, 3), 0.4)
    index = np.full((H, W), DOCK_ID, np.uint8)
    index[:5] = 10  # LEDs too
    out = _image(_post(water, "article", light_depth=5.0), np.full((H, W), 2.0), rgb, _looking_along_x(-9.0), index)
    r = planar_depth_to_range(np.full((H, W), 2.0), K)
    wgt = 1 - np.exp(-0.2 * r)[..., None]
    colour = np.array(optics.wp.ARTICLE_WATER_COLOR)
    np.testing.assert_allclose(out, ((1 - wgt) * 0.4 + wgt * colour) * math.exp(-0.2 * 5.0), rtol=1e-5)


def test_surface_depth_is_clamped_above_the_surface_and_uses_camera_depth_for_open_water():
    rng = np.full((H, W), np.inf, np.float32)
    rng[H // 2 :] = 10.0
    depth, cam = compose.surface_depth(rng, K, _looking_along_x(-1.0), 0.0)
    assert cam == pytest.approx(1.0)
    assert np.all(depth >= 0) and np.all(depth[: H // 2] == pytest.approx(1.0))
