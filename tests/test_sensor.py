"""Sensor model: sRGB, noise statistics and determinism, motion blur, distortion oracle."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from blendgen.physics.camera import sensor as s

K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
DIST = [-0.25, 0.08, 0.001, -0.0005, 0.01]


def test_srgb_matches_piecewise_definition():
    x = np.linspace(0, 1, 200001)
    ref = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(s.srgb_encode(x), ref, atol=1e-12)
    np.testing.assert_allclose(s.srgb_encode(x.astype(np.float32)), ref, atol=1e-6)


def test_srgb_round_trip():
    x = np.linspace(0, 1, 10001)
    np.testing.assert_allclose(s.srgb_decode(s.srgb_encode(x)), x, atol=1e-12)
    k = np.arange(256, dtype=np.uint8)
    assert np.array_equal(s.to_uint8(s.srgb_decode(k)), k)
    assert np.array_equal(s.to_uint8(s.srgb_decode(k.astype(np.float64) / 255)), k)


def test_encode_clips_and_handles_nan():
    out = s.to_uint8(np.array([[-1.0, 0.0, 0.5, 1.0, 7.0, np.nan]], np.float32))
    assert out.tolist() == [[0, 0, 188, 255, 255, 0]]


def test_noise_std_matches_request():
    lin = np.full((400, 400, 3), s.srgb_decode(np.float64(128 / 255)), np.float32)
    for std in (2.0, 10.0, 25.0):
        out = s.to_uint8(lin, std, np.random.default_rng(1)).astype(np.float64)
        measured = (out - 128).std()
        assert measured == pytest.approx(np.hypot(std, 1 / np.sqrt(12)), rel=0.02)
        assert abs((out - 128).mean()) < 0.2
    assert np.array_equal(s.to_uint8(lin, 0.0), s.to_uint8(lin))
    with pytest.raises(ValueError):
        s.to_uint8(lin, 300.0, np.random.default_rng(0))
    with pytest.raises(ValueError):
        s.to_uint8(lin, 5.0)


def test_same_seed_same_noise():
    lin = np.random.default_rng(0).random((60, 80, 3), dtype=np.float32)
    m = s.SensorModel(noise_std=8.0, full_well_e=2000.0, responsivity_e_per_s=2e5, read_noise_e=3.0, noise=True)
    a = m.apply(lin, np.random.default_rng(42))
    b = m.apply(lin, np.random.default_rng(42))
    c = m.apply(lin, np.random.default_rng(43))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_shot_noise_statistics():
    rng = np.random.default_rng(3)
    for level, fw in ((0.5, 4000.0), (0.02, 4000.0)):  # Gaussian branch and exact Poisson
        x = np.full((300, 300), level * fw, np.float32)
        e = s.shot_read_noise_e(x, rng, read_noise_e=5.0).astype(np.float64)
        assert e.mean() == pytest.approx(level * fw, rel=0.01)
        assert e.var() == pytest.approx(level * fw + 25.0, rel=0.03)


def test_motion_blur():
    img = np.zeros((41, 41), np.float32)
    img[20, 20] = 1.0
    out = s.motion_blur(img, (10.0, 0.0))
    assert out.sum() == pytest.approx(1.0, rel=1e-5)
    assert np.allclose(out[:19], 0) and np.allclose(out[22:], 0)
    cols = np.nonzero(out[20] > 1e-6)[0]
    assert cols.min() >= 14 and cols.max() <= 26 and cols.size >= 9
    xs = np.arange(41)
    assert (out.sum(axis=0) * xs).sum() == pytest.approx(20.0, abs=1e-4)  # centred
    diag = s.motion_blur(img, (6.0, 6.0))
    assert diag.sum() == pytest.approx(1.0, rel=1e-5) and diag[23, 23] > 0 and abs(diag[23, 17]) < 1e-6
    assert np.array_equal(s.motion_blur(img, (0, 0)), img)


def test_distort_points_match_project_points():
    pts3 = np.array([[-1.0, -0.7, 2.0], [0.8, 0.5, 2.5], [0.0, 0.0, 3.0], [-0.3, 0.6, 1.5]])
    ideal, _ = cv2.projectPoints(pts3, np.zeros(3), np.zeros(3), K, np.zeros(5))
    expect, _ = cv2.projectPoints(pts3, np.zeros(3), np.zeros(3), K, np.array(DIST))
    got = s.distort_points(ideal.reshape(-1, 2), K, DIST)
    np.testing.assert_allclose(got, expect.reshape(-1, 2), atol=1e-9)
    back = s.undistort_points(got, K, DIST)
    np.testing.assert_allclose(back, ideal.reshape(-1, 2), atol=1e-5)


def _checker(w, h, square, off, ss=4):
    """Anti-aliased checkerboard in ideal pixel coordinates (corners at off + k*square)."""
    u = (np.arange(w * ss) + 0.5) / ss - 0.5
    v = (np.arange(h * ss) + 0.5) / ss - 0.5
    cu = np.floor((u - off[0]) / square).astype(int)
    cv = np.floor((v - off[1]) / square).astype(int)
    big = ((cu[None, :] + cv[:, None]) % 2).astype(np.float32)
    return big.reshape(h, ss, w, ss).mean(axis=(1, 3))


def test_distorted_image_corners_match_project_points():
    w, h, square, off = 640, 480, 40.0, (20.3, 19.7)
    # slightly blurred so bilinear resampling does not bias cornerSubPix (ideal-image
    # baseline error ~0.03 px)
    img = cv2.GaussianBlur(_checker(w, h, square, off) * 0.8 + 0.1, (0, 0), 1.5)
    dimg = s.distort_image(img, K, DIST)
    # corners of the ideal board, back-projected to 3-D at z = 2 m and projected with dist
    ks = [(i, j) for i in range(2, 15, 3) for j in range(2, 11, 2)]
    ideal = np.array([[off[0] + i * square, off[1] + j * square] for i, j in ks])
    z = 2.0
    pts3 = np.column_stack(
        [(ideal[:, 0] - K[0, 2]) / K[0, 0] * z, (ideal[:, 1] - K[1, 2]) / K[1, 1] * z, np.full(len(ks), z)]
    )
    expect, _ = cv2.projectPoints(pts3, np.zeros(3), np.zeros(3), K, np.array(DIST))
    expect = expect.reshape(-1, 2)
    inside = (expect[:, 0] > 15) & (expect[:, 0] < w - 15) & (expect[:, 1] > 15) & (expect[:, 1] < h - 15)
    assert inside.sum() >= 15
    guess = (expect[inside] + 0.7).astype(np.float32).reshape(-1, 1, 2)
    found = cv2.cornerSubPix(
        (dimg * 255).astype(np.float32),
        guess,
        (7, 7),
        (-1, -1),
        (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4),
    )
    err = np.linalg.norm(found.reshape(-1, 2) - expect[inside], axis=1)
    assert err.max() < 0.1 and err.mean() < 0.07, err
    # and the remap itself: the ideal pixel sampled at the predicted location is p
    mx, my = s.distortion_maps(K, DIST, w, h)
    q = expect.astype(np.float32).reshape(-1, 1, 2)
    px = cv2.remap(mx, q[..., 0], q[..., 1], cv2.INTER_LINEAR).ravel()
    py = cv2.remap(my, q[..., 0], q[..., 1], cv2.INTER_LINEAR).ravel()
    np.testing.assert_allclose(np.column_stack([px, py]), ideal, atol=0.03)


def test_distortion_maps_cached_and_zero_is_identity():
    a = s.distortion_maps(K, DIST, 64, 48)
    b = s.distortion_maps(K.copy(), list(DIST), 64, 48)
    assert a[0] is b[0]
    img = np.random.default_rng(0).random((48, 64, 3)).astype(np.float32)
    np.testing.assert_allclose(s.distort_image(img, K, [0, 0, 0, 0, 0]), img, atol=1e-5)
    with pytest.raises(ValueError):
        s.distortion_maps(K, [0.1, 0.2], 64, 48)


def test_pose_timestamp():
    assert s.pose_timestamp(1.0, 0.25) == pytest.approx(0.75)
    np.testing.assert_allclose(s.pose_timestamp(np.array([0.0, 0.1]), 0.05), [-0.05, 0.05])
    with pytest.raises(ValueError):
        s.pose_timestamp(1.0, -0.1)


def test_sensor_model_pipeline():
    img = np.random.default_rng(0).random((48, 64, 3)).astype(np.float32)
    m = s.SensorModel(noise_std=0.0)
    out = m.apply(img, None, velocity_px=(3.0, 0.0))
    assert out.dtype == np.uint8 and out.shape == img.shape
    assert np.array_equal(s.SensorModel().apply(img), s.to_uint8(img))  # noise-free: the sRGB encode
    with pytest.raises(ValueError):
        s.SensorModel(noise=True).apply(img)  # noise needs a Generator


def test_exact_poisson_only_where_the_read_noise_leaves_the_count_skewed():
    """Poisson(lam) + Normal(0, r) has skewness lam / (lam + r^2)^1.5 (cumulants lam, lam + r^2,
    lam): the Normal stand-in is used where that is below 1/sqrt(20), as for the shot noise alone
    above 20 e-. With the default 2.3 e- no pixel needs the exact draw; with 1 e- the low counts do,
    and those draws keep the Poisson's skew."""
    lam = np.linspace(0.0, 30.0, 3001, dtype=np.float32)
    assert s._exact_poisson(lam, 0.0).tolist() == np.flatnonzero(lam < 20).tolist()
    assert s._exact_poisson(lam, 2.3).size == 0
    skew = lam.astype(np.float64) / (lam.astype(np.float64) + 1.0) ** 1.5
    want = np.flatnonzero((skew >= 20**-0.5) & (lam < 20))
    got = s._exact_poisson(lam, 1.0)
    assert want.size > 0 and abs(got.size - want.size) <= 2 and set(got) <= set(range(lam.size))
    rng = np.random.default_rng(3)
    x = np.full(400_000, 2.0, np.float32)  # skew 2 / 3^1.5 = 0.385 with r = 1
    e = s.shot_read_noise_e(x, rng, read_noise_e=1.0).astype(np.float64)
    z = (e - e.mean()) / e.std()
    assert e.mean() == pytest.approx(2.0, abs=0.01) and e.var() == pytest.approx(3.0, rel=0.02)
    assert (z**3).mean() == pytest.approx(2.0 / 3.0**1.5, abs=0.03)


