"""The fast vehicle-lamp model (physics/light/lamp_water.py) against analytic values and an
independent quadrature, and the zero-cost path of the pipeline without lamps."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.integrate import quad

from blendgen.config.models import Lamp, Sensor, Water
from blendgen.geometry import intrinsics_from_hfov
from blendgen.physics.light import lamp_water
from blendgen.physics.light.sources import PointLight, blender_spot_blend, lamp_lights
from blendgen.physics.water import optics
from blendgen.pipeline import compose
from blendgen.pipeline.plan import SequencePost


def _water(b, a=0.0, g=0.0):
    return optics.WaterOptics(name="t", sigma_a=[a] * 3, sigma_s=[b] * 3, Kd=[0.1] * 3, B_inf=[0.0] * 3, g=g)


def _iso_light(pos, i0=1.0):
    return PointLight(np.asarray(pos, float), np.array([0.0, 0.0, 1.0]), np.full(3, i0))


@pytest.mark.parametrize("c", [0.0, 0.5])
def test_card_radiance_inverse_square_times_attenuation(c):
    """A grey card facing a lamp 0.3 m off the camera: rho/pi I0 cos(i)/d_l^2 exp(-c d_l) exp(-c d)
    at 1, 2, 4, 8 m (5 %; written out here, not through lights.irradiance)."""
    lamp = Lamp(offset_m=[0.0, 0.3, 0.0], half_angle_deg=30.0, edge_deg=5.0, power_w=20.0)
    model = lamp_water.LampWater.build(lamp_lights([lamp]), _water(c * 0.2, c * 0.8), forward_kept=0.0)
    i0 = 20.0 / (2 * math.pi * (1 - math.cos(math.radians(30.0))))
    rays = np.array([[[0.0, 0.0, 1.0]]], np.float32)
    n = np.array([[[0.0, 0.0, -1.0]]], np.float32)
    for d in (1.0, 2.0, 4.0, 8.0):
        got = lamp_water.surface_radiance(
            model, rays, np.array([[d]], np.float32), np.full((1, 1, 3), 0.5, np.float32), n
        )[0, 0, 1]
        d_l = math.hypot(d, 0.3)
        law = 0.5 / math.pi * i0 * (d / d_l) / d_l**2 * math.exp(-c * (d_l + d))
        assert got == pytest.approx(law, rel=0.05)
        assert got == pytest.approx(law, rel=1e-4)  # and in fact to float precision


def test_veil_matches_closed_form_isotropic():
    """Isotropic lamp h off a ray, isotropic phase, no absorption (c -> 0): the veil along the
    ray to range r is b I0/(4 pi h) (atan(r/h)) -- the table + range interpolation at 1 %."""
    h, b = 0.4, 1e-4
    model = lamp_water.LampWater.build([_iso_light([h, 0.0, 0.0])], _water(b), forward_kept=0.0)
    K = intrinsics_from_hfov(33, 33, math.radians(40.0))
    for r in (0.5, 2.0, 9.0):
        v = lamp_water.backscatter(model, K, np.full((33, 33), r, np.float32), step=16)[16, 16, 1]
        exact = b / (4 * math.pi * h) * math.atan(r / h) * math.exp(-b * r)  # exp(-c(...)) ~ 1 at b = 1e-4
        assert v == pytest.approx(exact, rel=0.01)


def test_veil_matches_quadrature_hg_cone():
    """Turbid water, HG g = 0.9, a 30 deg spot 0.3 m below the camera aimed 5 deg down:
    one pixel's veil against scipy.quad of b p(theta) I(psi)/d^2 exp(-c d) exp(-c t) (2 %)."""
    w = optics.get_preset("moderate")
    lamp = Lamp(offset_m=[0.0, 0.3, 0.0], pitch_deg=5.0, half_angle_deg=30.0, edge_deg=5.0, power_w=20.0)
    light = lamp_lights([lamp])[0]
    model = lamp_water.LampWater.build([light], w, forward_kept=0.0)
    K = intrinsics_from_hfov(65, 49, math.radians(60.0))
    v = lamp_water.backscatter(model, K, np.full((49, 65), np.inf, np.float32), step=16)[32, 48, 1]
    u = np.array([(48 - K[0, 2]) / K[0, 0], (32 - K[1, 2]) / K[1, 1], 1.0])
    u /= np.linalg.norm(u)
    s, ax = light.position_m, light.axis
    b, c, i0, g = w.sigma_s[1], w.c[1], light.intensity_w_sr[1], w.g

    def f(t):
        x = t * u - s
        d = np.linalg.norm(x)
        psi = math.acos(np.clip(x @ ax / d, -1, 1))
        half, inner = math.radians(30.0), math.radians(25.0)
        prof = (
            1.0
            if psi <= inner
            else (
                0.0
                if psi >= half
                else (lambda q: q * q * (3 - 2 * q))(
                    (math.cos(psi) - math.cos(half)) / (math.cos(inner) - math.cos(half))
                )
            )
        )
        mu = -(x @ u) / d
        p = (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * mu) ** 1.5)
        return b * p * i0 * prof / d**2 * math.exp(-c * (d + t))

    exact = quad(f, 0.0, 60.0, limit=400, points=[0.5, 1.0, 2.0])[0]
    assert v == pytest.approx(exact, rel=0.02)


