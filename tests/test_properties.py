"""Property-based stress of the pure core at extreme values (hypothesis; profile "ci" by
default, "slow" with --slow). Complements the per-module tests: only what they do not cover
(metrics near d_true = 0 and at the 10 m edge, optics in float32 and vectorised, occlusion at
rho -> 0 and huge N, dynamics at large dt / extreme density, pixel<->ray round trips with
shifted principal points, Blender<->OpenCV camera frames)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import assume, example, given
from hypothesis import strategies as st

from blendgen import geometry as g
from blendgen.physics.particles.field import MAX_PARTICLES, ParticleField
from blendgen.physics.water import optics as o
from blendgen.vehicle.dynamics import DT_MAX, Plant, check_dt
from evalkit.metrics import core as metrics

TINY = [0.0, 5e-324, 1e-300, 1e-12, float(np.nextafter(0.2, 0.0)), 0.2, float(np.nextafter(0.2, 1.0))]
EDGE = [float(np.nextafter(10.0, 0.0)), 10.0, float(np.nextafter(10.0, 11.0)), 10.0 - 1e-9, 10.0 + 1e-9]
finite = dict(allow_nan=False, allow_infinity=False)


# ------------------------------------------------------------------ metrics
def _df(d_true, d_est, success=True):
    n = len(d_true)
    return pd.DataFrame(
        {
            "localizer": "l",
            "sequence": [f"s{i % 2}" for i in range(n)],
            "condition": "c",
            "d_true": d_true,
            "detected": success,
            "d_est": d_est,
        }
    )


@given(
    st.lists(st.one_of(st.sampled_from(TINY), st.floats(0.0, 1e-3)), min_size=1, max_size=20),
    st.lists(st.floats(0.0, 1e6, **finite), min_size=20, max_size=20),
    st.sampled_from([1e-12, 0.2, 1.0]),
)
def test_metrics_near_zero_distance(d_true, d_est, d_min_rel):
    df = _df(d_true, d_est[: len(d_true)])
    err = metrics.frame_errors(df, d_min_rel)
    assert np.isfinite(err.e_abs).all()  # successful frames: e_abs always
    e_rel = err.e_rel.to_numpy()
    d = np.asarray(d_true)
    assert (np.isnan(e_rel) == ((d < d_min_rel) | (d <= 0.0))).all()
    assert not np.isinf(e_rel).any()  # never 1/0: inf would poison means
    tr = metrics.summarize(df, d_min_rel=d_min_rel)[0]
    assert tr.n_total.sum() == len(d_true) and not np.isinf(tr.e_rel_mean).any()


def test_metrics_zero_d_min_rel_subnormal_distance():
    err = metrics.frame_errors(_df([5e-324], [1.0]), d_min_rel=0.0)
    assert not np.isinf(err.e_rel).any()


@given(
    st.lists(st.one_of(st.sampled_from(EDGE), st.floats(9.999, 10.001)), min_size=1, max_size=20),
    st.floats(0.0, 20.0, **finite),
)
def test_metrics_ten_metre_edge(d_true, d_est):
    df = _df(d_true, d_est)
    counted = metrics.counted_mask(df.d_true).to_numpy()
    assert (counted == (np.asarray(d_true) <= 10.0)).all()  # 10.0 itself counts, one ulp above does not
    tr = metrics.summarize(df)[0]
    assert tr.n_total.sum() == counted.sum()
    assert ((tr.P_detect == 1.0) | (tr.n_total == 0)).all()


@given(st.floats(0.0, 10.0, **finite), st.floats(0.0, 10.0, **finite), st.floats(0.0, 30.0, **finite))
@example(0.0, 2.225073858507203e-309, 1.0)  # subnormal d_true: the ratio overflows
def test_e_rel_defined_exactly_above_d_min_rel(d_min_rel, d_true, d_est):
    err = metrics.frame_errors(_df([d_true], [d_est]), d_min_rel)
    with np.errstate(over="ignore"):
        ratio = abs(d_true - d_est) / d_true if d_true > 0 else math.inf
    if d_true >= d_min_rel and d_true > 0 and math.isfinite(ratio):  # overflow: undefined, never inf
        assert err.e_rel.iloc[0] == pytest.approx(ratio)
    else:
        assert np.isnan(err.e_rel.iloc[0])


# ------------------------------------------------------------------ optics
def _water(beta, B, model=None):
    c = np.full(3, beta)
    return o.WaterOptics(name="t", sigma_a=0.5 * c, sigma_s=0.5 * c, Kd=(0.3, 0.1, 0.05), B_inf=B, g=0.9)


@given(
    beta=st.lists(st.floats(0.0, 5.0), min_size=2, max_size=6),
    rng_m=st.lists(st.floats(0.0, 1e4), min_size=2, max_size=40),
    j=st.floats(0.0, 1.0),
    b=st.floats(0.0, 1.0),
    dtype=st.sampled_from([np.float32, np.float64]),
    model=st.sampled_from(o.MODELS),
)
def test_optics_monotone_vectorised(beta, rng_m, j, b, dtype, model):
    """A row of pixels with growing range (one call, both dtypes and models) moves
    monotonically from J toward the veiling light; more beta never moves it back."""
    r = np.sort(np.asarray(rng_m, dtype))[None, :]
    J = np.full(r.shape + (3,), j, dtype)
    eps = 8 * float(np.finfo(dtype).eps)
    prev = None
    for be in sorted(beta):
        out = o.apply_water(J, r, None, _water(be, (b, b, b)), 0.0, model=model)
        assert out.dtype == dtype and np.isfinite(out).all()
        dist = np.abs(out[0, :, 0].astype(np.float64) - b)  # distance to B_inf (depth 0: D = 1)
        assert np.all(np.diff(dist) <= eps)  # farther -> closer to B
        assert np.all(dist <= abs(j - b) + eps)
        if prev is not None:
            assert np.all(dist <= prev + eps)  # more beta -> closer to B
        prev = dist


@given(
    st.floats(0.0, 5.0),
    st.lists(st.floats(0.0, 1e4), min_size=1, max_size=30),
    st.sampled_from([np.float32, np.float64]),
)
def test_transmittance_bounded_and_exact_at_zero_range(beta, rng_m, dtype):
    r = np.asarray([[0.0] + list(rng_m) + [np.inf, np.nan]], dtype)
    t = o.transmittance(_water(beta, (0.1, 0.1, 0.1)), r, dtype)
    assert t.dtype == dtype and np.isfinite(t).all()
    assert np.all((t >= 0) & (t <= 1)) and np.all(t[0, 0] == 1)
    if beta == 0:
        assert np.all(t == 1)


# ------------------------------------------------------------------ occlusion
BOX = ([0.0, 0.0, -8.0], [15.0, 5.0, 0.0])


@given(st.floats(0.0, 1e-9), st.floats(1.0, 1e5), st.integers(0, 2**32 - 1))
def test_occlusion_vanishing_density(rho, side, seed):
    lo, hi = [0.0, 0.0, -side], [side, side, 0.0]
    f = ParticleField.sample(seed, lo, hi, density=rho, count_dist="poisson")
    assert f.n >= 0 and f.positions.shape == (f.n, 3) and np.isfinite(f.positions).all()
    if rho * side**3 < 0.5:
        assert ParticleField.sample(seed, lo, hi, density=rho, count_dist="fixed").n == 0
    if f.n:
        assert np.all(f.positions >= np.float32(lo)) and np.all(f.positions < np.float32(hi))


@given(st.floats(0.0, float(MAX_PARTICLES)), st.integers(0, 3000), st.integers(0, 2**32 - 1))
def test_occlusion_huge_mean_is_capped_by_n_max(mean, n_max, seed):
    f = ParticleField.sample(seed, *BOX, n_total=mean, n_max=n_max)
    assert 0 <= f.n <= n_max and f.radii.shape == (f.n,)


@given(
    st.one_of(st.floats(MAX_PARTICLES * 1.0001, 1e300), st.just(math.inf), st.just(math.nan), st.floats(-1e9, -1e-9))
)
def test_occlusion_impossible_counts_raise_clearly(mean):
    with pytest.raises(ValueError, match="particle count"):
        ParticleField.sample(0, *BOX, n_total=mean)
    with pytest.raises(ValueError, match="particle count"):
        ParticleField.sample(0, *BOX, density=mean)


# ------------------------------------------------------------------ dynamics
@given(
    st.one_of(
        st.floats(DT_MAX, 1e9, exclude_min=True), st.floats(-1e9, 0.0), st.sampled_from([math.inf, -math.inf, math.nan])
    )
)
def test_dt_outside_stable_range_is_a_clear_error(dt):
    with pytest.raises(ValueError, match="dt"):
        check_dt(dt)


@given(
    dt=st.floats(1e-4, DT_MAX),
    rho=st.one_of(st.just(0.0), st.floats(0.0, 2e4)),
    cmd=st.floats(-1.0, 1.0),
    roll=st.floats(-1.0, 1.0),
)
def test_plant_stays_finite_for_stable_dt_and_any_density(dt, rho, cmd, roll):
    p = Plant(rho=rho)
    p.set_pose_ned([0.0, 0.0, 2.0, roll, 0.2, 0.0])
    n_cmd = np.full(p.thrusters.n, cmd) * p.thrusters.n_max
    for _ in range(int(min(200, 2.0 / dt))):  # ~2 s of simulated time
        p.step(n_cmd, (0.3, 0.0, 0.0), dt)
    assert np.isfinite(p.s).all() and np.isfinite(p.n).all()


def test_plant_step_rejects_unstable_dt():
    p = Plant()
    p.set_pose_ned([0.0, 0.0, 2.0, 0.3, 0.2, 0.0])
    with pytest.raises(ValueError, match="dt"):
        for _ in range(50):
            p.step(np.full(p.thrusters.n, 50.0), dt=2.0)


@pytest.mark.parametrize("rho", [math.nan, -5.0, math.inf])
def test_plant_rejects_impossible_density(rho):
    with pytest.raises(ValueError):
        Plant(rho=rho)


# ------------------------------------------------------------------ geometry
@given(
    w=st.integers(16, 8192),
    h=st.integers(16, 8192),
    fov=st.floats(0.05, math.pi - 0.05),
    sx=st.floats(-0.5, 0.5),
    sy=st.floats(-0.5, 0.5),
    u=st.floats(-1e4, 1e4),
    v=st.floats(-1e4, 1e4),
    z=st.floats(1e-3, 1e4),
)
def test_pixel_ray_pixel_round_trip(w, h, fov, sx, sy, u, v, z):
    """unproject then project returns the pixel (principal point shifted, far off-image
    pixels, near and far depths); the ray's z is the planar depth given."""
    K = g.intrinsics_from_hfov(w, h, fov, sx, sy)
    P = g.unproject(K, [[u, v]], [z])
    assert P[0, 2] == z
    uv = g.project(K, P)
    scale = max(1.0, abs(u), abs(v))
    assert np.allclose(uv, [[u, v]], rtol=0, atol=1e-9 * scale)


