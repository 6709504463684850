"""The forward caustic map (``blendgen/physics/surface/caustic_map.py``, ``caustic_mesh.py``).

Oracles, each independent of the mesh code:
- a single sinusoidal wave beyond its first focus, against a dense 1-D trace of the same ray
  map (every preimage counted by construction), with a constant and with a varying beam path;
- the sun's disc blur of a point is a uniform disc of radius ``L theta_sun / n`` (energy 1);
- culling (only the light that can reach the wanted bins is traced) leaves those bins as the
  full map has them;
- the scattered part's own (coarser) deposit mesh gives the map of the finest mesh, to a few
  % of the contrast;
- a frame's points read the map made at their footprint's bins and beam path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.physics.surface import caustic_map as cmap
from blendgen.physics.surface import caustic_mesh
from blendgen.physics.surface import optics as sf

ALPHA = 1.0 - 1.0 / sf.N_WATER


def _one_wave(amp: float, wavelength: float) -> sf.WaveField:
    """eta = amp sin(k x): one still wave along x."""
    k = 2 * math.pi / wavelength
    return sf.WaveField(amp=np.array([amp]), k=np.array([[k, 0.0]]), omega=np.array([0.0]), phase=np.array([0.0]))


def _traced_profile(amp, wavelength, path, x_edges, samples=2_000_000):
    """Irradiance over the flat value in bins ``x_edges`` (m) of the 1-D ray map
    ``X = xi + L(X) alpha eta'(xi)`` (zenith sun), ``path(X)`` affine, solved for X exactly;
    ``samples`` evenly spaced surface points over a span wider than the bins plus the reach."""
    k = 2 * math.pi / wavelength
    lo, hi = x_edges[0] - 2.0, x_edges[-1] + 2.0
    xi = np.linspace(lo, hi, samples, endpoint=False) + (hi - lo) / samples / 2
    s = ALPHA * amp * k * np.cos(k * xi)  # alpha eta'(xi)
    c0, c1 = path  # L(X) = c0 + c1 X
    X = (xi + c0 * s) / (1.0 - c1 * s)
    counts, _ = np.histogram(X, x_edges)
    return counts * ((hi - lo) / samples) / np.diff(x_edges)


@pytest.mark.parametrize("bin_m", [0.01, 0.02])
@pytest.mark.parametrize("tilt", [0.0, 0.5, 2.0])
def test_a_folded_wave_gets_the_light_of_every_sheet(bin_m, tilt):
    """One wave 0.5 m long with slope 0.08 (first focus 4 m down) seen three focal lengths
    down, on a floor (``tilt`` 0) and on receivers whose beam path changes by ``tilt`` m per
    metre across the patch (a wall seen under a 27-deg sun has 2): the map's profile matches
    the dense 1-D trace of the same ray map, blurred by the same sun disc (rms < 5 % of its
    contrast; without folds counted the bright caustic pairs would be missing), mean within 1 %."""
    lam, slope = 0.5, 0.08
    k = 2 * math.pi / lam
    amp = slope / k
    f = 1.0 / (ALPHA * amp * k * k)
    n = int(round(2.0 / bin_m))
    patch = cmap.Patch(0.013, -0.1, bin_m, (8, n))
    xc, _ = patch.centres()
    path = (3 * f - tilt * 1.0, tilt)  # 3 focal lengths mid-patch
    L = np.broadcast_to(path[0] + path[1] * xc, patch.shape).copy()
    profile = cmap.light_map(_one_wave(amp, lam), patch, L, 0.0).mean(axis=0)
    truth = _traced_profile(amp, lam, path, patch.x0 + bin_m * np.arange(n + 1))
    assert truth.max() > 3.0  # folded: bright caustic pairs
    radius = L * sf.SUN_RADIUS_RAD / sf.N_WATER / bin_m
    seen = caustic_mesh.disc_blur(
        np.broadcast_to(truth, patch.shape).astype(np.float32), radius, np.ones(patch.shape, bool)
    ).mean(axis=0)
    inner = slice(8, -8)  # the oracle's blur stops at its edge
    err = np.sqrt(np.mean((profile[inner] - seen[inner]) ** 2))
    assert err < 0.05 * seen[inner].std(), (err, seen.std())
    assert profile.mean() == pytest.approx(truth.mean(), rel=0.01)


def test_the_sun_disc_blur_is_a_uniform_disc():
    """A point of light blurred at a bin whose radius is 3 bins: a disc of that radius whose
    weights sum to the point's energy; a bin with radius < 1/4 keeps its value."""
    E = np.zeros((21, 21), np.float32)
    E[10, 10] = 1.0
    radius = np.full(E.shape, 3.0)
    out = caustic_mesh.disc_blur(E, radius, np.ones(E.shape, bool))
    r = np.hypot(*np.meshgrid(np.arange(21) - 10, np.arange(21) - 10))
    assert out.sum() == pytest.approx(1.0, rel=1e-5)
    assert np.all(out[r <= 2.5] == pytest.approx(out[10, 10])) and not out[r >= 3.5].any()
    assert out[10, 10] == pytest.approx(1.0 / (math.pi * 9), rel=0.03)
    same = caustic_mesh.disc_blur(E, np.full(E.shape, 0.2), np.ones(E.shape, bool))
    np.testing.assert_array_equal(same, E)


