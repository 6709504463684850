"""A real Ray cluster: a head and a worker node started with ``ray start`` on this host.

`dockbench generate --executor ray --address HOST:PORT` on it writes the dataset the
local executor writes (same content hash). The cluster uses its own port and a token
made for this test (RAY_AUTH_MODE=token, RAY_AUTH_TOKEN), and is torn down by killing
the processes it started (found by their session directory), never with ``ray stop``,
which would stop every Ray on the host.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.blender, pytest.mark.ray]

TINY = {  # 64x48, 1 spp, two camera paths: one Ray task each, so both nodes get work
    "name": "tiny-ray",
    "version": "1.0.0",
    "seed": 5,
    "scene": {"template": "pool_15x5x8"},
    "camera": {"width": 64, "height": 48, "hfov_deg": 60, "fps": 5},
    "render": {"fidelity": "fast", "samples": 1, "threads": 1},  # one Ray CPU per task
    "conditions": [{"label": "clear"}, {"label": "mild", "water": {"preset": "mild"}}],
    "trajectories": [
        {"kind": "linear", "id": "a", "start_range_m": 3.0, "end_range_m": 1.5, "speed_mps": 3.0},
        {"kind": "linear", "id": "b", "start_range_m": 2.5, "end_range_m": 1.0, "speed_mps": 3.0, "lateral_m": 0.2},
    ],
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session_pids(temp_dir: Path) -> list[int]:
    """Processes whose command line names this cluster's temp dir (its whole session)."""
    pids = []
    for d in os.listdir("/proc"):
        if d.isdigit() and int(d) != os.getpid():
            try:
                cmd = Path(f"/proc/{d}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if str(temp_dir) in cmd:
                pids.append(int(d))
    return pids


def _teardown(temp_dir: Path) -> None:
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in _session_pids(temp_dir):
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        time.sleep(2.0)


@pytest.fixture
def cluster(tmp_path_factory):
    ray_bin = Path(sys.executable).with_name("ray")
    if not ray_bin.is_file():
        pytest.skip("ray not installed (optional extra: pip install 'dockbench[ray]')")
    temp_dir = (
        Path(tempfile.gettempdir()) / f"dbray{secrets.token_hex(3)}"
    )  # short: Ray's socket paths have a length limit
    port, client_port = _free_port(), _free_port()
    env = {
        **os.environ,
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
        "RAY_USAGE_STATS_ENABLED": "0",
    }
    common = ["--num-cpus", "1", "--disable-usage-stats"]
    head = [
        ray_bin,
        "start",
        "--head",
        "--port",
        str(port),
        "--temp-dir",
        str(temp_dir),
        "--include-dashboard",
        "false",
        "--ray-client-server-port",
        str(client_port),
        *common,
    ]
    address = f"127.0.0.1:{port}"
    try:
        for cmd in (head, [ray_bin, "start", "--address", address, "--temp-dir", str(temp_dir), *common]):
            r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=180)
            if r.returncode != 0:
                pytest.skip(
                    f"`ray start` failed here ({' '.join(map(str, cmd[1:3]))}): "
                    f"{(r.stderr or r.stdout).strip().splitlines()[-1:]}"
                )
        yield address, env
    finally:
        _teardown(temp_dir)
        shutil.rmtree(temp_dir, ignore_errors=True)


def test_two_node_ray_cluster_writes_the_local_dataset(cluster, tmp_path):
    address, env = cluster
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(json.dumps(TINY))  # JSON is YAML
    root = Path(__file__).resolve().parent.parent
    env = {**env, "PYTHONPATH": os.pathsep.join([str(root), env.get("PYTHONPATH", "")])}
    nodes = subprocess.run(
        [
            sys.executable,
            "-c",
            "import ray, json; ray.init(address='auto'); "
            "print(json.dumps(sum(1 for n in ray.nodes() if n['Alive']))); ray.shutdown()",
        ],
        env={**env, "RAY_ADDRESS": address},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert nodes.returncode == 0 and nodes.stdout.strip().splitlines()[-1] == "2", nodes.stdout + nodes.stderr

    def gen(out: Path, *extra) -> dict:
        r = subprocess.run(
            [sys.executable, "-c", "import cli; cli.main()", "generate", str(cfg), "-o", str(out), *extra],
            cwd=root,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert r.returncode == 0, r.stdout + r.stderr
        return json.loads((out / "manifest.json").read_text())

    on_cluster = gen(tmp_path / "ray", "--executor", "ray", "--address", address)
    local = gen(tmp_path / "local", "--workers", "1")
    assert on_cluster["content_hash"] == local["content_hash"]
    assert (tmp_path / "ray" / "manifest.json").read_bytes() == (tmp_path / "local" / "manifest.json").read_bytes()
