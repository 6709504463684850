"""One camera in both image-formation modes: the sensor runs after the water, its
defaults come from a real sensor's EMVA 1288 data, the exposure is set for the dock's beacons.

Oracles: the EMVA 1288 photon-transfer model (signal ``mu_e``, temporal variance
``K^2 (mu_e + sigma_d^2) + 1/12`` DN^2 with quantisation, plus the article's additive
``noise_std^2``), the thin-lens irradiance ``pi L / (4 N^2)`` and the LED disc radiance
``I / (pi r^2)``, each derived here independently of the code under test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.config.bundled import bundled_file
from blendgen.config.models import Condition, Sensor, Water, load_experiment
from blendgen.physics.camera import sensor
from blendgen.physics.water.presets import ARTICLE_K
from blendgen.pipeline import compose, plan

K_CAM = np.array([[100.0, 0, 64], [0, 100.0, 64], [0, 0, 1]])


def _horizontal_camera(post, below_m: float = 1.0) -> np.ndarray:
    """T_world_cam (4, 4): OpenCV camera ``below_m`` under the water surface looking along world +x."""
    T = np.eye(4)
    T[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    T[2, 3] = post.surface_z_m - below_m
    return T


def _post(mode: str, depth: float, noise_std: float = 0.0, preset: str = "clear"):
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    exp.image_formation = mode
    exp.camera.noise_std = noise_std
    exp.camera.sensor.response = "linear"
    cond = Condition(label="c", water=Water(preset=preset), dock_water_depth_m=depth)
    return plan.condition_post(exp, cond, 3)


def _patch_snr(mode: str, depth: float, radiance: float, noise_std: float = 0.0) -> tuple[float, float, object]:
    """Mean / std (DN) of a uniform patch of ``radiance`` seen 5 m away through the pipeline."""
    post = _post(mode, depth, noise_std)
    st = compose.SequenceState.start(post)
    n = 128
    passes = {
        "rgb": np.full((n, n, 3), radiance, np.float32),
        "range_m": np.full((n, n), 5.0, np.float32),
        "index": np.zeros((n, n), np.int32),
    }
    frame = {"T_world_cam": _horizontal_camera(post)}
    img = compose.camera_image(passes, st, K_CAM, frame, [], "fast")[..., 1].astype(float)
    return img.mean() / img.std(), img.mean(), st.camera


def _emva_snr(mu_e: float, cam, noise_std: float) -> float:
    k = 255.0 / cam.full_well_e
    mu_e = mu_e + cam.dark_current_e_per_s * cam.exposure_s
    var = k * k * (mu_e + cam.read_noise_e**2) + 1.0 / 12.0 + noise_std**2
    return k * mu_e / math.sqrt(var)


@pytest.mark.parametrize("noise_std", [0.0, 20.0])
def test_noise_after_attenuation_lowers_an_leds_snr_with_depth(noise_std):
    """Article mode: every pixel times exp(-k d), THEN the sensor. The patch's SNR follows the EMVA
    prediction at every depth; with the article's additive noise dominant it falls exactly as
    exp(-k d) (shot-noise limited: as its square root). Noise before the attenuation (or none, as
    article mode had) would leave the SNR unchanged with depth."""
    cam = compose.sensor_model(_post("article", 0.0))
    radiance = 0.5 * cam.full_well_e / (cam.responsivity_e_per_s * cam.exposure_s)  # half the well at d = 0
    snr = {}
    for d in (0.0, 1.0, 5.0):
        snr[d], _, cam = _patch_snr("article", d, radiance, noise_std)
        mu_e = 0.5 * cam.full_well_e * math.exp(-ARTICLE_K * d)
        assert snr[d] == pytest.approx(_emva_snr(mu_e, cam, noise_std), rel=0.04), d
    drop = snr[5.0] / snr[0.0]
    if noise_std > 0:
        assert drop == pytest.approx(math.exp(-ARTICLE_K * 5.0), rel=0.05)
    else:
        assert drop == pytest.approx(math.exp(-ARTICLE_K * 5.0 / 2), rel=0.05)


def test_both_modes_run_the_same_noisy_sensor():
    """No mode is noise-free by default; the two modes share one sensor."""
    a, p = compose.sensor_model(_post("article", 1.0)), compose.sensor_model(_post("physical", 1.0))
    assert a == p and a.noise and a.bloom_fraction > 0 and a.read_noise_e > 0


def _disc(cx: float, cy: float, r: float, n: int = 41, ss: int = 8) -> np.ndarray:
    """(n, n) coverage of a disc centred at (cx, cy) (pixel i spans [i, i + 1)), ss x ss supersampled."""
    yy, xx = (np.mgrid[0 : n * ss, 0 : n * ss] + 0.5) / ss
    m = ((xx - cx) ** 2 + (yy - cy) ** 2 <= r * r).astype(np.float32)
    return m.reshape(n, ss, n, ss).mean(axis=(1, 3))


def _centroid_rms(over: float, bloom: float, rng) -> float:
    """RMS error (px) of the background-subtracted weighted centroid (pixels > 5 DN) of a far LED
    (radius 1.5 px) ``over`` times the full well, at 200 random sub-pixel positions."""
    d = Sensor()
    cam = sensor.SensorModel(
        exposure_s=1.0,
        responsivity_e_per_s=d.full_well_e * over,
        full_well_e=d.full_well_e,
        read_noise_e=d.read_noise_e,
        noise=True,
        bloom_fraction=bloom,
        bloom_sigma_px=d.bloom_sigma_px,
        response="linear",
    )
    ys, xs = np.mgrid[0:41, 0:41]
    err = []
    for _ in range(200):
        cx, cy = 20 + rng.uniform(-0.5, 0.5), 20 + rng.uniform(-0.5, 0.5)
        img = cam.apply(np.repeat(_disc(cx, cy, 1.5)[..., None], 3, axis=2), rng)[..., 1].astype(float)
        w = np.where(img > 5, img, 0.0)
        err.append(math.hypot((w * xs).sum() / w.sum() + 0.5 - cx, (w * ys).sum() / w.sum() + 0.5 - cy))
    return float(np.sqrt(np.mean(np.square(err))))


def test_saturated_far_led_centroid_stays_sub_pixel_with_blooming():
    """A far LED driven 30-100x past the full well clips to a flat block whose centroid is
    quantised by the pixel grid (> 0.1 px RMS); the charge blooming spills around it is
    symmetric about the true centre and brings the centroid back within 0.1 px."""
    rng = np.random.default_rng(7)
    for over in (30.0, 100.0):
        clipped = _centroid_rms(over, 0.0, rng)
        bloomed = _centroid_rms(over, sensor.BLOOM_FRACTION, rng)
        assert clipped > 0.1 and bloomed < 0.1 and bloomed < 0.6 * clipped, (over, clipped, bloomed)


def test_default_responsivity_is_the_imx264_behind_an_f2_8_lens():
    """QE x pixel area x pi / (4 N^2) / (h c / lambda), computed here from the sheet's numbers."""
    qe, pitch, n_f, lam = 0.70, 3.45e-6, 2.8, 530e-9
    expect = qe * pitch**2 * math.pi / (4 * n_f**2) / (6.62607015e-34 * 299792458.0 / lam)
    assert sensor.responsivity_e_per_s() == pytest.approx(expect, rel=1e-9)
    assert Sensor().responsivity_e_per_s == pytest.approx(expect, rel=0.01)
    s = Sensor()
    assert (s.full_well_e, s.read_noise_e) == (sensor.IMX264.full_well_e, sensor.IMX264.read_noise_e)