@pytest.mark.parametrize("scattering", [0.0, 0.05, 0.4])
def test_tracing_only_what_reaches_the_wanted_bins_keeps_them(scattering):
    """Random sparse wanted bins: their values equal the full map's (clear water: 1e-5; in
    scattering water the far tails of the scattered light see the mean where nothing was
    traced: 3 % of the contrast)."""
    waves = sf.waves_for(7, 3.0)
    patch = cmap.Patch(1.3, -0.7, 0.02, (120, 150))
    D = sf.sun_deflection([0.4, 0.2, -0.9])
    full = cmap.light_map(waves, patch, 3.0, 0.4, D, scattering, 0.92)
    wanted = np.random.default_rng(0).random(patch.shape) < 0.01
    part = cmap.light_map(waves, patch, 3.0, 0.4, D, scattering, 0.92, wanted=wanted)
    tol = 1e-5 if scattering == 0 else 0.03 * float(full.std())
    np.testing.assert_allclose(part[wanted], full[wanted], atol=tol)


@pytest.mark.parametrize("path_m, rms_tol", [(2.0, 0.01), (4.0, 0.05)])
def test_the_scattered_parts_mesh_gives_the_finest_meshs_map(monkeypatch, path_m, rms_tol):
    """Turbid coastal water (b = 0.3 /m, g = 0.92): the map with ``SCATTERED_PER_BIN`` vertices
    per side of the scattered part's bins against the same map with ``MAX_PER_BIN`` (the
    densest mesh a deposit uses): rms difference within ``rms_tol`` of the map's contrast
    (std) and the contrast within 1 %. One vertex per side fails (2 m: 4.6 % rms; 4 m: 11 %
    rms and 6 % less contrast)."""
    waves = sf.waves_for(7, 2.0)
    patch = cmap.Patch(0.3, -0.4, 0.01, (200, 240))
    D = sf.sun_deflection([0.3, 0.1, -0.95])
    got = cmap.light_map(waves, patch, path_m, 0.4, D, 0.3, 0.92)
    monkeypatch.setattr(cmap, "SCATTERED_PER_BIN", cmap.MAX_PER_BIN)
    finest = cmap.light_map(waves, patch, path_m, 0.4, D, 0.3, 0.92)
    contrast = float(finest.std())
    assert float(np.sqrt(np.mean((got - finest) ** 2))) < rms_tol * contrast
    assert float(got.std()) == pytest.approx(contrast, rel=0.01)


def test_a_frames_points_read_the_map_of_their_footprint():
    """Points at the 2-cm bin centres of a floor 3 m down with 2-cm footprints read that map
    (1e-4); with footprints wider than ``COARSEST_BIN_M`` they read 1 (the network averaged
    out); points on a wall (beam paths 0.5-3.9 m) get one group per octave of path."""
    waves = sf.waves_for(3, 2.0)
    patch = cmap.Patch(0.0, 0.0, 0.02, (40, 60))
    X, Y = np.meshgrid(*patch.centres())
    x, y = X.ravel(), Y.ravel()
    M = cmap.light_map(waves, patch, 3.0, 0.2)
    got = cmap.frame_factor(waves, x, y, np.full(x.size, 3.0), np.full(x.size, 0.02), 0.2)
    np.testing.assert_allclose(got, M.ravel(), atol=1e-4)
    wide = cmap.frame_factor(waves, x, y, np.full(x.size, 3.0), np.full(x.size, 0.5), 0.2)
    np.testing.assert_array_equal(wide, 1.0)
    path = 0.5 + 3.4 * (x - x.min()) / np.ptp(x)
    calls = []
    real = cmap._light_at
    try:
        cmap._light_at = lambda *a, **k: calls.append(a) or real(*a, **k)
        cmap.frame_factor(waves, x, y, path, np.full(x.size, 0.02), 0.2)
    finally:
        cmap._light_at = real
    assert len(calls) == 3  # 0.5-1, 1-2, 2-4 m


def test_footprint_levels_are_at_least_the_footprint():
    """1 cm x 2^l, the first at least as wide as the footprint; none (-1) beyond 0.32 m, for
    inf and for nan."""
    f = np.array([0.001, 0.01, 0.014, 0.02, 0.03, 0.2, 0.32, 0.33, np.inf, np.nan])
    np.testing.assert_array_equal(cmap._levels(f), [0, 0, 1, 1, 2, 5, 5, -1, -1, -1])