@given(st.integers(0, 2**32 - 1), st.floats(1e-3, 1e3))
def test_range_factor_is_ray_length(seed, z):
    rng = np.random.default_rng(seed)
    w, h = int(rng.integers(16, 200)), int(rng.integers(16, 200))
    K = g.intrinsics_from_hfov(w, h, rng.uniform(0.2, 2.8), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3))
    ui, vi = int(rng.integers(0, w)), int(rng.integers(0, h))
    P = g.unproject(K, [[ui, vi]], [z])[0]
    r = g.planar_depth_to_range(np.full((h, w), z, np.float64), K)[vi, ui]
    assert r == pytest.approx(np.linalg.norm(P), rel=1e-6)  # float32 ray-norm grid


def _random_T(rng, scale=100.0):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    R = np.array(
        [
            [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
            [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
            [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d],
        ]
    )
    return g.make_T(R, rng.uniform(-scale, scale, 3))


@given(st.integers(0, 2**32 - 1))
def test_blender_opencv_camera_conversion(seed):
    """For any camera pose: matrix_world <-> T_world_cam round-trips, stays a rotation, and a
    point in front of the OpenCV camera (+z) is at -Z of the Blender camera, image-up = +Y."""
    rng = np.random.default_rng(seed)
    T_wc = _random_T(rng)
    M = g.blender_matrix_world_from_T_world_cam(T_wc)
    assert np.allclose(g.T_world_cam_from_blender_matrix_world(M), T_wc, atol=1e-12)
    assert np.linalg.det(M[:3, :3]) == pytest.approx(1.0) and np.allclose(M[3], [0, 0, 0, 1])
    p_cv = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0.1, 50)])
    p_w = g.transform_points(T_wc, p_cv)[0]
    p_bl = g.transform_points(g.invert_T(M), p_w)[0]
    assert np.allclose(p_bl, [p_cv[0], -p_cv[1], -p_cv[2]], atol=1e-9 * (1 + np.abs(T_wc[:3, 3]).max()))


@given(st.integers(0, 2**32 - 1), st.integers(1, 2000))
def test_long_compositions_stay_rigid(seed, n):
    """Compose/invert many random transforms: the result is still rigid (R^T R = I, det 1)
    and T @ inv(T) = I, without re-orthonormalising."""
    assume(n > 0)
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    for _ in range(min(n, 300)):
        T = T @ _random_T(rng, 1.0)
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-10) and np.linalg.det(R) == pytest.approx(1.0, abs=1e-10)
    assert np.allclose(T @ g.invert_T(T), np.eye(4), atol=1e-8 * max(1.0, np.abs(T[:3, 3]).max()))
