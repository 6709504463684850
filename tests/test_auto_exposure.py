"""Auto-exposure (physics/camera/sensor.AutoExposure) and default blooming of saturated LEDs (docs/sensor.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.physics.camera import sensor
from blendgen.physics.camera.sensor import AutoExposure, SensorModel


def _frame(level=0.1, led=20.0):
    img = np.full((120, 160, 3), level, np.float32)
    img[50:60, 70:80] = [0.1 * led, 0.3 * led, led]  # a blue LED, 100 px of 19200
    return img


def test_percentile_metering_puts_the_led_at_the_target_at_once():
    cam = SensorModel()
    ae = AutoExposure(metering="percentile", percentile=99.9, target=0.9, time_constant_s=0.0)
    t = ae.next_exposure(_frame(), cam.exposure_s, cam, 0.1)
    assert t == pytest.approx(0.9 * cam.full_well_e / (20.0 * cam.responsivity_e_per_s))
    img = SensorModel(exposure_s=t).apply(_frame())
    assert img[55, 75, 2] < 255 and img[55, 75, 2] > 240  # just below the full well: blue
    assert img[55, 75, 0] < img[55, 75, 1] < img[55, 75, 2]  # the LED keeps its colour


def test_mean_metering_time_constant_and_limits():
    cam = SensorModel(exposure_s=0.01)
    ae = AutoExposure(metering="mean", target=0.18, time_constant_s=0.3, max_exposure_s=0.05)
    flat = np.full((10, 10, 3), 0.09, np.float32)  # wants t* = 0.18e4 / (0.09e6) = 0.02 s
    t1 = ae.next_exposure(flat, 0.01, cam, 0.1)
    alpha = 1 - math.exp(-0.1 / 0.3)
    assert t1 == pytest.approx(0.01 * 2.0**alpha)  # first-order lag in log exposure
    t = 0.01
    for _ in range(60):
        t = ae.next_exposure(flat, t, cam, 0.1)
    assert t == pytest.approx(0.02, rel=1e-4)
    dark = np.zeros((10, 10, 3), np.float32)
    assert AutoExposure(time_constant_s=0).next_exposure(dark, 0.01, cam, 0.1) == 0.05  # clamps
    bright = np.full((10, 10, 3), 1e6, np.float32)
    assert AutoExposure(time_constant_s=0, min_exposure_s=1e-4).next_exposure(bright, 0.01, cam, 0.1) == pytest.approx(
        1e-4
    )


def test_blooming_keeps_the_led_colour_around_a_clipped_core():
    """A blue LED 20x over the full well: without blooming a white disc with a hard edge; with
    5 % of the excess charge spilled, the ring outside the disc is blue-dominated (b > g > r),
    and the spilled charge equals 5 % of the excess (conservation, before clipping)."""
    img = np.zeros((60, 60, 3), np.float32)
    yy, xx = np.mgrid[:60, :60]
    disc = np.hypot(yy - 30, xx - 30) <= 4
    img[disc] = [2.0, 6.0, 20.0]
    plain = SensorModel().apply(img)
    assert (plain[disc] == 255).all() and plain[30, 36].max() == 0
    cam = SensorModel(bloom_fraction=0.05)
    ring = cam.apply(img)[30, 36].astype(int)
    assert ring[2] > ring[1] > ring[0] and ring[2] > 60
    mu = img * np.float32(cam.responsivity_e_per_s * cam.exposure_s)
    spilled = cam._bloom(mu).sum(axis=(0, 1)) - mu.sum(axis=(0, 1))
    excess = np.maximum(mu - cam.full_well_e, 0).sum(axis=(0, 1))
    np.testing.assert_allclose(spilled, 0.05 * excess, rtol=1e-3)


def test_auto_exposure_config_and_frame_records():
    from blendgen.config.models import AutoExposureConfig

    with pytest.raises(ValueError, match="min_exposure_s"):
        AutoExposureConfig(min_exposure_s=0.1, max_exposure_s=0.01)


def test_sequence_defaults_and_the_ae_loop_in_compose():
    """Blooming defaults on in both modes (one camera; formerly off in article mode); with
    auto_exposure the sequence's camera
    follows the AE loop frame by frame and remembers the exposure of each image."""
    from blendgen.config.bundled import bundled_file
    from blendgen.config.models import AutoExposureConfig, load_experiment
    from blendgen.pipeline import compose, plan

    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    post = plan.condition_post(exp, exp.conditions[0], 1)
    assert compose.sensor_model(post).bloom_fraction == sensor.BLOOM_FRACTION
    exp.image_formation = "article"
    art = compose.sensor_model(plan.condition_post(exp, exp.conditions[0], 1))
    assert art.bloom_fraction == sensor.BLOOM_FRACTION and art.noise  # the same camera as physical
    exp.image_formation = "physical"
    assert compose.SequenceState.start(post).auto_exposure is None
    exp.camera.sensor.auto_exposure = AutoExposureConfig(time_constant_s=0.0)
    st = compose.SequenceState.start(plan.condition_post(exp, exp.conditions[0], 1))
    img = _frame()
    passes = {"rgb": img}
    K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
    exposures = []
    for _ in range(2):
        compose.camera_image(passes, st, K, {"T_world_cam": np.eye(4)}, [], "reference")
        exposures.append(st.exposure_s)
    assert exposures[0] == plan.resolved_sensor(exp).exposure_s  # null: resolved (beacon exposure)
    s = exp.camera.sensor
    assert exposures[1] == pytest.approx(0.9 * s.full_well_e / (20.0 * s.responsivity_e_per_s))
