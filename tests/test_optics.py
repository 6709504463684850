"""Water optics: presets, config validation, fast model, analytic oracles (docs/water.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from blendgen.config.models import Water
from blendgen.physics.water import optics as o


def _water(c, B=(0.1, 0.3, 0.25), Kd=(0.3, 0.1, 0.05), albedo=0.5):
    c = np.broadcast_to(np.asarray(c, float), (3,))
    return o.WaterOptics(name="t", sigma_a=(1 - albedo) * c, sigma_s=albedo * c, Kd=Kd, B_inf=B, g=0.9)


def _cfg(**kw):
    return o.water_optics(Water(**kw))


def _scene(dtype=np.float32, h=24, w=32, seed=0):
    rng = np.random.default_rng(seed)
    J = rng.random((h, w, 3)).astype(dtype)
    r = (rng.random((h, w)) * 20).astype(dtype)
    r[0, :5] = np.inf
    r[1, :3] = 0.0
    r[2, :3] = 1e4
    return J, r


# --------------------------------------------------------------------------- oracles


def test_jerlov_type_I_kd_oracle():
    w = o.get_preset("jerlov_I")
    np.testing.assert_allclose(np.exp(-10.0 * w.Kd), [0.0498, 0.589, 0.831], rtol=0.01)


def test_jerlov_kd_table_matches_optics_md():
    table = {
        "I": (0.300, 0.053, 0.018),
        "II": (0.332, 0.082, 0.065),
        "III": (0.372, 0.118, 0.126),
        "1C": (0.373, 0.125, 0.210),
        "5C": (0.473, 0.305, 0.495),
        "9C": (0.670, 0.705, 1.415),
    }
    for t, kd in table.items():
        np.testing.assert_allclose(o.get_preset(f"jerlov_{t}").Kd, kd, rtol=0.03, atol=0.001)


def test_all_presets_valid():
    for name in o.PRESETS:
        w = o.get_preset(name)
        assert np.all(np.isfinite(w.c)) and np.all(w.c >= 0)
        assert np.all(w.B_inf >= 0) and -1 < w.g < 1
        assert w.to_dict()["name"] == name


def test_article_presets_mapping():
    for name, beta in (("clear", 0.0), ("mild", 0.2), ("moderate", 0.5)):
        w = o.get_preset(name)
        np.testing.assert_allclose(w.c, beta, atol=1e-12)
        np.testing.assert_allclose(w.Kd, 0.2)
    w = o.get_preset("moderate")
    # albedo proportional to the water colour, max 0.8
    np.testing.assert_allclose(w.albedo, 0.8 * w.B_inf / w.B_inf.max())


@pytest.mark.parametrize("g, expected", [(0.0, (0.0286, 0.0912, 0.1103)), (0.9, (0.00223, 0.00711, 0.00860))])
def test_single_scatter_oracle4(g, expected):
    L = o.single_scatter_backscatter([0.35, 0.07, 0.03], 0.2, g=g, E=3.0, depth_m=2.0, range_m=8.0)
    np.testing.assert_allclose(L, expected, rtol=0.02)


def test_single_scatter_limits():
    sa, ss = [0.35, 0.07, 0.03], 0.2
    inf = o.single_scatter_backscatter(sa, ss, 0.5, 1.0, 0.0, np.inf)
    far = o.single_scatter_backscatter(sa, ss, 0.5, 1.0, 0.0, 1e4)
    np.testing.assert_allclose(inf, far)
    assert np.all(o.single_scatter_backscatter(sa, ss, 0.5, 1.0, 0.0, 0.0) == 0)
    zero = o.single_scatter_backscatter(0, 0, 0.5, 1.0, 0.0, [0, 1, np.inf])
    assert zero.shape == (3, 3) and np.all(zero == 0)


def test_phase_functions_normalised():
    th = np.concatenate([np.geomspace(1e-7, 1e-2, 20000), np.linspace(1e-2, np.pi, 200000)])
    th = np.unique(th)
    for g in (0.0, 0.5, 0.9):
        p = o.hg_phase(np.cos(th), g)
        assert np.trapezoid(2 * np.pi * np.sin(th) * p, th) == pytest.approx(1.0, abs=2e-3)
    p = o.ff_phase(th, 1.1, 0.0183)
    m = 2 * np.pi * np.sin(th) * p
    assert np.trapezoid(m, th) == pytest.approx(1.0, abs=3e-3)
    back = th >= np.pi / 2
    assert np.trapezoid(m[back], th[back]) == pytest.approx(0.0183, rel=1e-3)
    # Petzold average particle: n = 1.10, mu = 3.5835 (nu = -0.29)
    assert o.ff_nu(1.1, 0.0183) == pytest.approx((3 - 3.5835) / 2, abs=2e-3)


# --------------------------------------------------------------------------- config


def test_config_preset_and_overrides():
    assert _cfg(preset="mild").name == "mild"
    w = _cfg(preset="mild", k=0.7)
    np.testing.assert_allclose(w.Kd, 0.7)
    np.testing.assert_allclose(w.c, 0.2)
    w = _cfg(preset="Jerlov II")
    assert w.name == "jerlov_II"
    w = _cfg(sigma_a=[0.1, 0.05, 0.02], sigma_s=0.2, g=0.8, B_inf=[0.01, 0.02, 0.03], Kd=[0.3, 0.1, 0.05])
    np.testing.assert_allclose(w.c, [0.3, 0.25, 0.22])
    assert w.g == 0.8 and w.name == "clear+custom"
    w = _cfg(beta=[0.1, 0.2, 0.3], water_color=[0.1, 0.5, 0.4])
    np.testing.assert_allclose(w.c, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(w.B_inf, [0.1, 0.5, 0.4])
    assert _cfg(preset="clear").is_clear
    for name in ("jerlov_1C", "mild"):  # to_dict round-trips
        w0 = o.get_preset(name)
        assert o.WaterOptics(**w0.to_dict()).to_dict() == w0.to_dict()


@pytest.mark.parametrize(
    "cfg, fragment",
    [
        ({"preset": "murky"}, "unknown water preset"),
        ({"sigma_a": [6, 0, 0]}, "less than or equal to 5"),
        ({"sigma_s": -0.1}, "greater than or equal to 0"),
        ({"g": 1.0}, "less than 1"),
        ({"g": -1.0}, "greater than -1"),
        ({"beta": float("nan")}, "finite number"),
        ({"water_color": [0, 2, 0]}, "less than or equal to 1"),
        ({"sigma_s": [1, 2]}, "at least 3 items"),
        ({"colour": 1}, "Extra inputs are not permitted"),
        ({"k": 0.1, "Kd": 0.1}, "not both"),
        ({"preset": "jerlov_II", "beta": 0.1}, "article presets"),
        ({"model": "article"}, "Extra inputs are not permitted"),  # the mode is image_formation now
        ({"calibrated": "maybe"}, "valid boolean"),
    ],
)
def test_config_errors(cfg, fragment):
    with pytest.raises(ValidationError) as e:
        Water(**cfg)
    assert fragment in str(e.value)


# --------------------------------------------------------------------------- fast model


def test_beer_lambert_exact():
    J, r = _scene(np.float64)
    w = _water([0.4, 0.2, 0.1])
    depth = 3.0
    out = o.apply_water(J, r, None, w, depth)
    D = np.exp(-w.Kd * depth)
    t = np.exp(-w.c * r[..., None])
    expected = J * D * t + w.B_inf * D * (1 - t)
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(out[0, :5], np.broadcast_to(w.B_inf * D, (5, 3)))
    out32 = o.apply_water(J.astype(np.float32), r.astype(np.float32), None, w, depth)
    assert out32.dtype == np.float32
    np.testing.assert_allclose(out32, expected, rtol=2e-5, atol=1e-6)


def test_article_form_and_emissive():
    J, r = _scene(np.float64)
    w = o.get_preset("moderate")
    em = np.zeros(r.shape, bool)
    em[5:8, 5:8] = True
    depth = 4.0
    out = o.apply_water(J, r, em, w, depth, model="article")
    wgt = 1 - np.exp(-0.5 * r[..., None])
    expected = ((1 - wgt) * J + wgt * w.B_inf) * math.exp(-0.2 * depth)  # every pixel, LEDs too
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)
    phys = o.apply_water(J, r, em, w, depth, model="physical")
    np.testing.assert_allclose(phys[0, :5], np.broadcast_to(w.B_inf * math.exp(-0.8), (5, 3)))
    t = np.exp(-0.5 * r[5:8, 5:8, None])  # emitters: only their own path
    np.testing.assert_allclose(phys[5:8, 5:8], J[5:8, 5:8] * t + w.B_inf * math.exp(-0.8) * (1 - t))


def test_per_pixel_depth_and_irradiance():
    J, r = _scene(np.float64)
    w = _water([0.3, 0.2, 0.1])
    depth = np.linspace(0, 5, r.size).reshape(r.shape)
    out = o.apply_water(J, r, None, w, depth, irradiance=3.0, veil_depth_m=2.0)
    D = np.exp(-w.Kd * depth[..., None])
    t = np.exp(-w.c * r[..., None])
    veil = 3.0 * w.B_inf * np.exp(-w.Kd * 2.0)  # the veil dims with the camera's depth
    np.testing.assert_allclose(out, J * D * t + veil * (1 - t), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_beta_zero_identity(dtype):
    J, r = _scene(dtype)
    for w in (o.get_preset("clear"), _water(0.0)):
        out = o.apply_water(J, r, None, w, 0.0)
        assert out.dtype == dtype
        np.testing.assert_array_equal(out, J)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("beta", [0.0, 1e-6, 0.2, 1.5, 5.0])
@pytest.mark.parametrize("depth", [0.0, 10.0, 1000.0])
def test_extremes_finite_and_bounded(dtype, beta, depth):
    J, r = _scene(dtype)
    J[3, :4] = [[0, 0, 0], [1, 1, 1], [0, 1, 0], [1, 0, 1]]
    w = _water(beta, B=(0.0, 1.0, 0.5))
    em = np.zeros(r.shape, bool)
    em[4, :4] = True
    for model in o.MODELS:
        out = o.apply_water(J, r, em, w, depth, model=model)
        assert out.dtype == dtype and np.all(np.isfinite(out))
        eps = 4 * np.finfo(dtype).eps
        assert out.min() >= 0 and out.max() <= 1 + eps
        upper = np.maximum(J, w.B_inf)
        assert np.all(out <= upper * (1 + eps) + eps)


def test_nan_and_negative_range():
    J, r = _scene()
    r[5, 5] = np.nan
    r[6, 6] = -3.0
    w = _water(0.5)
    out = o.apply_water(J, r, None, w, 0.0)
    np.testing.assert_allclose(out[5, 5], w.B_inf, rtol=1e-6)  # NaN: no surface
    np.testing.assert_allclose(out[6, 6], J[6, 6], rtol=1e-6)  # negative: range 0


def test_input_validation():
    J, r = _scene()
    with pytest.raises(ValueError):
        o.apply_water(J[..., :2], r, None, _water(0.1))
    with pytest.raises(ValueError):
        o.apply_water(J, r[:-1], None, _water(0.1))
    with pytest.raises(ValueError):
        o.apply_water(J, r, None, _water(0.1), depth_m=-1.0)


@settings(max_examples=40, deadline=None)
@given(
    b1=st.floats(0, 5),
    b2=st.floats(0, 5),
    r1=st.floats(0, 1e4),
    r2=st.floats(0, 1e4),
    j=st.floats(0, 1),
    bi=st.floats(0, 1),
)
def test_monotone_in_beta_and_range(b1, b2, r1, r2, j, bi):
    """Output moves monotonically from J toward B as beta or range grows."""
    (b_lo, b_hi), (r_lo, r_hi) = sorted((b1, b2)), sorted((r1, r2))
    J = np.full((1, 1, 3), j)
    B = (bi, bi, bi)

    def f(beta, rng):
        return o.apply_water(J, np.full((1, 1), rng), None, _water(beta, B=B), 0.0)[0, 0, 0]

    def between(a, b, x):
        return min(a, b) - 1e-12 <= x <= max(a, b) + 1e-12

    for r_ in (r_lo, r_hi):
        lo, hi = f(b_lo, r_), f(b_hi, r_)
        assert between(j, bi, lo) and between(j, bi, hi)
        assert abs(hi - bi) <= abs(lo - bi) + 1e-12  # closer to B with more beta
    lo, hi = f(b_hi, r_lo), f(b_hi, r_hi)
    assert abs(hi - bi) <= abs(lo - bi) + 1e-12  # closer to B with more range


def test_forward_scatter_blur():
    h, w = 64, 64
    J = np.zeros((h, w, 3), np.float32)
    J[32, 32] = 1.0
    J[10, 10] = 1.0
    r = np.full((h, w), 2.0, np.float32)
    r[:20, :20] = 0.0  # near pixel: unblurred
    wat = _water(0.5, B=(0, 0, 0), albedo=1.0)
    sharp = o.apply_water(J, r, None, wat, 0.0)
    soft = o.apply_water(J, r, None, wat, 0.0, blur=True, blur_px_per_tau=2.0, blur_max_px=3.0)
    assert soft[32, 32, 0] < 0.5 * sharp[32, 32, 0]  # sigma = 2 px: spread
    assert soft[32, 30:35, 0].sum() > soft[32, 32, 0]
    assert soft[10, 10, 0] == pytest.approx(sharp[10, 10, 0], rel=1e-6)
    # energy (roughly) conserved away from the level seams
    assert soft[24:41, 24:41].sum() == pytest.approx(sharp[24:41, 24:41].sum(), rel=0.02)
    assert np.all(np.isfinite(soft))
    f64 = o.apply_water(J.astype(np.float64), r, None, wat, 0.0, blur=True)
    assert f64.dtype == np.float64
