"""The leaderboard refuses hand-edited numbers it would rank (evalkit.reports.numbers)."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest
from click.testing import CliRunner

import cli
from tests.fake_dataset import write_fake_dataset


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    base = tmp_path_factory.mktemp("lb")
    ds = write_fake_dataset(base / "ds")
    res = CliRunner().invoke(cli.main, ["evaluate", str(ds), "-l", "aruco", "-o", str(base / "res"), "-q"])
    assert res.exit_code == 0, res.output
    return base / "res"


def _copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def _edit_csv(path, col, value, row=0):
    df = pd.read_csv(path)
    df[col] = df[col].astype(object)
    df.loc[row, col] = value
    df.to_csv(path, index=False)


def test_the_untouched_run_is_accepted(results, tmp_path):
    res = CliRunner().invoke(cli.main, ["leaderboard", str(results), "-o", str(tmp_path / "lb.html")])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(
    "col, value, says",
    [
        ("P_succ_mean", -5.0, "outside [0, 1]"),  # P_succ -500 %
        ("P_detect_hi", 1.5, "outside [0, 1]"),
        ("E_rel_mean", 1e308, "outside [0, 50000]"),  # E_rel 1e308: beyond 10 km / d_min_rel 0.2 m
        ("E_rel_mean", -1e308, "outside [0, 50000]"),
        ("e_rot_deg_mean", 181.0, "outside [0, 180]"),
        ("n_fp", 99, "n_fp = 99 exceeds n_est"),  # counts that disagree
        ("n_trials", 0, "not an integer >= 1"),
        ("n_frames", 2.5, "not an integer"),
        ("P_succ_mean", "lots", "not a number"),
    ],
)
def test_a_hand_edited_metric_is_refused_in_one_line(results, tmp_path, col, value, says):
    run = _copy(results, tmp_path / "run")
    _edit_csv(run / "metrics.csv", col, value)
    res = CliRunner().invoke(cli.main, ["leaderboard", str(run), "-o", str(tmp_path / "lb.html")])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and says in lines[0], res.output
    assert str(run / "metrics.csv") in lines[0] and col in lines[0]
    assert not (tmp_path / "lb.html").exists()


def test_an_interval_that_does_not_hold_its_mean_is_refused(results, tmp_path):
    run = _copy(results, tmp_path / "run")
    df = pd.read_csv(run / "metrics.csv")
    df.loc[0, ["P_succ_lo", "P_succ_mean", "P_succ_hi"]] = [0.5, 0.9, 0.6]
    df.to_csv(run / "metrics.csv", index=False)
    res = CliRunner().invoke(cli.main, ["leaderboard", str(run), "-o", str(tmp_path / "lb.html")])
    assert res.exit_code == 2 and "P_succ_lo <= P_succ_mean <= P_succ_hi" in res.output


def test_run_json_metrics_are_checked_too(results, tmp_path):
    run = _copy(results, tmp_path / "run")
    (run / "metrics.csv").unlink()  # the leaderboard then reads run.json's copy
    doc = json.loads((run / "run.json").read_text())
    doc["metrics"][0]["P_detect_mean"] = math.inf
    (run / "run.json").write_text(json.dumps(doc))
    res = CliRunner().invoke(cli.main, ["leaderboard", str(run), "-o", str(tmp_path / "lb.html")])
    assert res.exit_code == 2 and "run.json" in res.output and "P_detect_mean" in res.output


def test_closed_loop_numbers_are_checked():
    from evalkit.reports.numbers import NumberError, check_closed_loop_row

    good = {
        "success_rate": 0.5,
        "ci_low": 0.2,
        "ci_high": 0.8,
        "final_lateral_abs_mean_m": 0.1,
        "final_heading_abs_mean_deg": 3.0,
        "time_to_dock_median_s": 40.0,
    }
    check_closed_loop_row("x", good)
    for key, bad in (
        ("final_lateral_abs_mean_m", 1e308),
        ("final_lateral_abs_mean_m", -1.0),
        ("ci_high", 1.2),
        ("time_to_dock_median_s", math.inf),
        ("final_heading_abs_mean_deg", 270),
    ):
        with pytest.raises(NumberError, match=key):
            check_closed_loop_row("x", {**good, key: bad})
    with pytest.raises(NumberError, match="ci_low <= success_rate <= ci_high"):
        check_closed_loop_row("x", {**good, "ci_low": 0.6})
