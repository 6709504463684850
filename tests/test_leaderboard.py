"""Static HTML leaderboard: ranking (a constant answer never wins), content, CLI, headless Chromium."""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner
from fake_dataset import write_fake_dataset
from test_metrics_extra import Constant, Oracle, run_fake

import cli
from evalkit.dataset import Dataset
from evalkit.metrics.extra import EvalSettings
from evalkit.reports import leaderboard, results


def _save(est, out, ds, names):
    results.save_run(est, out, results.RunRecord(ds, names, EvalSettings(n_boot=100), make_plots=False))
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two runs on the same dataset (the second holds the constant-answer localizer) and one on another."""
    root = tmp_path_factory.mktemp("lb")
    ds = Dataset.open(write_fake_dataset(root / "ds"))
    other = Dataset.open(write_fake_dataset(root / "ds2", sequences=[("x", "murky", 0, [1.0, 2.0, 3.0])]))
    dirs = {
        "runA": _save(
            run_fake(ds, [("oracle", Oracle()), ("noisy", Oracle(0.3, seed=1))]), root / "runA", ds, ["oracle", "noisy"]
        ),
        "runB": _save(
            run_fake(ds, [("always_4.2m", Constant()), ("noisier", Oracle(0.6, seed=2))]),
            root / "runB",
            ds,
            ["always_4.2m", "noisier"],
        ),
        "runC": _save(run_fake(other, [("oracle", Oracle())]), root / "runC", other, ["oracle"]),
    }
    return root, dirs


def test_constant_answer_ranks_last(runs):
    root, dirs = runs
    table = results.compare_runs([dirs["runA"], dirs["runB"]])
    ranked = leaderboard.rank(table)
    assert ranked["label"].iloc[-1] == "always_4.2m"
    const = ranked.set_index("label").loc["always_4.2m"]
    assert const["P_detect_mean"] == 1.0  # it answers every frame ...
    assert const["P_succ_mean"] < ranked.set_index("label").loc["noisier", "P_succ_mean"]  # ... and is wrong
    text = leaderboard.build_leaderboard([dirs["runA"], dirs["runB"]], root / "const.html").read_text()
    rows = re.findall(r'<tr class="lb-row[^"]*" data-localizer="([^"]+)"', text)
    assert rows[-1] == "always_4.2m" and rows[0] == "oracle"
    matrix = re.findall(r'<tr class="mx-row" data-localizer="([^"]+)"', text)
    assert matrix[-1] == "always_4.2m"


def test_html_groups_by_dataset_and_ranks(runs):
    root, dirs = runs
    out = leaderboard.build_leaderboard([dirs["runA"], dirs["runB"], dirs["runC"]], root / "board.html")
    text = out.read_text()
    assert text.count('<section class="dataset"') == 2  # two datasets, never mixed
    assert text.count('class="lb-row') == 4 + 1
    assert "http://" not in text and "https://" not in text  # fully offline
    assert "M &lt; 10 trials" in text and "2*" in text  # few trials are flagged
    assert 'class="bins"' in text and 'class="matrix"' in text


def test_autoescape_and_short_names(runs, tmp_path):
    root, dirs = runs
    ds = Dataset.open(root / "ds")
    spec = "/very/long/path/to/my_plugins/<script>alert(1)</script>.py:Loc"
    _save(run_fake(ds, [(spec, Oracle())]), tmp_path / "evil", ds, [spec])
    text = leaderboard.build_html([results.load_run(tmp_path / "evil")])
    assert "<script>alert" not in text and "&lt;script&gt;" in text
    assert leaderboard.short_name("/a/b/c/file.py:Cls") == "file.py:Cls"
    assert leaderboard.short_name("exec:python3 /x/y/run_me.py --fast") == "exec:python3 run_me.py"


def test_runs_with_different_thresholds_are_not_ranked_together(runs, tmp_path):
    from evalkit.metrics.core import SuccessCriteria

    root, dirs = runs
    ds = Dataset.open(root / "ds")
    results.save_run(
        run_fake(ds, [("oracle", Oracle())]),
        tmp_path / "loose",
        results.RunRecord(
            ds, ["oracle"], EvalSettings(criteria=SuccessCriteria(max_rel_dist=0.5), n_boot=50), make_plots=False
        ),
    )
    groups = leaderboard.group_runs([results.load_run(dirs["runA"]), results.load_run(tmp_path / "loose")])
    assert len(groups) == 2


def test_cli_and_errors(runs, tmp_path):
    root, dirs = runs
    res = CliRunner().invoke(cli.main, ["leaderboard", str(dirs["runA"]), "-o", str(tmp_path / "b.html")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "b.html").is_file()
    res = CliRunner().invoke(cli.main, ["leaderboard", str(root / "ds"), "-o", str(tmp_path / "c.html")])
    assert res.exit_code == 2 and "not a dockbench results directory" in res.output


@pytest.mark.integration  # a headless browser
@pytest.mark.skipif(
    leaderboard.find_chromium() is None, reason="chromium not installed (Debian: apt-get install -y chromium)"
)
def test_renders_in_headless_chromium_within_1280px(runs, tmp_path):
    root, dirs = runs
    html_path = leaderboard.build_leaderboard([dirs["runA"], dirs["runB"], dirs["runC"]], tmp_path / "b.html")
    dom = leaderboard.chromium(html_path, "--dump-dom", fragment="sort=label&dir=asc")
    assert 'data-sortable="yes"' in dom  # the inline JS ran
    rows = re.findall(r'<tr class="lb-row[^"]*" data-localizer="([^"]+)"', dom)
    assert len(rows) == 5
    assert rows[:4] == sorted(rows[:4])  # sorted by the URL fragment
    assert 'data-sorted="label:asc"' in dom
    # the page's scroll width at a 1280 px window: nothing sticks out to the right
    probe = html_path.read_text().replace(
        "</body>",
        "<script>document.body.setAttribute('data-scroll-width',document.documentElement.scrollWidth)</script></body>",
    )
    html_path.write_text(probe)
    dom = leaderboard.chromium(html_path, "--dump-dom", "--window-size=1280,900")
    width = int(re.search(r'data-scroll-width="(\d+)"', dom).group(1))
    assert width <= 1280, width
    png = leaderboard.screenshot(html_path, tmp_path / "b.png", size=(1280, 900))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_legends_and_bin_frame_counts_are_on_the_page(runs):
    """A screenshot or print shows what every column means and how many frames each range bin holds
    (not only hover tooltips); the matrix has no averaged column (trajectories are never averaged)."""
    import html

    root, dirs = runs
    text = leaderboard.build_leaderboard([dirs["runA"]], root / "legend.html").read_text()
    legend = html.unescape(re.search(r'<dl class="legend">(.*?)</dl>', text, re.S).group(1))
    for _key, header, _, help_text in leaderboard.COLUMNS:
        assert f"<dt>{header}</dt><dd>{help_text}</dd>" in legend, header
    bins = re.search(r'<table class="bins">(.*?)</table>', text, re.S).group(1)
    titles = re.findall(r'title="(\d+) frames">[^<]*<span class="ci">n=(\d+)</span>', bins)
    assert titles and all(a == b for a, b in titles)  # the tooltip's count, visible
    head = re.search(r'<table class="matrix">(.*?)</thead>', text, re.S).group(1)
    assert "<th>worst</th>" in head and ">mean<" not in head
