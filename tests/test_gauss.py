"""Box-Muller float32 normals (physics/gauss.py): the law, independence, reproducibility."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from blendgen.physics.gauss import TAIL_SIGMA, standard_normal32


def test_draws_follow_the_standard_normal_law():
    z = standard_normal32(np.random.default_rng(7), 400_001)
    assert z.dtype == np.float32 and z.shape == (400_001,)
    assert stats.kstest(z, "norm").pvalue > 1e-3
    assert abs(z.mean()) < 5 / np.sqrt(z.size) and abs(z.std() - 1) < 0.005
    assert stats.kurtosis(z) == pytest.approx(0.0, abs=0.05)       # tails: 3 sigma share
    assert np.mean(np.abs(z) > 3) == pytest.approx(2 * stats.norm.sf(3), rel=0.1)


def test_the_two_halves_and_neighbours_are_uncorrelated():
    """cos and sin of the same angle, and the neighbours of a (N, 3) reshape, are independent."""
    z = standard_normal32(np.random.default_rng(3), 300_000)
    a, b = z[:150_000], z[150_000:]
    tol = 5 / np.sqrt(150_000)
    assert abs(np.corrcoef(a, b)[0, 1]) < tol
    assert abs(np.corrcoef(a ** 2, b ** 2)[0, 1]) < tol               # R shared by the pair
    xyz = z.reshape(-1, 3)
    assert np.all(np.abs(np.corrcoef(xyz.T) - np.eye(3)) < 5 / np.sqrt(xyz.shape[0]))


def test_the_tail_is_cut_at_the_float32_resolution_of_the_uniforms():
    class Extreme:                                     # U1 = largest float32 below 1, then 0
        def random(self, shape, dtype):
            u = np.zeros(shape, dtype)
            u[0] = np.nextafter(np.float32(1.0), np.float32(0.0))
            return u
    z = standard_normal32(Extreme(), 4)
    assert np.all(np.isfinite(z))
    assert z[0] == pytest.approx(TAIL_SIGMA, rel=1e-5) and TAIL_SIGMA == pytest.approx(5.768, abs=1e-3)
    assert np.all(z[2:] == 0.0)                        # sin(0) = 0


@pytest.mark.parametrize("n", [0, 1, 2, 5])
def test_same_state_same_draws_any_length(n):
    a = standard_normal32(np.random.default_rng(11), n)
    b = standard_normal32(np.random.default_rng(11), n)
    assert a.shape == (n,) and a.tobytes() == b.tobytes()
    with pytest.raises(ValueError):
        standard_normal32(np.random.default_rng(0), -1)
