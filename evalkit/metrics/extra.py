"""Every table of a run from one scored frame table: the single metrics path.

:func:`compute_all` takes the runner's per-frame table (:data:`evalkit.runner.COLUMNS`,
which carries the ground truth the scoring needs), scores every frame once
(:func:`evalkit.metrics.core.score_frames`), and derives from it the per-trial table,
the per-(localizer, trajectory, condition) metrics with CIs, pose-level recall,
distance bins, false positives and runtime. Units: metres, degrees,
milliseconds; rates are fractions.

* **Groups** are (localizer, trajectory, condition): M = the number of trials (seeded
  repetitions) in the group; trajectories are never pooled as trials.
* **CIs** over the M trials by :func:`scipy.stats.bootstrap` (BCa; percentile where BCa
  is undefined, e.g. all trials equal), one seeded stream per (group, metric) so results
  do not depend on row order. No CI for M < 2; ``few_trials`` flags M < :data:`MIN_TRIALS_FOR_CI`.
* **False positives** (over *all* frames, the 0..10 m window does not apply):
  ``fp_rate`` = false / detected, ``fp_rate_no_view`` = detections on frames with no
  marker in view / such frames.
* **Distance bins** (1 m by default) pool the counted frames of a group; **usable
  range** = upper edge of the farthest bin whose ``P_succ >= 0.9``.
* **Range-matched error** (:func:`range_matched`): a condition that loses its far frames
  reports a lower mean error over the frames it keeps only because they are nearer (the
  relative error grows with range). ``E_rel_matched`` / ``e_abs_matched`` average the
  per-bin errors over the bins where *every* condition of the (localizer, trajectory)
  has an estimate, each bin weighted equally, so conditions are compared at the same
  ranges; ``matched_lo_m`` / ``matched_hi_m`` / ``n_matched_bins`` say which.
* **Runtime**: ``ms`` per ``localize`` call, median and 95th percentile (frames that
  never reached ``localize`` because ``reset`` failed excluded).
"""

from __future__ import annotations

import warnings
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from evalkit.metrics import core
from evalkit.metrics import recall as rec
from evalkit.metrics.core import GROUP, SuccessCriteria

MIN_TRIALS_FOR_CI = 10
CI_METRICS = {"P_succ": "P_succ", "P_detect": "P_detect", "e_rel_mean": "E_rel"}
BIN_COLUMNS = GROUP + [
    "bin_lo",
    "bin_hi",
    "n_total",
    "n_detect",
    "n_succ",
    "P_detect",
    "P_succ",
    "e_abs_mean",
    "e_rel_mean",
]
METRIC_COLUMNS = GROUP + [
    "n_trials",
    "few_trials",
    "P_succ_mean",
    "P_succ_lo",
    "P_succ_hi",
    "P_detect_mean",
    "P_detect_lo",
    "P_detect_hi",
    "E_rel_mean",
    "E_rel_lo",
    "E_rel_hi",
    "e_abs_mean",
    "e_trans_mean",
    "e_rot_deg_mean",
    "e_range_abs_mean",
    "e_lateral_mean",
    "AR_dock",
    "AR_dock_MSSD",
    "AR_dock_MSPD",
    "n_targets",
    "n_frames",
    "n_est",
    "n_fp",
    "fp_rate",
    "fp_rate_no_view",
    "max_range_m",
    "E_rel_matched",
    "e_abs_matched",
    "n_matched_bins",
    "matched_lo_m",
    "matched_hi_m",
]
MATCHED_COLUMNS = ["E_rel_matched", "e_abs_matched", "n_matched_bins", "matched_lo_m", "matched_hi_m"]
RUNTIME_COLUMNS = ["localizer", "n_calls", "ms_median", "ms_p95", "ms_mean"]


@dataclass(frozen=True)
class EvalSettings:
    """How a run is scored and summarised (all recorded in run.json).

    ``d_max_m`` / ``d_min_rel_m``: counted window and e_rel floor (m); ``criteria``:
    thresholded success; ``bin_m``: distance bin width (m); ``usable_threshold``:
    P_succ a bin needs to count as usable; bootstrap ``n_boot`` resamples at ``level``
    with ``seed``."""

    d_max_m: float = core.D_MAX_M
    d_min_rel_m: float = core.D_MIN_REL_M
    criteria: SuccessCriteria = field(default_factory=SuccessCriteria)
    bin_m: float = 1.0
    usable_threshold: float = 0.9
    n_boot: int = 2000
    level: float = 0.95
    seed: int = 0

    def as_dict(self) -> dict:
        """JSON-able form."""
        return {
            "d_max_m": self.d_max_m,
            "d_min_rel_m": self.d_min_rel_m,
            "success": self.criteria.as_dict(),
            "bin_m": self.bin_m,
            "usable_threshold": self.usable_threshold,
            "bootstrap": {
                "method": "scipy.stats.bootstrap BCa (percentile if BCa undefined)",
                "n_boot": self.n_boot,
                "level": self.level,
                "seed": self.seed,
                "min_trials_for_ci": MIN_TRIALS_FOR_CI,
            },
        }


