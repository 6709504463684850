"""Closed-loop visual docking: filter, geometry of success, guidance on an estimate, warm renderer."""

import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from blendgen.config.models import Dock, Pose
from blendgen.geometry import invert_T, make_T, rot_y, rot_z
from blendgen.vehicle import trajectories as tj
from blendgen.vehicle.closed_loop import DelayLine, Observation, TrialSetup, simulate_closed_loop
from blendgen.vehicle.docking import DockAxesNED
from blendgen.vehicle.dynamics import F_WORLD_NED, T_world_body_to_eta
from blendgen.vehicle.visual_nav import (
    CaptureSpec,
    DockFix,
    FilterParams,
    RelativePoseFilter,
    crossing_outcome,
    fix_from_estimate,
    interpolate_crossing,
)

T_WD = tj.T_world_dock_from_spec(Dock())
T_BC = tj.T_body_cam_from_spec(Pose(xyz=[0.65, 0.0, 0.0]))
CAPTURE = CaptureSpec.from_dock([1.0, 1.0, 0.4], 0.191 / 2)
START = {"range_m": 8.0, "lateral_m": 0.8, "vertical_m": 0.3, "heading_error_deg": 8.0}


def oracle(lateral_bias_m=0.0, noise_m=0.0, seed=0, drop_every=0):
    """A localizer that sees the true T_cam_dock, shifted by a lateral bias in the dock frame,
    with optional Gaussian position noise and a dropout every ``drop_every`` frames."""
    rng = np.random.default_rng(seed)

    def observe(k, t, T_world_cam):
        if drop_every and k % drop_every == 0:
            return Observation(None, {"d_true": float("nan")})
        shift = np.array([lateral_bias_m, 0.0, 0.0]) + rng.normal(0.0, noise_m, 3) * (noise_m > 0)
        T_cd = invert_T(T_world_cam) @ T_WD @ make_T(np.eye(3), shift)
        return Observation({"distance": float(T_cd[2, 3]), "T_cam_dock": T_cd}, {})

    return observe


def setup(**kw):
    return TrialSetup(T_WD, kw.pop("start", START), T_BC, CAPTURE, **kw)


# ---------------------------------------------------------------- docking success by geometry
def test_capture_radius_default_from_dock_face_and_hull():
    assert CAPTURE.capture_radius_m == pytest.approx(0.5 - 0.0955)
    assert CAPTURE.frame_half_m == pytest.approx((0.5955, 0.5955))


def test_capture_limits_come_from_the_config_and_bad_values_are_refused():
    from pydantic import ValidationError

    from blendgen.config.models import DockingTrajectory
    from blendgen.tools.apps.closed_loop import capture_spec

    default = capture_spec(DockingTrajectory(), [1.0, 1.0, 0.4], 0.0955)
    assert default == CAPTURE
    t = DockingTrajectory.model_validate(
        {"capture": {"radius_m": 0.25, "max_heading_deg": 5, "max_lateral_speed_mps": 0.1}}
    )
    c = capture_spec(t, [1.0, 1.0, 0.4], 0.0955)
    assert (c.capture_radius_m, c.max_heading_deg, c.max_lateral_speed_mps) == (0.25, 5.0, 0.1)
    assert crossing_outcome(c, np.array([0.3, 0.0, 0.0]), 0.0, 0.0) == "collision"  # docked by default
    assert crossing_outcome(c, np.zeros(3), 6.0, 0.0) == "misaligned"
    for bad in ({"max_heading_deg": 0}, {"radius_m": -1}, {"max_lateral_speed_mps": 5}, {"funnel": 1}):
        with pytest.raises(ValidationError):
            DockingTrajectory.model_validate({"capture": bad})


@pytest.mark.parametrize(
    "nose, head, vlat, expected",
    [
        ((0.0, 0.0, 0.0), 0.0, 0.0, "docked"),
        ((0.28, 0.28, 0.0), 14.9, -0.24, "docked"),  # r = 0.396 < 0.4045, limits just met
        ((0.0, 0.0, 0.0), 15.1, 0.0, "misaligned"),
        ((0.0, 0.0, 0.0), 0.0, 0.26, "misaligned"),
        ((0.5, 0.0, 0.0), 0.0, 0.0, "collision"),  # outside the mouth, on the frame
        ((0.0, -0.59, 0.0), 0.0, 0.0, "collision"),
        ((0.6, 0.0, 0.0), 0.0, 0.0, "out_of_capture"),  # beside the dock
    ],
)
def test_crossing_outcome(nose, head, vlat, expected):
    assert crossing_outcome(CAPTURE, np.array(nose), head, vlat) == expected


