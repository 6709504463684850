"""Real waters: the article's labels as Jerlov types in physical mode, turbidity readings, the
contrast-threshold prediction, the depth definition and the turbidity ladder's config."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from blendgen.config.models import Dock, Experiment, Water
from blendgen.physics.water import optics, turbidity, visibility
from blendgen.physics.water import presets as wp
from blendgen.vehicle import trajectories as tj

# Band-mean beam attenuation c (1/m, R/G/B) of the Jerlov types, summed by hand from the
# source spectra (docs/waters.md: Solonenko & Mobley 2015 a + b at the channel wavelengths).
JERLOV_C = {
    "I": (0.29, 0.06, 0.02),
    "IB": (0.33, 0.11, 0.09),
    "II": (0.575, 0.427, 0.505),
    "1C": (0.588, 0.452, 0.582),
    "9C": (2.94, 3.64, 5.03),
}


def test_article_levels_are_the_jerlov_types_of_nearest_c():
    # mild: IB is 0.65 from grey 0.2 in RMS ln c, II 0.92; moderate: II 0.12, 1C 0.14 (hand sums
    # on the table above: ln(0.575/.5), ln(.427/.5), ln(.505/.5) -> RMS 0.122)
    assert wp.nearest_jerlov_type(0.5) == ("II", pytest.approx(0.122, abs=2e-3))
    assert wp.nearest_jerlov_type(0.2)[0] == "IB"
    assert wp.ARTICLE_JERLOV == {"clear": "I", "mild": "IB", "moderate": "II"}
    for label, t in wp.ARTICLE_JERLOV.items():
        w = optics.water_for_mode(Water(preset=label), "physical")
        np.testing.assert_allclose(w.c, JERLOV_C[t], atol=0.006)
        assert f"jerlov_{t}" in w.provenance
        np.testing.assert_allclose(
            optics.water_for_mode(Water(preset=label), "article").c, wp.ARTICLE_BETAS[label]
        )  # article mode keeps the grey beta


def test_red_reference_led_fades_as_in_real_water():
    """Over 10 m, Jerlov I (physical clear) keeps exp(-0.29 * 10) = 5.5 % of red, the article's
    clear all of it; moderate (II) keeps exp(-5.75) = 0.3 % of red, more green."""
    r = np.array([[10.0]])
    clear = optics.transmittance(optics.water_for_mode(Water(preset="clear"), "physical"), r)[0, 0]
    assert clear[0] == pytest.approx(math.exp(-2.87), rel=0.02) and clear[0] < 0.06
    assert optics.transmittance(optics.water_for_mode(Water(preset="clear"), "article"), r)[0, 0, 0] == 1.0
    mod = optics.transmittance(optics.water_for_mode(Water(preset="moderate"), "physical"), r)[0, 0]
    assert mod[0] < mod[1] and mod[0] == pytest.approx(math.exp(-5.75), rel=0.05)


def test_secchi_reading_follows_tyler():
    """(c + Kd)_G Z_SD = 8.7 (Tyler 1968); a Secchi depth that a ladder type itself gives
    (3C: 8.7 / (1.185 + 0.195) = 6.30 m) gives that type's water."""
    for z in (2.5, 5.0, 20.0):
        w = optics.reading_water("secchi_m", z)
        assert (w.c[1] + w.Kd[1]) * z == pytest.approx(8.7, rel=1e-6)
    c3 = wp.jerlov_coefficients("3C")
    z3 = 8.7 / (c3["sigma_a"][1] + c3["sigma_s"][1] + c3["Kd"][1])
    assert z3 == pytest.approx(6.30, abs=0.02)
    w = optics.reading_water("secchi_m", z3)
    np.testing.assert_allclose(w.sigma_s, c3["sigma_s"], rtol=1e-3)
    np.testing.assert_allclose(w.Kd, c3["Kd"], rtol=1e-3)
    assert w.c[0] < w.c[2]  # coastal: blue attenuated most


def test_ntu_reading_follows_kirk_and_names_its_neighbours():
    w = optics.reading_water("ntu", 1.0)
    assert w.sigma_s[1] == pytest.approx(1.0, rel=1e-6)  # b_G = 1.0 x NTU (Kirk 1994)
    assert "between Jerlov 1C and 3C" in w.provenance
    spec = Water(ntu=1.0)
    assert spec.preset == "jerlov_1C" and not spec.is_bare
    np.testing.assert_allclose(optics.water_for_mode(spec, "physical").c, w.c)
    lo, hi = turbidity.reading_range("ntu")
    assert hi == pytest.approx(3.25, abs=0.01)  # Jerlov 9C's b_G


def test_duntley_contrast_and_threshold_range():
    """Against the water itself, C(r) = C0 exp(-c r): C0 = 100, c = 0.5, C_t = 0.02 ->
    r = ln(5000) / 0.5 = 17.03 m."""
    L_inf = np.array([1.0, 1.0, 1.0])
    r = np.array([0.0, 2.0])
    C = visibility.apparent_contrast(101.0 * L_inf, L_inf, L_inf, [0.5] * 3, r)
    np.testing.assert_allclose(C[:, 0], 100.0 * np.exp(-0.5 * r))
    grid = np.arange(0.01, 40.0, 0.001)
    C = visibility.apparent_contrast(np.broadcast_to(101.0 * L_inf, (len(grid), 3)), L_inf, L_inf, [0.5] * 3, grid)
    assert visibility.visible_range_m(C, grid) == pytest.approx(math.log(5000) / 0.5, abs=2e-3)