def test_veil_grows_with_scattering_and_vanishes_in_clear_water():
    lamp = Lamp(offset_m=[0.0, 0.3, 0.0])
    K = intrinsics_from_hfov(64, 48, math.radians(60.0))
    rng = np.full((48, 64), np.inf, np.float32)
    means = [
        lamp_water.backscatter(lamp_water.LampWater.build(lamp_lights([lamp]), _water(b, 0.05)), K, rng).mean()
        for b in (0.0, 0.05, 0.2)
    ]
    assert means[0] == 0.0 and 0 < means[1] < means[2]


def test_blender_blend_reproduces_profile():
    """Cycles' spot mask smoothstep((cos t - cos a)/((1 - cos a) blend)) with our blend equals
    PointLight.profile at every angle."""
    half, edge = math.radians(30.0), math.radians(5.0)
    light = PointLight(np.zeros(3), np.array([0, 0, 1.0]), np.ones(3), half, edge)
    blend = blender_spot_blend(half, edge)
    th = np.linspace(0.0, math.radians(40.0), 200)
    x = np.clip((np.cos(th) - math.cos(half)) / ((1 - math.cos(half)) * blend), 0, 1)
    assert np.allclose(light.profile(np.cos(th)), x * x * (3 - 2 * x), atol=1e-12)


def _post(lamps):
    return SequencePost(
        seed=0,
        fps=10,
        image_formation="physical",
        water=Water(preset="mild"),
        light_depth_m=2.0,
        surface_z_m=0.0,
        irradiance_w_m2=3.2,
        sensor=Sensor(noise=False),
        lamps=lamps,
    )