def test_interpolated_crossing_lies_on_the_plane():
    p = interpolate_crossing(np.array([1.0, 2.0, 0.3]), np.array([2.0, 0.0, -0.1]), 0.0)
    np.testing.assert_allclose(p, [1.75, 0.5, 0.0])


# ---------------------------------------------------------------- the fix and the filter
def test_fix_from_true_pose_recovers_relative_pose_heading_and_dock_depth():
    T_wb = make_T(rot_z(math.radians(180 + 7.0)), [2.0, 0.4, -1.3])  # 5 m in front, 0.4 m aside
    eta = T_world_body_to_eta(T_wb)
    sens = {
        "depth_m": round(float(eta[2]), 2),
        "heading_deg": math.degrees(eta[5]) % 360,
        "pitch_deg": 0.0,
        "roll_deg": 0.0,
    }
    T_cd = invert_T(T_wb @ T_BC) @ T_WD
    fix = fix_from_estimate({"distance": 4.0, "T_cam_dock": T_cd}, T_BC, sens)
    axes = DockAxesNED(T_WD)
    np.testing.assert_allclose(fix.p_dock, axes.p_dock(F_WORLD_NED @ T_wb[:3, 3]), atol=1e-9)
    assert fix.p_dock[2] == pytest.approx(5.0)
    assert fix.psi_dock == pytest.approx(axes.approach_psi, abs=1e-9)
    # the face centre: the dock's top 1 m deep, the 1 m face's centre 0.5 m below it
    assert fix.depth_dock == pytest.approx(1.5, abs=1e-9)


def test_a_wrong_pnp_rotation_does_not_move_the_filtered_position():
    # planar PnP at range may return the mirrored tilt with the right translation: the filter
    # places the fix with its own dock heading and the translation, so the lateral stays right
    T_wb = make_T(rot_z(math.radians(180 + 5.0)), [-3.0, 1.0, -1.0])  # 10 m out, 1 m aside (dock x = -world y)
    eta = T_world_body_to_eta(T_wb)
    sens = {"depth_m": 1.0, "heading_deg": math.degrees(eta[5]) % 360, "pitch_deg": 0.0, "roll_deg": 0.0}
    T_cd = invert_T(T_wb @ T_BC) @ T_WD
    flipped = T_cd.copy()
    flipped[:3, :3] = T_cd[:3, :3] @ rot_y(math.radians(25.0))
    f = RelativePoseFilter()
    f.update(0.0, fix_from_estimate({"distance": 9.3, "T_cam_dock": T_cd}, T_BC, sens))
    bad = fix_from_estimate({"distance": 9.3, "T_cam_dock": flipped}, T_BC, sens)
    assert abs(bad.p_dock[0] + 1.0) > 3.0  # its own pose is far off
    f.update(0.1, bad)
    assert f.xz[0] == pytest.approx(-1.0, abs=0.02) and f.xz[1] == pytest.approx(10.0, abs=0.02)


def test_distance_only_fix_knows_the_range_alone():
    fix = fix_from_estimate({"distance": 3.0}, T_BC, {"depth_m": 1.0, "heading_deg": 0, "pitch_deg": 0, "roll_deg": 0})
    assert fix.p_dock[2] == pytest.approx(3.65) and math.isnan(fix.p_dock[0]) and math.isnan(fix.psi_dock)
    f = RelativePoseFilter()
    f.update(0.0, fix)
    assert not f.initialised  # a distance alone cannot start it


def test_kalman_filter_converges_on_a_constant_velocity_track_and_extrapolates():
    f = RelativePoseFilter(FilterParams())
    v = np.array([0.05, -0.4])
    for k in range(100):
        t = 0.1 * k
        xz = np.array([0.5, 8.0]) + v * t
        f.update(t, DockFix(np.array([xz[0], 0.2, xz[1]]), 0.1, 1.0))
    p, vel = f.state(9.9 + 0.5, depth_sensor_m=0.9)
    np.testing.assert_allclose(vel, v, atol=2e-3)
    np.testing.assert_allclose(p, [0.5 + v[0] * 10.4, 0.1, 8.0 + v[1] * 10.4], atol=2e-3)


