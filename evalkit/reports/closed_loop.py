"""Closed-loop docking results on the leaderboard: read ``closed_loop.json`` and rank it.

The file is the interface between ``dockbench dock`` (which writes it) and the leaderboard
(which only reads it); its format is ``datasets_spec/CLOSED_LOOP.md``. evalkit imports
nothing from blendgen here: a third-party closed-loop simulator can write the same file.

Ranking inside one condition: docking success rate desc, then the Wilson lower bound desc
(more trials at the same rate rank higher), then median time to dock asc, then mean
|final lateral error| asc, then label. The ground-truth-guidance row (``baseline``) is shown
first and not ranked: it is what perfect localization would give, not a competitor.
Runs are ranked together only when their experiment config hash, capture geometry and
latency agree (different resolutions or latencies are different benchmarks).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

RESULTS_FILE = "closed_loop.json"
FORMAT, FORMAT_VERSION = "dockbench-closed-loop", "1"
ROW_KEYS = ("localizer", "condition", "n_trials", "n_docked", "success_rate", "ci_low", "ci_high")

# (key, header, kind, help) for the ranked tables; kinds as in leaderboard.COLUMNS
CL_COLUMNS: list[tuple[str, str, str, str]] = [
    ("rank", "#", "int", "rank in this condition (the ground-truth baseline is not ranked)"),
    ("label", "localizer", "text", "localizer steering the vehicle (truth = ground-truth guidance)"),
    (
        "success_rate",
        "docked %",
        "pct_ci",
        "trials docked (entry plane inside the capture radius, heading and lateral speed within limits); Wilson 95% CI",
    ),
    ("n_docked", "docked", "int", "docked trials"),
    ("n_trials", "M", "int", "trials (seeded random starts)"),
    ("time_to_dock_median_s", "t dock s", "num", "median time to dock over docked trials (s)"),
    ("final_lateral_abs_mean_m", "lat m", "num", "mean |lateral offset| at the last frame (m)"),
    ("final_heading_abs_mean_deg", "head deg", "num", "mean |heading error| at the last frame (deg)"),
    ("P_detect_mean", "P_detect %", "pct", "per-frame answers of the same run"),
    ("P_succ_mean", "P_succ %", "pct", "per-frame right answers of the same run"),
    ("outcomes", "outcomes", "text", "outcome counts"),
    (
        "authority",
        "authority",
        "text",
        "can the thrusters hold the condition's mean current while docking at all "
        "(`dockbench authority`); 'beyond': failures there are not the localizer's",
    ),
]


class ClosedLoopError(ValueError):
    """A closed-loop results file that cannot be read (message names the file and key)."""


@dataclass
class ClosedLoopRun:
    """One ``closed_loop.json``: its directory and parsed document."""

    path: Path
    doc: dict

    @property
    def group_key(self) -> str:
        d = self.doc
        return json.dumps(
            [
                d["experiment"].get("config_hash"),
                d.get("capture"),
                d["camera"].get("latency_s"),
                d.get("compute_latency"),
            ],
            sort_keys=True,
        )


def is_closed_loop_dir(path: str | Path) -> bool:
    return (Path(path) / RESULTS_FILE).is_file()


def _check_row(f: Path, i: int, r) -> None:
    if not isinstance(r, dict):
        raise ClosedLoopError(f"{f}: rows[{i}] is not an object")
    missing = [k for k in ROW_KEYS if k not in r]
    if missing:
        raise ClosedLoopError(f"{f}: rows[{i}] misses {', '.join(missing)}")
    n, k, p = r["n_trials"], r["n_docked"], r["success_rate"]
    if not (isinstance(n, int) and isinstance(k, int) and 0 <= k <= n and n >= 1):
        raise ClosedLoopError(f"{f}: rows[{i}]: need integers 0 <= n_docked <= n_trials, n_trials >= 1")
    if not (isinstance(p, (int, float)) and abs(p - k / n) < 1e-9):
        raise ClosedLoopError(f"{f}: rows[{i}].success_rate must equal n_docked / n_trials = {k / n:.6g}")
    from evalkit.reports.numbers import NumberError, check_closed_loop_row

    try:
        check_closed_loop_row(f"{f}: rows[{i}]", r)
    except NumberError as exc:
        raise ClosedLoopError(str(exc)) from None


def load_closed_loop(path: str | Path) -> ClosedLoopRun:
    """Read and check ``PATH/closed_loop.json``; :class:`ClosedLoopError` names what is wrong."""
    f = Path(path) / RESULTS_FILE
    try:
        doc = json.loads(f.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:
        raise ClosedLoopError(f"{f}: cannot read: {type(exc).__name__}: {str(exc)[:120]}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ClosedLoopError(f'{f}: "format" is not {FORMAT!r}')
    if str(doc.get("format_version")) != FORMAT_VERSION:
        raise ClosedLoopError(
            f"{f}: format_version {doc.get('format_version')!r}, this dockbench reads {FORMAT_VERSION!r}"
        )
    for key in ("experiment", "camera", "capture", "rows"):
        if key not in doc:
            raise ClosedLoopError(f"{f}: missing key {key!r}")
    if not isinstance(doc["rows"], list) or not doc["rows"]:
        raise ClosedLoopError(f'{f}: "rows" must be a non-empty list')
    for i, r in enumerate(doc["rows"]):
        _check_row(f, i, r)
    return ClosedLoopRun(Path(path), doc)


def _num(v, default: float) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return default
    return f if math.isfinite(f) else default


def rank_rows(rows: Sequence[dict]) -> list[dict]:
    """Rows of one condition: the baseline first (rank None), then the others ranked (module doc)."""
    base = [dict(r, rank=None) for r in rows if r.get("baseline")]
    rest = sorted(
        (r for r in rows if not r.get("baseline")),
        key=lambda r: (
            -_num(r["success_rate"], -1.0),
            -_num(r.get("ci_low"), -1.0),
            _num(r.get("time_to_dock_median_s"), math.inf),
            _num(r.get("final_lateral_abs_mean_m"), math.inf),
            str(r["label"]),
        ),
    )
    return base + [dict(r, rank=i) for i, r in enumerate(rest, start=1)]


def _labelled_rows(group: Sequence[ClosedLoopRun]) -> list[dict]:
    """All rows of a group; a localizer appearing in several runs gets ``name (run dir)``."""
    rows = [dict(r, run=run.path.name) for run in group for r in run.doc["rows"]]
    runs_of: dict[str, set] = {}
    for r in rows:
        runs_of.setdefault(r["localizer"], set()).add(r["run"])
    for r in rows:
        r["label"] = r["localizer"] + (f" ({r['run']})" if len(runs_of[r["localizer"]]) > 1 else "")
        r["ci_lo_hi"] = (r.get("ci_low"), r.get("ci_high"))
    return rows


def group_closed_loop(runs: Sequence[ClosedLoopRun]) -> list[list[ClosedLoopRun]]:
    """Runs that may be ranked together (same config hash, capture and latency), first-seen order."""
    groups: dict[str, list[ClosedLoopRun]] = {}
    for r in runs:
        groups.setdefault(r.group_key, []).append(r)
    return list(groups.values())


__all__ = [
    "RESULTS_FILE",
    "FORMAT",
    "FORMAT_VERSION",
    "CL_COLUMNS",
    "ClosedLoopError",
    "ClosedLoopRun",
    "is_closed_loop_dir",
    "load_closed_loop",
    "rank_rows",
    "group_closed_loop",
]
