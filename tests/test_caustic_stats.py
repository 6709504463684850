"""Caustic statistics of `bench caustics` (tools/bench/caustic_bench.py: radial_psd, spectrum_stats): a
pattern of known wavelength, white noise removed, shifted patterns are equal in statistics."""

import numpy as np
import pytest

from blendgen.tools.bench.caustic_bench import radial_psd, spectrum_stats

N, BIN = 96, 2.0 / 96


def _waves(lam_m, phase=0.0):
    x = (np.arange(N) + 0.5) * BIN
    X, Y = np.meshgrid(x, x)
    return 1.0 + 0.3 * np.cos(2 * np.pi * X / lam_m + phase) * np.cos(2 * np.pi * Y / lam_m)


@pytest.mark.parametrize("lam", [0.2, 0.4])
def test_cell_size_of_a_known_pattern(lam):
    """cos(2 pi x / lam) cos(2 pi y / lam) has its power at |k| = sqrt(2) / lam: cell = lam / sqrt(2)."""
    s = spectrum_stats(_waves(lam), _waves(lam), BIN, 0.0)
    assert s["cell_m_ref"] == pytest.approx(lam / np.sqrt(2), rel=0.12)
    assert s["psd_log10_err"] == pytest.approx(0.0, abs=1e-9)


def test_shot_noise_is_removed_and_shifts_do_not_matter():
    """The reference with white noise of known variance (its E2) keeps the clean pattern's cell
    size; a pattern shifted by half a period (correlation -1) has the same statistics."""
    rng = np.random.default_rng(0)
    clean = _waves(0.3)
    noisy = clean + rng.normal(0.0, 0.05, clean.shape)
    s = spectrum_stats(noisy, _waves(0.3, np.pi), BIN, 0.05**2)
    assert s["cell_m_ref"] == pytest.approx(s["cell_m_fast"], rel=0.1)
    assert s["psd_log10_err"] < 0.15
    _, p, _ = radial_psd(rng.normal(0.0, 0.05, clean.shape), BIN, 0.05**2)
    _, p_sig, _ = radial_psd(clean, BIN)
    assert np.abs(p).max() < 0.1 * p_sig.max()  # pure noise minus its level: ~0


def test_a_finer_pattern_is_told_apart():
    """Twice the spatial frequency: half the cell size and a large spectral error."""
    s = spectrum_stats(_waves(0.4), _waves(0.2), BIN, 0.0)
    assert s["cell_m_fast"] == pytest.approx(0.5 * s["cell_m_ref"], rel=0.15)
    assert s["psd_log10_err"] > 0.5