# -- bootstrap ---------------------------------------------------------------
def _rng(seed: int, *key: str) -> np.random.Generator:
    """A generator that depends only on ``seed`` and the text key (not on row order)."""
    return np.random.default_rng([int(seed), zlib.crc32("\0".join(map(str, key)).encode())])


def bootstrap_ci(
    values, n_boot: int = 2000, level: float = 0.95, seed: int | np.random.Generator = 0
) -> tuple[float, float]:
    """CI ``(lo, hi)`` of the mean of ``values`` by :func:`scipy.stats.bootstrap`.

    NaNs are dropped; fewer than 2 values give ``(nan, nan)`` (no CI from one trial).
    BCa, or the percentile method where BCa is undefined (degenerate data)."""
    from scipy import stats

    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < 2:
        return float("nan"), float("nan")
    if np.all(v == v[0]):
        return float(v[0]), float(v[0])
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    state = rng.bit_generator.state
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ci = stats.bootstrap(
            (v,), np.mean, n_resamples=int(n_boot), confidence_level=level, method="BCa", rng=rng
        ).confidence_interval
        if not (np.isfinite(ci.low) and np.isfinite(ci.high)):
            rng.bit_generator.state = state
            ci = stats.bootstrap(
                (v,), np.mean, n_resamples=int(n_boot), confidence_level=level, method="percentile", rng=rng
            ).confidence_interval
    return float(ci.low), float(ci.high)


def condition_cis(trials: pd.DataFrame, settings: EvalSettings) -> pd.DataFrame:
    """Per group: ``<prefix>_lo, <prefix>_hi`` for :data:`CI_METRICS` over the group's trials
    (``n_total > 0`` only; NaN values dropped)."""
    valid = trials[trials["n_total"] > 0]
    rows = []
    for key, g in valid.groupby(GROUP, sort=True, dropna=False):
        row = dict(zip(GROUP, key))
        g = g.sort_values("sequence", kind="stable")  # resample in a fixed order
        for col, prefix in CI_METRICS.items():
            lo, hi = bootstrap_ci(
                g[col].to_numpy(float), settings.n_boot, settings.level, _rng(settings.seed, *key, col)
            )
            row[f"{prefix}_lo"], row[f"{prefix}_hi"] = lo, hi
        rows.append(row)
    cols = GROUP + [f"{p}_{s}" for p in CI_METRICS.values() for s in ("lo", "hi")]
    return pd.DataFrame(rows, columns=cols)


# -- distance bins and usable range ------------------------------------------
def distance_bins(frames: pd.DataFrame, bin_m: float = 1.0, d_max: float = core.D_MAX_M) -> pd.DataFrame:
    """Per group and distance bin: counted frames pooled over trials (scored table in).

    Bins are ``[k*bin_m, (k+1)*bin_m)`` for ``0 <= d_true <= d_max``; ``d_true == d_max``
    falls in the last bin. Every bin appears for every group (empty ones with
    ``n_total = 0`` and NaN rates). Columns :data:`BIN_COLUMNS`."""
    n_bins = int(np.ceil(d_max / bin_m - 1e-9))
    counted = core.counted_mask(frames["d_true"], d_max)
    x = frames.loc[counted, GROUP + ["e_abs", "e_rel"]].copy()
    x["_bin"] = np.minimum((frames.loc[counted, "d_true"].astype(float) / bin_m + 1e-12).astype(int), n_bins - 1)
    x["_det"] = core.detected_mask(frames)[counted]
    x["_succ"] = frames.loc[counted, "success"].astype(bool)
    stats = (
        x.groupby(GROUP + ["_bin"], dropna=False)
        .agg(
            n_total=("_det", "size"),
            n_detect=("_det", "sum"),
            n_succ=("_succ", "sum"),
            e_abs_mean=("e_abs", "mean"),
            e_rel_mean=("e_rel", "mean"),
        )
        .reset_index()
    )
    full = frames[GROUP].drop_duplicates().merge(pd.DataFrame({"_bin": np.arange(n_bins)}), how="cross")
    out = full.merge(stats, on=GROUP + ["_bin"], how="left")
    for c in ("n_total", "n_detect", "n_succ"):
        out[c] = out[c].fillna(0).astype("int64")
    total = out["n_total"].where(out["n_total"] > 0)
    out["P_detect"], out["P_succ"] = out["n_detect"] / total, out["n_succ"] / total
    out["bin_lo"] = out["_bin"] * bin_m
    out["bin_hi"] = np.minimum((out["_bin"] + 1) * bin_m, d_max)
    out = out.sort_values(GROUP + ["_bin"], kind="stable").reset_index(drop=True)
    return out[BIN_COLUMNS].astype(
        {c: float for c in ("P_detect", "P_succ", "e_abs_mean", "e_rel_mean", "bin_lo", "bin_hi")}
    )


