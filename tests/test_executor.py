"""Executors: the local pool's stop semantics (no Blender), the orphan guard, the
executor choice as a user error, and Ray writing the same bytes as the local pool."""

import _thread
import importlib.util
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from blendgen.config.models import ConfigError, Experiment
from blendgen.pipeline import executor as ex

pytestmark = pytest.mark.integration  # worker processes, signals, the orphan guard

ROOT = Path(__file__).resolve().parent.parent

# 64x48 at 1 spp: three short sequences (14 frames), a few seconds to render
TINY = {
    "name": "tiny-exec",
    "version": "1.0.0",
    "seed": 5,
    "scene": {"template": "pool_15x5x8"},
    "camera": {"width": 64, "height": 48, "hfov_deg": 60, "fps": 5},
    "render": {"fidelity": "fast", "samples": 1},
    "water": {"preset": "clear"},
    "trajectories": [
        {"kind": "linear", "id": "a", "start_range_m": 3.0, "end_range_m": 1.0, "speed_mps": 2.0},
        {"kind": "linear", "id": "b", "start_range_m": 2.5, "end_range_m": 0.8, "speed_mps": 2.0, "lateral_m": 0.2},
    ],
}


def _live_children(marker: str) -> list[int]:
    """Pids of live (not zombie) children of this process whose command line holds ``marker``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if fields[0] != "Z" and int(fields[1]) == os.getpid() and marker in cmd:
            out.append(int(d.name))
    return out


def _fake(script: str):
    return lambda jf: [sys.executable, "-c", script, str(jf)]


def _jobs(tmp_path, n):
    return [ex.write_job({}, tmp_path / f"j{i}.json") for i in range(n)]


def test_interrupt_kills_running_workers_and_starts_no_more(tmp_path):
    jobs, done = _jobs(tmp_path, 4), []
    marker = "import time; time.sleep(60)  # dockbench-test-interrupt"
    # a process started with SIGINT ignored (a background job of a non-interactive shell)
    # would make interrupt_main a no-op: install Python's handler for this test
    import signal

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    threading.Timer(1.5, _thread.interrupt_main).start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            ex.run_local(jobs, tmp_path, 2, done.append, command=_fake(marker))
    finally:
        signal.signal(signal.SIGINT, old)
    assert time.perf_counter() - t0 < 10
    assert done == [] and _live_children("dockbench-test-interrupt") == []


def test_failure_lets_running_jobs_finish_and_starts_no_more(tmp_path):
    jobs, done = _jobs(tmp_path, 5), []
    script = (
        "import sys, time\n"
        "name = sys.argv[1]\n"
        "if name.endswith('j0.json'): print('boom: bad scene'); sys.exit(3)\n"
        "time.sleep(1.0)\n"
    )
    with pytest.raises(ex.RenderError, match=r"exit 3.*j0\.json[\s\S]*boom: bad scene"):
        ex.run_local(jobs, tmp_path, 2, done.append, command=_fake(script))
    assert [p.name for p in done] == ["j1.json"]  # running when j0 failed: finished and committed


def test_orphaned_worker_exits():
    code = (
        "import time\nfrom blendgen.pipeline.executor import _exit_with_parent\n"
        "_exit_with_parent(1)\ntime.sleep(30)\n"
    )  # pid 1 is not our parent: we are 'orphaned'
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=20)
    assert r.returncode == 137 and time.perf_counter() - t0 < 10


def test_slots():
    cpus = os.cpu_count() or 1
    n, t = ex.slots("local", 10, None)
    assert n == min(10, cpus) and t == max(1, cpus // n)  # one worker per core: cores never oversubscribed
    assert n * t <= max(cpus, n)
    assert ex.slots("local", 1, None)[0] == 1  # never more workers than jobs
    assert ex.slots("local", 10, 3, threads=4) == (3, 4)
    assert ex.slots("ray", 10, None) == (None, min(ex.RAY_THREADS, cpus))


def test_importing_generate_does_not_import_ray():
    code = "import sys, blendgen.pipeline.generate, cli; sys.exit('ray' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT).returncode == 0


@pytest.mark.ray
def test_bad_executor_choice_is_a_user_error_and_writes_nothing(tmp_path, monkeypatch):
    from blendgen.pipeline.generate import generate

    exp = Experiment.model_validate(TINY)
    with pytest.raises(ConfigError, match="unknown executor 'dask'"):
        generate(exp, tmp_path / "a", executor="dask")
    if importlib.util.find_spec("ray") is not None:
        with socket.socket() as s:  # a port nobody listens on
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        with pytest.raises(ConfigError, match="no Ray cluster answers"):
            generate(exp, tmp_path / "c", executor="ray", ray_address=f"127.0.0.1:{port}")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    with pytest.raises(ConfigError, match=r"pip install 'dockbench\[ray\]'"):
        generate(exp, tmp_path / "b", executor="ray")
    assert not any((tmp_path / d).exists() for d in "abc")


@pytest.mark.blender
@pytest.mark.ray
def test_ray_writes_the_same_dataset_as_local(tmp_path):
    ray = pytest.importorskip("ray", reason="ray not installed (optional extra: pip install 'dockbench[ray]')")
    from blendgen.pipeline.generate import generate

    exp = Experiment.model_validate(TINY)
    t0 = time.perf_counter()
    local = generate(exp, tmp_path / "local", workers=1, progress=False)
    t1 = time.perf_counter()
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        t2 = time.perf_counter()
        remote = generate(exp, tmp_path / "ray", progress=False, executor="ray")
        t3 = time.perf_counter()
    finally:
        ray.shutdown()
    print(f"tiny config wall time: local {t1 - t0:.1f} s, ray {t3 - t2:.1f} s (ray.init excluded)")
    assert remote["content_hash"] == local["content_hash"]
    assert remote["files"] == local["files"]
    # the manifest holds no paths or times: the whole file is the same bytes
    assert (tmp_path / "ray" / "manifest.json").read_bytes() == (tmp_path / "local" / "manifest.json").read_bytes()
    job = next((tmp_path / "ray" / ".work" / "jobs").glob("*--a-t000-default.json"))
    assert json.loads(job.read_text())["render"]["threads"] == ex.slots("ray", 2, None)[1]


# -- persistent workers (executor --serve): the protocol with a fake server, no Blender --
_FAKE_SERVER = (
    "import json, sys, time, os\n"
    "for line in sys.stdin:\n"
    "    req = json.loads(line)\n"
    "    open(req['log'], 'a').write(f'pid {os.getpid()}\\n')\n"
    "    if req['job'].endswith('j0.json'): print('boom: bad scene', file=open(req['log'], 'a')); sys.exit(3)\n"
    "    time.sleep(float(os.environ.get('FAKE_SLEEP', '0.3')))\n"
    "    print(json.dumps({'ok': True, 'rss_mb': 1.0}), flush=True)\n"
)


def test_persistent_workers_take_job_after_job(tmp_path, monkeypatch):
    monkeypatch.setattr(ex, "serve_command", lambda d: [sys.executable, "-c", _FAKE_SERVER.replace("j0.json", "none")])
    jobs, done = _jobs(tmp_path, 6), []
    ex.run_local(jobs, tmp_path, 2, done.append)
    assert sorted(done) == sorted(jobs)
    pids = {(tmp_path / f"{j.stem}.log").read_text() for j in jobs}
    assert len(pids) == 2  # two processes served the six jobs
    assert _live_children(_FAKE_SERVER[:20]) == []


def test_persistent_worker_crash_is_reported_and_no_new_job_starts(tmp_path, monkeypatch):
    monkeypatch.setattr(ex, "serve_command", lambda d: [sys.executable, "-c", _FAKE_SERVER])
    jobs, done = _jobs(tmp_path, 5), []
    with pytest.raises(ex.RenderError, match=r"worker exited \(code 3\).*j0\.json[\s\S]*boom: bad scene"):
        ex.run_local(jobs, tmp_path, 2, done.append)
    assert [p.name for p in done] == ["j1.json"]  # running when j0 failed: finished and committed


def test_persistent_worker_killed_mid_job_is_retried_once_in_a_fresh_worker(tmp_path, monkeypatch):
    once = (
        "import os, signal, pathlib\n"
        "flag = pathlib.Path(req['job']).with_suffix('.crashed')\n"
        "if req['job'].endswith('j2.json') and not flag.exists(): flag.touch(); os.kill(os.getpid(), 9)\n"
    )
    server = _FAKE_SERVER.replace("j0.json", "none").replace(
        "    time.sleep", "    " + once.replace("\n", "\n    ") + "time.sleep"
    )
    monkeypatch.setattr(ex, "serve_command", lambda d: [sys.executable, "-c", server])
    jobs, done = _jobs(tmp_path, 4), []
    ex.run_local(jobs, tmp_path, 2, done.append)
    assert sorted(done) == sorted(jobs) and (tmp_path / "j2.crashed").exists()
    assert len((tmp_path / "j2.log").read_text().splitlines()) == 2  # two processes ran it


def test_interrupt_kills_persistent_workers(tmp_path, monkeypatch):
    monkeypatch.setattr(
        ex, "serve_command", lambda d: [sys.executable, "-c", _FAKE_SERVER + "# dockbench-test-serve-int"]
    )
    monkeypatch.setenv("FAKE_SLEEP", "60")
    jobs, done = _jobs(tmp_path, 4), []
    import signal

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    threading.Timer(1.5, _thread.interrupt_main).start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            ex.run_local(jobs, tmp_path, 2, done.append)
    finally:
        signal.signal(signal.SIGINT, old)
    assert time.perf_counter() - t0 < 10
    assert done == [] and _live_children("dockbench-test-serve-int") == []


@pytest.mark.blender
def test_persistent_worker_renders_two_scenes_as_fresh_workers_do(tmp_path, monkeypatch):
    """One persistent worker renders A (two paths: the scene reused), then B (another scene:
    rebuilt in the same process): every file is byte-identical to one fresh process per job."""
    from blendgen.pipeline.generate import generate_many

    a = Experiment.model_validate(TINY)
    b = Experiment.model_validate(
        {
            **TINY,
            "name": "tiny-exec-b",
            "seed": 6,
            "scene": {**TINY["scene"], "sun_elevation_deg": 50},
            "camera": {**TINY["camera"], "hfov_deg": 70},
        }
    )
    warm = generate_many([(a, tmp_path / "warm_a"), (b, tmp_path / "warm_b")], workers=1, progress=False)
    jobs = {
        json.dumps(json.loads(p.read_text())["scene"], sort_keys=True)
        for d in ("warm_a", "warm_b")
        for p in (tmp_path / d / ".work" / "jobs").glob("*.json")
    }
    assert len(jobs) == 2  # two different scenes went through one worker
    logs = [p for d in ("warm_a",) for p in (tmp_path / d / ".work" / "logs").glob("worker-*.log")]
    assert len(logs) == 1
    fresh_run = ex.run_local
    monkeypatch.setattr(
        ex, "run_local", lambda files, logs, n, on_done: fresh_run(files, logs, n, on_done, command=ex.worker_command)
    )
    fresh = generate_many([(a, tmp_path / "fresh_a"), (b, tmp_path / "fresh_b")], workers=1, progress=False)
    for w, f, d in zip(warm, fresh, ("a", "b")):
        assert w["files"] == f["files"] and w["content_hash"] == f["content_hash"]
        assert (tmp_path / f"warm_{d}" / "manifest.json").read_bytes() == (
            tmp_path / f"fresh_{d}" / "manifest.json"
        ).read_bytes()
