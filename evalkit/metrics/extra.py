"""Metrics beyond the article (SPEC.md section 7 stays the headline: ``P_succ``, ``E_rel``).

Input is the runner's per-frame estimate table (:data:`evalkit.runner.COLUMNS`)
optionally joined with the dataset's ground truth (:func:`attach_truth` with
:func:`evalkit.metrics.truth.frame_truth_table`). Units: metres, degrees, milliseconds;
rates and probabilities are fractions.

* **Pose errors** (needs the estimate column ``T_cam_dock_est``, 16 floats
  row-major, and the truth ``T_cam_dock``): ``e_trans`` = |t_est - t_true| (m)
  of the dock origin in the camera frame; ``e_rot_deg`` = angle of
  ``R_true^T R_est`` (deg); the position error split along the viewing ray to
  the true dock origin, ``u = t_true/|t_true|``: ``e_range = (t_est - t_true).u``
  (signed, + = estimated too far) and ``e_lateral`` = norm of the perpendicular
  part (m). Only successful frames with a pose have them.
* **False positives** (over *all* frames, the 0..10 m window does not apply): a
  successful frame where no marker is in view (``in_view`` false), or whose
  reported ``marker_id`` is not among the markers in view
  (``markers_in_fov`` from the truth). ``fp_rate`` = false / all estimates,
  ``fp_rate_no_view`` = estimates on frames with no marker in view / such frames.
* **Distance bins** (1 m by default) pooling the counted frames of a
  condition; **usable range** = upper edge of the farthest bin whose
  ``P_succ >= 0.9`` (not required to be contiguous with the near bins).
* **Bootstrap CIs** over trials (percentile method, seeded numpy, each
  (localizer, condition, metric) its own stream so results do not depend on
  row order) for ``P_succ_mean`` and ``E_rel_mean``.
* **Runtime**: ``ms`` per ``localize`` call, median and 95th percentile
  (frames that never reached ``localize`` because ``reset`` failed excluded).
"""
from __future__ import annotations

import zlib
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from evalkit.metrics import core as metrics
from evalkit.metrics.truth import as_matrices

EST_POSE = "T_cam_dock_est"
TRUE_POSE = "T_cam_dock"
POSE_ERROR_COLUMNS = ["e_trans", "e_rot_deg", "e_range", "e_lateral"]
GROUP = ["localizer", "condition"]
BIN_COLUMNS = GROUP + ["bin_lo", "bin_hi", "n_total", "n_succ", "P_succ", "e_abs_mean", "e_rel_mean"]
METRIC_COLUMNS = GROUP + [
    "n_trials", "P_succ_mean", "P_succ_lo", "P_succ_hi", "E_rel_mean", "E_rel_lo", "E_rel_hi",
    "e_abs_mean", "e_trans_mean", "e_rot_deg_mean", "e_range_abs_mean", "e_lateral_mean",
    "n_est", "n_fp", "fp_rate", "fp_rate_no_view", "max_range_m", "ms_median", "ms_p95"]
RUNTIME_COLUMNS = ["localizer", "n_calls", "ms_median", "ms_p95", "ms_mean"]


