"""Checks of the numbers a results folder hands to the leaderboard (and to ``compare``):
results are files anyone can edit, so every number that is shown or ranked is checked
against what ``dockbench evaluate`` can produce, and a run that breaks it is refused whole
with one line naming the file, the row, the column and the allowed range.

Bounds, from the metric definitions (evalkit.metrics.core):

* probabilities and rates (P_succ, P_detect with their CI ends, AR, fp rates): [0, 1],
  and ``lo <= mean <= hi``;
* lengths (m): [0, MAX_DISTANCE_M], the largest distance an estimate may have before the
  runner records ``out_of_range`` (:data:`evalkit.runner.MAX_DISTANCE_M`, 10 km); a signed
  lateral error within +-MAX_DISTANCE_M;
* ``E_rel`` = |d_est - d_true| / d_true over d_true >= d_min_rel: [0, MAX_DISTANCE_M / d_min_rel];
* rotation errors: [0, 180] deg; times: finite and >= 0;
* counts: integers with 1 <= n_trials, 0 <= n_fp <= n_est <= n_frames, n_targets <= n_frames.

NaN (an empty cell) means "not available" and is allowed everywhere but in counts.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

MAX_DISTANCE_M = 1e4  # = evalkit.runner.MAX_DISTANCE_M (kept import-light here)
MIN_D_REL_M = 1e-3  # floor of d_min_rel for the E_rel bound (a manifest may set less)

FRACTIONS = (
    "P_succ_mean",
    "P_succ_lo",
    "P_succ_hi",
    "P_detect_mean",
    "P_detect_lo",
    "P_detect_hi",
    "AR",
    "AR_MSSD",
    "AR_MSPD",
    "AR_dock",
    "AR_dock_MSSD",
    "AR_dock_MSPD",
    "fp_rate",
    "fp_rate_no_view",
)
LENGTHS = (
    "e_abs_mean",
    "e_trans_mean",
    "e_range_abs_mean",
    "max_range_m",
    "e_abs_matched",
    "matched_lo_m",
    "matched_hi_m",
)
SIGNED_LENGTHS = ("e_lateral_mean",)
ANGLES = ("e_rot_deg_mean",)
TIMES = ("ms_median", "ms_p95")
COUNTS = ("n_trials", "n_targets", "n_frames", "n_est", "n_fp", "n_matched_bins")
INTERVALS = ("P_succ", "P_detect", "E_rel")


class NumberError(ValueError):
    """A number outside what dockbench can produce (message: file, row, column, range)."""


def _value(v: Any) -> float | None:
    """A cell as float (None: empty / NaN); non-numeric -> NumberError by the caller."""
    if v is None or (isinstance(v, str) and v.strip() == ""):
        return None
    if isinstance(v, bool):
        raise TypeError("boolean")
    f = float(v)
    return None if math.isnan(f) else f


def _check(where: str, key: str, v: Any, lo: float, hi: float) -> float | None:
    try:
        f = _value(v)
    except (TypeError, ValueError):
        raise NumberError(f"{where}: {key} = {v!r} is not a number (allowed: {lo:g}..{hi:g} or empty)") from None
    if f is not None and not (math.isfinite(f) and lo <= f <= hi):
        raise NumberError(
            f"{where}: {key} = {f!r} is outside [{lo:g}, {hi:g}] (hand-edited? re-run dockbench to rewrite it)"
        )
    return f


def _count(where: str, key: str, v: Any, lo: int) -> int | None:
    try:
        f = _value(v)
    except (TypeError, ValueError):
        f = math.nan
    if f is None:
        return None
    if not (math.isfinite(f) and f == int(f) and f >= lo):
        raise NumberError(f"{where}: {key} = {v!r} is not an integer >= {lo}")
    return int(f)


def check_metric_row(where: str, row: dict, d_min_rel_m: float | None = None) -> None:
    """One metrics.csv / run.json metrics row (with runtime columns if merged)."""
    e_rel_max = MAX_DISTANCE_M / max(d_min_rel_m or MIN_D_REL_M, MIN_D_REL_M)
    bounds = {
        **{k: (0.0, 1.0) for k in FRACTIONS},
        **{k: (0.0, MAX_DISTANCE_M) for k in LENGTHS},
        **{k: (-MAX_DISTANCE_M, MAX_DISTANCE_M) for k in SIGNED_LENGTHS},
        **{k: (0.0, 180.0) for k in ANGLES},
        **{k: (0.0, math.inf) for k in TIMES},
        **{f"E_rel_{s}": (0.0, e_rel_max) for s in ("mean", "lo", "hi", "matched")},
    }
    vals = {k: _check(where, k, row[k], lo, hi) for k, (lo, hi) in bounds.items() if k in row}
    for name in INTERVALS:
        lo, mean, hi = (vals.get(f"{name}_{s}") for s in ("lo", "mean", "hi"))
        if lo is not None and mean is not None and hi is not None and not (lo - 1e-9 <= mean <= hi + 1e-9):
            raise NumberError(
                f"{where}: {name}_lo <= {name}_mean <= {name}_hi does not hold ({lo!r}, {mean!r}, {hi!r})"
            )
    n = {k: _count(where, k, row[k], 1 if k == "n_trials" else 0) for k in COUNTS if k in row}
    for small, big in (("n_fp", "n_est"), ("n_est", "n_frames"), ("n_targets", "n_frames")):
        n_small, n_big = n.get(small), n.get(big)
        if n_small is not None and n_big is not None and n_small > n_big:
            raise NumberError(f"{where}: {small} = {n_small} exceeds {big} = {n_big} (counts disagree)")


def check_metric_rows(path: Path, rows: Iterable[dict], d_min_rel_m: float | None = None) -> None:
    """Every row of a metrics table (``path`` names it in the error)."""
    for i, row in enumerate(rows):
        label = "/".join(str(row.get(k, "")) for k in ("localizer", "trajectory", "condition"))
        check_metric_row(f"{path}: row {i + 1} ({label})", row, d_min_rel_m)


CL_FRACTIONS = ("success_rate", "ci_low", "ci_high", "P_detect_mean", "P_succ_mean")
CL_BOUNDS = {
    "final_lateral_abs_mean_m": (0.0, MAX_DISTANCE_M),
    "final_heading_abs_mean_deg": (0.0, 180.0),
    "time_to_dock_median_s": (0.0, math.inf),
}


def check_closed_loop_row(where: str, row: dict) -> None:
    """One row of closed_loop.json (counts are checked by evalkit.reports.closed_loop)."""
    vals = {k: _check(where, k, row[k], 0.0, 1.0) for k in CL_FRACTIONS if k in row}
    for k, (k_lo, k_hi) in CL_BOUNDS.items():
        if k in row:
            _check(where, k, row[k], k_lo, k_hi)
    lo, p, hi = vals.get("ci_low"), vals.get("success_rate"), vals.get("ci_high")
    if lo is not None and p is not None and hi is not None and not (lo - 1e-9 <= p <= hi + 1e-9):
        raise NumberError(f"{where}: ci_low <= success_rate <= ci_high does not hold ({lo!r}, {p!r}, {hi!r})")