def test_default_exposure_puts_the_brightest_led_just_below_the_full_well():
    """Default LED: 0.1 W/sr per colour weight over a 4 cm radius disc, reference colour red 1.0:
    radiance 0.1 / (pi 0.04^2) = 19.9 W m^-2 sr^-1; the exposure puts it at 0.9 of the well."""
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    s = plan.resolved_sensor(exp)
    peak = 0.1 * 1.0 / (math.pi * 0.04**2)
    assert s.exposure_s == pytest.approx(0.9 * s.full_well_e / (s.responsivity_e_per_s * peak), rel=1e-6)


@pytest.mark.parametrize("mode", ["article", "physical"])
def test_clear_water_never_clips_a_default_led(mode):
    """An LED core's radiance does not fall with range: in clear water at any range it stays below
    the full well at the default exposure, so clearer water cannot lose to murkier by saturation."""
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    led = next(m for m in exp.scene.dock.markers if m.kind == "led_array")
    core = np.array(led.reference_color) * led.intensity_w_sr / (math.pi * led.led_radius_m**2)
    post = _post(mode, 0.0)
    st = compose.SequenceState.start(post)
    n = 64
    idx = np.full((n, n), led_index := 5, np.int32)
    markers = [{"kind": "led_array", "object_index": led_index}]
    for r in (1.0, 4.0, 10.0):
        passes = {
            "rgb": np.broadcast_to(core.astype(np.float32), (n, n, 3)).copy(),
            "range_m": np.full((n, n), r, np.float32),
            "index": idx,
        }
        img = compose.camera_image(passes, st, K_CAM, {"T_world_cam": _horizontal_camera(post)}, markers, "fast")
        assert img.max() < 255, (r, img.max())
        if mode == "article":  # the article's clear water keeps the core at 0.9 of the well
            assert img[..., 0].mean() == pytest.approx(0.9 * 255, abs=3)


@pytest.mark.parametrize("mode", ["article", "physical"])
def test_leds_glow_in_turbid_water_in_both_modes_unless_turned_off(mode):
    """The water's forward scatter puts light around an LED in both modes (article: sigma_s =
    albedo * beta); ``water.glow: false`` removes it, and clear article water (beta 0) has none."""
    n = 96
    idx = np.zeros((n, n), np.int32)
    idx[46:50, 46:50] = 5
    rgb = np.zeros((n, n, 3), np.float32)
    rgb[idx == 5] = [0.0, 17.0, 12.0]
    passes = {"rgb": rgb, "range_m": np.full((n, n), 6.0, np.float32), "index": idx}
    markers = [{"kind": "led_array", "object_index": 5}]

    def image(preset: str, glow: bool) -> np.ndarray:
        exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
        exp.image_formation = mode
        post = plan.condition_post(exp, Condition(label="c", water=Water(preset=preset, glow=glow)), 1)
        st = compose.SequenceState.start(post)
        return compose.water_image(passes, st, K_CAM, _horizontal_camera(post), markers)

    glow = image("moderate", True) - image("moderate", False)
    assert glow.min() >= 0 and glow[48, 53, 1] > 1e-3  # light added beside the LED, none taken
    assert glow[48, 53, 1] > glow[48, 70, 1] > 0  # fading with distance from it
    if mode == "article":
        assert np.array_equal(image("clear", True), image("clear", False))  # beta 0: no scattering
