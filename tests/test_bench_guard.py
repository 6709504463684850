"""The regression guard of `dockbench bench check` and the stage terms it compares, on synthetic
numbers and a fake clock (nothing rendered, nothing timed)."""

import json

import pytest
from click.testing import CliRunner

import cli
from blendgen.config.models import ConfigError
from blendgen.pipeline import stagetimer
from blendgen.tools.bench import guard
from blendgen.tools.bench import suitebench as sb


def _flags(old, new, **kw):
    df = guard.compare(old, new, **kw)
    return dict(zip(df["stage"], df["flag"]))


def test_a_stage_25_percent_slower_is_flagged_15_percent_is_not():
    old = {"physical render": 100.0, "physical compose": 40.0, "article write": 10.0}
    new = {"physical render": 125.0, "physical compose": 46.0, "article write": 10.0}
    assert _flags(old, new) == {"physical render": "slower", "physical compose": "", "article write": ""}


def test_faster_by_more_than_the_tolerance_is_flagged_too():
    flags = _flags({"a": 100.0, "b": 100.0}, {"a": 75.0, "b": 85.0})
    assert flags == {"a": "faster", "b": ""}
    assert _flags({"a": 100.0}, {"a": 85.0}, tolerance=0.1) == {"a": "faster"}


def test_new_and_missing_stages_are_reported():
    df = guard.compare({"render": 10.0, "compose.lamp": 3.0}, {"render": 10.0, "compose.caustics": 5.0})
    assert list(df["stage"]) == ["render", "compose.lamp", "compose.caustics"]
    assert list(df["flag"]) == ["", "missing", "new stage"]


def test_ratio_is_new_over_old_and_small_stages_are_not_flagged():
    df = guard.compare({"big": 8.0, "tiny": 0.1}, {"big": 10.0, "tiny": 0.3}, floor_s=0.5)
    assert df.loc[0, "ratio"] == pytest.approx(1.25) and df.loc[0, "flag"] == "slower"
    assert df.loc[1, "ratio"] == pytest.approx(3.0) and df.loc[1, "flag"] == ""  # both under the floor
    assert _flags({"tiny": 0.1}, {"tiny": 0.3}, floor_s=0.0) == {"tiny": "slower"}