def test_kalman_filter_smooths_noise_and_gates_an_outlier():
    rng = np.random.default_rng(0)
    f = RelativePoseFilter(FilterParams(meas_std_per_m2=0.005))
    truth = lambda t: np.array([0.0, 8.0 - 0.3 * t])  # noqa: E731
    err, raw = [], []
    for k in range(80):
        t = 0.1 * k
        z = truth(t) + rng.normal(0.0, 0.005 * truth(t)[1] ** 2, 2)  # the modelled noise
        if k == 60:
            z = truth(t) + np.array([3.0, 0.0])  # a wrong 3 m lateral fix
        f.update(t, DockFix(np.array([z[0], 0.0, z[1]]), 0.0, 1.0))
        if k > 30 and k != 60:
            err.append((f.xz - truth(t))[0])
            raw.append((z - truth(t))[0])
    assert f.rejected == 1
    assert np.std(err) < 0.7 * np.std(raw)  # smoother than the fixes
    assert abs(f.v[1] + 0.3) < 3 * math.sqrt(f.P[1, 1, 1])  # consistent with its covariance


def test_dock_heading_estimate_trusts_near_fixes_over_mirrored_far_ones():
    rng = np.random.default_rng(1)
    psi_true, f = 0.3, RelativePoseFilter()
    for k in range(100):
        rng_m = 10.0 - 0.09 * k  # approach from 10 m to 1 m
        flip = 0.5 if (rng_m > 6 and k % 3 == 0) else 0.0  # mirrored IPPE pose far away
        psi = psi_true + flip + rng.normal(0.0, 0.02 * rng_m * 0.5)
        f.update(0.1 * k, DockFix(np.array([0.0, 0.0, rng_m]), psi, 1.0, np.array([rng_m, 0.0, 0.0])))
    assert abs(f.psi_dock - psi_true) < math.radians(1.0)
    assert f.psi_var < math.radians(1.0) ** 2


def test_dropouts_hold_for_hold_s_then_stale_then_lost():
    f = RelativePoseFilter(FilterParams(hold_s=1.0, lost_s=3.0))
    f.update(0.0, DockFix(np.array([0.0, 0.0, 5.0]), 0.0, 1.0))
    assert f.fresh(0.9) and not f.fresh(1.1)
    assert not f.lost(2.9) and f.lost(3.1)
    g = RelativePoseFilter(FilterParams(hold_s=1.0, lost_s=3.0))
    g.update(0.0, None)  # never a fix: lost counts from the start
    assert not g.fresh(0.0) and g.lost(3.1)


def test_filter_parameters_are_checked():
    with pytest.raises(ValueError, match="hold_s"):
        FilterParams(hold_s=5.0, lost_s=2.0)
    with pytest.raises(ValueError, match="const_gain"):
        FilterParams(const_gain=1.5)


# ---------------------------------------------------------------- closed loop on an estimate
@pytest.mark.parametrize("start", [START, {**START, "lateral_m": -1.2, "heading_error_deg": -12.0}])
def test_lateral_bias_of_one_metre_makes_docking_fail_while_ground_truth_docks(start):
    truth = simulate_closed_loop(setup(start=start))
    perfect = simulate_closed_loop(setup(start=start), oracle())
    biased = simulate_closed_loop(setup(start=start), oracle(lateral_bias_m=1.0))
    assert truth["outcome"] == "docked" and perfect["outcome"] == "docked"
    assert abs(truth["cross_lateral_m"]) < 0.15
    assert biased["outcome"] in ("out_of_capture", "collision")
    # the vehicle steered onto the axis it believed in: 1 m beside the true one
    assert biased["cross_lateral_m"] == pytest.approx(1.0, abs=0.15)


