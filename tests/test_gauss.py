"""Box-Muller float32 normals on SplitMix64 words (physics/particles/gauss.py): the law, independence,
reproducibility."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from blendgen.physics.particles.gauss import TAIL_SIGMA, drift_normals


def test_draws_follow_the_standard_normal_law():
    z = drift_normals(7, 140_000).reshape(-1)
    assert z.dtype == np.float32 and z.shape == (420_000,)
    assert stats.kstest(z, "norm").pvalue > 1e-3
    assert abs(z.mean()) < 5 / np.sqrt(z.size) and abs(z.std() - 1) < 0.005
    assert stats.kurtosis(z) == pytest.approx(0.0, abs=0.05)  # tails: 3 sigma share
    assert np.mean(np.abs(z) > 3) == pytest.approx(2 * stats.norm.sf(3), rel=0.1)


def test_the_tail_is_cut_at_the_float32_resolution_of_the_uniforms():
    from blendgen.physics.particles.kernels import box_muller

    z = box_muller(np.full(2, np.uint64(0xFFFFFF) << np.uint64(40), np.uint64))  # U1 = 1 - 2^-24, angle 0
    assert np.all(np.isfinite(z))
    assert z[0, 0] == pytest.approx(TAIL_SIGMA, rel=1e-5) and TAIL_SIGMA == pytest.approx(5.768, abs=1e-3)
    assert np.all(np.abs(z[1]) < 1e-6)  # sin(0) = 0


def test_compiled_transform_equals_box_muller_in_float64():
    """particle_kernels.box_muller (log and sin/cos polynomials, the angle's octant in integers)
    against the transform evaluated in float64 on the same 64-bit words, every octant included."""
    from blendgen.physics.particles.kernels import box_muller

    words = np.random.default_rng(5).integers(0, 2**64, 200_000, dtype=np.uint64)
    words[:8] = (np.arange(8, dtype=np.uint64) << np.uint64(37)) | np.uint64(1 << 40)  # octant edges
    k = (words >> np.uint64(40)).astype(np.float64)
    j = ((words >> np.uint64(16)) & np.uint64(0xFFFFFF)).astype(np.float64)
    radius = np.sqrt(-2.0 * np.log1p(-k / 2**24))
    theta = 2 * np.pi * j / 2**24
    got = box_muller(words)
    assert np.max(np.abs(got[0] - radius * np.cos(theta))) < 3e-6
    assert np.max(np.abs(got[1] - radius * np.sin(theta))) < 3e-6


def test_compiled_log_is_as_accurate_as_float32_allows():
    from blendgen.physics.particles.kernels import log32

    edges = [1.0, 2.0, 0.5, 2**-24, 1 - 2**-24]
    x = np.concatenate([np.exp(np.random.default_rng(2).uniform(-40, 40, 3000)), edges])
    x32 = x.astype(np.float32)
    got = np.array([log32(v) for v in x32], np.float64)
    ref = np.log(x32.astype(np.float64))
    assert np.max(np.abs(got - ref) / np.maximum(np.abs(ref), 1.0)) < 3e-7


@pytest.mark.parametrize("n", [0, 1, 2, 5])
def test_same_seed_same_draws_any_length(n):
    a, b = drift_normals(11, n), drift_normals(11, n)
    assert a.shape == (3, n) and a.tobytes() == b.tobytes()
    assert np.array_equal(drift_normals(11, n + 3)[:, :n], a)  # particle i's draw: its own words
    with pytest.raises(ValueError):
        drift_normals(0, -1)


# ----------------------------------------------------------------------------- drift normals
def test_splitmix64_gives_the_reference_outputs():
    """The first outputs from state 1234567 of Vigna's splitmix64.c (its published test values),
    in numpy and in the compiled kernel."""
    from blendgen.physics.particles.gauss import splitmix64
    from blendgen.physics.particles.kernels import splitmix64 as compiled

    ref = [6457827717110365317, 3203168211198807973, 9817491932198370423, 4593380528125082431, 16408922859458223821]
    assert splitmix64(1234567, 5).tolist() == ref
    assert [int(compiled(np.uint64(1234567), k)) for k in range(1, 6)] == ref
    assert splitmix64(2**64 - 1, 3).tolist() == [int(compiled(np.uint64(2**64 - 1), k)) for k in (1, 2, 3)]


def test_drift_normals_follow_the_law_and_are_independent():
    """The three normals per particle of a drift step: N(0, 1), uncorrelated across axes, across
    neighbouring particles (consecutive words) and across steps (other seeds)."""
    n = 200_000
    z = drift_normals(0x243F6A8885A308D3, n)
    assert z.shape == (3, n) and z.dtype == np.float32
    tol = 5 / np.sqrt(n)
    for axis in z:
        assert stats.kstest(axis, "norm").pvalue > 1e-3
        assert abs(axis.mean()) < tol and abs(axis.std() - 1) < 0.01
    assert np.all(np.abs(np.corrcoef(z) - np.eye(3)) < tol)
    assert abs(np.corrcoef(z[0] ** 2, z[1] ** 2)[0, 1]) < tol  # R shared by the pair
    assert abs(np.corrcoef(z[2, :-1], z[2, 1:])[0, 1]) < tol  # neighbours
    other = drift_normals(0x243F6A8885A308D4, n)  # the next seed
    assert np.all(np.abs(np.corrcoef(z, other)[:3, 3:]) < tol)
