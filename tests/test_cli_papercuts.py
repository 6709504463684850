"""CLI paper cuts: bundled configs by name, the quickstart's header, the demo target, outputs only under -o."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

import cli
from blendgen.config.bundled import bundled_file, bundled_names, resolve_config
from blendgen.config.models import ConfigError, load_experiment

ROOT = Path(__file__).resolve().parents[1]


def test_bundled_configs_by_name_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no configs/ folder here
    for spec in ("quickstart", "quickstart.yaml", "configs/quickstart.yaml"):
        assert resolve_config(spec) == bundled_file("configs", "quickstart.yaml")
        assert load_experiment(spec).name == "quickstart"
    (tmp_path / "quickstart.yaml").write_text(
        (ROOT / "configs" / "quickstart.yaml").read_text().replace("name: quickstart", "name: mine")
    )
    assert load_experiment("quickstart.yaml").name == "mine"  # a real file wins over the bundled name
    with pytest.raises(ConfigError, match="bundled configs.*quickstart"):
        load_experiment("no_such_config")


def test_configs_command_lists_every_bundled_config():
    res = CliRunner().invoke(cli.main, ["configs"])
    assert res.exit_code == 0, res.output
    names = [line.split()[0] for line in res.output.splitlines() if not line.startswith("(")]
    assert names == bundled_names("configs") and "quickstart" in names and "paper_turbidity" in names
    assert "Small demo" in res.output


def test_generate_unknown_config_is_a_one_line_error(tmp_path):
    res = CliRunner().invoke(cli.main, ["generate", "nope", "-o", str(tmp_path / "o")])
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "dockbench configs" in res.output
    assert not (tmp_path / "o").exists()


def test_quickstart_header_says_what_it_runs():
    text = (ROOT / "configs" / "quickstart.yaml").read_text()
    approach = next(t for t in yaml.safe_load(text)["trajectories"] if t["kind"] == "linear")
    m = re.search(r"from ([\d.]+) m to ([\d.]+) m", text.splitlines()[0])
    assert (float(m.group(1)), float(m.group(2))) == (approach["start_range_m"], approach["end_range_m"])


def test_demo_evaluates_the_hybrid_too():
    demo = re.search(r"^demo:.*?(?=^\S)", (ROOT / "Makefile").read_text(), re.DOTALL | re.MULTILINE).group(0)
    assert all(f"-l {name}" in demo for name in ("led", "qr", "aruco", "hybrid"))


def test_calibrate_size_and_trials_override_the_config():
    from blendgen.tools.calibration import camera as cal

    cfg = cal.load_config(cal.DEFAULT_CONFIG)
    small = cal.with_overrides(cfg, (320, 240), 2)
    assert small.resolutions == [(320, 240)] and small.trials == 2
    assert cal.with_overrides(cfg).resolutions == cfg.resolutions and cfg.trials == 5


@pytest.mark.parametrize(
    "args",
    [
        ["calibrate", "--size", "320 240"],
        ["calibrate", "--size", "8x8"],
        ["bench", "particles", "--size", "640", "480"],
        ["bench", "particles", "--size", "abc"],
    ],
)
def test_one_size_syntax_wxh(args, tmp_path):
    """--size is WxH everywhere (16..8192 each); `W H` and out-of-range sizes are usage errors, before any work."""
    res = CliRunner().invoke(cli.main, args + ["-o", str(tmp_path / "o")] if args[0] == "calibrate" else args)
    assert res.exit_code == 2, res.output
    assert not (tmp_path / "o").exists()


def test_no_width_height_options_left():
    assert not [
        path
        for path, cmd in _walk(cli.main)
        for p in cmd.params
        if {"--width", "--height"} & set(getattr(p, "opts", ()))
    ]


def test_size_options_share_one_parser():
    import click

    sizes = {}
    for path, cmd in _walk(cli.main):
        for p in cmd.params:
            if "--size" in getattr(p, "opts", ()) and path not in ("bench glow", "bench caustics"):
                sizes[path] = p
    assert {
        "calibrate",
        "bench particles",
        "bench suite",
        "dock",
        "bench closed-loop",
        "preview",
        "bench fidelity",
        "calibrate-water",
    } <= set(sizes)
    for path, p in sizes.items():
        assert p.type == click.STRING or isinstance(p.type, click.types.StringParamType), path
        assert p.nargs == 1, path


def _walk(group, prefix=""):
    import click

    for name, cmd in group.commands.items():
        path = f"{prefix} {name}".strip()
        if isinstance(cmd, click.Group):
            yield from _walk(cmd, path)
        else:
            yield path, cmd


def test_lamp_bench_announces_each_cycles_render(tmp_path, monkeypatch):
    """bench lamp's renders take minutes: each uncached one is announced (the CLI prints the line)."""
    import subprocess

    import numpy as np

    from blendgen.tools.bench import lamp_bench as lb

    def fake_run(cmd, **kw):
        np.save(cmd[-1], np.zeros((2, 2, 3)))
        return subprocess.CompletedProcess(cmd, 0, "", "")

    seen = []
    monkeypatch.setattr(lb.subprocess, "run", fake_run)
    monkeypatch.setattr(lb, "ON_RENDER", seen.append)
    spec = {"width": 96, "height": 72, "samples": 64, "volume_bounces": 0, "seed": 1}
    lb.reference(spec, tmp_path)
    lb.reference(spec, tmp_path)  # cached: no render, no line
    lb.reference({**spec, "samples": 8}, tmp_path)
    assert len(seen) == 2 and "96x72, 64 spp, 0 volume bounces" in seen[0] and "8 spp" in seen[1]


#: every writing command whose output once defaulted to the current directory: argv without -o (positional
#: arguments valid, so the missing -o is the first error)
_OUT_REQUIRED = {
    "docking-paths": [],
    "bench stages": [],
    "bench fidelity": [],
    "bench render-settings": ["{base}", "{base}"],
    "bench pnp": [],
    "bench glow": [],
    "bench caustics": [],
    "bench lamp": [],
    "bench localizers": ["{base}"],
    "bench closed-loop": [],
    "bench suite": [],
    "calibrate": [],
    "calibrate-water": [],
    "calibrate-veil": [],
    "preview": [],
    "reproduce": ["turbidity"],
    "run": ["quickstart", "-l", "aruco"],
    "dock": ["turbidity"],
    "leaderboard": ["{base}"],
}


@pytest.mark.parametrize("command", sorted(_OUT_REQUIRED))
def test_writing_commands_require_out_and_write_nothing_without_it(command, tmp_path, monkeypatch):
    base = tmp_path / "in"
    base.mkdir()
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    argv = command.split() + [a.format(base=base) for a in _OUT_REQUIRED[command]]
    res = CliRunner().invoke(cli.main, argv)
    assert res.exit_code == 2, res.output
    assert "Missing option '-o' / '--out'" in res.output, res.output
    assert list(cwd.iterdir()) == [] and list(base.iterdir()) == []


def test_no_output_defaults_under_the_current_directory(tmp_path, monkeypatch):
    """No -o defaults to a path of the current directory; `dockbench bench` alone runs nothing."""
    required = set()
    for path, cmd in _walk(cli.main):
        for p in cmd.params:
            if "-o" in getattr(p, "opts", ()):
                assert not isinstance(p.default, Path), (path, p.default)
                if p.required:
                    required.add(path)
    assert set(_OUT_REQUIRED) <= required
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(cli.main, ["bench"])
    assert res.exit_code == 2 and "Commands:" in res.output, res.output
    assert list(tmp_path.iterdir()) == []
