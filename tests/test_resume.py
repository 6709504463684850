"""Interrupted generation loses nothing: `dockbench generate` killed at a random
point (kill -9 of its process group, kill -9 of the parent alone, Ctrl-C) and
re-run ends with exactly the dataset of an uninterrupted run.

Images are compared exactly: Cycles at a fixed seed renders the same bits run
after run (and for any Cycles thread count) on one machine, so the tolerance is
zero and the content hashes must match.
"""

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.blender
ROOT = Path(__file__).resolve().parent.parent

# 64x48 at 1 spp, four short sequences: one render process each, ~2 s apiece
TINY = {
    "name": "tiny-resume",
    "version": "1.0.0",
    "seed": 11,
    "scene": {"template": "pool_15x5x8"},
    # 20 fps: a run is still going after its first commit (persistent workers start jobs at once)
    "camera": {"width": 64, "height": 48, "hfov_deg": 60, "fps": 20},
    "render": {"fidelity": "fast", "samples": 1},
    "water": {"preset": "clear"},
    "trajectories": [
        {"kind": "linear", "id": "a", "start_range_m": 3.0, "end_range_m": 1.0, "speed_mps": 2.0},
        {"kind": "linear", "id": "b", "start_range_m": 2.5, "end_range_m": 0.8, "speed_mps": 2.0, "lateral_m": 0.2},
        {"kind": "linear", "id": "c", "start_range_m": 2.0, "end_range_m": 0.75, "speed_mps": 2.0, "vertical_m": 0.1},
        {"kind": "circle", "id": "d", "radius_m": 1.5, "start_deg": -20, "end_deg": 20, "speed_mps": 2.0},
    ],
}


def _cmd(*args) -> list[str]:
    return [sys.executable, "-c", "import cli; cli.main()", *map(str, args)]


