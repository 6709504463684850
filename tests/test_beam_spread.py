"""Beam spread of a lamp in forward-scattering water (physics/light/beam_spread.py): the Hankel
convolutions against a Monte Carlo of the same photons, energy conservation, limits, the table
lookup, and zero cost when F = 0."""

import functools
import math

import numpy as np
import pytest

from blendgen.physics.light import beam_spread as bs
from blendgen.physics.light import lamp_water
from blendgen.physics.light.sources import PointLight
from blendgen.physics.water import optics

AXIS = np.array([0.0, 0.0, 1.0])


def _lamp(half_deg=30.0, edge_deg=5.0):
    return PointLight(np.zeros(3), AXIS, np.ones(3), math.radians(half_deg), math.radians(edge_deg))


def _planar_energy(f, psi):
    return np.trapezoid(f * 2 * math.pi * psi, psi)


def _monte_carlo(lamp, g, F, n, samples=400_000, seed=3):
    """Planar angles (samples,) from the lamp: a direction drawn from the profile (rejection, in
    the plane), then n deflections theta (the lobe's inverse CDF) at uniform azimuth, each
    scaled by (1 - s/d), s uniform."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.random(samples * 3)) * lamp.half_angle_rad
    r = r[rng.random(r.size) < lamp.profile(np.cos(r))][:samples]
    phi = rng.random(r.size) * 2 * math.pi
    x, y = r * np.cos(phi), r * np.sin(phi)
    theta, w = bs._lobe(functools.partial(optics.hg_phase, g=g), F)
    cdf = np.cumsum(w)
    for _ in range(n):
        t = theta[np.minimum(np.searchsorted(cdf, rng.random(r.size)), theta.size - 1)] * rng.random(r.size)
        a = rng.random(r.size) * 2 * math.pi
        x, y = x + t * np.cos(a), y + t * np.sin(a)
    return np.hypot(x, y)


@pytest.mark.parametrize("n", [1, 3])
def test_spread_profiles_match_a_monte_carlo_of_the_same_photons(n):
    """P_n from the Hankel products vs a histogram of Monte Carlo photons (independent: direct
    sampling of the lobe, no transforms): radial density within 0.03 of the on-axis level
    (MC noise ~0.01) over 0-60 deg, and both put light past the 30-deg cone."""
    lamp = _lamp()
    prof = bs.spread_profiles(bs.light_key(lamp), ("hg", 0.9), 0.85, 4)[n - 1]
    psi = bs.psis()
    rho = _monte_carlo(lamp, 0.9, 0.85, n)
    edges = np.radians(np.arange(0.0, 62.0, 2.0))
    counts, _ = np.histogram(rho, edges)
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    total = _planar_energy(lamp.profile(np.cos(psi)), psi)
    mc = counts / rho.size / area * total  # same normalisation: energy of P
    mid = 0.5 * (edges[1:] + edges[:-1])
    hk = np.interp(mid, psi, prof)
    assert np.max(np.abs(mc - hk)) < 0.03, np.round(np.c_[np.degrees(mid), mc, hk], 3)
    assert hk[mid > math.radians(34)].max() > 0.02


def test_spread_conserves_the_beams_energy():
    """Each P_n carries the profile's energy (planar) within 0.5 %; the table at distance d
    carries exp(-c' d) of it (the Poisson sum), per channel, within 1 %."""
    lamp, psi = _lamp(), bs.psis()
    e0 = _planar_energy(lamp.profile(np.cos(psi)), psi)
    prof = bs.spread_profiles(bs.light_key(lamp), ("hg", 0.9), 0.85, 64)
    for n in (1, 8, 64):
        assert _planar_energy(prof[n - 1], psi) == pytest.approx(e0, rel=0.005)
    w = optics.get_preset("moderate")
    table = bs.beam_table(lamp, w.c, w.sigma_s, 0.85, ("hg", 0.9))
    c_lamp = lamp_water.lamp_attenuation(w, 0.85)
    for i in (0, 200, 350):
        d = bs.distances()[i]
        for ch in range(3):
            assert _planar_energy(table[i, :, ch], psi) == pytest.approx(e0 * math.exp(-c_lamp[ch] * d), rel=0.01)


def test_a_narrow_lobe_keeps_the_profile():
    """g = 0.999: the lobe holding 85 % of the light is a fraction of a degree wide, so one event
    barely moves the light: P_1 is the profile, within 0.5 % inside the cone (25 deg) and within
    the 2-deg taper's blur across the 5-deg edge."""
    lamp, psi = _lamp(), bs.psis()
    prof = bs.spread_profiles(bs.light_key(lamp), ("hg", 0.999), 0.85, 1)[0]
    sharp = lamp.profile(np.cos(psi))
    inner = psi < math.radians(22.0)
    assert np.max(np.abs(prof - sharp)[inner]) < 0.005
    assert np.max(np.abs(prof - sharp)) < 0.15


def test_lookup_reads_the_table():
    """At grid nodes the lookup returns the table; between distance nodes it is linear."""
    lamp = _lamp()
    w = optics.get_preset("mild")
    table = bs.beam_table(lamp, w.c, w.sigma_s, 0.85, ("hg", 0.9))
    j, i = np.array([[0, 40, 100]]), np.array([[10, 300, 500]])
    got = bs.lookup(table, np.cos(bs.psis()[j]), bs.distances()[i])
    np.testing.assert_allclose(got, table[i, j], rtol=2e-3, atol=1e-6)
    d_mid = np.sqrt(bs.distances()[300] * bs.distances()[301])
    mid = bs.lookup(table, np.cos(bs.psis()[[[0]]]), np.array([[d_mid]]))[0, 0]
    np.testing.assert_allclose(mid, 0.5 * (table[300, 0] + table[301, 0]), rtol=2e-3)


def test_no_forward_scattering_no_spread_no_tables():
    """F = 0 (single scattering) or clear water: no tables are built and the beam is the sharp
    profile times exp(-c d)."""
    lamp = _lamp()
    for water, F in ((optics.get_preset("moderate"), 0.0), (optics.get_preset("clear"), 0.85)):
        m = lamp_water.LampWater.build([lamp], water, F)
        if not np.any(water.sigma_s > 0):
            assert not m.spread and m.tables == ()
        if F == 0.0:
            assert not m.spread and m.tables == ()
            cos_psi, d = np.cos(np.radians([[0.0, 29.0, 40.0]])), np.array([[1.0, 2.0, 3.0]])
            np.testing.assert_allclose(
                m.beam(lamp, cos_psi, d), lamp.profile(cos_psi)[..., None] * np.exp(-d[..., None] * water.c)
            )


def test_beam_beyond_the_table_keeps_attenuating():
    """Past D_MAX the beam goes on falling as exp(-c' d) (the table's last row, then attenuated)."""
    w = optics.get_preset("mild")
    lamp = _lamp()
    m = lamp_water.LampWater.build([lamp], w, 0.85)
    d = np.array([[bs.D_MAX, bs.D_MAX + 10.0]], np.float32)
    b = m.beam(lamp, np.ones_like(d), d)[0]
    np.testing.assert_allclose(b[1] / b[0], np.exp(-10.0 * m.c_lamp), rtol=1e-4)


@pytest.mark.parametrize("half_deg,edge_deg", [(10.0, 2.0), (60.0, 5.0), (89.0, 10.0)])
def test_narrow_and_wide_cones_keep_energy_and_stay_non_negative(half_deg, edge_deg):
    """Cones from 10 to 89 deg (the planar angle treatment's range): the table carries
    exp(-c' d) of the profile's energy within 1 % at 20 m and never goes negative."""
    lamp, psi = _lamp(half_deg, edge_deg), bs.psis()
    w = optics.get_preset("moderate")
    table = bs.beam_table(lamp, w.c, w.sigma_s, 0.85, ("hg", 0.9))
    i = int(np.searchsorted(bs.distances(), 20.0))
    e0 = _planar_energy(lamp.profile(np.cos(psi)), psi)
    c_lamp = lamp_water.lamp_attenuation(w, 0.85)
    assert _planar_energy(table[i, :, 1], psi) == pytest.approx(e0 * math.exp(-c_lamp[1] * bs.distances()[i]), rel=0.01)
    assert table.min() >= 0.0
