"""Fast caustics against the Cycles photon-map reference (``blendgen/blender/caustic_reference.py``).

Oracles: the reference's mean irradiance is the Fresnel transmittance at normal incidence
``1 - ((n-1)/(n+1))^2 = 0.980`` in clear water (energy: every refracted sun ray lands);
its contrast falls with depth beyond the focal zone in turbid water (Maritorena et al. 2000);
the fast pattern (all sheets of the folded ray map summed, ``physics/surface/caustic_map.py``) matches it
before and beyond the first focus (correlation) and its contrast stays within the stated error
(README of ``bench caustics``: +-35 %)."""

from __future__ import annotations

import pytest

from blendgen.tools.bench import caustic_bench as cb

N = 1.333


def _row(tmp_path, water, depth, size, renders):
    w = cb.water_of(water)
    spec = cb.reference_spec(depth, w, size, renders)
    return cb.compare(cb.run_reference(spec, tmp_path / f"{water}-{depth}.npz"), spec, w)


@pytest.mark.blender
def test_clear_water_reference_conserves_energy_and_fast_pattern_matches(tmp_path):
    """No medium, floor 1 m down (before the first focus): reference mean E = Fresnel
    transmittance (1 %), fast contrast within 25 % of it, patterns correlated > 0.9."""
    r = _row(tmp_path, None, 1.0, 768, 2)
    assert r["meanE_ref"] == pytest.approx(1 - ((N - 1) / (N + 1)) ** 2, abs=0.01)
    assert r["contrast_ref"] > 2 * r["noise_contrast_ref"]  # the pattern is resolved
    assert abs(r["contrast_fast"] / r["contrast_ref"] - 1) < 0.25, r
    assert r["corr"] > 0.9, r


@pytest.mark.blender
def test_beyond_the_first_focus_the_fast_network_is_the_references(tmp_path):
    """No medium, floor 4 m down (the waves' first focus is near 2.5 m: the ray map has folded):
    the same network, pixel for pixel (correlation > 0.9 once the reference's photon noise is
    divided out), the same cell size (10 %) and contrast (15 %). The single-preimage factor
    this replaced had correlation 0.56 and cells 30 % too small here."""
    r = _row(tmp_path, None, 4.0, 768, 2)
    assert r["contrast_ref"] > 3 * r["noise_contrast_ref"]
    assert r["corr_noise_free"] > 0.9, r
    assert r["cell_m_fast"] == pytest.approx(r["cell_m_ref"], rel=0.10), r
    assert abs(r["contrast_fast"] / r["contrast_ref"] - 1) < 0.15, r


@pytest.mark.slow
@pytest.mark.blender
def test_turbid_reference_contrast_falls_with_depth_and_fast_follows(tmp_path):
    """Jerlov 1C (green: b = 0.38 1/m, g = 0.914): reference contrast at 6 m below that at
    2 m; fast contrast within 35 % of the reference at both; mean irradiance within 25 % of
    the fast path's exp(-Kd h)."""
    shallow, deep = (_row(tmp_path, "1C", h, 768, 2) for h in (2.0, 6.0))
    assert deep["contrast_ref"] < shallow["contrast_ref"]
    assert deep["contrast_fast"] < shallow["contrast_fast"]
    for r in (shallow, deep):
        assert abs(r["contrast_fast"] / r["contrast_ref"] - 1) < 0.35, r
        assert r["meanE_ref"] == pytest.approx(r["meanE_fast"], rel=0.25), r


@pytest.mark.blender
def test_oblique_sun_reference_energy_and_fast_pattern(tmp_path):
    """Sun 20 deg from the zenith, no medium, floor 1 m down: the reference's mean irradiance on
    the floor is the Fresnel transmittance at 20 deg times cos 20 deg (the beam's footprint on
    any horizontal plane is the same in air and in water), and the fast pattern, evaluated at
    each point's upstream surface crossing with the slant beam path, matches it (contrast within
    25 %, correlation > 0.9)."""
    import math

    import numpy as np

    from blendgen.physics.surface.optics import fresnel_reflectance

    w = cb.water_of(None)
    spec = cb.reference_spec(1.0, w, 768, 2, sun_zenith_deg=20.0)
    r = cb.compare(cb.run_reference(spec, tmp_path / "oblique.npz"), spec, w)
    cos_i = math.cos(math.radians(20.0))
    transmitted = 1.0 - float(fresnel_reflectance(np.array([cos_i]), 1.0, N)[0])
    assert r["meanE_ref"] == pytest.approx(transmitted * cos_i, abs=0.01), r
    assert r["contrast_ref"] > 2 * r["noise_contrast_ref"]
    assert abs(r["contrast_fast"] / r["contrast_ref"] - 1) < 0.25, r
    assert r["corr"] > 0.9, r