def test_same_seed_gives_the_same_outcome_and_path():
    kw = dict(current_world=(0.0, 0.5, 0.0), seed=11)
    a = simulate_closed_loop(setup(**kw), oracle(noise_m=0.05, seed=3, drop_every=7))
    b = simulate_closed_loop(setup(**kw), oracle(noise_m=0.05, seed=3, drop_every=7))
    c = simulate_closed_loop(setup(current_world=(0.0, 0.5, 0.0), seed=12), oracle(noise_m=0.05, seed=3, drop_every=7))
    assert a["outcome"] == b["outcome"] and a["t_end"] == b["t_end"]
    pd.testing.assert_frame_equal(pd.DataFrame(a["frames"]), pd.DataFrame(b["frames"]))
    assert not pd.DataFrame(a["frames"])["y_world"].equals(pd.DataFrame(c["frames"])["y_world"])  # gusts differ


def test_a_blind_localizer_loses_the_target_after_lost_s():
    r = simulate_closed_loop(setup(filter=FilterParams(hold_s=1.0, lost_s=4.0)), lambda k, t, T: Observation(None))
    assert r["outcome"] == "lost_target"
    assert r["t_end"] == pytest.approx(4.1)
    assert math.isnan(r["time_to_dock_s"])


def test_timeout_when_time_runs_out_before_the_dock():
    r = simulate_closed_loop(setup(max_time_s=3.0))
    assert r["outcome"] == "timeout" and r["t_end"] == pytest.approx(3.0) and len(r["frames"]) == 31


def test_ground_truth_guidance_drifts_out_of_capture_in_a_strong_cross_current():
    # 1.0 m/s across the axis exceeds the lateral thrusters: the "reached by range" trial of
    # the open-loop generator is a miss by geometry
    r = simulate_closed_loop(setup(current_world=(0.0, 1.0, 0.0), seed=1))
    assert r["outcome"] in ("out_of_capture", "collision", "misaligned")
    assert abs(r["cross_lateral_m"]) > CAPTURE.capture_radius_m or abs(r["cross_heading_deg"]) > 15


# ---------------------------------------------------------------- camera + localizer latency
def test_delay_line_delivers_fixes_stamped_at_capture_in_capture_order():
    class Rec:
        def __init__(self):
            self.calls = []

        def update(self, t, fix):
            self.calls.append((t, fix))

    d, rec = DelayLine(0.3, "measured"), Rec()
    d.push(0.0, "a", 250.0)  # arrives 0.55 s
    d.push(0.1, "b", 10.0)  # would arrive 0.41 s: cannot overtake "a"
    d.push(0.2, "c", float("nan"))  # no measured time: link latency only -> 0.5, still after "a"
    d.deliver(rec, 0.54)
    assert rec.calls == []
    d.deliver(rec, 0.55)
    assert rec.calls == [(0.0, "a"), (0.1, "b"), (0.2, "c")]  # stamped at capture, not arrival
    d2 = DelayLine(0.0, 0.25)
    d2.push(1.0, "x", 999.0)  # a configured compute time ignores the measured one
    assert d2.queue[0][0] == pytest.approx(1.25)


def test_latency_settings_are_checked_and_zero_latency_builds_no_delay_line(monkeypatch):
    with pytest.raises(ValueError, match="latency_s"):
        setup(latency_s=-0.1)
    with pytest.raises(ValueError, match="compute_latency"):
        setup(compute_latency="sometimes")
    assert not setup().delayed and setup(compute_latency="measured").delayed

    def boom(*a, **k):
        raise AssertionError("the latency path ran with zero latency")

    monkeypatch.setattr("blendgen.vehicle.closed_loop.DelayLine", boom)
    assert simulate_closed_loop(setup(), oracle())["outcome"] == "docked"


LATENCY_STARTS = [START, {**START, "range_m": 10.0, "lateral_m": -1.2}, {**START, "range_m": 6.0, "lateral_m": 1.5}]


