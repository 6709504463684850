"""PNG plots of a run (matplotlib, Agg backend; no display needed).

* :func:`plot_error_vs_distance` -- the article's Figures 18-21 style: the
  positioning error against ``d_true`` for **one representative trial per
  (trajectory, condition)**, the *same* trial in every localizer's panel, one
  panel per localizer, each panel with its own y axis.
* :func:`plot_success_vs_distance` -- ``P_succ`` per distance bin (frames of
  all trials pooled), one line per condition, one panel per localizer.
* :func:`plot_range_bins` -- the experiment's figure: success and error per 1 m range
  bin, one column per localizer, conditions as lines (physics at equal range).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from evalkit.metrics import core as metrics

ERROR_LABELS = {"e_abs": "positioning error |d_true - d_est| (m)", "e_rel": "relative positioning error e_rel (%)"}


def _pyplot():
    """matplotlib.pyplot on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _panels(plt, n: int):
    """Figure and a flat list of ``n`` axes on a grid of at most 3 columns (extra axes hidden)."""
    ncols = max(1, min(3, n))
    nrows = -(-max(n, 1) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.2 * ncols, 3.8 * nrows), squeeze=False, sharey=False)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[: max(n, 1)]


def _save(plt, fig, axes, ylabel: str, title: str | None, path: Path) -> Path:
    """Label every panel (each has its own y axis), title, write the PNG, free the figure."""
    for ax in axes:
        ax.set_ylabel(ylabel, fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def representative_trials(trials: pd.DataFrame) -> pd.DataFrame:
    """Per (trajectory, condition) one sequence, the same for every localizer: the trial
    whose ``P_succ`` averaged over the localizers is closest to the median over the
    trials (ties: smallest sequence id). ``trials`` is the per-trial table
    (:func:`evalkit.metrics.core.per_trial`). Columns ``trajectory, condition, sequence``."""
    rows = []
    for (traj, cond), g in trials.groupby(["trajectory", "condition"], sort=True, dropna=False):
        per_seq = g.groupby("sequence", sort=True)["P_succ"].mean()
        if per_seq.notna().any():
            dist = (per_seq - per_seq.median()).abs()
            seq = dist[dist == dist.min()].index.min()
        else:
            seq = per_seq.index.min()
        rows.append({"trajectory": traj, "condition": cond, "sequence": seq})
    return pd.DataFrame(rows, columns=["trajectory", "condition", "sequence"])


def plot_error_vs_distance(
    frames: pd.DataFrame,
    path: str | Path,
    trials: pd.DataFrame,
    error: str = "e_abs",
    d_max: float = metrics.D_MAX_M,
    title: str | None = None,
) -> Path:
    """Error (``e_abs`` m or ``e_rel`` %) vs ``d_true`` of the representative trial of each
    (trajectory, condition) (:func:`representative_trials`), one line each; one panel per
    localizer. ``frames`` is the scored per-frame table. Writes ``path`` (PNG)."""
    plt = _pyplot()
    path = Path(path)
    df = frames.assign(_err=frames[error] * (100.0 if error == "e_rel" else 1.0))
    df = df[metrics.counted_mask(df["d_true"], d_max)]
    reps = representative_trials(trials)
    locs = sorted(df["localizer"].unique()) or ["(none)"]
    fig, axes = _panels(plt, len(locs))
    for ax, loc in zip(axes, locs):
        for _, r in reps.iterrows():
            s = df[(df["localizer"] == loc) & (df["sequence"] == r["sequence"])].sort_values("d_true")
            ok = s["_err"].notna()
            ax.plot(
                s.loc[ok, "d_true"],
                s.loc[ok, "_err"],
                marker=".",
                ms=3,
                lw=0.8,
                label=f"{r['trajectory']}/{r['condition']} ({r['sequence']})",
            )
        ax.set_title(str(loc))
        ax.set_xlabel("d_true (m)")
        ax.set_xlim(0, d_max)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    return _save(plt, fig, axes, ERROR_LABELS.get(error, error), title, path)


def plot_success_vs_distance(
    bins: pd.DataFrame, path: str | Path, threshold: float | None = 0.9, title: str | None = None
) -> Path:
    """``P_succ`` per distance bin (from :func:`evalkit.metrics.extra.distance_bins`),
    one line per (trajectory, condition), one panel per localizer; ``threshold`` drawn dashed."""
    plt = _pyplot()
    path = Path(path)
    locs = sorted(bins["localizer"].unique()) or ["(none)"]
    fig, axes = _panels(plt, len(locs))
    for ax, loc in zip(axes, locs):
        b = bins[bins["localizer"] == loc]
        for (traj, cond), g in b.groupby(["trajectory", "condition"], sort=True):
            centre = (g["bin_lo"] + g["bin_hi"]) / 2.0
            ax.plot(centre, 100.0 * g["P_succ"], marker="o", ms=3, label=f"{traj}/{cond}")
        if threshold is not None:
            ax.axhline(100.0 * threshold, ls="--", lw=0.8, color="grey")
        ax.set_title(str(loc))
        ax.set_xlabel("d_true (m), bin centre")
        ax.set_ylim(-2, 102)
        if len(b):
            ax.set_xlim(0, float(np.nanmax(b["bin_hi"])))
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    return _save(plt, fig, axes, "P_succ (%)", title, path)


def plot_range_bins(
    bins: pd.DataFrame, path: str | Path, threshold: float | None = 0.9, title: str | None = None
) -> Path:
    """One figure of an experiment: success (top row, ``P_succ`` %) and error (bottom row,
    ``e_rel_mean`` % over the frames with an estimate) against the 1 m range bin, one
    column per localizer, one line per condition (``trajectory/condition`` when the run
    has several trajectories). Read along a line, the error at a given range shows what
    the water does there; where a line stops, the condition lost its frames (the pooled
    error of such a condition is lower by selection, not by physics). Writes ``path``."""
    plt = _pyplot()
    path = Path(path)
    locs = sorted(bins["localizer"].unique()) or ["(none)"]
    several = bins["trajectory"].nunique() > 1
    fig, axes = plt.subplots(
        2, len(locs), figsize=(4.6 * len(locs), 6.4), squeeze=False, sharex=True, sharey="row"
    )  # one error scale: localizers compare at a glance
    for col, loc in enumerate(locs):
        b = bins[(bins["localizer"] == loc) & (bins["n_total"] > 0)]
        for (traj, cond), g in b.groupby(["trajectory", "condition"], sort=True, dropna=False):
            g = g.sort_values("bin_lo")
            centre = (g["bin_lo"] + g["bin_hi"]) / 2.0
            label = f"{traj}/{cond}" if several else str(cond)
            line = axes[0, col].plot(centre, 100.0 * g["P_succ"], marker="o", ms=3, label=label)[0]
            axes[1, col].plot(centre, 100.0 * g["e_rel_mean"], marker="o", ms=3, color=line.get_color(), label=label)
        _range_bin_axes(axes[:, col], str(loc), threshold, b)
    axes[0, 0].set_ylabel("P_succ (%)", fontsize=8)
    axes[1, 0].set_ylabel("relative error e_rel (%)", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _range_bin_axes(pair, loc: str, threshold: float | None, b: pd.DataFrame) -> None:
    """Titles, limits, grid and legend of one localizer's (success, error) panels."""
    top, bottom = pair
    top.set_title(loc)
    top.set_ylim(-2, 102)
    if threshold is not None:
        top.axhline(100.0 * threshold, ls="--", lw=0.8, color="grey")
    bottom.set_xlabel("d_true (m), 1 m bin centre")
    bottom.set_ylim(bottom=0)
    if len(b):
        bottom.set_xlim(0, float(np.nanmax(b["bin_hi"])))
    for ax in pair:
        ax.grid(alpha=0.3)
    if top.get_legend_handles_labels()[0]:
        top.legend(fontsize=7)