def _start(cfg: Path, out: Path) -> subprocess.Popen:
    """`dockbench generate` in its own session (process group), SIGINT at its default."""
    return subprocess.Popen(
        _cmd("generate", cfg, "-o", out, "--workers", "1"),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _run(cfg: Path, out: Path) -> dict:
    r = subprocess.run(
        _cmd("generate", cfg, "-o", out, "--workers", "1"), cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads((out / "manifest.json").read_text())


def _procs() -> list[tuple[int, int, int, str]]:
    """(pid, ppid, pgid, cmdline) of every live (not zombie) process."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            f = stat[stat.rindex(")") + 2 :].split()
            if f[0] != "Z":
                out.append((int(d.name), int(f[1]), int(f[2]), cmd))
    return out


def _workers_of(out: Path) -> list[int]:
    return [pid for pid, _, _, cmd in _procs() if "blendgen.pipeline.executor" in cmd and str(out) in cmd]


def _wait_for(cond, timeout_s: float, what: str):
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _committed(out: Path) -> list[str]:
    d = out / "sequences"
    return sorted(p.name for p in d.iterdir() if not p.name.startswith(".")) if d.is_dir() else []


def _tmp_frames(out: Path) -> dict[str, int]:
    """Frames written so far into each partial (``.tmp``) sequence."""
    n = {}
    for f in out.glob("sequences/.*.tmp/frames.jsonl"):
        try:
            n[f.parent.name] = f.read_bytes().count(b"\n")
        except OSError:
            pass
    return {k: v for k, v in n.items() if v}


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    d = tmp_path_factory.mktemp("resume")
    cfg = d / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    return cfg, _run(cfg, d / "clean"), d / "clean"


def _check_same_as_clean(out: Path, clean_manifest: dict, clean_dir: Path):
    man = json.loads((out / "manifest.json").read_text())
    ids = [s["id"] for s in man["sequences"]]
    assert len(ids) == len(set(ids)) == 4 and _committed(out) == sorted(ids)
    for s in man["sequences"]:
        lines = (out / s["path"] / "frames.jsonl").read_bytes()
        assert lines.count(b"\n") == s["n_frames"] > 0
        assert lines == (clean_dir / s["path"] / "frames.jsonl").read_bytes()  # ground truth byte-identical
    assert not list((out / "sequences").glob(".*"))  # no .tmp left
    r = subprocess.run(_cmd("verify", out), cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert man["files"] == clean_manifest["files"]  # images too: bit-identical
    assert man["content_hash"] == clean_manifest["content_hash"]


def test_kill9_of_the_process_group_at_a_random_point_then_resume(clean, tmp_path):
    cfg, man0, clean_dir = clean
    out = tmp_path / "ds"
    rng = random.Random(20240607)
    # 1st kill: a seeded random time after the first commit (often between jobs);
    # 2nd kill: a seeded random time after a sequence's temp dir holds a frame
    for attempt, partial in ((0, False), (1, True)):
        p = _start(cfg, out)
        _wait_for(lambda: len(_committed(out)) > attempt or p.poll() is not None, 120, "a committed sequence")
        if partial:
            _wait_for(lambda: _tmp_frames(out) or p.poll() is not None, 120, "a partial sequence")
        time.sleep(rng.uniform(0.0, 0.3 if partial else 2.0))
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            print(f"kill -9 group: committed {_committed(out)}, partial {_tmp_frames(out)}")
        p.wait(30)
        _wait_for(lambda: not [q for q in _procs() if q[2] == p.pid], 10, "the killed group to be gone")
    _run(cfg, out)
    _check_same_as_clean(out, man0, clean_dir)


def test_kill9_of_the_parent_alone_stops_its_workers(clean, tmp_path):
    cfg, man0, clean_dir = clean
    out = tmp_path / "ds"
    p = _start(cfg, out)
    workers = _wait_for(lambda: _workers_of(out), 60, "a render worker")
    os.kill(p.pid, signal.SIGKILL)  # the workers are orphaned, not killed
    p.wait(30)
    _wait_for(lambda: not (set(workers) & set(_workers_of(out))), 10, "orphaned workers to exit")
    _run(cfg, out)
    _check_same_as_clean(out, man0, clean_dir)


def test_ctrl_c_kills_workers_and_keeps_finished_sequences(clean, tmp_path):
    cfg, man0, clean_dir = clean
    out = tmp_path / "ds"
    p = _start(cfg, out)
    _wait_for(lambda: _committed(out), 60, "a committed sequence")
    workers = _wait_for(lambda: _workers_of(out), 60, "a render worker")
    kept = _committed(out)
    second = subprocess.run(_cmd("generate", cfg, "-o", out), cwd=ROOT, capture_output=True, text=True)
    assert second.returncode == 2 and "being written by another dockbench generate" in second.stderr
    os.kill(p.pid, signal.SIGINT)  # the parent alone: it must stop its workers itself
    text = p.communicate(timeout=30)[0].decode()
    assert p.returncode == 130 and "re-run the same command to resume" in text, text
    assert not (set(workers) & set(_workers_of(out)))
    assert set(kept) <= set(_committed(out)) and not (out / "manifest.json").exists()
    _run(cfg, out)
    _check_same_as_clean(out, man0, clean_dir)


def test_resume_a_shared_render_with_one_sequence_already_committed(tmp_path):
    """Two image-space conditions share one render job; if a kill lands between the
    two commits, the re-run writes only the missing sequence."""
    cfg = tmp_path / "shared.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                **TINY,
                "trajectories": TINY["trajectories"][:1],
                "conditions": [{"label": "clear"}, {"label": "murky", "water": {"preset": "moderate"}}],
            }
        )
    )
    out = tmp_path / "ds"
    man0 = _run(cfg, out)
    assert len(man0["sequences"]) == 2 and len(list((out / ".work" / "jobs").glob("*.json"))) == 1
    f0, f1 = (json.loads((out / s["path"] / "frames.jsonl").read_text().splitlines()[0]) for s in man0["sequences"])
    assert f0["depth"] == f1["depth"] and f0["depth"].startswith("renders/")  # one copy for both
    assert f0["object_index"] == f1["object_index"] and f0["image"] != f1["image"]
    clean = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and ".work" not in p.parts}
    kept, lost = (out / s["path"] for s in man0["sequences"])
    kept_inode = (kept / "frames.jsonl").stat().st_ino
    (out / "manifest.json").unlink()
    shutil.rmtree(lost)  # as if killed after the first commit
    man = _run(cfg, out)
    assert man["content_hash"] == man0["content_hash"]
    assert (kept / "frames.jsonl").stat().st_ino == kept_inode  # not rewritten
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and ".work" not in p.parts} == clean


def test_datasets_generated_together_share_renders_and_equal_separate_runs(tmp_path):
    """generate_many renders a camera path once for every dataset that needs it, and each
    dataset is byte-identical to the one a separate generate writes."""
    from blendgen.config.models import Experiment
    from blendgen.pipeline.generate import generate, generate_many

    base = {
        "seed": 3,
        "camera": {"width": 64, "height": 48},
        "render": {"samples": 1},
        "scene": {"dock": {"markers": [{"kind": "led_array"}]}},
        "trajectories": [{"kind": "linear", "id": "a", "start_range_m": 3, "end_range_m": 2, "speed_mps": 4}],
    }
    exp_a = Experiment.model_validate({**base, "name": "A", "conditions": [{"label": "clear"}]})
    exp_b = Experiment.model_validate(
        {**base, "name": "B", "conditions": [{"label": "mild", "water": {"preset": "mild"}}]}
    )
    together = generate_many([(exp_a, tmp_path / "A"), (exp_b, tmp_path / "B")], workers=1, progress=False)
    jobs = list((tmp_path / "A" / ".work" / "jobs").glob("*.json")) + list(
        (tmp_path / "B" / ".work" / "jobs").glob("*.json")
    )
    assert len(jobs) == 1  # one render for both datasets
    apart = generate(exp_b, tmp_path / "B2", workers=1, progress=False)
    assert together[1]["content_hash"] == apart["content_hash"]
    depth = [p for p in together[0]["files"] if p.startswith("renders/") and "/depth/" in p]
    assert depth and all(
        (tmp_path / "A" / p).stat().st_ino == (tmp_path / "B" / p).stat().st_ino for p in depth
    )  # written once, hard-linked into the other dataset