def _lateral_errors(latency_s: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Per start: |lateral offset| of the nose at the entry plane, RMS error of the estimate
    guidance used (m), outcome; a perfect localizer, calm water."""
    cross, rms, outcomes = [], [], []
    for i, st in enumerate(LATENCY_STARTS):
        r = simulate_closed_loop(setup(start=st, seed=i, latency_s=latency_s), oracle())
        f = pd.DataFrame(r["frames"])
        e = (f["est_lateral_m"] - f["lateral_m"]).dropna()
        cross.append(abs(r["cross_lateral_m"]))
        rms.append(float(np.sqrt(np.mean(e**2))))
        outcomes.append(r["outcome"])
    return np.array(cross), np.array(rms), outcomes


def test_latency_small_still_docks_and_one_second_degrades_lateral_error():
    c0, e0, o0 = _lateral_errors(0.0)
    c2, e2, o2 = _lateral_errors(0.2)  # a typical camera link + PnP time
    c10, e10, o10 = _lateral_errors(1.0)
    assert o0 == ["docked"] * 3 and o2 == ["docked"] * 3
    # 1 s of delay: the constant-velocity re-propagation cannot follow the vehicle's turns
    assert e10.mean() > 3 * e0.mean() and np.all(e10 > e2)
    assert c10.mean() > 2 * c0.mean() + 0.1
    assert o10.count("docked") < 3


def test_closed_loop_modules_never_import_bpy():
    code = (
        "import sys\nimport blendgen.vehicle.closed_loop, blendgen.tools.apps.closed_loop, blendgen.blender.serve\n"
        "sys.exit(1 if 'bpy' in sys.modules else 0)\n"
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# ---------------------------------------------------------------- lost target, contact
def scripted_dropout(t_from, t_to, **kw):
    """The oracle, blind for capture times in [t_from, t_to) s."""
    see = oracle(**kw)

    def observe(k, t, T_world_cam):
        return Observation(None, {}) if t_from <= t < t_to else see(k, t, T_world_cam)

    return observe


def test_a_long_dropout_dead_reckons_backs_off_and_reacquires():
    from blendgen.vehicle.closed_loop import Recovery

    fp = FilterParams(hold_s=2.0, lost_s=30.0)
    r = simulate_closed_loop(setup(filter=fp, recovery=Recovery(backoff_s=12.0)), scripted_dropout(5.0, 22.0))
    f = pd.DataFrame(r["frames"])
    modes = f.set_index("t")["nav_mode"]
    assert modes.loc[4.0] == "tracking"
    assert set(modes.loc[5.2:6.9]) == {"dead_reckoning"}  # within hold_s of the last fix (4.9 s)
    assert set(modes.loc[7.1:18.8]) == {"back_off"}  # then back off for backoff_s
    assert set(modes.loc[19.1:21.9]) == {"hold"}
    # backing off: the vehicle stops and the range to the dock grows again while it faces the dock
    rng = f.set_index("t")["range_m"]
    assert rng.loc[18.8] > rng.loc[7.0:18.8].min() + 1.0
    assert abs(f.set_index("t")["heading_err_deg"].loc[18.8]) < 5.0
    assert r["reacquisitions"] == 1 and r["outcome"] == "docked"
    assert math.isnan(r["lost_after_s"])


def test_a_localizer_that_goes_blind_for_good_aborts_after_lost_s():
    fp = FilterParams(hold_s=2.0, lost_s=10.0)
    r = simulate_closed_loop(setup(filter=fp), scripted_dropout(3.0, 1e9))
    assert r["outcome"] == "lost_target" and r["reacquisitions"] == 0
    assert r["lost_after_s"] == pytest.approx(10.1, abs=1e-6)  # last fix at 2.9 s, abort at 13.0 s
    assert r["t_end"] == pytest.approx(13.0)


def test_hitting_the_dock_frame_is_a_collision_with_the_nose_speed_into_the_face():
    # steering onto an axis 0.5 m beside the true one: the nose meets the face plate between the
    # capture radius (0.40 m) and the face edge plus hull radius (0.60 m)
    r = simulate_closed_loop(
        setup(start={**START, "lateral_m": 0.5, "heading_error_deg": 0.0}), oracle(lateral_bias_m=0.5)
    )
    assert r["outcome"] == "collision"
    assert CAPTURE.capture_radius_m < abs(r["cross_lateral_m"]) < CAPTURE.frame_half_m[0]
    # independent: the nose's range rate over the last frame (finite difference of logged poses)
    f = pd.DataFrame(r["frames"])
    axes = DockAxesNED(T_WD)
    noses = [
        axes.p_dock(F_WORLD_NED @ np.array([x, y, z]))[2]
        for x, y, z in zip(f["x_cam_world"], f["y_cam_world"], f["z_world"])
    ]
    fd = (noses[-2] - noses[-1]) / 0.1
    assert r["impact_speed_mps"] == pytest.approx(fd, abs=0.02)
    assert 0.2 <= r["impact_speed_mps"] < 0.5  # between final and cruise speed
    # 0.1 m further out, the nose passes beside the face: no contact, no impact speed
    miss = simulate_closed_loop(
        setup(start={**START, "lateral_m": 0.7, "heading_error_deg": 0.0}), oracle(lateral_bias_m=0.7)
    )
    assert miss["outcome"] == "out_of_capture" and math.isnan(miss["impact_speed_mps"])


def test_nose_closing_speed_of_a_straight_approach_and_of_a_turn():
    from blendgen.vehicle.closed_loop import nose_closing_speed

    axes = DockAxesNED(T_WD)
    eta = [0.0, 0.0, 1.0, 0.0, 0.0, axes.approach_psi]
    assert nose_closing_speed(axes, eta, [0.3, 0, 0, 0, 0, 0], T_BC) == pytest.approx(0.3)
    # a yaw rate swings the nose sideways, not into the face
    assert nose_closing_speed(axes, eta, [0.3, 0, 0, 0, 0, 0.5], T_BC) == pytest.approx(0.3)
    # sway at a 90 deg heading error is all closing speed
    eta90 = eta[:5] + [axes.approach_psi + math.pi / 2]
    assert abs(nose_closing_speed(axes, eta90, [0.0, 0.25, 0, 0, 0, 0], T_BC)) == pytest.approx(0.25)


def test_before_the_first_fix_the_vehicle_creeps_on_along_its_start_heading_until_it_sees_the_dock():
    r = simulate_closed_loop(setup(), scripted_dropout(0.0, 6.0))
    f = pd.DataFrame(r["frames"]).set_index("t")
    assert set(f["nav_mode"].loc[0.0:5.9]) == {"acquire"}
    assert f["nav_mode"].loc[6.5] == "tracking"
    # heading held at the start's, forward at about the final approach speed (0.2 m/s) once up to speed
    assert f["heading_err_deg"].loc[0.0:5.9].sub(START["heading_error_deg"]).abs().max() < 1.0
    assert (f["range_m"].loc[3.0] - f["range_m"].loc[5.9]) / 2.9 == pytest.approx(
        0.2 * math.cos(math.radians(START["heading_error_deg"])), abs=0.05
    )
    assert r["outcome"] == "docked" and r["reacquisitions"] == 0


def test_summary_of_an_older_run_without_lost_target_and_contact_columns():
    from blendgen.tools.apps.closed_loop import summary_table

    old = pd.DataFrame(
        {
            "localizer": ["truth"] * 2,
            "condition": ["c"] * 2,
            "trial": [0, 1],
            "outcome": ["docked", "collision"],
            "docked": [True, False],
            "time_to_dock_s": [20.0, math.nan],
            "final_lateral_m": [0.1, -0.5],
            "final_heading_deg": [1.0, 2.0],
        }
    )
    s = summary_table(old, pd.DataFrame(), authority={"c": "within (margin 61%)"}).iloc[0]
    assert s["n_docked"] == 1 and s["n_reacquired"] == 0 and math.isnan(s["impact_speed_median_mps"])
    assert s["authority"] == "within (margin 61%)"


def test_dock_with_localizer_none_runs_the_truth_baseline_alone(tmp_path):
    from click.testing import CliRunner

    import cli

    out = tmp_path / "truth"
    args = ["dock", "current", "-l", "none", "--trials", "1", "--condition", "current_0.0", "-o", str(out)]
    res = CliRunner().invoke(cli.main, args)
    assert res.exit_code == 0, res.output
    trials = pd.read_parquet(out / "trials.parquet")
    assert list(trials["localizer"]) == ["truth"] and trials["outcome"].iloc[0] == "docked"
    assert trials["contact_part"].iloc[0] == "" and math.isnan(trials["impact_speed_mps"].iloc[0])
    assert not (out / "render_server.log").exists()  # nothing rendered
    bad = CliRunner().invoke(cli.main, ["dock", "current", "-l", "none", "--no-baseline", "-o", str(tmp_path / "b")])
    assert bad.exit_code == 2 and "nothing to run" in bad.output and not (tmp_path / "b").exists()
