"""Evaluation metrics of SPEC.md section 7.

All distances are in metres; errors ``e_abs`` in metres, ``e_rel`` and
probabilities are dimensionless (fractions, not percent).

Input is a per-frame estimate table (see :mod:`evalkit.runner`) with at least
the columns ``localizer, sequence, condition, d_true, success, d_est``
(``trial`` optional). One sequence of the dataset is one trial.

Rules
-----
* A frame counts only if ``0 <= d_true <= d_max`` (``d_max`` = 10 m by
  default); other frames (and frames with a non-finite ``d_true``) are ignored
  by every metric.
* A frame is successful if ``success`` is true and ``d_est`` is finite and
  ``>= 0``.
* For successful frames ``e_abs = |d_true - d_est|`` and
  ``e_rel = e_abs / d_true``. **``e_rel`` is not computed (NaN) for frames with
  ``d_true < d_min_rel``** (0.2 m by default, the manifest's ``d_min_rel_m``
  when present): near the dock the ratio explodes and would dominate the mean.
  Such frames still count in ``n_total``/``n_succ`` and ``e_abs_mean``.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

D_MAX_M = 10.0
D_MIN_REL_M = 0.2
TRIAL_KEYS = ["localizer", "sequence", "condition"]
TRIAL_COLUMNS = TRIAL_KEYS + ["n_total", "n_succ", "P_succ", "e_abs_mean", "e_rel_mean"]
CONDITION_COLUMNS = ["localizer", "condition", "n_trials", "P_succ_mean", "E_rel_mean"]


def counted_mask(d_true: pd.Series, d_max: float = D_MAX_M) -> pd.Series:
    """True where a frame counts: ``0 <= d_true <= d_max`` (metres); NaN never counts."""
    d = pd.to_numeric(d_true, errors="coerce").astype(float)
    return (d >= 0.0) & (d <= d_max)


def success_mask(df: pd.DataFrame) -> pd.Series:
    """True where ``success`` is set and ``d_est`` is a finite, non-negative distance."""
    d_est = pd.to_numeric(df["d_est"], errors="coerce").astype(float)
    ok = df["success"].fillna(False).astype(bool)
    return ok & np.isfinite(d_est) & (d_est >= 0.0)


def frame_errors(df: pd.DataFrame, d_min_rel: float = D_MIN_REL_M) -> pd.DataFrame:
    """Per-frame errors: ``e_abs`` (m) and ``e_rel`` (1) for successful frames, else NaN.

    ``e_rel`` is NaN when ``d_true < d_min_rel`` (m) or when the ratio overflows. Returns a frame with the
    same index as ``df`` and columns ``e_abs, e_rel``.
    """
    d_true = pd.to_numeric(df["d_true"], errors="coerce").astype(float)
    d_est = pd.to_numeric(df["d_est"], errors="coerce").astype(float)
    succ = success_mask(df)
    e_abs = (d_true - d_est).abs().where(succ)
    e_rel = (e_abs / d_true).where(succ & (d_true >= d_min_rel) & (d_true > 0.0))
    e_rel = e_rel.where(np.isfinite(e_rel))  # a subnormal d_true overflows: undefined, never inf
    return pd.DataFrame({"e_abs": e_abs, "e_rel": e_rel}, index=df.index)


def _prepare(df: pd.DataFrame, d_max: float, d_min_rel: float) -> pd.DataFrame:
    """Counted frames only, with recomputed ``_succ``, ``e_abs``, ``e_rel``."""
    out = df[TRIAL_KEYS].copy()
    out["_succ"] = success_mask(df)
    out[["e_abs", "e_rel"]] = frame_errors(df, d_min_rel)
    return out[counted_mask(df["d_true"], d_max)]


def per_trial(df: pd.DataFrame, d_max: float = D_MAX_M,
              d_min_rel: float = D_MIN_REL_M) -> pd.DataFrame:
    """Metrics per (localizer, sequence) trial.

    Columns: ``localizer, sequence, condition, n_total, n_succ, P_succ,
    e_abs_mean`` (m) ``, e_rel_mean`` (1). ``n_total`` counts frames with
    ``0 <= d_true <= d_max``; ``P_succ = n_succ / n_total`` (NaN if
    ``n_total == 0``); ``e_abs_mean`` / ``e_rel_mean`` are means over
    successful frames (``e_rel`` only where ``d_true >= d_min_rel``), NaN when
    there is none. Trials whose frames all fall outside the range still appear
    (with ``n_total = 0``). Rows are sorted by localizer, sequence.
    """
    keys = df[TRIAL_KEYS].drop_duplicates()
    frames = _prepare(df, d_max, d_min_rel)
    grouped = frames.groupby(TRIAL_KEYS, dropna=False, sort=False)
    stats = grouped.agg(n_total=("_succ", "size"), n_succ=("_succ", "sum"),
                        e_abs_mean=("e_abs", "mean"), e_rel_mean=("e_rel", "mean")).reset_index()
    out = keys.merge(stats, on=TRIAL_KEYS, how="left")
    out["n_total"] = out["n_total"].fillna(0).astype("int64")
    out["n_succ"] = out["n_succ"].fillna(0).astype("int64")
    out["P_succ"] = out["n_succ"] / out["n_total"].where(out["n_total"] > 0)
    out = out.sort_values(TRIAL_KEYS, kind="stable").reset_index(drop=True)
    return out[TRIAL_COLUMNS].astype({"P_succ": float, "e_abs_mean": float, "e_rel_mean": float})


def per_condition(trials: pd.DataFrame) -> pd.DataFrame:
    """Metrics per (localizer, condition) over its M trials, from :func:`per_trial`.

    * ``n_trials``: trials of the condition with at least one counted frame
      (``n_total > 0``).
    * ``P_succ_mean``: mean of the per-trial ``P_succ`` over those trials.
    * ``E_rel_mean``: mean of the per-trial ``e_rel_mean``, **skipping trials
      with no successful frame** (or no frame with ``d_true >= d_min_rel``),
      whose ``e_rel_mean`` is undefined; NaN when no trial has one. The
      article's headline indicator.
    """
    valid = trials[trials["n_total"] > 0]
    grouped = valid.groupby(["localizer", "condition"], dropna=False, sort=True)
    out = grouped.agg(n_trials=("sequence", "size"), P_succ_mean=("P_succ", "mean"),
                      E_rel_mean=("e_rel_mean", "mean")).reset_index()
    out["n_trials"] = out["n_trials"].astype("int64")
    return out[CONDITION_COLUMNS].astype({"P_succ_mean": float, "E_rel_mean": float})


def summarize(df: pd.DataFrame, d_max: float = D_MAX_M,
              d_min_rel: float = D_MIN_REL_M) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(per_trial(df), per_condition(per_trial(df)))``."""
    trials = per_trial(df, d_max, d_min_rel)
    return trials, per_condition(trials)
