"""Per-frame scoring and per-trial metrics against hand-computed values, plus properties."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evalkit.metrics import core as metrics
from evalkit.metrics.core import SuccessCriteria
from evalkit.reports import tables

NAN = float("nan")


def _table(rows):
    """rows: (localizer, sequence, condition, d_true, detected, d_est)."""
    return pd.DataFrame(rows, columns=["localizer", "sequence", "condition", "d_true", "detected", "d_est"])


@pytest.fixture
def synthetic():
    return _table(
        [
            # s1: boundary distances; 10.01 m and -1 m do not count.
            ("a", "s1", "c", 0.0, True, 0.05),  # counts, e_abs .05 (= 5 cm floor: success), no e_rel
            ("a", "s1", "c", 0.1, True, 0.12),  # counts, e_abs .02, no e_rel, success
            ("a", "s1", "c", 0.2, True, 0.25),  # counts, e_abs .05, e_rel .25, success (floor)
            ("a", "s1", "c", 10.0, True, 8.5),  # counts, e_abs 1.5, e_rel .15 > 10 %: detected, not success
            ("a", "s1", "c", 10.01, True, 10.01),  # ignored (> 10 m)
            ("a", "s1", "c", -1.0, True, 1.0),  # ignored (< 0)
            ("a", "s1", "c", 5.0, False, NAN),  # counts, failure
            # s2: all failures
            ("a", "s2", "c", 1.0, False, NAN),
            ("a", "s2", "c", 2.0, False, NAN),
            ("a", "s2", "c", 3.0, False, NAN),
            # s3: one detection with e_rel .1 (at the bound: success)
            ("a", "s3", "c", 1.0, True, 1.1),
            ("a", "s3", "c", 2.0, False, NAN),
            # s4: nothing in range
            ("a", "s4", "c", 12.0, True, 12.0),
            # another localizer / condition
            ("b", "s1", "c", 4.0, True, 3.0),  # e_rel .25
            ("b", "t1", "d", 4.0, True, 5.0),  # e_rel .25
        ]
    )


def _by_seq(trials, loc, seq):
    return trials[(trials.localizer == loc) & (trials.sequence == seq)].iloc[0]


def test_frame_errors_boundaries(synthetic):
    err = metrics.frame_errors(synthetic)
    assert err["e_abs"].iloc[:4].tolist() == pytest.approx([0.05, 0.02, 0.05, 1.5])
    assert err["e_rel"].iloc[:2].isna().all()  # d_true 0 and 0.1 < 0.2 m
    assert err["e_rel"].iloc[2:4].tolist() == pytest.approx([0.25, 0.15])  # 0.2 m counts
    assert math.isnan(err["e_abs"].iloc[6])  # failure


def test_counted_mask_boundaries():
    d = pd.Series([0.0, 0.1, 0.2, 10.0, 10.01, -0.001, NAN])
    assert metrics.counted_mask(d).tolist() == [True, True, True, True, False, False, False]


def test_per_trial_hand_computed(synthetic):
    trials, _ = metrics.summarize(synthetic)
    assert list(trials.columns) == metrics.TRIAL_COLUMNS
    s1 = _by_seq(trials, "a", "s1")
    assert (s1.n_total, s1.n_detect, s1.n_succ) == (5, 4, 3)
    assert s1.P_detect == pytest.approx(0.8) and s1.P_succ == pytest.approx(0.6)
    assert s1.e_abs_mean == pytest.approx((0.05 + 0.02 + 0.05 + 1.5) / 4)  # over detections
    assert s1.e_rel_mean == pytest.approx((0.25 + 0.15) / 2)
    s2 = _by_seq(trials, "a", "s2")
    assert (s2.n_total, s2.n_succ, s2.P_succ, s2.P_detect) == (3, 0, 0.0, 0.0)
    assert math.isnan(s2.e_abs_mean) and math.isnan(s2.e_rel_mean)
    s3 = _by_seq(trials, "a", "s3")
    assert s3.P_succ == pytest.approx(0.5) and s3.e_rel_mean == pytest.approx(0.1)
    s4 = _by_seq(trials, "a", "s4")
    assert s4.n_total == 0 and math.isnan(s4.P_succ)
    assert _by_seq(trials, "b", "s1").P_succ == 0.0 and _by_seq(trials, "b", "s1").P_detect == 1.0


def test_d_min_rel_parameter(synthetic):
    trials, _ = metrics.summarize(synthetic, d_min_rel=0.05)
    # now d_true = 0.1 gets e_rel 0.2; d_true = 0 never does (division by zero)
    assert _by_seq(trials, "a", "s1").e_rel_mean == pytest.approx((0.2 + 0.25 + 0.15) / 3)


def test_d_max_parameter(synthetic):
    trials, _ = metrics.summarize(synthetic, d_max=20.0)
    assert _by_seq(trials, "a", "s1").n_total == 6
    assert _by_seq(trials, "a", "s4").n_total == 1


def test_per_condition_hand_computed(synthetic):
    _, cond = metrics.summarize(synthetic)
    a = cond[(cond.localizer == "a") & (cond.condition == "c")].iloc[0]
    assert a.n_trials == 3  # s4 has no counted frame
    assert a.P_detect_mean == pytest.approx((0.8 + 0.0 + 0.5) / 3)
    assert a.P_succ_mean == pytest.approx((0.6 + 0.0 + 0.5) / 3)
    assert a.E_rel_mean == pytest.approx((0.2 + 0.1) / 2)  # s2 (no detection) skipped
    b = cond[cond.localizer == "b"].set_index("condition")
    assert b.loc["c", "E_rel_mean"] == pytest.approx(0.25)
    assert b.loc["d", "n_trials"] == 1


def test_detection_needs_finite_nonnegative_estimate():
    df = _table(
        [
            ("a", "s", "c", 1.0, True, NAN),
            ("a", "s", "c", 1.0, True, -1.0),
            ("a", "s", "c", 1.0, True, math.inf),
            ("a", "s", "c", 1.0, True, 1.0),
        ]
    )
    t = metrics.summarize(df)[0].iloc[0]
    assert (t.n_total, t.n_detect, t.n_succ) == (4, 1, 1)


def _pose(t=(0.0, 0.0, 5.0), rot_deg=0.0):
    a = math.radians(rot_deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    T[:3, 3] = t
    return T.ravel().tolist()


def test_success_criteria_distance_pose_and_identity():
    """Each row fails (or passes) exactly one of the criteria, at d_true = 5 m (tol 0.5 m)."""
    rows = [  # d_est, T_est, marker_id, in_view, markers_in_fov -> expected success
        (5.49, None, "m1", True, "m1", True),  # distance only, within 10 %
        (5.51, None, "m1", True, "m1", False),  # distance beyond 10 %
        (5.0, _pose((0.0, 0.6, 5.0)), "m1", True, "m1", False),  # translation 0.6 > 0.5 m
        (5.0, _pose((0.0, 0.4, 5.0)), "m1", True, "m1", True),
        (5.0, _pose(rot_deg=10.5), "m1", True, "m1", False),  # rotation > 10 deg
        (5.0, _pose(rot_deg=9.5), "m1", True, "m1", True),
        (5.0, _pose(), "m2", True, "m1", False),  # wrong id: false positive
        (5.0, _pose(), None, False, "", False),  # nothing in view: false positive
    ]
    df = pd.DataFrame(
        [
            {
                "localizer": "x",
                "sequence": "s",
                "condition": "c",
                "d_true": 5.0,
                "detected": True,
                "d_est": d,
                "T_cam_dock_est": T,
                "T_cam_dock": _pose(),
                "marker_id": mid,
                "in_view": v,
                "markers_in_fov": fov,
            }
            for d, T, mid, v, fov, _ in rows
        ]
    )
    s = metrics.score_frames(df)
    assert s["success"].tolist() == [r[-1] for r in rows]
    assert s["fp"].tolist() == [False] * 6 + [True, True]
    loose = metrics.score_frames(df, SuccessCriteria(max_rel_dist=0.2, max_rel_trans=0.2, max_rot_deg=20))
    assert loose["success"].tolist() == [True] * 6 + [False, False]
    with pytest.raises(ValueError, match="max_rot_deg"):
        SuccessCriteria(max_rot_deg=0.0)


def test_tables_formatters(synthetic):
    summary = metrics.summarize(synthetic)[0][["localizer", "sequence", "n_total", "P_succ", "e_rel_mean"]]
    md = tables.to_markdown(summary)
    lines = md.splitlines()
    assert lines[0].startswith("| localizer") and len(lines) == 2 + len(summary)
    assert "-" in lines[3]  # NaN shown as '-'
    tex = tables.to_latex(summary, caption="50% of s_1")
    assert r"\begin{tabular}{llrrr}" in tex and r"50\% of s\_1" in tex
    assert r"e\_rel\_mean" in tex


@settings(max_examples=300, deadline=None)
@given(st.floats(0, 1), st.floats(0, 1), st.floats(0, 1), st.integers(0, 3))
def test_printed_mean_never_outside_its_printed_ci(a, b, c, digits):
    lo, mean, hi = sorted([a, b, c])
    text = tables._pct(mean, lo, hi, digits)
    m, rest = text.split(" [")
    plo, phi = (float(x) for x in rest.rstrip("]").split(", "))
    assert plo <= float(m) <= phi


# -- properties -----------------------------------------------------------
_d_true = st.one_of(st.floats(-1.0, 12.0, allow_nan=False), st.sampled_from([0.0, 0.2, 10.0]))
_d_est = st.one_of(st.floats(0.0, 30.0, allow_nan=False), st.just(NAN), st.just(-1.0))
_row = st.tuples(st.sampled_from(["a", "b"]), st.sampled_from(["s1", "s2", "s3"]), _d_true, st.booleans(), _d_est)


def _from_rows(rows):
    df = pd.DataFrame(rows, columns=["localizer", "sequence", "d_true", "detected", "d_est"])
    df["condition"] = df["sequence"].map({"s1": "c", "s2": "c", "s3": "d"})
    return df


@settings(max_examples=150, deadline=None)
@given(st.lists(_row, min_size=1, max_size=40))
def test_properties(rows):
    df = _from_rows(rows)
    trials, cond = metrics.summarize(df)
    p, pd_ = trials["P_succ"], trials["P_detect"]
    assert ((p >= 0) & (p <= 1) | p.isna()).all()
    assert (p.isna() == (trials["n_total"] == 0)).all()
    assert (trials["n_succ"] <= trials["n_detect"]).all() and (trials["n_detect"] <= trials["n_total"]).all()
    assert ((p <= pd_) | p.isna()).all()  # success implies detection
    err = metrics.frame_errors(df)
    assert (err["e_rel"].dropna() >= 0).all() and (err["e_abs"].dropna() >= 0).all()
    assert (trials["e_rel_mean"].dropna() >= 0).all()
    pm = cond["P_succ_mean"]
    assert ((pm >= 0) & (pm <= 1)).all()
    assert (cond["E_rel_mean"].dropna() >= 0).all()


@settings(max_examples=100, deadline=None)
@given(st.lists(_row, min_size=1, max_size=40), st.randoms(use_true_random=False))
def test_row_order_invariance(rows, rnd):
    df = _from_rows(rows)
    shuffled = df.iloc[rnd.sample(range(len(df)), len(df))]
    a, b = metrics.summarize(df), metrics.summarize(shuffled)
    pd.testing.assert_frame_equal(a[0], b[0], check_exact=False, rtol=1e-9)
    pd.testing.assert_frame_equal(a[1], b[1], check_exact=False, rtol=1e-9)