@pytest.mark.parametrize("dark", [0.0, 3.0])
@pytest.mark.parametrize("bloom", [0.0, 0.05])
@pytest.mark.parametrize("read", [2.3, 1.8, 40.0])
def test_fused_sensor_pass_is_bit_identical_to_the_numpy_chain(dark, bloom, read):
    """The compiled pass (sensor_kernels) gives the very numbers of electrons() x gain, clipped at
    1, from the same Generator state: dark, saturated, negative, NaN and infinite radiance,
    blooming on and off, read noise from just above the exact-draw threshold to large."""
    model = s.SensorModel(
        exposure_s=0.002,
        responsivity_e_per_s=2.23e6,
        full_well_e=10500.0,
        read_noise_e=read,
        noise=True,
        bloom_fraction=bloom,
        dark_current_e_per_s=dark,
    )
    assert s._no_exact_draws(read)
    x = np.random.default_rng(1).gamma(0.5, 0.2, (60, 80, 3)).astype(np.float32)
    x[10:14, 20:26] = 400.0  # an LED far beyond the full well (bloom, cap at 4 wells)
    x[0, :5] = np.array([np.nan, -1.0, np.inf, 0.0, -0.0])[:, None]
    x[1, :3] = np.array([1e-9, 1e30, 3e-4])[:, None]
    want = model.electrons(x, np.random.default_rng(7)) * np.float32(model.K / s.DN_MAX)
    np.minimum(want, np.float32(1.0), out=want)
    got = model._signal_fused(x, np.random.default_rng(7))
    np.testing.assert_array_equal(got, want)
    # and the whole apply(): the same 8-bit image either way
    assert np.array_equal(
        model.apply(x, np.random.default_rng(3)),
        s.srgb_lut.encode_uint8(
            np.minimum(model.electrons(x, np.random.default_rng(3)) * np.float32(model.K / s.DN_MAX), np.float32(1.0)),
            s.srgb_encode,
        ),
    )


def test_the_fused_pass_is_not_used_where_exact_poisson_draws_are_needed():
    assert not s._no_exact_draws(0.0) and not s._no_exact_draws(1.0)
    model = s.SensorModel(read_noise_e=0.0, noise=True, exposure_s=1e-6, responsivity_e_per_s=1e6)
    dim = np.full((40, 40, 3), 2.0, np.float32)  # 2 electrons: exact Poisson counts, integers
    img = model.electrons(dim, np.random.default_rng(0))
    assert np.all(img == np.round(img))
