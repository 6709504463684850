"""Metrics of SPEC.md section 7 against hand-computed values, plus properties."""
from __future__ import annotations

import math

import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evalkit.metrics import core as metrics

from evalkit.reports import tables

NAN = float("nan")


def _table(rows):
    """rows: (localizer, sequence, condition, d_true, success, d_est)."""
    return pd.DataFrame(rows, columns=["localizer", "sequence", "condition", "d_true",
                                       "success", "d_est"])


@pytest.fixture
def synthetic():
    return _table([
        # s1: boundary distances; 10.01 m and -1 m do not count.
        ("a", "s1", "c", 0.0, True, 0.05),     # counts, e_abs .05, no e_rel (d < 0.2)
        ("a", "s1", "c", 0.1, True, 0.12),     # counts, e_abs .02, no e_rel
        ("a", "s1", "c", 0.2, True, 0.25),     # counts, e_abs .05, e_rel .25
        ("a", "s1", "c", 10.0, True, 9.0),     # counts, e_abs 1, e_rel .1
        ("a", "s1", "c", 10.01, True, 10.01),  # ignored (> 10 m)
        ("a", "s1", "c", -1.0, True, 1.0),     # ignored (< 0)
        ("a", "s1", "c", 5.0, False, NAN),     # counts, failure
        # s2: all failures
        ("a", "s2", "c", 1.0, False, NAN),
        ("a", "s2", "c", 2.0, False, NAN),
        ("a", "s2", "c", 3.0, False, NAN),
        # s3: one success with e_rel .1
        ("a", "s3", "c", 1.0, True, 1.1),
        ("a", "s3", "c", 2.0, False, NAN),
        # s4: nothing in range
        ("a", "s4", "c", 12.0, True, 12.0),
        # another localizer / condition
        ("b", "s1", "c", 4.0, True, 3.0),      # e_rel .25
        ("b", "t1", "d", 4.0, True, 5.0),      # e_rel .25
    ])


def _by_seq(trials, loc, seq):
    return trials[(trials.localizer == loc) & (trials.sequence == seq)].iloc[0]


def test_frame_errors_boundaries(synthetic):
    err = metrics.frame_errors(synthetic)
    assert err["e_abs"].iloc[:4].tolist() == pytest.approx([0.05, 0.02, 0.05, 1.0])
    assert err["e_rel"].iloc[:2].isna().all()            # d_true 0 and 0.1 < 0.2 m
    assert err["e_rel"].iloc[2:4].tolist() == pytest.approx([0.25, 0.1])  # 0.2 m counts
    assert math.isnan(err["e_abs"].iloc[6])                # failure


def test_counted_mask_boundaries():
    d = pd.Series([0.0, 0.1, 0.2, 10.0, 10.01, -0.001, NAN])
    assert metrics.counted_mask(d).tolist() == [True, True, True, True, False, False, False]


def test_per_trial_hand_computed(synthetic):
    trials = metrics.per_trial(synthetic)
    assert list(trials.columns) == tables.SUMMARY_COLUMNS
    s1 = _by_seq(trials, "a", "s1")
    assert (s1.n_total, s1.n_succ) == (5, 4)
    assert s1.P_succ == pytest.approx(0.8)
    assert s1.e_abs_mean == pytest.approx((0.05 + 0.02 + 0.05 + 1.0) / 4)
    assert s1.e_rel_mean == pytest.approx((0.25 + 0.1) / 2)
    s2 = _by_seq(trials, "a", "s2")
    assert (s2.n_total, s2.n_succ, s2.P_succ) == (3, 0, 0.0)
    assert math.isnan(s2.e_abs_mean) and math.isnan(s2.e_rel_mean)
    s3 = _by_seq(trials, "a", "s3")
    assert s3.P_succ == pytest.approx(0.5) and s3.e_rel_mean == pytest.approx(0.1)
    s4 = _by_seq(trials, "a", "s4")
    assert s4.n_total == 0 and math.isnan(s4.P_succ)


