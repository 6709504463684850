"""Closed-loop docking on the leaderboard: closed_loop.json written by `dockbench dock`'s code,
read by evalkit alone, ranked beside open-loop runs; bad files exit 2."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner
from fake_dataset import write_fake_dataset
from test_metrics_extra import Oracle, run_fake

import cli
from evalkit.dataset import Dataset
from evalkit.metrics.extra import EvalSettings
from evalkit.reports import closed_loop as clr
from evalkit.reports import leaderboard, results

REPO = Path(__file__).resolve().parents[1]
# docked trials per (localizer, condition) out of 10
DOCKED = {"truth": (10, 10, 10), "led": (10, 9, 2), "hybrid": (10, 9, 3), "aruco": (0, 0, 0)}
CONDS = ("clear", "mild", "moderate")


def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval, written out from Wilson (1927), independent of the code under test."""
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return c - h, c + h


def write_run(out: Path, latency_s: float = 0.0, docked=DOCKED, t_dock: float = 20.0) -> Path:
    """A closed-loop run directory made by the dock command's own summary + writer."""
    from blendgen.config.models import load_experiment
    from blendgen.tools.apps import closed_loop as cl
    from blendgen.vehicle.visual_nav import CaptureSpec

    exp = load_experiment(REPO / "configs" / "paper_turbidity.yaml")
    exp.camera.latency_s = latency_s
    rows = [
        {
            "localizer": loc,
            "condition": cond,
            "trial": t,
            "docked": t < k,
            "outcome": "docked" if t < k else "collision",
            "time_to_dock_s": t_dock + t if t < k else math.nan,
            "final_lateral_m": 0.05 if t < k else 0.5,
            "final_heading_deg": -3.0,
        }
        for loc, ks in docked.items()
        for cond, k in zip(CONDS, ks)
        for t in range(10)
    ]
    frames = pd.DataFrame(columns=["localizer", "condition", "trial", "d_true"])
    summary = cl.summary_table(pd.DataFrame(rows), frames)
    out.mkdir(parents=True, exist_ok=True)
    cl.write_results_file(summary, out, exp, CaptureSpec.from_dock([1.0, 1.0, 0.4], 0.0955), 10)
    return out


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    root = tmp_path_factory.mktemp("cllb")
    ds = Dataset.open(write_fake_dataset(root / "ds"))
    results.save_run(
        run_fake(ds, [("oracle", Oracle())]),
        root / "open",
        results.RunRecord(ds, ["oracle"], EvalSettings(n_boot=50), make_plots=False),
    )
    return root, write_run(root / "dock"), root / "open"


def test_results_file_round_trip_keeps_counts_ci_and_the_baseline_flag(board):
    _, dock, _ = board
    run = clr.load_closed_loop(dock)
    rows = {(r["localizer"], r["condition"]): r for r in run.doc["rows"]}
    assert len(rows) == 12
    r = rows[("led", "mild")]
    assert (r["n_docked"], r["n_trials"], r["success_rate"]) == (9, 10, 0.9)
    assert (r["ci_low"], r["ci_high"]) == pytest.approx(wilson(9, 10), abs=1e-9)
    assert rows[("truth", "clear")]["baseline"] and not r["baseline"]
    assert rows[("aruco", "clear")]["time_to_dock_median_s"] is None  # no docked trial: null, not NaN
    assert run.doc["capture"]["capture_radius_m"] == pytest.approx(0.5 - 0.0955)


def test_ranking_puts_the_baseline_first_unranked_and_more_docked_higher():
    rows = [
        {
            "localizer": n,
            "label": n,
            "condition": "c",
            "success_rate": p,
            "ci_low": lo,
            "time_to_dock_median_s": t,
            "final_lateral_abs_mean_m": 0.1,
            "baseline": n == "truth",
        }
        for n, p, lo, t in (
            ("slow", 0.9, 0.6, 30.0),
            ("truth", 1.0, 0.7, 20.0),
            ("fast", 0.9, 0.6, 25.0),
            ("bad", 0.2, 0.05, 22.0),
            ("more_trials", 0.9, 0.8, 40.0),
        )
    ]
    ranked = clr.rank_rows(rows)
    assert [r["label"] for r in ranked] == ["truth", "more_trials", "fast", "slow", "bad"]
    assert ranked[0]["rank"] is None and [r["rank"] for r in ranked[1:]] == [1, 2, 3, 4]


def test_leaderboard_shows_closed_loop_beside_open_loop(board, tmp_path):
    _, dock, open_dir = board
    text = leaderboard.build_leaderboard([open_dir, dock], tmp_path / "b.html").read_text()
    assert text.count('<section class="dataset"') == 1 and text.count('<section class="closed-loop"') == 1
    assert text.index('class="dataset"') < text.index('class="closed-loop"')
    lo, hi = wilson(2, 10)
    assert f'20.0 <span class="ci">[{100 * lo:.1f}, {100 * hi:.1f}]</span>' in text
    assert "90.0 (9/10)" in text
    moderate = text[text.index("<h3>condition moderate</h3>") :]
    order = re.findall(r'<tr class="cl-row[^"]*" data-localizer="([^"]+)"', moderate)
    assert order == ["truth", "hybrid", "led", "aruco"]
    assert '<tr class="cl-row baseline" data-localizer="truth">' in moderate


def test_runs_with_other_latency_are_separate_and_same_config_runs_are_ranked_together(board, tmp_path):
    _, dock, _ = board
    late = write_run(tmp_path / "late", latency_s=0.5)
    again = write_run(tmp_path / "again", docked={"led": (10, 10, 5)}, t_dock=15.0)
    text = leaderboard.build_html([], closed_loop=[clr.load_closed_loop(p) for p in (dock, late, again)])
    assert text.count('<section class="closed-loop"') == 2
    first = text[: text.index("data-config-hash", text.index("data-config-hash") + 1)]
    assert "led (dock)" in first and "led (again)" in first  # a name in two runs is told apart
    moderate = first[first.index("<h3>condition moderate</h3>") :]
    order = re.findall(r'data-localizer="([^"]+)"', moderate)
    assert order[:3] == ["truth", "led (again)", "hybrid"]


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.update(format="other"), "format"),
        (lambda d: d["rows"][0].update(success_rate=0.5), "rows[0].success_rate"),
        (lambda d: d["rows"][1].pop("n_docked"), "rows[1] misses n_docked"),
        (lambda d: d["rows"][2].update(n_docked=11), "n_docked <= n_trials"),
    ],
)
def test_a_bad_results_file_is_refused_with_exit_code_2(board, tmp_path, edit, message):
    _, dock, _ = board
    bad = tmp_path / "bad"
    bad.mkdir()
    doc = json.loads((dock / clr.RESULTS_FILE).read_text())
    edit(doc)
    (bad / clr.RESULTS_FILE).write_text(json.dumps(doc))
    res = CliRunner().invoke(cli.main, ["leaderboard", str(bad), "-o", str(tmp_path / "x.html")])
    assert res.exit_code == 2 and message in res.output and "closed_loop.json" in res.output
    assert not (tmp_path / "x.html").exists()
