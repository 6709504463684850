"""PnP numerical stress (evalkit.pnp_bench): no NaN / behind-camera successes, planar-ambiguity
picks no worse than OpenCV's first IPPE solution, range error ~ Z^2. A reduced sweep (~3 s);
the full one is ``dockbench bench pnp`` (or ``--slow``)."""

import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

import cli
from evalkit import pnp_bench as pb
from evalkit.localizers.pnp import pose_is_plausible, solve_planar


@pytest.fixture(scope="module")
def sweep():
    return pb.run_sweep(
        distances=(0.5, 1.0, 2.0, 3.0, 5.0, 7.5),
        angles=(0.0, 30.0, 60.0, 80.0),
        noises=(0.0, 1.0, 2.0),
        n_trials=25,
        seed=1,
    )


def test_no_nan_or_behind_camera_success(sweep):
    assert sweep.nan_ours.sum() == 0 and sweep.behind_ours.sum() == 0
    assert sweep.nan_prior.sum() == 0 and sweep.behind_prior.sum() == 0
    # solve_planar refuses rarely (only where OpenCV gives nothing usable)
    assert sweep.none_ours.sum() <= 0.01 * sweep.n.sum()


def test_noise_free_is_exact_and_unambiguous(sweep):
    clean = sweep[(sweep.sigma_px == 0) & (sweep.n > 0)]
    assert (clean.ok_ours == clean.n).all()
    assert clean.rms_ez_m.max() < 1e-6 and clean.wrong_ours.sum() == 0


def test_disambiguation_better_than_naive(sweep):
    noisy = sweep[sweep.sigma_px > 0]
    bad = {m: pb._bad(noisy, m) for m in pb.METHODS}
    # solve_planar never does worse than OpenCV's own first solution (which includes NaN and
    # behind-camera poses near R ~ diag(1,-1,-1)); an attitude prior removes most flips at tilt
    assert bad["ours"] <= bad["naive"]
    assert noisy.wrong_ours.sum() <= noisy.wrong_naive.sum() * 1.05 + 2
    tilted = noisy[noisy.angle_deg >= 30]
    assert pb._bad(tilted, "prior") < 0.25 * pb._bad(tilted, "ours")


@pytest.mark.parametrize("target", ["led", "square"])
def test_error_follows_z_squared(sweep, target):
    k = pb.fit_exponent(sweep, target, sigma_px=1.0)
    assert 1.5 <= k <= 2.5, k
    # and within a small factor of 0.7 Z^2 sigma / (f s) (pooled tilts shrink the target)
    d = sweep[(sweep.target == target) & (sweep.sigma_px == 1.0) & sweep.detectable]
    ratio = d.rms_ez_m / d.theory_m
    assert ratio.between(0.3, 5.0).all(), ratio.describe()


def test_pose_generator_matches_its_definition():
    rng = np.random.default_rng(3)
    for angle in (0.0, 35.0, 80.0):
        T = pb.random_pose(rng, 4.0, angle)
        v = T[:3, 3] / np.linalg.norm(T[:3, 3])
        n = T[:3, 2]  # target normal in the camera
        assert math.degrees(math.acos(np.clip(-n @ v, -1, 1))) == pytest.approx(angle, abs=1e-6)
        assert T[2, 3] == pytest.approx(4.0) and pose_is_plausible(T, pb.TARGETS["led"].obj)


@given(
    Z=st.floats(0.2, 20.0),
    angle=st.floats(0.0, 80.0),
    sigma=st.floats(0.0, 2.0),
    seed=st.integers(0, 2**32 - 1),
    square=st.booleans(),
)
def test_solve_planar_property_never_nan_or_behind(Z, angle, sigma, seed, square):
    target = pb.TARGETS["square" if square else "led"]
    rng = np.random.default_rng(seed)
    T = pb._valid_pose(rng, target, Z, angle)
    if T is None:
        return
    uv = pb.project(T, target.obj) + rng.normal(0, sigma, (4, 2))
    pose = solve_planar(target.obj, uv, pb.K, None, square=target.square)
    if pose is not None:
        assert np.all(np.isfinite(pose.T_cam_target)) and np.isfinite(pose.reproj_err_px)
        assert pose_is_plausible(pose.T_cam_target, target.obj)


def test_cli_command_writes_csv_and_png(tmp_path, monkeypatch):
    monkeypatch.setattr(pb, "DISTANCES_M", (1.0, 3.0, 10.0))
    small = pb.run_sweep.__defaults__
    monkeypatch.setattr(pb.run_sweep, "__defaults__", (small[0], (1.0, 3.0, 10.0), (0.0, 40.0), (0.0, 1.0)) + small[4:])
    res = CliRunner().invoke(cli.main, ["bench", "pnp", "--trials", "5", "-o", str(tmp_path / "b")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "b" / "pnp.csv").stat().st_size > 0 and (tmp_path / "b" / "pnp.png").stat().st_size > 0
    assert "fitted exponent" in res.output and "square" in res.output


@pytest.mark.slow
def test_full_default_sweep(tmp_path):
    res = CliRunner().invoke(cli.main, ["bench", "pnp", "-o", str(tmp_path)])
    assert res.exit_code == 0, res.output
    df = __import__("pandas").read_csv(tmp_path / "pnp.csv")
    assert df.nan_ours.sum() == 0 and df.behind_ours.sum() == 0
    for t in ("led", "square"):
        assert 1.5 <= pb.fit_exponent(df, t) <= 2.5