def _passes(h=48, w=64):
    rng = np.full((h, w), 3.0, np.float32)
    rng[:, : w // 4] = np.inf
    return {
        "rgb": np.full((h, w, 3), 0.2, np.float32),
        "range_m": rng,
        "index": np.zeros((h, w), np.uint8),
        "albedo": np.full((h, w, 3), 0.5, np.float32),
        "normal": np.broadcast_to(np.array([0, 0, 1.0], np.float32), (h, w, 3)).copy(),
    }


def test_no_lamp_costs_nothing_and_changes_nothing(monkeypatch):
    """Without lamps the state holds no lamp model, the lamp code is never called, and the
    image is exactly apply_water's."""
    st = compose.SequenceState.start(_post([]))
    assert st.lamp is None
    monkeypatch.setattr(lamp_water, "lamp_radiance", lambda *a, **k: (_ for _ in ()).throw(AssertionError))
    K = intrinsics_from_hfov(64, 48, math.radians(60.0))
    T = np.eye(4)
    p = _passes()
    got = compose.water_image(p, st, K, T, [])
    depth, vd = compose.surface_depth(p["range_m"], K, T, 0.0)
    ref = optics.apply_water(
        p["rgb"],
        p["range_m"],
        np.zeros((48, 64), bool),
        st.water,
        depth,
        model="physical",
        veil_depth_m=vd,
        irradiance=st.water_opts["irradiance"],
        blur=st.water_opts["blur"],
        blur_px_per_tau=optics.BLUR_RAD_PER_TAU * K[0, 0],
        blur_max_px=optics.BLUR_MAX_RAD * K[0, 0],
        glow_fx=K[0, 0],
    )
    assert np.array_equal(got, ref)


def test_lamp_brightens_the_image():
    """With a lamp: lit surfaces brighter, and open water (no surface) gains the veil."""
    K = intrinsics_from_hfov(64, 48, math.radians(60.0))
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # world normal +z = camera -z (faces the camera)
    off = compose.water_image(_passes(), compose.SequenceState.start(_post([])), K, T, [])
    on = compose.water_image(_passes(), compose.SequenceState.start(_post([Lamp(power_w=50.0)])), K, T, [])
    assert (on >= off).all()
    assert on[24, 40, 1] > off[24, 40, 1] * 1.2 and on[24, 5, 1] > off[24, 5, 1]


def test_lamp_lights_from_namespace():
    ns = SimpleNamespace(
        offset_m=[0, 0.3, 0], yaw_deg=0, pitch_deg=0, half_angle_deg=30, edge_deg=5, power_w=10, color=[1, 1, 1]
    )
    assert lamp_lights([ns])[0].intensity_w_sr[0] == pytest.approx(10 / (2 * math.pi * (1 - math.cos(math.pi / 6))))


def test_lamp_config_errors_name_the_key(tmp_path):
    """An out-of-range lamp key is a one-line config error naming it (CLI exit 2)."""
    import yaml

    from blendgen.config.models import ConfigError, load_experiment

    root = __import__("pathlib").Path(__file__).resolve().parent.parent
    cfg = yaml.safe_load((root / "configs" / "lamp_night.yaml").read_text())
    assert load_experiment(root / "configs" / "lamp_night.yaml").vehicle.lamps[0].power_w == 20.0
    for key, bad in (("lamp_forward_kept", 1.5), ("lamps", [{"half_angle_deg": 120}]), ("lamp_shadows", "maybe")):
        p = tmp_path / f"{key}.yaml"
        p.write_text(yaml.safe_dump({**cfg, "vehicle": {**cfg["vehicle"], key: bad}}))
        with pytest.raises(ConfigError) as e:
            load_experiment(p)
        assert key in str(e.value) and "\n" not in str(e.value).strip()


def test_particles_and_surfaces_see_the_same_lamp_beam():
    """A particle and a surface at the same point of the lamp's beam get light that falls off
    alike, I exp(-c' d)/d^2 with c' = c - F b (the beam's effective attenuation), in turbid water
    with F = 0.85: the particle/surface ratio is the same at 1 m and 4 m (with c on the particle's
    path it would differ by exp(F b 3 m) = 2.2x in 'moderate'). Lamp at the camera centre, particles
    on the optical axis: same scattering angle at both distances."""
    from blendgen.geometry import make_T
    from blendgen.physics.particles.field import ParticleField, project_particles
    from blendgen.pipeline import particle_light
    from blendgen.pipeline.plan import OcclusionPost

    box = [[-20.0] * 3, [20.0] * 3]
    lamp = Lamp(offset_m=[0.0, 0.0, 0.0], half_angle_deg=30.0, edge_deg=5.0, power_w=20.0)
    post = SequencePost(
        seed=1,
        fps=10.0,
        image_formation="physical",
        water=Water(preset="moderate"),
        light_depth_m=1.0,
        surface_z_m=0.0,
        irradiance_w_m2=0.0,
        lamps=[lamp],
        occlusion=OcclusionPost(n_total=0, region_min=box[0], region_max=box[1], v_flow=[0, 0, 0]),
        lamp_forward_kept=0.85,
    )
    st = compose.SequenceState.start(post)
    T_WC = make_T(np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), [0.0, 0.0, -1.0])
    K = intrinsics_from_hfov(64, 48, math.radians(60.0))
    model = lamp_water.LampWater.build(lamp_lights([lamp]), st.water, 0.85, shadows=False)
    assert model.c_lamp[1] < st.water.c[1] - 0.2
    ratios = []
    for d in (1.0, 4.0):
        field = ParticleField(np.array([[d, 0.0, -1.0]], np.float32), np.array([0.01], np.float32), *map(np.array, box))
        p = project_particles(field, K, T_WC, 64, 48)
        J = particle_light.shader(st.post, st.water, T_WC, lamp=st.lamp)(p)[0, 1]
        surf = lamp_water.surface_radiance(
            model,
            np.array([[[0.0, 0.0, 1.0]]], np.float32),
            np.array([[d]], np.float32),
            np.ones((1, 1, 3), np.float32),
            np.array([[[0, 0, -1.0]]], np.float32),
        )
        E = surf[0, 0, 1] * math.pi / math.exp(-st.water.c[1] * d)  # irradiance at the point
        ratios.append(J / E)
    assert ratios[0] > 0 and ratios[1] == pytest.approx(ratios[0], rel=1e-3)
