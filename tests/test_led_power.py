"""LED power as a physical value (docs/light.md): radiant intensity (W/sr) -> disc radiance, the same
in both fidelities; the old ``strength`` key still reads (exactly converted)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.config.models import LedArray
from blendgen.markers import manifest_marker
from blendgen.physics.light import leds
from blendgen.physics.light.sources import irradiance
from blendgen.physics.water import optics


def test_radiance_is_intensity_over_disc_area():
    L = leds.led_radiance(0.1, [1.0, 0.5, 0.0], 0.04)
    np.testing.assert_allclose(L, [0.1 / (math.pi * 0.04**2), 0.05 / (math.pi * 0.04**2), 0.0])
    with pytest.raises(ValueError):
        leds.led_radiance(0.0, [1, 1, 1], 0.04)


def test_old_strength_key_reads_as_the_same_radiance():
    old = LedArray(strength=20.0, led_radius_m=0.035)
    assert old.intensity_w_sr == pytest.approx(20.0 * math.pi * 0.035**2)
    m = manifest_marker(old)
    np.testing.assert_allclose(m["radiance"][1], 20.0 * np.asarray(old.color), rtol=1e-12)
    assert "strength" not in m and m["intensity_w_sr"] == old.intensity_w_sr
    with pytest.raises(ValueError, match="intensity_w_sr"):
        LedArray(strength=20.0, intensity_w_sr=0.1)
    with pytest.raises(ValueError, match="strength"):
        LedArray(strength=-1.0)


def test_lambertian_led_light_on_a_surface():
    """An LED 1 m in front of a plane it faces head-on gives E = I/d^2 (inverse square);
    at 60 deg off its axis on a surface facing the LED: I cos60 / d^2 (Lambert); behind it: 0."""
    T = np.eye(4)
    m = {"intensity_w_sr": 0.2, "keypoints": [[0.0, 0.0, 0.0]], "colors": [[1.0, 0.5, 0.0]]}
    lights = leds.led_lights(m, T)  # axis = camera +z
    E = irradiance(lights, np.array([[0.0, 0.0, 1.0]]), np.zeros(3), np.array([[0.0, 0.0, -1.0]]))
    np.testing.assert_allclose(E[0], [0.2, 0.1, 0.0], rtol=1e-12)
    th = math.radians(60)
    p = np.array([[math.sin(th), 0.0, math.cos(th)]])
    E = irradiance(lights, p, np.zeros(3), -p)
    np.testing.assert_allclose(E[0, 0], 0.2 * math.cos(th), rtol=1e-9)  # surface faces the LED
    E = irradiance(lights, np.array([[0.0, 0.0, -1.0]]), np.zeros(3), np.array([[0.0, 0.0, 1.0]]))
    assert E.max() == 0.0


@pytest.mark.blender
def test_led_radiance_same_in_both_fidelities(tmp_path):
    """The dataset's LED disc rendered by Cycles: (1) without water, its irradiance at the camera
    sum(L Omega) equals the Lambertian disc's pi L a^2 / (r^2 + a^2) within 2 % (the intensity
    means W/sr); (2) through an absorbing Cycles medium (reference fidelity, LED sampled as a
    light) and through the fast model on the clear render, the same energy within 2 %;
    (3) with HG g 0.9 scattering (moderate), within 10 % inside 3 px (direct + near glow)."""
    from blendgen.config.models import Water
    from blendgen.tools.bench import fidelity as F

    size, hfov, r, a = 96, 20.0, 3.0, 0.04
    fx = (size / 2) / math.tan(math.radians(hfov) / 2)
    L = leds.led_radiance(0.1, [0.1, 0.3, 1.0], a)
    air = F.led_reference(None, r, L, a, tmp_path, size, hfov, 16, lights_scene=False).astype(np.float64)
    E = F.encircled_glow(air, fx, [size])[0]
    np.testing.assert_allclose(E, math.pi * np.asarray(L) * a * a / (r * r + a * a), rtol=0.02)
    em = air.max(axis=2) > 0
    rng = np.where(em, r, np.inf).astype(np.float32)
    moderate = optics.water_for_mode(Water(preset="moderate"), "physical")
    for w, radius, tol in ((moderate.replace(name="absorbing", sigma_s=np.zeros(3)), size, 0.02), (moderate, 3, 0.10)):
        ref = F.led_reference(w, r, L, a, tmp_path, size, hfov, 64, lights_scene=True).astype(np.float64)
        fast = optics.apply_water(air, rng, em, w, 0.0, model="physical", irradiance=0.0, glow_fx=fx)
        e_ref, e_fast = (F.encircled_glow(x, fx, [radius])[0] for x in (ref, fast))
        np.testing.assert_allclose(e_fast, e_ref, rtol=tol, err_msg=w.name)


def _wall(h=120, w=160, f=100.0, z=2.0):
    from blendgen.pipeline.compose import _unit_rays

    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    rays = _unit_rays(tuple(K.ravel()), w, h)
    rng = (z / rays[..., 2]).astype(np.float32)  # a wall at z facing the camera
    return rays, rng


def test_led_light_on_a_wall_is_lambert_times_inverse_square():
    """An LED 1 m in front of the camera facing a white-ish wall at z = 2 m: the reflected
    radiance is rho I cos(emit) cos(inc) / (pi d^2) exp(-c d) = rho I / (pi d^4) exp(-c d) with
    d the LED-point distance (cos = 1/d both), computed on a 1/4 grid and interpolated: within
    1 % of the analytic value over the whole wall."""
    rays, rng = _wall()
    c = np.array([0.1, 0.05, 0.02])
    lights = leds.led_lights(
        {"intensity_w_sr": 0.3, "keypoints": [[0.0, 0.0, 1.0]], "colors": [[1.0, 1.0, 1.0]]}, np.eye(4)
    )
    albedo = np.full(rng.shape + (3,), 0.5, np.float32)
    L = leds.surface_radiance(lights, rng, rays, albedo, c, min_radiance=0.0)
    p = rays * rng[..., None]
    d = np.linalg.norm(p - [0.0, 0.0, 1.0], axis=-1)[..., None]
    want = 0.5 * 0.3 / (np.pi * d**4) * np.exp(-c * d)
    np.testing.assert_allclose(L[4:-4, 4:-4], want[4:-4, 4:-4], rtol=0.01)


def test_led_light_costs_nothing_when_off_or_far():
    from blendgen.config.bundled import bundled_file
    from blendgen.config.models import load_experiment
    from blendgen.pipeline import compose, plan

    rays, rng = _wall(z=2.0)
    albedo = np.full(rng.shape + (3,), 0.5, np.float32)
    assert leds.surface_radiance([], rng, rays, albedo, np.zeros(3)) is None
    far = leds.led_lights(
        {"intensity_w_sr": 0.1, "keypoints": [[0.0, 0.0, 40.0]], "colors": [[1.0, 1.0, 1.0]]},
        np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1.0]]),
    )
    assert leds.surface_radiance(far, rng, rays, albedo, np.zeros(3)) is None  # 38 m away, below 1e-4
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    markers = plan.manifest_markers(exp)
    passes = {"range_m": rng, "albedo": albedo, "rgb": np.zeros_like(albedo)}
    for mode, expect_none in (("article", True), ("physical", False)):
        exp.image_formation = mode
        st = compose.SequenceState.start(plan.condition_post(exp, exp.conditions[0], 1))
        T_wd = np.eye(4)
        T_wd[2, 3] = 1.5  # LED array 1.5 m ahead (camera z up the world z)
        T_wc = np.eye(4)
        out = compose.led_light(
            passes, st, np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]]), T_wc, markers, T_wd
        )
        assert (out is None) == expect_none, mode
    assert compose.led_light(passes, st, np.eye(3), np.eye(4), [], np.eye(4)) is None
