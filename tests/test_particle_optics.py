"""Particles as a physical population (docs/particles.md): sizes, lit radiance in water, coverage,
thin-lens defocus, motion streaks, depth test under blur, zero cost without particles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from blendgen.config.models import Lamp, Lens, Water
from blendgen.geometry import intrinsics_from_hfov, make_T
from blendgen.physics.light import lamp_water
from blendgen.physics.particles import optics as popt
from blendgen.physics.particles.field import ParticleField, project_particles, render_particles
from blendgen.pipeline import compose, particle_light
from blendgen.pipeline.plan import OcclusionPost, SequencePost

W, H = 640, 480
K = intrinsics_from_hfov(W, H, math.radians(60.0))
# camera 1 m below the surface looking along world +x (OpenCV axes: x = -y_w, y = -z_w, z = +x_w)
R_WC = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
T_WC = make_T(R_WC, [0.0, 0.0, -1.0])
BOX = (np.array([-20.0, -20.0, -20.0]), np.array([20.0, 20.0, 20.0]))


AMBIENT = 2.6 / (4 * math.pi * 0.75)  # E_d0 / (4 pi mu_d), plan.ambient_radiance


def post(lamps=(), water="mild", lens=None, mode="physical", exposure=0.01, suns=(), **occ):
    o = OcclusionPost(n_total=0, region_min=BOX[0].tolist(), region_max=BOX[1].tolist(), v_flow=[0, 0, 0], **occ)
    p = SequencePost(
        seed=1,
        fps=10.0,
        image_formation=mode,
        water=Water(preset=water),
        light_depth_m=1.0,
        surface_z_m=0.0,
        irradiance_w_m2=2.6,
        occlusion=o,
        lamps=list(lamps),
        lens=lens,
        ambient_w_m2_sr=AMBIENT,
        suns=suns,
    )
    return p.model_copy(update={"sensor": p.sensor.model_copy(update={"exposure_s": exposure})})


def state_with(field, **kw):
    st = compose.SequenceState.start(post(**kw))
    st.field = field
    return st


def one(p_world, r):
    return ParticleField(np.array([p_world], np.float32), np.array([r], np.float32), *BOX)


def passes(range_m=np.inf):
    return {
        "rgb": np.zeros((H, W, 3), np.float32),
        "range_m": np.full((H, W), range_m, np.float32),
        "index": np.zeros((H, W), np.int32),
    }


def lambert_sphere(theta):  # independent: van de Hulst's Lambert sphere, phase angle pi - theta
    a = math.pi - theta
    return 2.0 / (3.0 * math.pi**2) * (math.sin(a) + (math.pi - a) * math.cos(a))


def hg(theta, g):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * math.cos(theta)) ** 1.5)


# ----------------------------------------------------------------------------- radiance
@pytest.mark.parametrize("z", [2.0, 4.0])
@pytest.mark.parametrize("lamp_on", [False, True])
def test_lit_particle_mean_radiance_in_water_matches_analytic(z, lamp_on):
    r = 0.04 * z
    lamp = Lamp(offset_m=[0.0, 0.3, 0.0], half_angle_deg=60.0, edge_deg=0.0, power_w=30.0)
    st = state_with(one([z, 0.0, -1.0], r), lamps=[lamp] if lamp_on else [])
    seen, occ = compose.add_particles(passes(), st, K, T_WC)
    img = compose.water_image(seen, st, K, T_WC, [], occ)
    rad = f = 0.5 * (K[0, 0] + K[1, 1]) * r / z
    v, u = np.mgrid[0:H, 0:W]
    inner = np.hypot(u - K[0, 2], v - K[1, 2]) < rad - 1.5
    measured = img[inner].mean(axis=0)
    # analytic, from the laws (not the code): ambient E/(4 pi mu_d) omega dimmed by exp(-Kd depth);
    # lamp I0 exp(-c' d)/d^2 omega p(theta) with the beam's c' = c - F b (physics/light/lamp_water.py: the
    # beam keeps its forward-scattered light, for particles as for surfaces and the veil); both
    # times exp(-c R); veil B_inf E exp(-Kd d_cam)(1-exp(-c R))
    w = st.water
    E, depth, R = 2.6, 1.0, z - r
    J = 0.3 * E / (4 * math.pi * 0.75) * np.exp(-w.Kd * depth)
    if lamp_on:
        i0 = 30.0 / (2 * math.pi * (1 - math.cos(math.radians(60.0))))
        d = math.hypot(z, 0.3)
        theta = math.acos(z / d)  # light travels lamp -> particle, scattered back to camera
        theta = math.pi - theta
        c_beam = w.c - lamp_water.FORWARD_KEPT * w.sigma_s
        J = J + 0.3 * i0 * np.exp(-c_beam * d) / d**2 * (0.5 * lambert_sphere(theta) + 0.5 * hg(theta, 0.9))
    expect = J * np.exp(-w.c * R) + w.B_inf * E * np.exp(-w.Kd * depth) * (1 - np.exp(-w.c * R))
    if lamp_on:  # plus the lamp's own backscatter veil in front of the particle (its oracle: test_lamp_water)
        expect = expect + lamp_water.backscatter(st.lamp, K, np.full((H, W), R, np.float32))[inner].mean(axis=0)
    assert f > 10 and inner.sum() > 100
    assert np.allclose(measured, expect, rtol=0.05), (measured, expect)


def _centre(st):
    seen, occ = compose.add_particles(passes(), st, K, T_WC)
    return compose.water_image(seen, st, K, T_WC, [], occ)[240, 320], compose.water_image(
        passes(), st, K, T_WC, [], None
    )[240, 320]


def test_particle_beside_lamp_is_bright_far_in_turbid_water_is_faint():
    lamp = Lamp(offset_m=[0.0, 0.3, 0.0], half_angle_deg=40.0, power_w=20.0)
    lit, bg = _centre(state_with(one([0.8, 0.0, -1.0], 0.01), lamps=[lamp]))
    dark, _ = _centre(state_with(one([0.8, 0.0, -1.0], 0.01)))
    assert np.all(lit > 4 * dark) and np.all(lit > 2 * bg)
    far, bg = _centre(state_with(one([6.0, 0.0, -1.0], 0.04), water="moderate"))
    assert np.all(np.abs(far - bg) < 0.35 * bg)  # a faint smudge in the veil


def test_particle_between_camera_and_led_glows_with_it():
    mat = popt.ParticleMaterial()
    led = popt.lt.PointLight(np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, -1.0]), np.full(3, 0.05), math.pi / 2)
    inline = popt.particle_radiance([[0.0, 0.0, 2.9]], mat, [0, 0, 0], [led], [0.1] * 3)
    beside = popt.particle_radiance([[0.3, 0.0, 2.9]], mat, [0, 0, 0], [led], [0.1] * 3)
    assert inline[0, 0] > 10 * beside[0, 0] > 0


def test_phase_functions_are_normalised():
    mu = np.linspace(-1, 1, 200001)
    for p in (popt.lambert_sphere_phase(mu), popt.ParticleMaterial().phase(mu)):
        assert 2 * math.pi * np.trapezoid(p, mu) == pytest.approx(1.0, rel=1e-3)


# ----------------------------------------------------------------------------- sizes, coverage
def test_power_law_radii_follow_the_truncated_law():
    rng = np.random.default_rng(3)
    r = popt.sample_radii(rng, 20000, "power_law", 0.00025, 0.015, 3.5)
    k = -2.5
    cdf = lambda x: (x**k - 0.00025**k) / (0.015**k - 0.00025**k)
    assert stats.kstest(r, cdf).pvalue > 1e-3
    assert r.min() >= 0.00025 and r.max() <= 0.015


@pytest.mark.parametrize("r_pix,lam", [(0.3, 0.3), (1.5, 0.4), (5.0, 0.6)])
def test_image_coverage_matches_poisson_expectation(r_pix, lam):
    z, w, h = 5.0, 320, 240
    k = intrinsics_from_hfov(w, h, math.radians(60.0))
    r = r_pix * z / k[0, 0]
    half = np.array([0.8 * z, 0.6 * z])  # slab wider than the view at z
    n = int(lam * w * h / (math.pi * r_pix**2) * (4 * half[0] * half[1]) / (w * h * (z / k[0, 0]) ** 2))
    rng = np.random.default_rng(7)
    pos = np.column_stack(
        [rng.uniform(-half[0], half[0], n), rng.uniform(-half[1], half[1], n), rng.uniform(z - 0.01, z + 0.01, n)]
    ).astype(np.float32)
    f = ParticleField(pos, np.full(n, r, np.float32), [-10, -10, 0], [10, 10, 10])
    out, _, _ = render_particles(
        np.zeros((h, w, 3), np.float32), np.full((h, w), np.inf, np.float32), f, k, np.eye(4), colour=[1, 1, 1]
    )
    p = project_particles(f, k, np.eye(4), w, h)
    inside = (p.u >= -0.5) & (p.u < w - 0.5) & (p.v >= -0.5) & (p.v < h - 0.5)
    expect = 1 - math.exp(-float(np.sum(math.pi * p.a[inside] * p.b[inside])) / (w * h))
    assert out[..., 0].mean() == pytest.approx(expect, rel=0.10)


# ----------------------------------------------------------------------------- optics
def test_coc_matches_thin_lens_formula():
    f, N, sf, s, fx = 0.008, 2.0, 2.0, 1.0, 1000.0
    c_mm = (8.0 / 2.0) * abs(1000.0 - 2000.0) / 1000.0 * 8.0 / (2000.0 - 8.0)  # mm on the sensor
    pitch_mm = 8.0 / fx
    assert popt.coc_px(np.array([s]), f, N, sf, fx)[0] == pytest.approx(c_mm / pitch_mm, rel=1e-9)
    assert popt.coc_px(np.array([sf]), f, N, sf, fx)[0] == 0.0


def test_rendered_defocus_disc_has_thin_lens_diameter_and_conserves_light():
    lens = Lens(focal_length_mm=8.0, f_number=1.0, focus_m=10.0)
    z, r = 0.3, 0.0003
    st = state_with(one([z, 0.0, -1.0], r), lens=lens, mode="article")
    sh = particle_light.shaper(st.post, K, T_WC)
    p = project_particles(st.field, K, T_WC, W, H, margin_px=8.0)
    out, _, _ = render_particles(
        np.zeros((H, W, 3), np.float32),
        np.full((H, W), np.inf, np.float32),
        st.field,
        K,
        T_WC,
        colour=[1, 1, 1],
        blur=sh,
    )
    cov = out[..., 0].astype(np.float64)
    v, u = np.mgrid[0:H, 0:W]
    m = cov.sum()
    var = (cov * (u - (cov * u).sum() / m) ** 2).sum() / m
    c_px = popt.coc_px(np.array([z]), 0.008, 1.0, 10.0, K[0, 0])[0]
    blurred = 2 * math.sqrt(p.b[0] ** 2 + (c_px / 2) ** 2)
    assert c_px > 10
    assert 4 * math.sqrt(var) == pytest.approx(blurred, rel=0.05)  # uniform disc: D = 4 sigma
    assert m == pytest.approx(math.pi * p.a[0] * p.b[0], rel=0.05)  # light spread, not created


def test_motion_streak_length_is_velocity_times_exposure():
    z, vy = 3.0, 0.5  # lateral drift (world y) 0.5 m/s, 10 ms
    st = state_with(one([z, 0.0, -1.0], 0.002), exposure=0.01)
    st.post.occlusion.v_flow = [0.0, vy, 0.0]
    p = project_particles(st.field, K, T_WC, W, H)
    s = project_particles(st.field, K, T_WC, W, H, blur=particle_light.shaper(st.post, K, T_WC, (0.0, T_WC), 0.1))
    streak = math.sqrt(3.0 * (s.a[0] ** 2 - s.b[0] ** 2))  # a'^2 = a^2 + L^2 / 3 along the streak
    assert s.b[0] == pytest.approx(p.b[0], rel=1e-5)  # across it: unchanged
    assert streak == pytest.approx(K[0, 0] * vy * 0.01 / z, rel=0.02)
    assert abs(s.c[0]) == pytest.approx(1.0, abs=1e-4)  # lateral drift: along the image rows
    assert s.opacity[0] == pytest.approx(p.a[0] * p.b[0] / (s.a[0] * s.b[0]), rel=1e-5)


def test_particle_behind_dock_never_shows_even_lit_and_blurred():
    lamp = Lamp(offset_m=[0.0, 0.0, 0.0], power_w=100.0)
    st = state_with(one([3.0, 0.0, -1.0], 0.05), lamps=[lamp], lens=Lens(f_number=1.0, focus_m=0.5))
    ps = passes(range_m=2.9)
    ps["rgb"][:] = 0.2
    seen, occ = compose.add_particles(ps, st, K, T_WC)
    assert np.array_equal(seen["rgb"], ps["rgb"]) and not occ.any()
    assert np.array_equal(seen["range_m"], ps["range_m"])


def test_no_particles_costs_nothing():
    st = compose.SequenceState.start(post().model_copy(update={"occlusion": None}))
    ps = passes()
    out, occ = compose.add_particles(ps, st, K, T_WC)
    assert out is ps and occ is None


def _law(lights_c_beam, pts, mat, amb, gain):
    """The light field written out in float64 numpy: amb albedo + gain sum E albedo p(theta), E from
    the shared ``lights.irradiance`` (or the lamp's beam), p the numpy phase functions."""
    pts = np.asarray(pts, float)
    view = -pts / np.linalg.norm(pts, axis=1, keepdims=True)
    art = np.zeros((pts.shape[0], 3))
    for li, c, beam in lights_c_beam:
        v = pts - li.position_m
        d = np.maximum(np.linalg.norm(v, axis=1), 1e-3)
        if beam is None:
            E = popt.lt.irradiance([li], pts, c)
        else:
            b = beam(li, ((v / d[:, None]) @ li.axis)[None, :].astype(np.float32), d[None, :].astype(np.float32))[0]
            E = b * (li.intensity_w_sr[None, :] / (d * d)[:, None])
        mu = ((v / d[:, None]) * view).sum(axis=1)
        art += E * (mat.phase(mu) * mat.albedo)[:, None]
    return mat.albedo * np.asarray(amb, float) + art * gain.T


@pytest.mark.parametrize("spread", [False, True])
def test_compiled_light_field_matches_the_numpy_laws(spread):
    """particle_light_kernels.radiance (vectorised: polynomial acos, exp32) against the laws in
    float64: hard-edged LED hemispheres, a soft-edged lamp (its spread beam table or profile x
    exp(-c' d)), cosine-power emitters (power 1 compiled, 2.5 by numpy) and an isotropic light,
    channel-dependent c, a gain."""
    rng = np.random.default_rng(3)
    pts = rng.uniform([-3, -2, 0.3], [3, 2, 9], (3000, 3))
    water = Water(preset="moderate")
    lamp = Lamp(offset_m=[0.1, 0.3, 0.0], yaw_deg=5.0, half_angle_deg=30.0, edge_deg=5.0, power_w=40.0)
    lamps = lamp_water.LampWater.build(popt.lt.lamp_lights([lamp]), _optics(water), 0.7 if spread else 1.0)
    assert lamps.spread == spread
    led = popt.lt.PointLight(
        np.array([0.2, -0.1, 4.0]), np.array([0.0, 0.0, -1.0]), np.array([0.5, 0.2, 0.1]), math.pi / 2, 0.0
    )
    axis = np.array([0.3, 0.0, -0.95]) / np.linalg.norm([0.3, 0.0, -0.95])
    lambertian = popt.lt.PointLight(np.array([-0.5, 0.4, 3.0]), axis, np.array([0.2, 0.3, 0.4]), math.pi / 2, 0.0, 1.0)
    iso = popt.lt.PointLight(np.array([1.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0]), np.array([0.1, 0.1, 0.1]))
    narrow = popt.lt.PointLight(
        np.array([0.0, -0.5, 2.0]), np.array([0.0, 0.0, 1.0]), np.array([0.3, 0.3, 0.3]), math.pi / 3, 0.1, 2.5
    )  # cos^2.5 inside a soft cone
    c = np.array([0.45, 0.12, 0.08])
    lights = [
        (lamps.lights[0], lamps.c_lamp, lamps.beam if spread else None),
        (led, c, None),
        (lambertian, c, None),
        (iso, c, None),
        (narrow, c, None),
    ]
    mat = popt.ParticleMaterial(0.3, 0.5, 0.9)
    gain = rng.uniform(0.5, 2.0, (3, pts.shape[0]))
    got = popt.light_field(tuple(pts.T.astype(np.float32)), mat, [0.01, 0.02, 0.03], lights, gain).T
    ref = _law(lights, pts, mat, [0.01, 0.02, 0.03], gain)
    assert np.allclose(got, ref, rtol=2e-4, atol=1e-9)
    assert (got > 1.01 * mat.albedo * np.array([0.01, 0.02, 0.03])).mean() > 0.3  # lights do light them


def _optics(water):
    return compose.SequenceState.start(post(water=water.preset)).water


def test_sun_lit_particle_radiance_is_lambert_sphere_reflection():
    sun_down = ([0.0, 0.0, -1.0], 3.0)  # straight down; camera looks horizontally
    st = state_with(one([2.0, 0.0, -1.0], 0.08), suns=[sun_down])
    st.post.ambient_w_m2_sr = 0.0
    p = project_particles(st.field, K, T_WC, W, H)
    J = particle_light.shader(st.post, st.water, T_WC)(p)
    # theta = 90 deg: p_lambert = 2/(3 pi^2); half the scattering is in the forward lobe
    assert np.allclose(J, 0.3 * 0.5 * 3.0 * 2 / (3 * math.pi**2), rtol=1e-4)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_blurred_shape_is_the_eigen_decomposition_of_the_summed_moments(seed):
    """Independent oracle: 4 x the second-moment matrix, R diag(a^2, b^2) R^T + R_c^2 I +
    (4/12) L L^T, decomposed by LAPACK (eigh); the compiled half-angle form must agree."""
    rng = np.random.default_rng(seed)
    n = 400
    a = rng.uniform(0.01, 20.0, n).astype(np.float32)
    b = (a * rng.uniform(0.05, 1.0, n)).astype(np.float32)
    phi = rng.uniform(-math.pi, math.pi, n)
    c, s = np.cos(phi).astype(np.float32), np.sin(phi).astype(np.float32)
    iso = rng.uniform(0.0, 9.0, n).astype(np.float32)
    iso[:50] = 0.0
    st = rng.normal(0.0, 6.0, (n, 2)).astype(np.float32)
    st[50:100] = 0.0
    a2, b2, c2, s2, op = popt.blurred_shapes(a, b, c, s, iso, st)
    for i in range(n):
        R = np.array([[c[i], -s[i]], [s[i], c[i]]], float)
        S = R @ np.diag([a[i] ** 2, b[i] ** 2]) @ R.T + iso[i] * np.eye(2) + np.outer(st[i], st[i]) / 3.0
        lam, vec = np.linalg.eigh(S)
        assert a2[i] == pytest.approx(math.sqrt(lam[1]), rel=1e-4, abs=1e-4)
        assert b2[i] == pytest.approx(math.sqrt(max(lam[0], 1e-12)), rel=1e-3, abs=2e-3)
        assert op[i] == pytest.approx(min(a[i] * b[i] / (a2[i] * b2[i]), 1.0), rel=1e-5)
        if lam[1] - lam[0] > 1e-3 * lam[1]:  # the major axis is defined
            assert abs(vec[0, 1] * c2[i] + vec[1, 1] * s2[i]) == pytest.approx(1.0, abs=1e-3)
    assert np.allclose(np.hypot(c2, s2), 1.0, atol=1e-6)
    same = popt.blurred_shapes(a, b, c, s)  # no blur: the ellipse itself
    assert np.allclose(same[0], a, rtol=1e-5) and np.allclose(same[1], b, rtol=1e-4)
    assert np.allclose(same[4], 1.0, atol=1e-4)


def test_blurred_projection_keeps_exactly_the_footprints_that_meet_the_image():
    """project_particles with a blur keeps a particle iff its blurred footprint (a speck's 2 x 2
    pixels, an ellipse's box) meets the image: the same set as projecting with a wide margin,
    blurring (particle_optics.blurred_shapes) and testing the footprint box."""
    from blendgen.physics.particles.kernels import box

    f = ParticleField.sample(
        5, *BOX, n_total=40000, count_dist="fixed", size_dist="power_law", r_min=0.0005, r_max=0.03
    )
    st = state_with(f, lens=Lens(focal_length_mm=6.0, f_number=1.4, focus_m=2.0), exposure=0.02)
    st.post.occlusion.v_flow = [0.3, 0.5, 0.0]
    T_prev = make_T(R_WC, [-0.2, 0.1, -1.0])
    b = particle_light.shaper(st.post, K, T_WC, (0.0, T_prev), 0.1)
    got = project_particles(f, K, T_WC, W, H, blur=b)
    wide = project_particles(f, K, T_WC, W, H, margin_px=400.0)
    x0, y0, z0 = b.M.astype(float) @ wide.pc.astype(float) + b.o[:, None].astype(float)
    u0 = K[0, 0] * x0 / z0 + K[0, 1] * y0 / z0 + K[0, 2]
    v0 = K[1, 1] * y0 / z0 + K[1, 2]
    st_uv = np.stack([(wide.u - u0) * b.scale, (wide.v - v0) * b.scale], axis=1)
    coc = float(b.coc_k) * np.abs(wide.pc[2] - float(b.focus_m)) / wide.pc[2]
    a2, b2, c2, s2, op = popt.blurred_shapes(wide.a, wide.b, wide.c, wide.s, 0.25 * coc * coc, st_uv)
    keep = []
    for i in range(wide.u.size):
        if a2[i] < 0.5:
            xa, ya, sx, sy = math.floor(wide.u[i]), math.floor(wide.v[i]), 2, 2
        else:
            xa, ya, sx, sy = box(wide.u[i], wide.v[i], a2[i], b2[i], c2[i], s2[i])
        keep.append(xa + sx - 1 >= 0 and xa <= W - 1 and ya + sy - 1 >= 0 and ya <= H - 1)
    keep = np.array(keep)
    differ = np.isin(wide.index, got.index) != keep  # float32 rounding at the box edge
    assert got.u.size > 1000 and keep.sum() > 1000 and differ.sum() <= 2
    assert np.isin(got.index, wide.index).all()
    sel = np.isin(wide.index, got.index)
    order = np.argsort(wide.index[sel])
    assert np.allclose(got.a[np.argsort(got.index)], a2[sel][order], rtol=1e-4, atol=1e-6)
    assert np.allclose(got.opacity[np.argsort(got.index)], op[sel][order], rtol=1e-4, atol=1e-6)
