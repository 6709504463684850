"""Isolated localizers in the bubblewrap sandbox (evalkit.sandbox): the dataset and everything
outside the scratch folder read-only, the whole process tree gone at the end, no network.
Skipped where bubblewrap is missing or cannot create namespaces (the fallback is tested)."""

from __future__ import annotations

import os
import socket
import sys
import textwrap
import uuid
from pathlib import Path

import pytest

from evalkit import runner, sandbox
from evalkit.dataset import Dataset
from evalkit.isolation import IsolatedLocalizer
from tests.fake_dataset import write_fake_dataset

needs_bwrap = pytest.mark.skipif(not sandbox.available(), reason=f"no sandbox here: {sandbox.probe()[1]}")

HOSTILE = textwrap.dedent("""
    import os, socket, sys, time

    class Hostile:
        def __init__(self, how, target="", port=0, token=""):
            self.how, self.target, self.port, self.token = how, target, int(port), token

        def reset(self, camera):
            pass

        def localize(self, image):
            if self.how == "write":            # overwrite a dataset image, then add a file beside it
                try:
                    open(self.target, "wb").write(b"x")
                except OSError as e:
                    return {"distance": 1.0, "marker_id": f"blocked {e.errno}"}
                return {"distance": 1.0, "marker_id": "written"}
            if self.how == "scratch":           # the one writable place
                p = os.path.join(os.environ["TMPDIR"], "note.txt")
                open(p, "w").write("ok")
                return {"distance": 1.0, "marker_id": open(p).read()}
            if self.how == "fork":              # leave detached processes behind
                for _ in range(3):
                    if os.fork() == 0:
                        os.setsid()
                        if os.fork() == 0:
                            os.execvp(sys.executable, [sys.executable, "-c",
                                                        "import time; time.sleep(600)", self.token])
                        os._exit(0)
                return {"distance": 1.0}
            if self.how == "net":
                try:
                    socket.create_connection(("127.0.0.1", self.port), timeout=2).close()
                    return {"distance": 1.0, "marker_id": "connected"}
                except OSError as e:
                    return {"distance": 1.0, "marker_id": f"no network {e.errno}"}
            return None
""")


@pytest.fixture
def plugin(tmp_path):
    p = tmp_path / "hostile_plugin.py"
    p.write_text(HOSTILE)
    return f"{p}:Hostile"


def _one_frame(spec: str, params: dict) -> dict | None:
    loc = IsolatedLocalizer(spec, params, timeout_s=20)
    try:
        loc.reset({"width": 64, "height": 48, "K": [[50, 0, 32], [0, 50, 24], [0, 0, 1]], "sequence": "s"})
        import numpy as np

        return loc.localize(np.zeros((48, 64, 3), np.uint8))
    finally:
        loc.close()


def _processes_with(token: str) -> list[int]:
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if token.encode() in (d / "cmdline").read_bytes():
                    pids.append(int(d.name))
            except OSError:
                pass
    return pids


@needs_bwrap
def test_a_plugin_cannot_write_into_the_dataset(tmp_path, plugin):
    import hashlib

    root = write_fake_dataset(tmp_path / "ds")
    image = root / "sequences" / "clear_000" / "rgb" / "000001.png"
    before = hashlib.sha256(image.read_bytes()).hexdigest()
    for target in (image, image.parent / "planted.png", tmp_path / "outside.txt"):
        est = _one_frame(plugin, {"how": "write", "target": str(target)})
        assert est["marker_id"] == "blocked 30", (target, est)  # EROFS
    assert hashlib.sha256(image.read_bytes()).hexdigest() == before
    assert not (image.parent / "planted.png").exists() and not (tmp_path / "outside.txt").exists()


@needs_bwrap
def test_the_scratch_folder_is_writable_and_removed_at_close(plugin):
    import numpy as np

    loc = IsolatedLocalizer(plugin, {"how": "scratch"}, timeout_s=20)
    loc.reset({"width": 64, "height": 48, "K": [[50, 0, 32], [0, 50, 24], [0, 0, 1]], "sequence": "s"})
    assert loc.localize(np.zeros((48, 64, 3), np.uint8))["marker_id"] == "ok"
    scratch = Path(loc._scratch)
    assert (scratch / "note.txt").read_text() == "ok"
    loc.close()
    assert not scratch.exists()


@needs_bwrap
def test_detached_children_die_with_the_plugin(plugin):
    token = f"dockbench-sandbox-test-{uuid.uuid4().hex}"
    loc = IsolatedLocalizer(plugin, {"how": "fork", "token": token}, timeout_s=20)
    import numpy as np

    loc.reset({"width": 64, "height": 48, "K": [[50, 0, 32], [0, 50, 24], [0, 0, 1]], "sequence": "s"})
    assert loc.localize(np.zeros((48, 64, 3), np.uint8)) == {"distance": 1.0}
    import time

    for _ in range(100):  # the sleepers exec asynchronously
        if len(_processes_with(token)) == 3:
            break
        time.sleep(0.05)
    assert len(_processes_with(token)) == 3  # the three double-forked, setsid sleepers
    loc.close()
    for _ in range(50):  # the kernel reaps the namespace asynchronously
        if not _processes_with(token):
            break
        time.sleep(0.1)
    assert _processes_with(token) == []


@needs_bwrap
def test_no_network_inside(plugin):
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        est = _one_frame(plugin, {"how": "net", "port": server.getsockname()[1]})
    assert est["marker_id"].startswith("no network"), est


@needs_bwrap
def test_an_external_program_is_sandboxed_too(tmp_path):
    from evalkit.external import ExternalLocalizer

    root = write_fake_dataset(tmp_path / "ds")
    prog = tmp_path / "prog.py"
    prog.write_text(
        textwrap.dedent("""
        import json, sys
        for line in sys.stdin:
            req = json.loads(line)
            if req["type"] == "reset":
                print(json.dumps({"ok": True}), flush=True)
                continue
            try:
                open(req["image"], "ab").write(b"x")
                print(json.dumps({"ok": False, "error": "wrote the image"}), flush=True)
            except OSError as e:
                print(json.dumps({"ok": True, "distance": 1.0, "marker_id": str(e.errno)}), flush=True)
    """)
    )
    before = (root / "sequences/clear_000/rgb/000000.png").read_bytes()
    df = runner.evaluate(
        Dataset.open(root), [("x", ExternalLocalizer([sys.executable, str(prog)], timeout_s=20))], progress=False
    )
    assert set(df["marker_id"]) == {"30"} and (root / "sequences/clear_000/rgb/000000.png").read_bytes() == before


def test_without_bubblewrap_evaluate_says_so_once_and_falls_back(monkeypatch, capsys, plugin):
    monkeypatch.setenv(sandbox.ENV_SWITCH, "0")
    sandbox.probe.cache_clear()
    monkeypatch.setattr(sandbox, "_WARNED", [])
    monkeypatch.setenv(sandbox.WARNED_ENV, "")  # restored (removed) after the test
    try:
        assert not sandbox.available() and sandbox.probe()[1] == "DOCKBENCH_SANDBOX=0"
        for _ in range(2):
            assert _one_frame(plugin, {"how": "nothing"}) is None  # runs, unconfined
        err = capsys.readouterr().err
        assert err.count("run without a sandbox: DOCKBENCH_SANDBOX=0") == 1, err
        import subprocess  # a child process (an evaluation worker) stays quiet

        code = "from evalkit import sandbox; sandbox.warn_once_unavailable()"
        r = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
        )
        assert r.returncode == 0 and r.stderr == "", r.stderr
    finally:
        sandbox.probe.cache_clear()
