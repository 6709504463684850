"""`dockbench evaluate` as a user runs it: integrity, provenance, reproducible summaries, safe output."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from fake_dataset import write_fake_dataset

import cli

pytestmark = pytest.mark.integration  # the CLI end to end: subprocesses, concurrent writers

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = '''
import time
import numpy as np

class Oracle:
    """d_true from the pixels (tests/fake_dataset.py encoding); optional delay per frame."""
    def __init__(self, delay_s=0.0, scale=1.0):
        self.delay_s, self.scale = float(delay_s), float(scale)
    def reset(self, camera):
        pass
    def localize(self, image):
        time.sleep(self.delay_s)
        r, g, b = (int(v) for v in image[0, 0])
        return {"distance": self.scale * ((r << 16) | (g << 8) | b) / 1000.0, "marker_id": "0"}
'''


@pytest.fixture
def setup(tmp_path):
    ds = write_fake_dataset(tmp_path / "ds")
    plugin = tmp_path / "plug" / "oracle_plugin.py"
    plugin.parent.mkdir()
    plugin.write_text(PLUGIN)
    return ds, f"{plugin}:Oracle", plugin


def _run(*args):
    res = CliRunner().invoke(cli.main, [str(a) for a in args])
    return res


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_same_inputs_give_byte_identical_summaries(setup, tmp_path):
    ds, spec, plugin = setup
    outs = []
    for name in ("a", "b"):
        res = _run("evaluate", ds, "-l", spec, "-p", "scale=1.02", "-o", tmp_path / name, "--json")
        assert res.exit_code == 0, res.output
        outs.append(json.loads(res.stdout))
    for f in ("summary.csv", "metrics.csv", "bins.csv", "recall.csv", "false_positives.csv"):
        assert _sha(tmp_path / "a" / f) == _sha(tmp_path / "b" / f), f
    assert {**outs[0], "results": ""} == {**outs[1], "results": ""}
    run = json.loads((tmp_path / "a" / "run.json").read_text())
    cmd = run["command"]
    assert cmd[:2] == ["dockbench", "evaluate"] and cmd[-1] == str(ds)
    assert cmd[cmd.index("--param") + 1] == "scale=1.02" and "--max-rel-error" in cmd
    loc = run["localizers"][0]
    assert loc["params"] == {"scale": 1.02}  # as given, not post-run state
    assert loc["code"] == [{"role": "plugin file", "path": str(plugin.resolve()), "sha256": _sha(plugin)}]
    env = run["environment"]
    assert {"python", "numpy", "pandas", "scipy"} <= set(env["packages"])
    assert run["dataset"]["verified"] is True and run["options"]["verify"] is True
    m = outs[0]["metrics"][0]
    assert m["P_detect_mean"] == 1.0 and m["n_fp"] == 1  # answers the out-of-view frame too


def test_tampered_ground_truth_refused_and_no_verify_recorded(setup, tmp_path):
    ds, spec, _ = setup
    path = ds / "sequences/clear_000/frames.jsonl"
    frames = [json.loads(x) for x in path.read_text().splitlines()]
    frames[3]["d_true"] += 1.0  # GT edit, JSON still valid
    path.write_text("".join(json.dumps(f) + "\n" for f in frames))
    res = _run("evaluate", ds, "-l", spec, "-o", tmp_path / "out")
    assert res.exit_code == 2
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "frames.jsonl: sha256 differs" in lines[0]
    assert not (tmp_path / "out").exists()
    res = _run("evaluate", ds, "-l", spec, "-o", tmp_path / "out", "--no-verify", "--quiet")
    assert res.exit_code == 0, res.output
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["options"]["verify"] is False and run["dataset"]["verified"] is False
    manifest = json.loads((ds / "manifest.json").read_text())
    assert run["dataset"]["manifest_content_hash"] == manifest["content_hash"]
    assert run["dataset"]["content_hash"] != manifest["content_hash"]  # recomputed from the bytes


def test_out_folder_refused_unless_overwrite(setup, tmp_path):
    ds, spec, _ = setup
    out = tmp_path / "out"
    assert _run("evaluate", ds, "-l", spec, "-o", out, "-q").exit_code == 0
    first = (out / "run.json").read_text()
    res = _run("evaluate", ds, "-l", spec, "-o", out, "-q")
    assert res.exit_code == 2 and "not empty" in res.output and "--overwrite" in res.output
    assert (out / "run.json").read_text() == first
    res = _run("evaluate", ds, "-l", spec, "-o", out, "-q", "--overwrite")
    assert res.exit_code == 0 and res.output == ""  # --quiet: nothing on stdout
    assert json.loads((out / "run.json").read_text())["options"]["overwrite"] is True
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no leftovers


def test_concurrent_writers_one_wins(setup, tmp_path):
    ds, spec, _ = setup
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-c",
        "import cli; cli.main()",
        "evaluate",
        str(ds),
        "-l",
        spec,
        "-p",
        "delay_s=0.25",
        "-o",
        str(out),
        "-q",
    ]
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    first = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lock = tmp_path / ".out.lock"
    deadline = time.monotonic() + 60
    while not lock.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    second = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert second.returncode == 2, second.stderr
    assert "being written by another dockbench evaluate (pid" in second.stderr
    assert first.wait(timeout=120) == 0, first.stderr.read()
    assert (out / "run.json").is_file() and not lock.exists()
