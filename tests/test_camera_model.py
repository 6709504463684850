"""One camera model: EMVA 1288 photon transfer, saturation, blooming, and lens distortion
applied to every pass so the ground truth stays aligned with the image."""

from __future__ import annotations

import numpy as np
import pytest

from blendgen.config.models import Sensor, Water
from blendgen.physics.camera import sensor as s
from blendgen.pipeline import compose
from blendgen.pipeline.plan import SequencePost


def _flat_fields(m: s.SensorModel, levels, n=400, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for e in levels:  # mean electrons of a flat field
        lin = np.full((n, n, 1), e / (m.responsivity_e_per_s * m.exposure_s), np.float32)
        y = m.apply(np.repeat(lin, 3, axis=2), rng)[:, :, 1].astype(np.float64)
        out.append((y.mean(), y.var()))
    return np.array(out)


@pytest.mark.parametrize("gain", [1.0, 2.5])
def test_flat_field_photon_transfer_gives_the_configured_gain(gain):
    """EMVA 1288: var(y) = K^2 sigma_d^2 + K mu_y (+ 1/12 quantisation): the slope of the
    photon-transfer line is the system gain K = gain * 255 / full_well."""
    m = s.SensorModel(full_well_e=20000.0, read_noise_e=8.0, gain=gain, noise=True, response="linear")
    K = gain * 255 / 20000.0
    levels = np.linspace(0.1, 0.8, 6) * 20000.0 / gain  # below saturation
    mv = _flat_fields(m, levels)
    slope, _ = np.polyfit(mv[:, 0], mv[:, 1], 1)
    assert slope == pytest.approx(K, rel=0.03)
    np.testing.assert_allclose(mv[:, 0], K * levels, rtol=0.01)  # mean: K mu_e


def test_saturation_at_the_full_well_and_without_noise_the_plain_encode():
    m = s.SensorModel(full_well_e=5000.0, noise=True, read_noise_e=3.0, response="linear")
    img = m.apply(np.full((20, 20, 3), 7.0, np.float32), np.random.default_rng(0))
    assert np.all(img == 255)  # 7x the full well: saturated, no noise left
    lin = np.random.default_rng(1).random((16, 16, 3)).astype(np.float32)
    assert np.array_equal(s.SensorModel().apply(lin), s.to_uint8(lin))


def test_blooming_spreads_only_charge_above_the_full_well():
    lin = np.zeros((41, 41, 3), np.float32)
    lin[20, 20] = 500.0  # an LED 500x over the full well
    lin[5, 5] = 0.9  # a bright, unsaturated pixel
    plain = s.SensorModel().apply(lin)
    bloom = s.SensorModel(bloom_fraction=0.1, bloom_sigma_px=2.0).apply(lin)
    assert (plain > 0).sum() == 2 * 3
    spilled = 0.1 * 499 / (2 * np.pi * 2.0**2)  # wells in each 4-neighbour (Gaussian peak)
    assert spilled > 1 and (bloom[:, :, 0] == 255).sum() >= 5  # the saturated disc grows
    assert 0 < bloom[20, 27, 0] < 255  # and fades with distance
    assert bloom[5, 5, 0] == plain[5, 5, 0]  # nothing spills from below the well
    lin[20, 20] = 0.99
    assert np.array_equal(s.SensorModel(bloom_fraction=0.1).apply(lin), s.SensorModel().apply(lin))


def test_led_centroid_of_index_and_rgb_agree_under_distortion():
    """An LED near the image corner, where barrel distortion moves it most: the index pass and
    the RGB image are remapped by the same lens map, so their centroids agree within 0.2 px."""
    W, H = 320, 240
    K = np.array([[260.0, 0, (W - 1) / 2], [0, 260.0, (H - 1) / 2], [0, 0, 1]])
    dist = [-0.3, 0.1, 0.0, 0.0, 0.0]
    centre = np.array([40.3, 35.7])
    ss = 8  # supersampled disc -> area coverage
    u = (np.arange(W * ss) + 0.5) / ss - 0.5
    v = (np.arange(H * ss) + 0.5) / ss - 0.5
    inside = ((u[None, :] - centre[0]) ** 2 + (v[:, None] - centre[1]) ** 2) <= 5.0**2
    cover = inside.reshape(H, ss, W, ss).mean(axis=(1, 3)).astype(np.float32)
    index = np.where(cover >= 0.5, 10, 0).astype(np.uint8)
    rgb = np.repeat(cover[..., None], 3, axis=2) * np.float32(0.8)
    post = SequencePost(
        seed=0,
        fps=10,
        image_formation="article",
        water=Water(),
        light_depth_m=0.0,
        surface_z_m=0.0,
        irradiance_w_m2=3.0,
        distortion=dist,
        sensor=Sensor(response="linear"),
    )
    state = compose.SequenceState.start(post)
    passes = {"rgb": rgb, "index": index, "range_m": np.full((H, W), 5.0, np.float32)}
    img = compose.camera_image(passes, state, K, {"T_world_cam": np.eye(4).tolist()}, [], "reference")
    out = compose.output_passes(passes, K, dist)

    def centroid(wgt):
        yy, xx = np.nonzero(wgt)
        w = wgt[yy, xx].astype(np.float64)
        return np.array([np.sum(xx * w), np.sum(yy * w)]) / w.sum()

    c_rgb = centroid(img[:, :, 0].astype(np.float64))
    c_idx = centroid((out["index"] == 10).astype(np.float64))
    assert np.linalg.norm(c_rgb - c_idx) < 0.2
    c_undistorted = centroid((index == 10).astype(np.float64))
    assert np.linalg.norm(c_rgb - c_undistorted) > 3.0  # the old, unaligned index pass
    expected = s.distort_points(centre[None], K, dist)[0]  # and both sit where the lens puts the LED
    assert np.linalg.norm(c_idx - expected) < 0.3
    assert np.array_equal(compose.output_passes(passes, K, None)["index"], index)


def test_motion_blur_vector_is_the_image_motion_over_the_exposure():
    """A camera yawing at omega: the dock centre, theta = omega t off-axis, moves
    fx (tan(theta + omega t_exp) - tan(theta)) px during the exposure."""
    from scipy.spatial.transform import Rotation

    from blendgen.config.models import Experiment
    from blendgen.pipeline import plan

    exp = Experiment.model_validate(
        {
            "name": "t",
            "trajectories": [{"kind": "linear"}],
            "camera": {"fps": 10, "sensor": {"exposure_s": 0.02, "motion_blur": True}},
        }
    )
    omega = 0.5  # rad/s
    R_cv = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # OpenCV camera looking along +x
    T_wc = []
    for i in range(4):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", omega * i / 10).as_matrix() @ R_cv
        T_wc.append(T)
    T_wd = np.eye(4)
    T_wd[:3, 3] = [5.0, 0, 0]
    flow = plan.exposure_flow(exp, np.array(T_wc), T_wd)
    fx = plan.camera_K(exp)[0, 0]
    th = omega * np.array([0, 1, 2, 2]) / 10  # the last frame repeats the previous motion
    np.testing.assert_allclose(np.abs(flow[:, 0]), fx * (np.tan(th + omega * 0.02) - np.tan(th)), rtol=1e-6)
    np.testing.assert_allclose(flow[:, 1], 0.0, atol=1e-9)


@pytest.mark.parametrize("gain", [0.5, 1.0, 3.0])
def test_noise_free_fast_path_equals_the_electron_path(gain):
    lin = (np.random.default_rng(2).random((30, 40, 3)) * 3).astype(np.float32)
    lin[0, 0] = np.nan
    fast = s.SensorModel(gain=gain, response="linear").apply(lin)
    slow = s.SensorModel(gain=gain, response="linear", bloom_fraction=1e-30).apply(lin)  # forces electrons()
    assert np.array_equal(fast, slow)