# -- joining the truth -------------------------------------------------------
def attach_truth(estimates: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Left-join truth columns (``T_cam_dock``, ``markers_in_fov``, per-marker) on (sequence, index).

    Columns already in ``estimates`` (``d_true``, ``in_view``, ...) are kept
    from ``estimates``. Row order and index of ``estimates`` are preserved.
    """
    keys = ["sequence", "index"]
    add = [c for c in truth.columns if c not in estimates.columns or c in keys]
    right = truth[add].copy()
    right["index"] = pd.to_numeric(right["index"]).astype("int64")
    right["sequence"] = right["sequence"].astype(str)
    left = estimates.copy()
    left["_row"] = np.arange(len(left))
    left["index"] = pd.to_numeric(left["index"]).astype("int64")
    left["sequence"] = left["sequence"].astype(str)
    out = left.merge(right, on=keys, how="left", validate="many_to_one")
    out = out.sort_values("_row").drop(columns="_row")
    out.index = estimates.index
    out.attrs.update(estimates.attrs)
    return out


# -- per-frame quantities -----------------------------------------------------
def pose_errors(df: pd.DataFrame) -> pd.DataFrame:
    """Per-frame ``e_trans`` (m), ``e_rot_deg`` (deg), ``e_range`` (m, signed), ``e_lateral`` (m).

    NaN where the frame failed, has no estimated pose (column ``T_cam_dock_est``
    missing or None) or no true pose (``T_cam_dock``). Same index as ``df``.
    """
    out = pd.DataFrame(np.nan, index=df.index, columns=POSE_ERROR_COLUMNS)
    if EST_POSE not in df.columns or TRUE_POSE not in df.columns or df.empty:
        return out
    est, true = as_matrices(df[EST_POSE]), as_matrices(df[TRUE_POSE])
    ok = metrics.success_mask(df).to_numpy() & np.isfinite(est).all(axis=(1, 2)) \
        & np.isfinite(true).all(axis=(1, 2))
    if not ok.any():
        return out
    e, t = est[ok], true[ok]
    dt = e[:, :3, 3] - t[:, :3, 3]
    norm = np.linalg.norm(t[:, :3, 3], axis=1, keepdims=True)
    ray = np.divide(t[:, :3, 3], norm, out=np.zeros_like(dt), where=norm > 0)
    along = np.einsum("ij,ij->i", dt, ray)
    lateral = np.linalg.norm(dt - along[:, None] * ray, axis=1)
    rel = np.einsum("nji,njk->nik", t[:, :3, :3], e[:, :3, :3])  # R_true^T R_est
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    out.loc[ok, "e_trans"] = np.linalg.norm(dt, axis=1)
    out.loc[ok, "e_rot_deg"] = np.degrees(np.arccos(cos))
    out.loc[ok, "e_range"] = along
    out.loc[ok, "e_lateral"] = lateral
    return out


def false_positive_mask(df: pd.DataFrame) -> pd.Series:
    """True for a successful frame with no marker in view, or with a ``marker_id`` not in view.

    The wrong-id test needs ``markers_in_fov`` (comma-joined ids, from
    :func:`attach_truth`); without it only the no-view test applies. An
    estimate without ``marker_id`` is never a wrong-id false positive.
    """
    succ = metrics.success_mask(df)
    no_view = ~df["in_view"].fillna(False).astype(bool)
    wrong = pd.Series(False, index=df.index)
    if "marker_id" in df.columns and "markers_in_fov" in df.columns:
        ids = df["marker_id"]
        has = ids.notna() & (ids.astype(str) != "")
        visible = df["markers_in_fov"].fillna("").astype(str)
        wrong = pd.Series([bool(h) and str(m) not in v.split(",")
                           for h, m, v in zip(has, ids, visible)], index=df.index)
    return succ & (no_view | wrong)


# -- bootstrap ---------------------------------------------------------------
def _rng(seed: int, *key: str) -> np.random.Generator:
    """A generator that depends only on ``seed`` and the text key (not on row order)."""
    return np.random.default_rng([int(seed), zlib.crc32("\0".join(map(str, key)).encode())])


def bootstrap_ci(values, n_boot: int = 2000, level: float = 0.95, seed: int | np.random.Generator = 0,
                 stat: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[float, float]:
    """Percentile bootstrap CI ``(lo, hi)`` of ``stat`` (default mean) of ``values``.

    NaNs are dropped first; no value gives ``(nan, nan)``, one value ``(v, v)``.
    ``stat`` maps an ``(n_boot, n)`` resample array to ``n_boot`` statistics.
    ``seed`` is an int or a numpy Generator; the same seed gives the same CI.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    if v.size == 1:
        return float(v[0]), float(v[0])
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    samples = v[rng.integers(0, v.size, size=(int(n_boot), v.size))]
    stats = stat(samples) if stat is not None else samples.mean(axis=1)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(stats, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


def condition_cis(trials: pd.DataFrame, columns: dict[str, str] | None = None, n_boot: int = 2000,
                  level: float = 0.95, seed: int = 0) -> pd.DataFrame:
    """Bootstrap CIs over the trials of each (localizer, condition), from :func:`metrics.per_trial`.

    ``columns`` maps a per-trial column to the output prefix (default
    ``P_succ -> P_succ``, ``e_rel_mean -> E_rel``); output columns
    ``<prefix>_lo, <prefix>_hi``. Trials with ``n_total == 0`` are left out,
    as in :func:`metrics.per_condition`; NaN values (no success) are dropped.
    """
    columns = columns or {"P_succ": "P_succ", "e_rel_mean": "E_rel"}
    valid = trials[trials["n_total"] > 0]
    rows = []
    for (loc, cond), g in valid.groupby(GROUP, sort=True, dropna=False):
        row = {"localizer": loc, "condition": cond}
        g = g.sort_values("sequence", kind="stable")   # resample in a fixed order
        for col, prefix in columns.items():
            lo, hi = bootstrap_ci(g[col].to_numpy(float), n_boot, level, _rng(seed, loc, cond, col))
            row[f"{prefix}_lo"], row[f"{prefix}_hi"] = lo, hi
        rows.append(row)
    cols = GROUP + [f"{p}_{s}" for p in columns.values() for s in ("lo", "hi")]
    return pd.DataFrame(rows, columns=cols)


# -- distance bins and usable range ------------------------------------------
def distance_bins(df: pd.DataFrame, bin_m: float = 1.0, d_max: float = metrics.D_MAX_M,
                  d_min_rel: float = metrics.D_MIN_REL_M) -> pd.DataFrame:
    """Per (localizer, condition, distance bin): counted frames pooled over trials.

    Bins are ``[k*bin_m, (k+1)*bin_m)`` for ``0 <= d_true <= d_max``; ``d_true
    == d_max`` falls in the last bin. Every bin appears for every group (empty
    ones with ``n_total = 0`` and NaN rates). Columns :data:`BIN_COLUMNS`.
    """
    n_bins = int(np.ceil(d_max / bin_m - 1e-9))
    counted = metrics.counted_mask(df["d_true"], d_max)
    frames = df.loc[counted, GROUP].copy()
    d = df.loc[counted, "d_true"].astype(float)
    frames["_bin"] = np.minimum((d / bin_m + 1e-12).astype(int), n_bins - 1)
    frames["_succ"] = metrics.success_mask(df)[counted]
    frames[["e_abs", "e_rel"]] = metrics.frame_errors(df, d_min_rel)[counted]
    stats = frames.groupby(GROUP + ["_bin"], dropna=False).agg(
        n_total=("_succ", "size"), n_succ=("_succ", "sum"),
        e_abs_mean=("e_abs", "mean"), e_rel_mean=("e_rel", "mean")).reset_index()
    groups = df[GROUP].drop_duplicates()
    full = groups.merge(pd.DataFrame({"_bin": np.arange(n_bins)}), how="cross")
    out = full.merge(stats, on=GROUP + ["_bin"], how="left")
    out["n_total"] = out["n_total"].fillna(0).astype("int64")
    out["n_succ"] = out["n_succ"].fillna(0).astype("int64")
    out["P_succ"] = out["n_succ"] / out["n_total"].where(out["n_total"] > 0)
    out["bin_lo"] = out["_bin"] * bin_m
    out["bin_hi"] = np.minimum((out["_bin"] + 1) * bin_m, d_max)
    out = out.sort_values(GROUP + ["_bin"], kind="stable").reset_index(drop=True)
    return out[BIN_COLUMNS].astype({"P_succ": float, "e_abs_mean": float, "e_rel_mean": float,
                                    "bin_lo": float, "bin_hi": float})


def max_usable_range(bins: pd.DataFrame, threshold: float = 0.9, min_frames: int = 1) -> pd.DataFrame:
    """Per (localizer, condition): ``max_range_m``, the ``bin_hi`` (m) of the farthest bin
    with at least ``min_frames`` frames and ``P_succ >= threshold``; NaN if there is none."""
    ok = bins[(bins["n_total"] >= min_frames) & (bins["P_succ"] >= threshold)]
    best = ok.groupby(GROUP, dropna=False)["bin_hi"].max().rename("max_range_m")
    groups = bins[GROUP].drop_duplicates()
    return groups.merge(best.reset_index(), on=GROUP, how="left").reset_index(drop=True)


# -- false positives and runtime ---------------------------------------------
def false_positive_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per (localizer, condition), all frames: ``n_frames, n_est, n_fp, fp_rate, n_no_view, fp_rate_no_view``."""
    x = df[GROUP].copy()
    x["_est"] = metrics.success_mask(df)
    x["_fp"] = false_positive_mask(df)
    x["_no_view"] = ~df["in_view"].fillna(False).astype(bool)
    x["_fp_nv"] = x["_est"] & x["_no_view"]
    out = x.groupby(GROUP, dropna=False, sort=True).agg(
        n_frames=("_est", "size"), n_est=("_est", "sum"), n_fp=("_fp", "sum"),
        n_no_view=("_no_view", "sum"), _n_fp_nv=("_fp_nv", "sum")).reset_index()
    out["fp_rate"] = out["n_fp"] / out["n_est"].where(out["n_est"] > 0)
    out["fp_rate_no_view"] = out["_n_fp_nv"] / out["n_no_view"].where(out["n_no_view"] > 0)
    cols = GROUP + ["n_frames", "n_est", "n_fp", "fp_rate", "n_no_view", "fp_rate_no_view"]
    return out[cols].astype({"fp_rate": float, "fp_rate_no_view": float})


def _timed(df: pd.DataFrame) -> pd.DataFrame:
    """Rows whose ``ms`` measures a ``localize`` call (finite; reset failures excluded)."""
    ms = pd.to_numeric(df["ms"], errors="coerce")
    reset_failed = df.get("fail_reason", pd.Series("", index=df.index)).fillna("").astype(str) \
        .str.endswith("(in reset)")
    return df.assign(ms=ms)[np.isfinite(ms) & ~reset_failed]


def runtime_table(df: pd.DataFrame, by: Sequence[str] = ("localizer",)) -> pd.DataFrame:
    """Per ``by`` group: ``n_calls, ms_median, ms_p95, ms_mean`` (ms per frame)."""
    by = list(by)
    t = _timed(df)
    out = t.groupby(by, dropna=False, sort=True)["ms"].agg(
        n_calls="size", ms_median="median", ms_p95=lambda s: float(np.quantile(s, 0.95)),
        ms_mean="mean").reset_index()
    return out[by + ["n_calls", "ms_median", "ms_p95", "ms_mean"]]


# -- everything together -------------------------------------------------------
def _pose_per_trial(df: pd.DataFrame, d_max: float) -> pd.DataFrame:
    """Per trial means of the pose errors over counted successful frames."""
    errs = pose_errors(df)
    x = df[metrics.TRIAL_KEYS].copy()
    x["e_trans"] = errs["e_trans"]
    x["e_rot_deg"] = errs["e_rot_deg"]
    x["e_range_abs"] = errs["e_range"].abs()
    x["e_lateral"] = errs["e_lateral"]
    x = x[metrics.counted_mask(df["d_true"], d_max)]
    return x.groupby(metrics.TRIAL_KEYS, dropna=False).agg(
        e_trans_mean=("e_trans", "mean"), e_rot_deg_mean=("e_rot_deg", "mean"),
        e_range_abs_mean=("e_range_abs", "mean"), e_lateral_mean=("e_lateral", "mean")).reset_index()


def compute_all(estimates: pd.DataFrame, truth: pd.DataFrame | None = None,
                d_max: float | None = None, d_min_rel: float | None = None, bin_m: float = 1.0,
                usable_threshold: float = 0.9, n_boot: int = 2000, level: float = 0.95,
                seed: int = 0) -> dict[str, pd.DataFrame]:
    """Every table of a run: ``frames, trials, conditions, metrics, bins, fp, runtime``.

    ``frames`` is ``estimates`` joined with ``truth`` (if given) plus the pose
    error columns; ``trials``/``conditions`` are the article's tables
    (:mod:`evalkit.metrics.core`); ``metrics`` is one row per (localizer,
    condition) with :data:`METRIC_COLUMNS` (condition values are means of the
    per-trial values, like ``E_rel_mean``; FP and runtime pool frames).
    ``d_max``/``d_min_rel`` default to ``estimates.attrs`` then the metrics defaults.
    """
    d_max = d_max if d_max is not None else estimates.attrs.get("d_max_m", metrics.D_MAX_M)
    d_min_rel = d_min_rel if d_min_rel is not None else estimates.attrs.get("d_min_rel_m", metrics.D_MIN_REL_M)
    frames = attach_truth(estimates, truth) if truth is not None else estimates.copy()
    frames[POSE_ERROR_COLUMNS] = pose_errors(frames)
    trials = metrics.per_trial(frames, d_max, d_min_rel)
    conditions = metrics.per_condition(trials)
    trials_x = trials.merge(_pose_per_trial(frames, d_max), on=metrics.TRIAL_KEYS, how="left")
    valid = trials_x[trials_x["n_total"] > 0]
    pose_means = valid.groupby(GROUP, dropna=False).agg(
        e_abs_mean=("e_abs_mean", "mean"), e_trans_mean=("e_trans_mean", "mean"),
        e_rot_deg_mean=("e_rot_deg_mean", "mean"), e_range_abs_mean=("e_range_abs_mean", "mean"),
        e_lateral_mean=("e_lateral_mean", "mean")).reset_index()
    bins = distance_bins(frames, bin_m, d_max, d_min_rel)
    fp = false_positive_table(frames)
    runtime = runtime_table(frames, GROUP)
    out = conditions
    for part in (condition_cis(trials, n_boot=n_boot, level=level, seed=seed), pose_means,
                 fp[GROUP + ["n_est", "n_fp", "fp_rate", "fp_rate_no_view"]],
                 max_usable_range(bins, usable_threshold), runtime[GROUP + ["ms_median", "ms_p95"]]):
        out = out.merge(part, on=GROUP, how="left")
    out = out.sort_values(GROUP, kind="stable").reset_index(drop=True)
    return {"frames": frames, "trials": trials, "conditions": conditions,
            "metrics": out[METRIC_COLUMNS], "bins": bins, "fp": fp,
            "runtime": runtime_table(frames)}
