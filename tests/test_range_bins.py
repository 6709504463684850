"""Reports per range bin: the range-matched error and the per-experiment figure/table.

Oracle: two conditions with the *same* error at every range, one of which loses its far
frames. The pooled error of the short one is lower (selection); the range-matched error
is the same for both (physics)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from evalkit.metrics import extra as mx
from evalkit.reports import plots, tables


def _bins(e_rel_of_bin, kept: dict[str, int], n_bins: int = 10) -> pd.DataFrame:
    """A bins table (mx.BIN_COLUMNS) for localizer ``led``, trajectory ``approach``:
    condition -> number of near bins with estimates (frames everywhere, estimates in the
    first ``kept`` bins, error ``e_rel_of_bin(k)``)."""
    rows = []
    for cond, n_kept in kept.items():
        for k in range(n_bins):
            ok = k < n_kept
            rows.append(
                {
                    "localizer": "led",
                    "trajectory": "approach",
                    "condition": cond,
                    "bin_lo": float(k),
                    "bin_hi": float(k + 1),
                    "n_total": 20,
                    "n_detect": 20 if ok else 0,
                    "n_succ": 20 if ok else 0,
                    "P_detect": 1.0 if ok else 0.0,
                    "P_succ": 1.0 if ok else 0.0,
                    "e_abs_mean": e_rel_of_bin(k) * (k + 0.5) if ok else np.nan,
                    "e_rel_mean": e_rel_of_bin(k) if ok else np.nan,
                }
            )
    return pd.DataFrame(rows, columns=mx.BIN_COLUMNS)


def err(k):
    return 0.002 * (k + 1)  # the relative error grows with range: 0.2 % per metre


def test_range_matched_error_removes_the_selection_by_range():
    bins = _bins(err, {"clear": 10, "moderate": 7})
    pooled = bins.groupby("condition")["e_rel_mean"].mean()
    assert pooled["moderate"] < pooled["clear"] - 0.002  # the selection
    m = mx.range_matched(bins).set_index("condition")
    expected = np.mean([err(k) for k in range(7)])  # bins 0-7 m, equal weights
    assert m.loc["clear", "E_rel_matched"] == pytest.approx(expected)
    assert m.loc["moderate", "E_rel_matched"] == pytest.approx(expected)
    assert (m.loc["clear", "matched_lo_m"], m.loc["clear", "matched_hi_m"]) == (0.0, 7.0)
    assert m.loc["moderate", "n_matched_bins"] == 7
    worse = _bins(lambda k: 2 * err(k), {"x": 7})  # twice the error: seen at matched range
    both = pd.concat([bins[bins.condition == "clear"], worse.assign(condition="murky")])
    m2 = mx.range_matched(both).set_index("condition")
    assert m2.loc["murky", "E_rel_matched"] == pytest.approx(2 * m2.loc["clear", "E_rel_matched"])


def test_no_common_bin_gives_nan():
    a = _bins(err, {"near": 3})
    b = _bins(err, {"far": 0})
    m = mx.range_matched(pd.concat([a, b])).set_index("condition")
    assert np.isnan(m.loc["near", "E_rel_matched"]) and m.loc["near", "n_matched_bins"] == 0


def test_range_bin_table_and_figure(tmp_path):
    bins = _bins(err, {"clear": 10, "moderate": 7})
    t = tables.range_bin_table(bins, "led", "approach").set_index("condition")
    assert t.loc["clear", "6-7 m"] == "100 / 1.40" and t.loc["moderate", "8-9 m"] == "0 / -"
    md = tables.range_bins_markdown(bins)
    assert "### approach: led" in md and "| moderate" in md
    png = plots.plot_range_bins(bins, tmp_path / "range_bins.png", title="t")
    assert png.stat().st_size > 10_000
