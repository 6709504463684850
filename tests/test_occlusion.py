"""Small-obstacle occlusion: field statistics, drift, depth-tested rendering, visibility."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from blendgen.geometry import intrinsics_from_hfov, look_at_R, make_T, project
from blendgen.physics.particles.field import (
    ParticleField,
    count_in_frustum,
    frustum_volume,
    led_visible_fraction,
    render_particles,
    visible_fraction_from_masks,
)
from blendgen.physics.particles.gauss import drift_normals

ALPHA = 1e-3  # significance level of every statistical test below
W, H = 160, 120
K_SMALL = intrinsics_from_hfov(W, H, math.radians(60.0))
F_SMALL = K_SMALL[0, 0]
BOX_MIN, BOX_MAX = np.array([-5.0, -5.0, -5.0]), np.array([5.0, 5.0, 5.0])


def one_particle(p_world, r):
    return ParticleField(np.array([p_world], np.float32), np.array([r], np.float32), BOX_MIN, BOX_MAX)


def draw(field, surface_range=np.inf, image_value=0.0, **kw):
    img = np.full((H, W, 3), image_value, np.float32)
    rng_m = np.full((H, W), surface_range, np.float32)
    out, mask, prange = render_particles(img, rng_m, field, K_SMALL, np.eye(4), **kw)
    return img, out, mask, prange


# ----------------------------------------------------------------------------- statistics
def test_frustum_count_is_poisson_rho_vcam():
    """Count in the frustum ~ Poisson(rho V_cam): mean (z-test) and dispersion (chi-square)."""
    W_, H_ = 640, 480
    K = intrinsics_from_hfov(W_, H_, math.radians(60.0))
    lo, hi = np.zeros(3), np.array([10.0, 10.0, 6.0])  # 600 m^3, like the article
    T = make_T(look_at_R([1.0, 0.0, 0.0]), [2.0, 5.0, 3.0])  # frustum stays inside the box
    z_near, z_far = 0.2, 3.0
    rho = 6000 / 600.0
    lam = rho * frustum_volume(K, W_, H_, z_near, z_far)
    counts = np.array(
        [
            count_in_frustum(ParticleField.sample(seed, lo, hi, density=rho), K, T, W_, H_, z_near, z_far)
            for seed in range(400)
        ]
    )
    n = counts.size
    z = (counts.mean() - lam) / math.sqrt(lam / n)
    assert abs(z) < stats.norm.ppf(1 - ALPHA / 2), (counts.mean(), lam)
    dispersion = ((counts - counts.mean()) ** 2).sum() / counts.mean()  # ~ chi2(n-1)
    p = stats.chi2.cdf(dispersion, n - 1)
    assert ALPHA / 2 < p < 1 - ALPHA / 2, (counts.var(ddof=1), lam)


def test_frustum_volume_matches_pyramid():
    K = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])  # image spans [-1, 1] z
    assert frustum_volume(K, 2, 2, 0.0, 3.0) == pytest.approx(4.0 * 27.0 / 3.0)
    assert frustum_volume(K, 2, 2, 1.0, 1.0) == 0.0


def test_uniform_count_never_exceeds_n_max():
    counts = [
        ParticleField.sample(s, BOX_MIN, BOX_MAX, n_total=100, count_dist="uniform", n_max=50).n for s in range(300)
    ]
    assert max(counts) <= 50 and min(counts) >= 0
    assert min(counts) < 5 and max(counts) > 45  # spans the whole range
    assert abs(np.mean(counts) - 25.0) < 5 * math.sqrt((51**2 - 1) / 12 / 300)


def test_fixed_and_capped_poisson_counts():
    assert ParticleField.sample(0, BOX_MIN, BOX_MAX, n_total=600, count_dist="fixed").n == 600
    assert all(ParticleField.sample(s, BOX_MIN, BOX_MAX, n_total=600, n_max=580).n <= 580 for s in range(20))


def test_same_seed_same_field_different_seed_differs():
    a = ParticleField.sample(7, BOX_MIN, BOX_MAX, n_total=1000)
    b = ParticleField.sample(np.random.default_rng(7), BOX_MIN, BOX_MAX, n_total=1000)
    c = ParticleField.sample(8, BOX_MIN, BOX_MAX, n_total=1000)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.radii, b.radii)
    assert a.n != c.n or not np.array_equal(a.positions, c.positions)
    sa, sb = a.step(0.1, [0.1, 0, 0], [0.01] * 3, 3), b.step(0.1, [0.1, 0, 0], [0.01] * 3, 3)
    assert np.array_equal(sa.positions, sb.positions)


def test_positions_and_radii_in_range():
    f = ParticleField.sample(1, [0, 0, -8], [15, 5, 0], n_total=6000, r_min=0.01, r_max=0.03)
    assert f.positions.dtype == np.float32 and f.positions.shape == (f.n, 3)
    assert np.all(f.positions >= [0, 0, -8]) and np.all(f.positions < [15, 5, 0])
    assert f.radii.min() >= 0.01 and f.radii.max() <= 0.03
    assert f.volume == pytest.approx(600.0)


def test_zero_density_gives_no_particles_and_unchanged_image():
    for kw in ({"density": 0.0}, {"density": 1e-12}, {"n_total": 0}):
        f = ParticleField.sample(0, BOX_MIN, BOX_MAX, **kw)
        assert f.n == 0
        img, out, mask, prange = draw(f, image_value=0.3)
        assert np.array_equal(out, img) and not mask.any() and np.all(np.isinf(prange))


def test_huge_field_fits_in_memory():
    tracemalloc.start()
    try:
        f = ParticleField.sample(0, BOX_MIN, BOX_MAX, n_total=1_000_000, count_dist="fixed")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert f.n == 1_000_000 and f.positions.nbytes + f.radii.nbytes == 16_000_000
    assert peak < 30e6, peak  # a few working copies at most
    n = count_in_frustum(f, K_SMALL, np.eye(4), W, H, 0.1, 4.0)
    lam = f.density * frustum_volume(K_SMALL, W, H, 0.1, 4.0)
    assert abs(n - lam) < 5 * math.sqrt(lam)


# ----------------------------------------------------------------------------- drift
def test_drift_without_noise_is_exact():
    f = ParticleField.sample(2, BOX_MIN, BOX_MAX, n_total=2000, count_dist="fixed")
    v, dt = np.array([0.3, -0.2, 0.1]), 0.5
    g = f.step(dt, v, [0.0, 0.0, 0.0], rng=0)
    moved = (f.positions + v * dt - BOX_MIN) % (BOX_MAX - BOX_MIN) + BOX_MIN
    assert np.allclose(g.positions, moved, atol=2e-6)
    assert np.array_equal(g.radii, f.radii)


def test_drift_mean_and_covariance():
    f = ParticleField.sample(3, BOX_MIN, BOX_MAX, n_total=100_000, count_dist="fixed")
    v, dt = np.array([0.5, 0.0, -0.25]), 0.2
    cov = np.array([[0.04, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.01]])
    g = f.step(dt, v, cov, rng=4)
    ext = BOX_MAX - BOX_MIN
    disp = (g.positions.astype(float) - f.positions + ext / 2) % ext - ext / 2  # undo the wrap
    tol = 5 * np.sqrt(np.diag(cov) / f.n)
    assert np.all(np.abs(disp.mean(axis=0) - v * dt) < tol)
    assert np.allclose(np.cov(disp.T), cov, atol=2e-3)


@settings(max_examples=25, deadline=None)
@given(
    dt=st.floats(0.0, 10.0),
    vx=st.floats(-5.0, 5.0),
    vz=st.floats(-5.0, 5.0),
    sig=st.floats(0.0, 3.0),
    seed=st.integers(0, 2**16),
)
def test_drift_wraps_into_region_keeping_count(dt, vx, vz, sig, seed):
    lo, hi = np.array([0.1, -0.3, -7.9]), np.array([15.1, 4.7, 0.1])  # not float32-exact
    f = ParticleField.sample(seed, lo, hi, n_total=300, count_dist="fixed")
    g = f.step(dt, [vx, 0.0, vz], [sig, sig, sig], seed)
    assert g.n == f.n
    assert np.all(g.positions >= lo) and np.all(g.positions < hi)


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(0.0, 1e4), seed=st.integers(0, 2**16))
def test_wrap_equals_the_modulo_formula_bit_for_bit(scale, seed):
    """The drift kernel's wrap (no flow, no noise) sends only the coordinates outside the region
    through the modulo; the result must equal lo + mod(pos - lo, ext) exactly (datasets keep
    their bytes), edges included."""
    from blendgen.physics.particles.field import _bounds32, _clamp32
    from blendgen.physics.particles.kernels import drift

    lo, hi = np.array([0.1, -0.3, -7.9]), np.array([15.1, 4.7, 0.1])
    rng = np.random.default_rng(seed)
    pos = lo + (hi - lo) * rng.uniform(-0.2, 1.2, (200, 3)) * (1.0 + scale * rng.random((200, 1)))
    pos[:6] = [lo, hi, lo - (hi - lo), hi + (hi - lo), np.nextafter(hi, -np.inf), -0.0 * lo]
    ref = _clamp32(np.ascontiguousarray((lo + np.mod(pos - lo, hi - lo)).astype(np.float32).T), lo, hi)
    wrapped = drift(
        np.ascontiguousarray(pos.T), np.zeros(3), np.zeros((3, 3)), np.uint64(0), lo, hi, *_bounds32(lo, hi)
    )
    assert wrapped.tobytes() == ref.tobytes()


# ----------------------------------------------------------------------------- rendering
def test_particle_behind_surface_never_changes_a_pixel():
    f = one_particle([0.0, 0.0, 2.0], 0.05)  # surface range 1.95 m
    for surface in (1.0, 1.94):
        img, out, mask, prange = draw(f, surface_range=surface, image_value=0.4)
        assert np.array_equal(out, img) and not mask.any() and np.all(np.isinf(prange))


def test_particle_in_front_of_surface_occludes():
    f = one_particle([0.0, 0.0, 2.0], 0.05)
    for surface in (1.96, np.inf):
        img, out, mask, prange = draw(f, surface_range=surface, image_value=0.4, mode="silhouette")
        assert mask.sum() > 10 and np.all(out[mask] < 0.1)
        assert np.allclose(prange[mask], 1.95, atol=1e-5)
    _, out, mask, _ = draw(f, image_value=0.0, mode="backscatter")
    assert np.all(out[mask].mean(axis=0) > 0.3)  # bright speck


def test_partial_depth_test_per_pixel():
    """Only the pixels whose surface is behind the particle get covered."""
    f = one_particle([0.0, 0.0, 2.0], 0.05)
    img = np.zeros((H, W, 3), np.float32)
    rng_m = np.full((H, W), 1.0, np.float32)
    rng_m[:, W // 2 :] = np.inf
    _, mask, _ = render_particles(img, rng_m, f, K_SMALL, np.eye(4))
    assert mask[:, W // 2 + 1 :].any() and not mask[:, : W // 2].any()


@pytest.mark.parametrize("r_pix", [0.3, 1.5, 3.0, 12.0, 40.0])
def test_pixel_radius_on_axis_matches_f_r_over_z(r_pix):
    z = 3.0
    f = one_particle([0.0, 0.0, z], r_pix * z / F_SMALL)
    _, out, mask, _ = draw(f, image_value=0.0, colour=(1.0, 1.0, 1.0))
    cov = out[..., 0]
    assert cov.sum() == pytest.approx(math.pi * r_pix**2, rel=0.10)
    if r_pix >= 10:  # lattice-limited below
        assert mask.sum() == pytest.approx(math.pi * r_pix**2, rel=0.10)
    vv, uu = np.mgrid[:H, :W]
    centre = (cov * uu).sum() / cov.sum(), (cov * vv).sum() / cov.sum()
    assert np.allclose(centre, K_SMALL[:2, 2], atol=0.1)  # centred on (cx, cy)


def test_off_axis_particle_is_a_radially_stretched_ellipse_at_its_projection():
    p = np.array([0.6, 0.0, 2.0])  # 17 deg off the axis
    r = 0.06
    f = one_particle(p, r)
    _, out, _, _ = draw(f, image_value=0.0, colour=(1.0, 1.0, 1.0))
    cov = out[..., 0].astype(float)
    b = F_SMALL * r / p[2]
    a = b * np.linalg.norm(p) / p[2]
    assert cov.sum() == pytest.approx(math.pi * a * b, rel=0.05)
    vv, uu = np.mgrid[:H, :W]
    cu, cv = (cov * uu).sum() / cov.sum(), (cov * vv).sum() / cov.sum()
    assert np.allclose([cu, cv], project(K_SMALL, p[None])[0], atol=0.1)
    var_u, var_v = (cov * (uu - cu) ** 2).sum(), (cov * (vv - cv) ** 2).sum()
    assert math.sqrt(var_u / var_v) == pytest.approx(a / b, rel=0.05)  # radial = +u here


def test_subpixel_specks_dim_proportionally_and_never_vanish():
    f = one_particle([0.3, -0.2, 4.0], 0.2 * 4.0 / F_SMALL)  # r_pix = 0.2
    _, out, mask, prange = draw(f, image_value=1.0, mode="silhouette", colour=(0.0, 0.0, 0.0))
    dimming = (1.0 - out[..., 0]).sum()
    assert dimming == pytest.approx(math.pi * 0.2**2, rel=0.05) and not mask.any()
    assert np.isfinite(prange).sum() >= 1


def test_rotated_camera_draws_particle_at_its_projection():
    T = make_T(look_at_R([1.0, 1.0, -0.3]), [1.0, 2.0, -3.0])
    p_cam = np.array([[0.3, -0.2, 2.5]])
    p_world = T[:3, :3] @ p_cam[0] + T[:3, 3]
    f = ParticleField([p_world], [0.05], [-10] * 3, [10] * 3)
    img, rng_m = np.zeros((H, W, 3), np.float32), np.full((H, W), np.inf, np.float32)
    out, _, prange = render_particles(img, rng_m, f, K_SMALL, T, colour=(1.0, 1.0, 1.0))
    cov = out[..., 0].astype(float)
    vv, uu = np.mgrid[:H, :W]
    centroid = [(cov * uu).sum() / cov.sum(), (cov * vv).sum() / cov.sum()]
    assert np.allclose(centroid, project(K_SMALL, p_cam)[0], atol=0.1)
    assert np.nanmin(prange) == pytest.approx(np.linalg.norm(p_cam) - 0.05, abs=1e-5)


def test_fixed_total_gives_binomial_frustum_counts():
    """With a fixed total the frustum count is binomial: variance n p (1 - p), under-dispersed vs
    Poisson. The region hugs the frustum (p ~ 0.32), so that the two variances differ by 4 sigma
    of a 300-field sample variance (with p = 0.07 they differed by 0.9 sigma: seed luck)."""
    T = make_T(look_at_R([1.0, 0.0, 0.0]), [-4.0, 0.0, 0.0])
    lo, hi = np.array([-3.9, -3.5, -2.7]), np.array([2.0, 3.5, 2.7])  # holds the 0.1-6 m frustum
    counts = np.array(
        [
            count_in_frustum(
                ParticleField.sample(s, lo, hi, n_total=2000, count_dist="fixed"), K_SMALL, T, W, H, 0.1, 6.0
            )
            for s in range(300)
        ]
    )
    p = frustum_volume(K_SMALL, W, H, 0.1, 6.0) / float(np.prod(hi - lo))
    var_binomial = 2000 * p * (1 - p)
    assert 0.25 < p < 0.4
    assert abs(counts.mean() - 2000 * p) < 5 * math.sqrt(var_binomial / counts.size)
    sd_var = var_binomial * math.sqrt(2.0 / (counts.size - 1))  # of the sample variance
    assert abs(counts.var(ddof=1) - var_binomial) < 4 * sd_var
    assert counts.var(ddof=1) < 0.85 * counts.mean()  # Poisson: = the mean


def test_direct_construction_is_validated():
    f = ParticleField([[0, 0, 1]], [0.1], BOX_MIN, BOX_MAX)
    assert f.positions.dtype == np.float32 and f.positions.shape == (1, 3)
    with pytest.raises(ValueError):
        ParticleField([[0, 0, 1]], [0.1, 0.2], BOX_MIN, BOX_MAX)
    with pytest.raises(ValueError):
        ParticleField([[0, 0, 1]], [-0.1], BOX_MIN, BOX_MAX)
    with pytest.raises(ValueError):
        ParticleField([[0, 0, 1]], [0.1], BOX_MAX, BOX_MIN)


def test_nearest_particle_wins_and_water_uses_its_own_range():
    near = ParticleField(
        np.array([[0, 0, 1.0], [0, 0, 3.0]], np.float32), np.array([0.02, 0.2], np.float32), BOX_MIN, BOX_MAX
    )
    water = {"beta": 0.5, "colour": (0.0, 0.0, 1.0)}
    _, out, mask, prange = draw(near, image_value=0.0, colour=(1.0, 1.0, 1.0), water=water)
    c = int(round(K_SMALL[1, 2])), int(round(K_SMALL[0, 2]))
    assert prange[c] == pytest.approx(0.98, abs=1e-5)  # the near one, in front
    assert prange[c[0], c[1] + 6] == pytest.approx(2.8, abs=1e-5)  # only the far one here
    w_near, w_far = 1 - math.exp(-0.5 * 0.98), 1 - math.exp(-0.5 * 2.8)
    assert out[c][0] == pytest.approx(1 - w_near, abs=1e-3)
    assert out[c[0], c[1] + 6][0] == pytest.approx(1 - w_far, abs=1e-3)


def test_render_of_a_real_field_does_not_touch_inputs():
    f = ParticleField.sample(5, [-3, -3, 0], [3, 3, 6], n_total=20000)
    img = np.full((H, W, 3), 0.5, np.float32)
    rng_m = np.full((H, W), 3.0, np.float32)
    img0, rng0 = img.copy(), rng_m.copy()
    out, mask, prange = render_particles(img, rng_m, f, K_SMALL, np.eye(4), mode="silhouette")
    assert np.array_equal(img, img0) and np.array_equal(rng_m, rng0)
    assert mask.any() and out.dtype == np.float32
    assert np.all(prange[np.isfinite(prange)] < 3.0)  # nothing drawn behind the wall
    assert np.all(out <= 0.5 + 1e-6) and np.all(out >= 0.0)


# ----------------------------------------------------------------------------- visibility
def test_visible_fraction_from_masks():
    marker = np.zeros((20, 20), bool)
    marker[5:15, 5:15] = True
    occ = np.zeros_like(marker)
    occ[5:10, 5:10] = True
    assert visible_fraction_from_masks(marker, occ, 100.0) == pytest.approx(0.75)
    assert visible_fraction_from_masks(marker, occ, 0.0) == 0.0
    assert visible_fraction_from_masks(marker, np.zeros_like(marker), 50.0) == 1.0


def test_led_visible_fraction():
    index = np.zeros((10, 10), np.uint8)
    for u, v in [(1, 1), (8, 1), (8, 8)]:
        index[v, u] = 7
    occ = np.zeros((10, 10), bool)
    occ[8, 8] = True
    leds = np.array([[1, 1], [8, 1], [8, 8], [1, 8]])  # last: not an LED pixel
    assert led_visible_fraction(leds, index, [7], occ) == pytest.approx(0.5)
    assert led_visible_fraction(np.array([[1, 1], [50, 1]]), index, 7, occ) == pytest.approx(0.5)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_total": -1},
        {"density": -0.1},
        {"n_total": 10, "density": 1.0},
        {},
        {"n_total": 10, "r_min": -0.01},
        {"n_total": 10, "r_min": 0.05, "r_max": 0.01},
        {"n_total": 10, "count_dist": "fixed", "n_max": 5},
        {"n_total": 10.5, "count_dist": "fixed"},
        {"n_total": 10, "count_dist": "gamma"},
        {"n_total": 10, "n_max": -1},
        {"n_total": 1e12},
        {"n_total": float("nan")},
        {"n_total": 10, "region_max": [5.0, 5.0, -5.0]},
    ],
)
def test_bad_sampling_parameters_raise(kwargs):
    region_max = kwargs.pop("region_max", BOX_MAX)
    with pytest.raises(ValueError):
        ParticleField.sample(0, BOX_MIN, region_max, **kwargs)


def test_bad_drift_and_render_parameters_raise():
    f = ParticleField.sample(0, BOX_MIN, BOX_MAX, n_total=10)
    for args in [
        (-1.0, [0, 0, 0], [0, 0, 0]),
        (1.0, [0, 0], [0, 0, 0]),
        (1.0, [0, 0, 0], [-0.1, 0, 0]),
        (1.0, [0, 0, 0], -np.eye(3)),
        (1.0, [0, 0, 0], np.array([[1, 2, 0], [0, 1, 0], [0, 0, 1]])),
    ]:
        with pytest.raises(ValueError):
            f.step(*args, rng=0)
    img, rng_m = np.zeros((H, W, 3), np.float32), np.full((H, W), np.inf, np.float32)
    with pytest.raises(ValueError):
        render_particles(img, rng_m, f, K_SMALL, np.eye(4), mode="glow")
    with pytest.raises(ValueError):
        render_particles(img, rng_m[:10], f, K_SMALL, np.eye(4))
    with pytest.raises(ValueError):
        render_particles(img, rng_m, f, K_SMALL, np.eye(4), water={"beta": 0.1})
    with pytest.raises(ValueError):
        frustum_volume(K_SMALL, W, H, 2.0, 1.0)


def _step_as_written(f: ParticleField, dt, v, L, rng) -> np.ndarray:
    """The drift as the article writes it, with broadcasting and column sums (the code before
    the flat, tiled loops): lo + mod(p + v dt + L z - lo, ext), rounded to float32 and kept inside."""
    pos = f.positions.astype(np.float64) + np.asarray(v, float) * dt
    z = np.zeros((f.n, 3))
    if np.any(L):  # one word of rng seeds the step's normals
        z = drift_normals(int(rng.integers(0, 2**64, dtype=np.uint64)), f.n).T.astype(np.float64)
    for i in range(3):
        pos[:, i] += z[:, 0] * L[i, 0] + z[:, 1] * L[i, 1] + z[:, 2] * L[i, 2]
    lo, hi = f.region_min, f.region_max
    out = (lo + np.mod(pos - lo, hi - lo)).astype(np.float32)
    lo32 = np.where(
        lo.astype(np.float32) < lo, np.nextafter(lo.astype(np.float32), np.float32(np.inf)), lo.astype(np.float32)
    )
    top = np.where(
        hi.astype(np.float32) >= hi, np.nextafter(hi.astype(np.float32), np.float32(-np.inf)), hi.astype(np.float32)
    )
    return np.minimum(np.maximum(out, lo32), top)


@settings(max_examples=40, deadline=None)
@given(
    dt=st.floats(0.0, 2.0),
    vx=st.floats(-3.0, 3.0),
    s=st.lists(st.sampled_from([0.0, 1e-3, 0.02, 0.7, 5.0]), min_size=3, max_size=3),
    seed=st.integers(0, 2**16),
)
def test_drift_step_equals_the_written_formula_bit_for_bit(dt, vx, s, seed):
    """ParticleField.step (diagonal sigma: one tiled product; flat tiled bounds) gives the same
    float32 bytes as the formula written out with broadcasting, zero std-devs included."""
    lo, hi = np.array([0.1, -0.3, -7.9]), np.array([15.1, 4.7, 0.1])
    f = ParticleField.sample(seed, lo, hi, n_total=500, count_dist="fixed")
    got = f.step(dt, [vx, 0.0, -0.5 * vx], s, np.random.default_rng(seed)).positions
    ref = _step_as_written(f, dt, [vx, 0.0, -0.5 * vx], np.diag(s), np.random.default_rng(seed))
    assert got.tobytes() == ref.tobytes()


def test_chained_steps_equal_fresh_fields_stepped_once():
    """A stepped field (built without a second validation, its region's float32 bounds carried
    over) steps exactly as a field built anew from the same positions; a scalar sigma is the
    same std-dev on every axis."""
    lo, hi = np.array([0.0, -2.5, -5.0]), np.array([15.0, 2.5, 3.0])
    f = ParticleField.sample(7, lo, hi, n_total=2000, count_dist="fixed")
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    a, radii = f, f.radii
    for _ in range(5):
        a = a.step(0.1, [0.3, 0.0, -0.1], 0.05, rng_a)
        b = ParticleField(np.array(f.positions), f.radii, lo, hi).step(0.1, [0.3, 0.0, -0.1], [0.05] * 3, rng_b)
        assert a.positions.tobytes() == b.positions.tobytes() and a.xyz.flags.c_contiguous
        assert a.radii is radii and np.array_equal(a.region_max, hi)
        f = b
    assert np.all((a.positions >= lo) & (a.positions < hi))


def test_nan_range_is_background_like_inf():
    """A NaN range pass (no surface hit) draws the particles exactly as inf does."""
    f = ParticleField.sample(3, BOX_MIN, BOX_MAX, n_total=3000, count_dist="fixed")
    _, out_inf, mask_inf, r_inf = draw(f, surface_range=np.inf, image_value=0.2, mode="backscatter")
    _, out_nan, mask_nan, r_nan = draw(f, surface_range=np.nan, image_value=0.2, mode="backscatter")
    assert mask_inf.any() and np.array_equal(out_inf, out_nan) and np.array_equal(mask_inf, mask_nan)
    assert np.array_equal(r_inf[mask_inf], r_nan[mask_nan])