def max_usable_range(bins: pd.DataFrame, threshold: float = 0.9, min_frames: int = 1) -> pd.DataFrame:
    """Per group: ``max_range_m``, the ``bin_hi`` (m) of the farthest bin with at least
    ``min_frames`` frames and ``P_succ >= threshold``; NaN if there is none."""
    ok = bins[(bins["n_total"] >= min_frames) & (bins["P_succ"] >= threshold)]
    best = ok.groupby(GROUP, dropna=False)["bin_hi"].max().rename("max_range_m")
    return bins[GROUP].drop_duplicates().merge(best.reset_index(), on=GROUP, how="left").reset_index(drop=True)


def range_matched(bins: pd.DataFrame) -> pd.DataFrame:
    """Per group: the error over the bins every condition of its (localizer, trajectory)
    has an error in (module docstring): ``E_rel_matched``, ``e_abs_matched`` (means of
    the bins' ``e_rel_mean`` / ``e_abs_mean``, bins weighted equally), ``n_matched_bins``
    and the matched bins' extent ``matched_lo_m``, ``matched_hi_m`` (NaN without any)."""
    rows = []
    for (loc, traj), g in bins.groupby(["localizer", "trajectory"], sort=True, dropna=False):
        has = g.assign(_ok=np.isfinite(g["e_rel_mean"].astype(float))).pivot_table(
            index="bin_lo", columns="condition", values="_ok", aggfunc="all", dropna=False
        )
        common = has.index[has.fillna(False).astype(bool).all(axis=1)]
        for cond, c in g.groupby("condition", sort=True, dropna=False):
            m = c[c["bin_lo"].isin(common)]
            rows.append(
                {
                    "localizer": loc,
                    "trajectory": traj,
                    "condition": cond,
                    "E_rel_matched": float(m["e_rel_mean"].mean()) if len(m) else np.nan,
                    "e_abs_matched": float(m["e_abs_mean"].mean()) if len(m) else np.nan,
                    "n_matched_bins": int(len(m)),
                    "matched_lo_m": float(m["bin_lo"].min()) if len(m) else np.nan,
                    "matched_hi_m": float(m["bin_hi"].max()) if len(m) else np.nan,
                }
            )
    return pd.DataFrame(rows, columns=GROUP + MATCHED_COLUMNS)


# -- false positives and runtime ---------------------------------------------
def false_positive_table(frames: pd.DataFrame) -> pd.DataFrame:
    """Per group, all frames: ``n_frames, n_est, n_fp, fp_rate, n_no_view, fp_rate_no_view``."""
    x = frames[GROUP].copy()
    x["_est"] = core.detected_mask(frames)
    x["_fp"] = frames["fp"].astype(bool)
    x["_no_view"] = ~frames["in_view"].fillna(False).astype(bool)
    x["_fp_nv"] = x["_est"] & x["_no_view"]
    out = (
        x.groupby(GROUP, dropna=False, sort=True)
        .agg(
            n_frames=("_est", "size"),
            n_est=("_est", "sum"),
            n_fp=("_fp", "sum"),
            n_no_view=("_no_view", "sum"),
            _n_fp_nv=("_fp_nv", "sum"),
        )
        .reset_index()
    )
    out["fp_rate"] = out["n_fp"] / out["n_est"].where(out["n_est"] > 0)
    out["fp_rate_no_view"] = out["_n_fp_nv"] / out["n_no_view"].where(out["n_no_view"] > 0)
    cols = GROUP + ["n_frames", "n_est", "n_fp", "fp_rate", "n_no_view", "fp_rate_no_view"]
    return out[cols].astype({"fp_rate": float, "fp_rate_no_view": float})