def test_d_min_rel_parameter(synthetic):
    trials = metrics.per_trial(synthetic, d_min_rel=0.05)
    # now d_true = 0.1 gets e_rel 0.2; d_true = 0 never does (division by zero)
    assert _by_seq(trials, "a", "s1").e_rel_mean == pytest.approx((0.2 + 0.25 + 0.1) / 3)


def test_d_max_parameter(synthetic):
    trials = metrics.per_trial(synthetic, d_max=20.0)
    assert _by_seq(trials, "a", "s1").n_total == 6
    assert _by_seq(trials, "a", "s4").n_total == 1


def test_per_condition_hand_computed(synthetic):
    cond = metrics.per_condition(metrics.per_trial(synthetic))
    assert list(cond.columns) == tables.CONDITION_COLUMNS
    a = cond[(cond.localizer == "a") & (cond.condition == "c")].iloc[0]
    assert a.n_trials == 3                                  # s4 has no counted frame
    assert a.P_succ_mean == pytest.approx((0.8 + 0.0 + 0.5) / 3)
    assert a.E_rel_mean == pytest.approx((0.175 + 0.1) / 2)  # s2 (no success) skipped
    b = cond[cond.localizer == "b"].set_index("condition")
    assert b.loc["c", "E_rel_mean"] == pytest.approx(0.25)
    assert b.loc["d", "n_trials"] == 1


def test_success_needs_finite_nonnegative_estimate():
    df = _table([("a", "s", "c", 1.0, True, NAN), ("a", "s", "c", 1.0, True, -1.0),
                 ("a", "s", "c", 1.0, True, math.inf), ("a", "s", "c", 1.0, True, 1.0)])
    t = metrics.per_trial(df).iloc[0]
    assert (t.n_total, t.n_succ) == (4, 1)


def test_tables_formatters(synthetic):
    summary = tables.summary_table(synthetic)
    md = tables.to_markdown(summary)
    lines = md.splitlines()
    assert lines[0].startswith("| localizer") and len(lines) == 2 + len(summary)
    assert "-" in lines[3]  # NaN shown as '-'
    txt = tables.to_text(tables.condition_table(summary))
    assert "E_rel_mean" in txt.splitlines()[0]
    tex = tables.to_latex(summary, caption="50% of s_1")
    assert r"\begin{tabular}{lllrrrrr}" in tex and r"50\% of s\_1" in tex
    assert r"e\_rel\_mean" in tex


def test_write_csv_columns(tmp_path, synthetic):
    path = tables.write_csv(tables.summary_table(synthetic), tmp_path / "s.csv")
    back = pd.read_csv(path)
    assert list(back.columns) == tables.SUMMARY_COLUMNS


# -- properties -----------------------------------------------------------
_d_true = st.one_of(st.floats(-1.0, 12.0, allow_nan=False), st.sampled_from([0.0, 0.2, 10.0]))
_d_est = st.one_of(st.floats(0.0, 30.0, allow_nan=False), st.just(NAN), st.just(-1.0))
_row = st.tuples(st.sampled_from(["a", "b"]), st.sampled_from(["s1", "s2", "s3"]),
                 _d_true, st.booleans(), _d_est)


def _from_rows(rows):
    df = pd.DataFrame(rows, columns=["localizer", "sequence", "d_true", "success", "d_est"])
    df["condition"] = df["sequence"].map({"s1": "c", "s2": "c", "s3": "d"})
    return df


@settings(max_examples=150, deadline=None)
@given(st.lists(_row, min_size=1, max_size=40))
def test_properties(rows):
    df = _from_rows(rows)
    trials = metrics.per_trial(df)
    p = trials["P_succ"]
    assert ((p >= 0) & (p <= 1) | p.isna()).all()
    assert (p.isna() == (trials["n_total"] == 0)).all()
    assert (trials["n_succ"] <= trials["n_total"]).all()
    err = metrics.frame_errors(df)
    assert (err["e_rel"].dropna() >= 0).all() and (err["e_abs"].dropna() >= 0).all()
    assert (trials["e_rel_mean"].dropna() >= 0).all()
    cond = metrics.per_condition(trials)
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