class _FakeClock:
    """process_time / perf_counter that advance only when told to."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_terms_exclude_nested_terms_and_sum_within_their_stage(monkeypatch):
    clock = _FakeClock()
    monkeypatch.setattr(stagetimer.time, "process_time", clock)
    monkeypatch.setattr(stagetimer.time, "perf_counter", clock)
    timer = stagetimer.StageTimer()
    with timer("compose"):
        clock.t += 1.0  # untimed part of the stage
        with stagetimer.term("water"):
            clock.t += 2.0
            with stagetimer.term("caustics"):
                clock.t += 4.0
        with stagetimer.term("sensor"):
            clock.t += 0.5
    assert timer.cpu_s == {"compose": 7.5, "compose.water": 2.0, "compose.caustics": 4.0, "compose.sensor": 0.5}
    assert timer.totals()["wall_compose.caustics_s"] == 4.0


def test_a_term_outside_any_stage_records_nothing():
    timer = stagetimer.StageTimer()

    @stagetimer.term("water")
    def water(x):
        """doc kept"""
        return 2 * x

    assert water(3) == 6 and water.__doc__ == "doc kept"
    assert timer.cpu_s == {} and stagetimer._ACTIVE == []


def _run(mode, render, compose, terms, led_s):
    run = sb.SuiteRun("x", 1, 640, 480, "-", "turbidity", mode=mode)
    run.cpu = {"render": render, "compose": compose, "write": 2.0, "generate": render + compose + 2.0 + 5.0}
    run.cpu.update(evaluate=8.0, generate_other=5.0)
    run.terms, run.localizers = terms, {"led": {"s": led_s, "frames": 100}}
    run.wall, run.disk = {"generate": 50.0, "evaluate": 5.0}, {"total": 10.0, "without_images": 2.0}
    return run


def test_stage_figures_split_compose_and_evaluate_and_add_up():
    figs = sb.stage_figures(_run("physical", 60.0, 30.0, {"compose.water": 20.0, "compose.sensor": 6.0}, 1.5))
    assert list(figs) == [
        "render",
        "compose",
        "compose.sensor",
        "compose.water",
        "compose.other",
        "write",
        "generate_other",
        "evaluate",
        "evaluate.led",
        "total",
    ]
    assert figs["compose.other"] == pytest.approx(4.0)
    assert figs["total"] == pytest.approx(60 + 30 + 2 + 5 + 8)


def test_side_by_side_has_a_column_per_mode_the_ratio_and_the_estimate():
    runs = {"physical": _run("physical", 60.0, 40.0, {}, 2.0), "article": _run("article", 60.0, 10.0, {}, 1.0)}
    df = sb.side_by_side(runs).set_index("stage")
    assert df.loc["compose", "physical / article"] == pytest.approx(4.0)
    est = df.loc[f"100 trials: h on {sb.REFERENCE_CORES} idle cores"]
    assert est["article CPU s"] == pytest.approx((60 + 10 + 2 + 5 + 8) * 100 / sb.REFERENCE_CORES / 3600)


def test_baseline_round_trip_and_bad_files_are_one_line_errors(tmp_path, monkeypatch):
    monkeypatch.setattr("evalkit.reports.provenance.git_state", lambda: {"commit": "abc", "dirty": False})
    runs = {"physical": _run("physical", 60.0, 40.0, {"compose.water": 30.0}, 2.0)}
    meas = guard.Measurement(("turbidity",), 1, (640, 480), "none", ("physical",))
    doc = guard.record(runs, meas, guard.machine())
    path = tmp_path / "b.json"
    guard.write_baseline(doc, path)
    back = guard.load_baseline(path)
    assert guard.Measurement.from_json(back["measurement"]) == meas and back["commit"] == "abc"
    assert back["command"] == (
        "dockbench bench check -o OUT --record --trials 1 -e turbidity --size 640x480 --images none --mode physical"
    )
    assert guard.flat_figures(back["runs"])["physical compose.water"] == 30.0
    assert back["machine"]["cores"] >= 1 and back["machine"]["cpu_model"]
    path.write_text(json.dumps({"runs": {}}))
    with pytest.raises(ConfigError, match=r"^--baseline .*b\.json: not a baseline"):
        guard.load_baseline(path)
    with pytest.raises(ConfigError, match="no such file"):
        guard.load_baseline(tmp_path / "absent.json")


def test_check_refuses_measurement_options_without_record(tmp_path):
    res = CliRunner().invoke(cli.main, ["bench", "check", "--trials", "2", "-o", str(tmp_path / "c")])
    assert res.exit_code == 2 and "apply with --record only" in res.output
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "c" / "suite-physical").exists()


def test_check_with_a_missing_baseline_is_a_one_line_error(tmp_path):
    res = CliRunner().invoke(
        cli.main, ["bench", "check", "--baseline", str(tmp_path / "no.json"), "-o", str(tmp_path / "c")]
    )
    assert res.exit_code == 2 and res.output.strip().splitlines() == [
        f"error: --baseline {tmp_path / 'no.json'}: no such file (expected a baseline written by "
        "`dockbench bench check --record`)"
    ]


def test_localizer_seconds_scale_each_sequence_by_its_process_cpu_share(tmp_path):
    import pandas as pd

    base = tmp_path / "exp"
    (base / "results").mkdir(parents=True)
    (base / ".stream" / "exp").mkdir(parents=True)
    rows = [("led", "s1", 10.0)] * 4 + [("led", "s2", 20.0)] * 2 + [("qr", "s1", 1.0)] * 4
    pd.DataFrame(rows, columns=["localizer", "sequence", "ms"]).to_parquet(base / "results" / "estimates.parquet")
    (base / ".stream" / "exp" / "s1.cost.json").write_text(json.dumps({"cpu_s": 1.0, "wall_s": 4.0, "frames": 4}))
    (base / ".stream" / "exp" / "s2.cost.json").write_text(json.dumps({"cpu_s": 3.0, "wall_s": 2.0, "frames": 2}))
    got = sb.localizer_seconds(tmp_path)
    assert got["led"]["wall_s"] == pytest.approx(0.080) and got["led"]["frames"] == 6
    assert got["led"]["s"] == pytest.approx(0.040 * 0.25 + 0.040 * 1.0)  # s2's share capped at 1
    assert got["qr"]["s"] == pytest.approx(0.004 * 0.25)


def test_check_records_then_flags_what_moved(tmp_path, monkeypatch):
    """The command's flow on synthetic suite runs (the measurement itself is bench suite's)."""
    calls, compose_s = [], [30.0]

    def fake_measure(trials, names, ov, out, workers, evaluate, images, modes):
        calls.append((trials, names, ov.size, images, modes))
        return {m: _run(m, 60.0, compose_s[0], {"compose.water": 20.0}, 2.0) for m in modes}

    monkeypatch.setattr(sb, "measure_modes", fake_measure)
    base = tmp_path / "base.json"
    rec = ["bench", "check", "--record", "--baseline", str(base), "--mode", "article", "--size", "320x240"]
    res = CliRunner().invoke(cli.main, [*rec, "-o", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    assert calls == [(1, ("turbidity",), (320, 240), "none", ("article",))] and "recorded the baseline" in res.output
    compose_s[0] = 40.0  # compose.other 10 -> 20 s, compose 30 -> 40 s
    res = CliRunner().invoke(cli.main, ["bench", "check", "--baseline", str(base), "-o", str(tmp_path / "b")])
    assert res.exit_code == 0, res.output
    assert calls[-1] == calls[0]  # the baseline's measurement, rerun
    moved = [ln for ln in res.output.splitlines() if ln.startswith("MOVED")]
    assert moved == [  # total 107 -> 117 s (x1.09) is within the tolerance
        "MOVED article compose: slower x1.33, more than 20 %",
        "MOVED article compose.other: slower x2.00, more than 20 %",
    ]
    assert (tmp_path / "b" / "bench_check.csv").is_file() and not (tmp_path / "b" / "bench_baseline.json").exists()


def test_the_package_baseline_loads_and_names_its_machine():
    base = guard.load_baseline(guard.BASELINE)
    assert base["commit"] and base["machine"]["cores"] and base["machine"]["cpu_model"]
    assert set(base["runs"]) == set(base["measurement"]["modes"])
    for run in base["runs"].values():
        assert {"render", "compose", "write", "evaluate", "total"} <= set(run["cpu_s"]) and run["frames_rendered"] > 0