def test_unresolved_led_dims_with_range_squared():
    """An LED smaller than a pixel: its pixel's excess radiance falls as 1/r^2 on top of
    exp(-c r), so in clear water (c -> 0) the range is where pi rho^2 f^2 / r^2 x L / L_bg = C_t."""
    rho, f, I = 0.04, 500.0, 0.1
    L_led = I / (math.pi * rho**2)
    L_bg = np.array([0.1, 0.1, 0.1])
    r = visibility.led_range_m([I, I, I], rho, L_bg, L_bg, [1e-9] * 3, f)
    expect = math.sqrt(math.pi * rho**2 * f**2 * (L_led - 0.1) / (0.02 * 0.1))
    assert r == pytest.approx(min(expect, visibility.RANGE_GRID_M[-1]), abs=0.02)


def test_depth_is_the_dock_top_below_the_surface():
    for depth in (0.0, 1.0, 5.0):
        dock = Dock(water_depth_m=depth)
        T = tj.T_world_dock_from_spec(dock)
        top = (np.c_[tj.dock_corners(dock), np.ones(8)] @ T.T)[:, 2].max()
        assert top == pytest.approx(-depth)
        assert T[2, 3] == pytest.approx(-depth - 0.5)  # 1 m face: centre 0.5 m below the top


def _exp(**kw) -> Experiment:
    return Experiment.model_validate({"name": "w", "trajectories": [{"kind": "linear"}], **kw})


def test_manifest_records_the_water_used():
    from blendgen.pipeline.plan import condition_post

    exp = _exp(image_formation="physical", conditions=[{"label": "m", "water": {"preset": "mild"}}])
    eff = condition_post(exp, exp.conditions[0], 0).water_effective
    assert eff["preset"] == "jerlov_IB" and eff["name"] == "mild"
    np.testing.assert_allclose(eff["c"], JERLOV_C["IB"], atol=0.006)
    art = condition_post(
        _exp(image_formation="article", conditions=exp.model_dump()["conditions"]), exp.conditions[0], 0
    ).water_effective
    assert art["preset"] == "mild" and art["c"] == pytest.approx([0.2] * 3)


def test_turbidity_ladder_is_reachable_and_spans_I_to_9C():
    from blendgen.tools.apps import reproduce, water_ladder

    exp = reproduce.experiment("turbidity_ladder", 2)
    assert exp.image_formation == "physical" and exp.trials == 2
    labels = [c.label for c in exp.conditions]
    assert labels[0] == "jerlov_I" and labels[-1] == "jerlov_9C"
    assert "aruco" in reproduce.localizers_of(("turbidity_ladder",))
    led = [water_ladder.predict(exp, c)["led"] for c in exp.conditions]
    assert all(a > b for a, b in zip(led, led[1:]))  # more turbid, shorter range
    assert led[-1] < 10.0 < led[1]  # 9C: the array at 10 m is gone
    m = pd.DataFrame({"localizer": ["led"] * len(labels), "condition": labels, "max_range_m": [8.0] * len(labels)})
    table = water_ladder.ladder_table(exp, m)
    assert "| jerlov_9C |" in table and "/ 8.0" in table


def test_physical_depth_experiment_puts_the_dock_at_the_deepest_condition():
    """reproduce depth --mode physical: the dock's top 5 m deep, the 0 m condition's surface at
    the dock's top, every condition's surface inside the pool's walls (z <= 0)."""
    from blendgen.pipeline.plan import condition_post
    from blendgen.tools.apps import reproduce

    exp = reproduce.experiment("depth", 1, "physical")
    assert exp.scene.dock.water_depth_m == 5.0
    top = tj.T_world_dock_from_spec(exp.scene.dock)[2, 3] + tj.dock_top_m(exp.scene.dock)
    surfaces = {c.label: condition_post(exp, c, 0).surface_z_m for c in exp.conditions}
    assert surfaces["depth_0m"] == pytest.approx(top) and surfaces["depth_5m"] == pytest.approx(0.0)
    assert reproduce.experiment("depth", 1, "article").scene.dock.water_depth_m == 1.0


def test_closed_loop_refuses_a_start_box_out_of_the_water(tmp_path):
    from blendgen.config.models import ConfigError
    from blendgen.tools.apps.closed_loop import Bench

    exp = _exp(trajectories=[{"kind": "docking", "id": "d", "start": {"vertical_m": 5}}])
    with pytest.raises(
        ConfigError,
        match=r"trajectories\[0\]\.start\.vertical_m: 5.0 puts a start 3.50 m above "
        r"the water surface \('d'\); allowed vertical_m <= 1.50",
    ):
        Bench.prepare(exp, tmp_path / "assets")
    assert not (tmp_path / "assets").exists()
