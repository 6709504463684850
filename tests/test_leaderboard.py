"""Static HTML leaderboard: content, ranking, CLI, and rendering in headless Chromium."""
from __future__ import annotations

import re
import shutil

import pytest
from click.testing import CliRunner

from evalkit.reports import leaderboard

from evalkit.reports import results
from evalkit.dataset import Dataset

from fake_dataset import write_fake_dataset
from test_metrics_extra import _oracle_estimates


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two runs on the same dataset and one on another dataset."""
    root = tmp_path_factory.mktemp("lb")
    ds = Dataset.open(write_fake_dataset(root / "ds"))
    other = Dataset.open(write_fake_dataset(root / "ds2", sequences=[("x", "murky", 0, [1.0, 2.0, 3.0])]))
    dirs = {}
    for name, d, seed in (("runA", ds, 0), ("runB", ds, 1), ("runC", other, 2)):
        est = _oracle_estimates(d, seed=seed)
        if name == "runB":
            est["localizer"] = est["localizer"].map({"oracle": "oracle2", "noisy": "noisy2"})
        results.save_run(est, root / name, d, sorted(est["localizer"].unique()), n_boot=100,
                         make_plots=False)
        dirs[name] = root / name
    return root, dirs


def test_html_groups_by_dataset_and_ranks(runs):
    root, dirs = runs
    out = leaderboard.build_leaderboard([dirs["runA"], dirs["runB"], dirs["runC"]], root / "board.html")
    text = out.read_text()
    assert text.count('<section class="dataset"') == 2            # two datasets, never mixed
    assert text.count('class="lb-row') == 4 + 2                   # 4 localizers + 2
    assert "http://" not in text.replace('xmlns="http://www.w3.org/2000/svg"', "") \
        and "https://" not in text                                 # fully offline
    first = re.findall(r'data-localizer="([^"]+)"', text)[:4]
    assert set(first[:2]) == {"oracle", "oracle2"}                # P_succ 1.0 ranked above noisy
    assert "<svg" in text and "[" in text                          # chart and CIs


def test_cli_and_errors(runs, tmp_path):
    root, dirs = runs
    res = CliRunner().invoke(leaderboard.leaderboard_cmd, [str(dirs["runA"]), "-o", str(tmp_path / "b.html")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "b.html").is_file()
    res = CliRunner().invoke(leaderboard.leaderboard_cmd, [str(root / "ds"), "-o", str(tmp_path / "c.html")])
    assert res.exit_code == 2 and "not a dockbench results directory" in res.output


@pytest.mark.skipif(leaderboard.find_chromium() is None,
                    reason="chromium not installed (Debian: apt-get install -y chromium)")
def test_renders_in_headless_chromium(runs, tmp_path):
    root, dirs = runs
    html_path = leaderboard.build_leaderboard([dirs["runA"], dirs["runB"], dirs["runC"]], tmp_path / "b.html")
    dom = leaderboard.chromium(html_path, "--dump-dom", fragment="sort=label&dir=asc")
    assert 'data-sortable="yes"' in dom                            # the inline JS ran
    rows = re.findall(r'<tr class="lb-row[^"]*" data-localizer="([^"]+)"', dom)
    assert len(rows) == 6
    assert rows[:4] == sorted(rows[:4])                            # sorted by the URL fragment
    assert 'data-sorted="label:asc"' in dom
    png = leaderboard.screenshot(html_path, tmp_path / "b.png", size=(1200, 700))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