def _timed(df: pd.DataFrame) -> pd.DataFrame:
    """Rows whose ``ms`` measures a ``localize`` call (finite; reset failures excluded)."""
    ms = pd.to_numeric(df["ms"], errors="coerce")
    reset_failed = (
        df.get("fail_reason", pd.Series("", index=df.index)).fillna("").astype(str).str.endswith("(in reset)")
    )
    return df.assign(ms=ms)[np.isfinite(ms) & ~reset_failed]


def runtime_table(df: pd.DataFrame, by: Sequence[str] = ("localizer",)) -> pd.DataFrame:
    """Per ``by`` group: ``n_calls, ms_median, ms_p95, ms_mean`` (ms per frame)."""
    by = list(by)
    out = (
        _timed(df)
        .groupby(by, dropna=False, sort=True)["ms"]
        .agg(n_calls="size", ms_median="median", ms_p95=lambda s: float(np.quantile(s, 0.95)), ms_mean="mean")
        .reset_index()
    )
    return out[by + ["n_calls", "ms_median", "ms_p95", "ms_mean"]]


# -- everything together -------------------------------------------------------
def score(estimates: pd.DataFrame, settings: EvalSettings, model: rec.DockModel | None = None) -> pd.DataFrame:
    """``estimates`` with :data:`~evalkit.metrics.core.SCORE_COLUMNS` (re)computed under
    ``settings`` and, with a ``model``, ``mssd_m``/``mspd_px``."""
    frames = core._with_defaults(estimates)
    frames = frames.drop(columns=[c for c in core.SCORE_COLUMNS if c in frames.columns])
    frames = pd.concat([frames, core.score_frames(frames, settings.criteria, settings.d_min_rel_m)], axis=1)
    if model is not None:
        frames[["mssd_m", "mspd_px"]] = rec.mssd_mspd(frames, model)
    return frames


def _group_means(trials: pd.DataFrame) -> pd.DataFrame:
    """Per group: ``n_trials`` and the means over trials with counted frames."""
    valid = trials[trials["n_total"] > 0]
    return (
        valid.groupby(GROUP, dropna=False, sort=True)
        .agg(
            n_trials=("sequence", "size"),
            P_succ_mean=("P_succ", "mean"),
            P_detect_mean=("P_detect", "mean"),
            E_rel_mean=("e_rel_mean", "mean"),
            e_abs_mean=("e_abs_mean", "mean"),
            e_trans_mean=("e_trans_mean", "mean"),
            e_rot_deg_mean=("e_rot_deg_mean", "mean"),
            e_range_abs_mean=("e_range_abs_mean", "mean"),
            e_lateral_mean=("e_lateral_mean", "mean"),
        )
        .reset_index()
    )


def compute_all(
    estimates: pd.DataFrame, settings: EvalSettings | None = None, model: rec.DockModel | None = None
) -> dict[str, pd.DataFrame]:
    """Every table of a run: ``frames, trials, metrics, bins, fp, recall, runtime``.

    ``frames`` is the scored per-frame table; ``trials`` one row per trial
    (:data:`~evalkit.metrics.core.TRIAL_COLUMNS`); ``metrics`` one row per group with
    :data:`METRIC_COLUMNS` (means over the group's trials with CIs; FP and recall pool
    frames; no timings, so the same inputs give the same table: ``runtime`` is apart);
    ``model`` (the dock's marker models) enables AR_dock."""
    settings = settings or EvalSettings()
    frames = score(estimates, settings, model)
    trials = core.per_trial(frames, settings.d_max_m)
    bins = distance_bins(frames, settings.bin_m, settings.d_max_m)
    fp = false_positive_table(frames)
    recall = rec.recall_table(frames, model, settings.d_max_m)
    out = frames[GROUP].drop_duplicates().merge(_group_means(trials), on=GROUP, how="left")
    for part in (
        condition_cis(trials, settings),
        recall,
        fp[GROUP + ["n_frames", "n_est", "n_fp", "fp_rate", "fp_rate_no_view"]],
        max_usable_range(bins, settings.usable_threshold),
        range_matched(bins),
    ):
        out = out.merge(part, on=GROUP, how="left")
    out["n_trials"] = out["n_trials"].fillna(0).astype("int64")
    out["few_trials"] = out["n_trials"] < MIN_TRIALS_FOR_CI
    out = out.sort_values(GROUP, kind="stable").reset_index(drop=True)
    return {
        "frames": frames,
        "trials": trials,
        "metrics": out[METRIC_COLUMNS],
        "bins": bins,
        "fp": fp,
        "recall": recall,
        "runtime": runtime_table(frames, GROUP),
    }
