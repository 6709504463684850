"""Per-frame scoring and per-trial metrics: the one place where a frame is judged.

All distances are in metres, angles in degrees; errors ``e_abs`` in metres,
``e_rel`` and probabilities are dimensionless (fractions, not percent).

Input is the runner's per-frame table (:data:`evalkit.runner.COLUMNS`) with at
least ``localizer, sequence, condition, d_true, detected, d_est``; the true
pose ``T_cam_dock`` and ``markers_in_fov`` (written by the runner) enable the
pose and wrong-id checks.

Words
-----
* **trial**: one sequence of the dataset = one (trajectory, trial index,
  condition). Trials of one (localizer, trajectory, condition) are the M
  independent repetitions (seeded random starts) that CIs are computed over;
  sequences of *different* trajectories are never averaged as trials.
* **detected**: the localizer returned a valid answer (the article's "success").
  ``P_detect`` = detected / counted frames.
* **false positive**: a detected frame with no marker in view, or whose
  reported ``marker_id`` is not among the markers in view.
* **success**: detected, not a false positive, and within the error bounds of
  :class:`SuccessCriteria`. ``P_succ`` = successes / counted frames.

Rules
-----
* A frame counts only if ``0 <= d_true <= d_max`` (``d_max`` = 10 m by
  default); other frames are ignored by every per-trial metric.
* For detected frames ``e_abs = |d_true - d_est|`` and ``e_rel = e_abs / d_true``;
  **``e_rel`` is NaN for ``d_true < d_min_rel``** (0.2 m by default, the
  manifest's ``d_min_rel_m``): near the dock the ratio explodes. Errors are
  means over *detected* frames (as in the article), not over successes only,
  so a threshold never truncates the error a localizer is charged with.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

D_MAX_M = 10.0
D_MIN_REL_M = 0.2
GROUP = ["localizer", "trajectory", "condition"]
TRIAL_KEYS = GROUP + ["sequence"]
EST_POSE = "T_cam_dock_est"
TRUE_POSE = "T_cam_dock"
POSE_ERROR_COLUMNS = ["e_trans", "e_rot_deg", "e_range", "e_lateral"]
SCORE_COLUMNS = ["e_abs", "e_rel", *POSE_ERROR_COLUMNS, "fp", "success"]
TRIAL_COLUMNS = TRIAL_KEYS + [
    "trial",
    "n_total",
    "n_detect",
    "n_succ",
    "P_detect",
    "P_succ",
    "e_abs_mean",
    "e_rel_mean",
    "e_trans_mean",
    "e_rot_deg_mean",
    "e_range_abs_mean",
    "e_lateral_mean",
]


@dataclass(frozen=True)
class SuccessCriteria:
    """When a detected frame counts as *localized* (the thresholded success).

    A frame succeeds when it is detected, is not a false positive, and

    * ``|d_est - d_true| <= max(max_rel_dist * d_true, min_tol_m)``, and
    * if the localizer returned a pose: ``|t_est - t_true| <= max(max_rel_trans * d_true,
      min_tol_m)`` and the rotation error ``<= max_rot_deg``.

    Defaults and why: 10 % of the range is the error at which a docking
    controller still converges on the funnel when it re-measures as it closes
    in (the error shrinks with the range: 0.5 m at 5 m, 0.1 m at 1 m) and is
    several times the E_rel that the article's working localizers reach (2-5 %),
    so it separates "localized" from "answered" without rewarding noise. The
    5 cm floor is about the funnel's lateral tolerance near the mouth and keeps
    the bound meaningful below ``d_min_rel``. 10 degrees: the heading error a
    typical docking funnel (half-angle 20-30 deg) absorbs with margin; ArUco /
    PnP planar-ambiguity flips (20-60 deg) fail it.
    """

    max_rel_dist: float = 0.10
    min_tol_m: float = 0.05
    max_rel_trans: float = 0.10
    max_rot_deg: float = 10.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"success criterion {name} must be a finite number > 0, got {value}")

    def as_dict(self) -> dict[str, float]:
        """The four thresholds by name (for run.json)."""
        return {k: float(v) for k, v in asdict(self).items()}


def _num(df: pd.DataFrame, col: str) -> pd.Series:
    """A column as float (NaN where missing / not a number)."""
    if col not in df.columns:
        return pd.Series(np.nan, index=df.index)
    return pd.to_numeric(df[col], errors="coerce").astype(float)


def counted_mask(d_true: pd.Series, d_max: float = D_MAX_M) -> pd.Series:
    """True where a frame counts: ``0 <= d_true <= d_max`` (metres); NaN never counts."""
    d = pd.to_numeric(d_true, errors="coerce").astype(float)
    return (d >= 0.0) & (d <= d_max)


def detected_mask(df: pd.DataFrame) -> pd.Series:
    """True where ``detected`` is set and ``d_est`` is a finite, non-negative distance."""
    d_est = _num(df, "d_est")
    ok = df["detected"].fillna(False).astype(bool)
    return ok & np.isfinite(d_est) & (d_est >= 0.0)


def frame_errors(df: pd.DataFrame, d_min_rel: float = D_MIN_REL_M) -> pd.DataFrame:
    """Per-frame ``e_abs`` (m) and ``e_rel`` (1) for detected frames, else NaN.

    ``e_rel`` is NaN when ``d_true < d_min_rel`` (m) or when the ratio overflows.
    Same index as ``df``.
    """
    d_true, d_est = _num(df, "d_true"), _num(df, "d_est")
    det = detected_mask(df)
    e_abs = (d_true - d_est).abs().where(det)
    e_rel = (e_abs / d_true).where(det & (d_true >= d_min_rel) & (d_true > 0.0))
    e_rel = e_rel.where(np.isfinite(e_rel))  # a subnormal d_true overflows: undefined, never inf
    return pd.DataFrame({"e_abs": e_abs, "e_rel": e_rel}, index=df.index)


def as_matrices(column) -> np.ndarray:
    """A column of flattened poses (16 floats, 4x4 array, or None/NaN) as ``(N, 4, 4)``; NaN if missing."""
    values = list(column)
    out = np.full((len(values), 4, 4), np.nan)
    for i, v in enumerate(values):
        if v is None or (isinstance(v, float) and np.isnan(v)):
            continue
        arr = np.asarray(v, dtype=float)
        if arr.size == 16:
            out[i] = arr.reshape(4, 4)
    return out


def pose_errors(df: pd.DataFrame) -> pd.DataFrame:
    """Per-frame ``e_trans`` (m), ``e_rot_deg`` (deg), ``e_range`` (m, signed), ``e_lateral`` (m).

    ``e_trans = |t_est - t_true|`` of the dock origin in the camera frame,
    ``e_rot_deg`` the angle of ``R_true^T R_est``; the position error split along
    the viewing ray ``u = t_true/|t_true|``: ``e_range = (t_est - t_true).u`` (+ = too
    far) and ``e_lateral`` the perpendicular norm. NaN where the frame was not
    detected or has no estimated (``T_cam_dock_est``) or true (``T_cam_dock``) pose.
    """
    out = pd.DataFrame(np.nan, index=df.index, columns=POSE_ERROR_COLUMNS)
    if EST_POSE not in df.columns or TRUE_POSE not in df.columns or df.empty:
        return out
    est, true = as_matrices(df[EST_POSE]), as_matrices(df[TRUE_POSE])
    ok = detected_mask(df).to_numpy() & np.isfinite(est).all(axis=(1, 2)) & np.isfinite(true).all(axis=(1, 2))
    if not ok.any():
        return out
    e, t = est[ok], true[ok]
    dt = e[:, :3, 3] - t[:, :3, 3]
    norm = np.linalg.norm(t[:, :3, 3], axis=1, keepdims=True)
    ray = np.divide(t[:, :3, 3], norm, out=np.zeros_like(dt), where=norm > 0)
    along = np.einsum("ij,ij->i", dt, ray)
    rel = np.einsum("nji,njk->nik", t[:, :3, :3], e[:, :3, :3])  # R_true^T R_est
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    out.loc[ok, "e_trans"] = np.linalg.norm(dt, axis=1)
    out.loc[ok, "e_rot_deg"] = np.degrees(np.arccos(cos))
    out.loc[ok, "e_range"] = along
    out.loc[ok, "e_lateral"] = np.linalg.norm(dt - along[:, None] * ray, axis=1)
    return out


def false_positive_mask(df: pd.DataFrame) -> pd.Series:
    """True for a detected frame with no marker in view, or with a ``marker_id`` not in view.

    The wrong-id test needs ``markers_in_fov`` (comma-joined ids); without it
    only the no-view test applies. An estimate without ``marker_id`` is never a
    wrong-id false positive.
    """
    det = detected_mask(df)
    if "in_view" not in df.columns:  # hand-made table without visibility: no no-view test
        no_view = pd.Series(False, index=df.index)
    else:
        no_view = ~df["in_view"].fillna(False).astype(bool)
    wrong = pd.Series(False, index=df.index)
    if "marker_id" in df.columns and "markers_in_fov" in df.columns:
        visible = df["markers_in_fov"].fillna("").astype(str)
        wrong = pd.Series(
            [
                m is not None
                and not (isinstance(m, float) and np.isnan(m))
                and str(m) != ""
                and str(m) not in v.split(",")
                for m, v in zip(df["marker_id"], visible)
            ],
            index=df.index,
        )
    return det & (no_view | wrong)


def score_frames(
    df: pd.DataFrame, criteria: SuccessCriteria | None = None, d_min_rel: float = D_MIN_REL_M
) -> pd.DataFrame:
    """Per-frame :data:`SCORE_COLUMNS`: errors, ``fp`` and the thresholded ``success`` (bool).

    See :class:`SuccessCriteria` for when a frame succeeds. Same index as ``df``.
    """
    criteria = criteria or SuccessCriteria()
    out = pd.concat([frame_errors(df, d_min_rel), pose_errors(df)], axis=1)
    out["fp"] = false_positive_mask(df)
    d_true = _num(df, "d_true")
    slack = 1.0 + 1e-9  # an error exactly at the bound passes despite float round-off
    tol_d = np.maximum(criteria.max_rel_dist * d_true, criteria.min_tol_m) * slack
    tol_t = np.maximum(criteria.max_rel_trans * d_true, criteria.min_tol_m) * slack
    has_pose = out["e_trans"].notna()
    pose_ok = ~has_pose | ((out["e_trans"] <= tol_t) & (out["e_rot_deg"] <= criteria.max_rot_deg * slack))
    out["success"] = (detected_mask(df) & ~out["fp"] & (out["e_abs"] <= tol_d) & pose_ok).astype(bool)
    return out[SCORE_COLUMNS]


def _with_defaults(df: pd.DataFrame) -> pd.DataFrame:
    """Fill optional key columns (``trajectory``, ``trial``) of older or hand-made tables."""
    out = df
    for col, value in (("trajectory", ""), ("trial", -1)):
        if col not in out.columns:
            out = out.assign(**{col: value})
    return out


def per_trial(df: pd.DataFrame, d_max: float = D_MAX_M) -> pd.DataFrame:
    """Metrics per trial (one sequence) from a scored table (:func:`score_frames` columns present).

    Columns :data:`TRIAL_COLUMNS`. ``n_total`` counts frames with ``0 <= d_true <= d_max``;
    ``P_detect = n_detect / n_total``, ``P_succ = n_succ / n_total`` (NaN if
    ``n_total == 0``); error means are over detected counted frames. Trials
    whose frames all fall outside the range still appear (``n_total = 0``).
    Rows are sorted by :data:`TRIAL_KEYS`.
    """
    df = _with_defaults(df)
    keys = df[TRIAL_KEYS + ["trial"]].drop_duplicates(TRIAL_KEYS)
    x = df[TRIAL_KEYS].copy()
    x["_det"], x["_succ"] = detected_mask(df), df["success"].astype(bool)
    for c in ("e_abs", "e_rel", "e_trans", "e_rot_deg", "e_lateral"):
        x[c] = df[c]
    x["e_range_abs"] = df["e_range"].abs()
    x = x[counted_mask(df["d_true"], d_max)]
    stats = (
        x.groupby(TRIAL_KEYS, dropna=False, sort=False)
        .agg(
            n_total=("_det", "size"),
            n_detect=("_det", "sum"),
            n_succ=("_succ", "sum"),
            e_abs_mean=("e_abs", "mean"),
            e_rel_mean=("e_rel", "mean"),
            e_trans_mean=("e_trans", "mean"),
            e_rot_deg_mean=("e_rot_deg", "mean"),
            e_range_abs_mean=("e_range_abs", "mean"),
            e_lateral_mean=("e_lateral", "mean"),
        )
        .reset_index()
    )
    out = keys.merge(stats, on=TRIAL_KEYS, how="left")
    for c in ("n_total", "n_detect", "n_succ"):
        out[c] = out[c].fillna(0).astype("int64")
    total = out["n_total"].where(out["n_total"] > 0)
    out["P_detect"], out["P_succ"] = out["n_detect"] / total, out["n_succ"] / total
    out = out.sort_values(TRIAL_KEYS, kind="stable").reset_index(drop=True)
    return out[TRIAL_COLUMNS].astype({c: float for c in TRIAL_COLUMNS[TRIAL_COLUMNS.index("P_detect") :]})


def summarize(
    df: pd.DataFrame, d_max: float = D_MAX_M, d_min_rel: float = D_MIN_REL_M, criteria: SuccessCriteria | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(trials, conditions)`` of a runner table: per trial, and the means over each
    (localizer, trajectory, condition)'s trials (``n_trials, P_succ_mean, P_detect_mean,
    E_rel_mean``; ``E_rel_mean`` skips trials with no ``e_rel``). No CIs (see
    :func:`evalkit.metrics.extra.compute_all` for the full table)."""
    df = _with_defaults(df)
    scored = df.drop(columns=[c for c in SCORE_COLUMNS if c in df.columns])
    scored = pd.concat([scored, score_frames(df, criteria, d_min_rel)], axis=1)
    trials = per_trial(scored, d_max)
    valid = trials[trials["n_total"] > 0]
    conds = (
        valid.groupby(GROUP, dropna=False, sort=True)
        .agg(
            n_trials=("sequence", "size"),
            P_succ_mean=("P_succ", "mean"),
            P_detect_mean=("P_detect", "mean"),
            E_rel_mean=("e_rel_mean", "mean"),
        )
        .reset_index()
    )
    return trials, conds
