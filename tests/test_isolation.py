"""Process isolation: a localizer that raises, hangs, crashes or returns garbage loses one frame.

Python localizers run in a child interpreter (evalkit.isolation.IsolatedLocalizer),
external programs through the JSON-lines protocol (evalkit.external); both are killed
on a timeout and restarted for the next frame with the sequence's reset replayed.
"""

from __future__ import annotations

import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from fake_dataset import SEQUENCES, write_fake_dataset  # noqa: E402

from evalkit import assemble, runner  # noqa: E402
from evalkit.dataset import Dataset  # noqa: E402
from evalkit.external import ExternalLocalizer  # noqa: E402
from evalkit.isolation import IsolatedLocalizer  # noqa: E402
from evalkit.registry import RegistryError  # noqa: E402

pytestmark = pytest.mark.integration  # child processes killed on timeouts (wall-clock waits)

N_FRAMES = sum(len(s[3]) for s in SEQUENCES)
TIMEOUT = 1.0

# Behaviour by d_true (m): clear_000 = 0.1 0.5 1 2 5 12, clear_001 = 0.15 0.3 3 8 10 10.5.
# Every other frame is answered exactly; localize before reset raises, so a success
# right after a crash or hang proves that reset was replayed in the new process.
PY_FAULTY = textwrap.dedent("""
    import os, time
    import numpy as np

    def decode(image):
        r, g, b = (int(v) for v in image[0, 0])
        return ((r << 16) | (g << 8) | b) / 1000.0

    class Faulty:
        def __init__(self, hang_s=60.0):
            self.hang_s = hang_s
            self.camera = None

        def reset(self, camera):
            self.camera = camera

        def localize(self, image):
            if self.camera is None:
                raise RuntimeError("localize before reset")
            d = decode(image)
            if d == 0.5:
                raise ValueError("bad frame")
            if d == 1.0:
                time.sleep(self.hang_s)
            if d == 2.0:
                os._exit(3)
            if d == 5.0:
                import ctypes
                ctypes.string_at(0)          # SIGSEGV
            if d == 3.0:
                return {"distance": float("nan")}
            if d == 8.0:
                return {"distance": d, "T_cam_dock": np.eye(3)}
            if d == 10.0:
                return {"distance": d, "f": lambda: 0}   # cannot be pickled back
            T = np.eye(4)
            T[2, 3] = d
            return {"distance": d, "T_cam_dock": T, "marker_id": "0"}

    class Oracle(Faulty):
        def localize(self, image):
            d = decode(image)
            T = np.eye(4)
            T[2, 3] = d
            return {"distance": d, "T_cam_dock": T, "marker_id": "0"}

    class Slow(Oracle):
        def localize(self, image):
            if decode(image) == 1.0:
                time.sleep(self.hang_s)
            return super().localize(image)

    class BadReset(Faulty):
        def reset(self, camera):
            raise RuntimeError("no camera for me")
""")

PY_EXPECTED = {
    0.5: "exception: ValueError: bad frame",
    1.0: "timeout",
    2.0: "crash: exit code 3",
    5.0: "crash: signal SIGSEGV",
    3.0: "nan",
    8.0: "bad_shape",
}

# The same faults from an external program (protocol 1).
EXT_FAULTY = textwrap.dedent("""
    import json, os, sys, time
    import cv2

    camera = None
    for line in sys.stdin:
        req = json.loads(line)
        if req["type"] == "reset":
            assert req["protocol"] == 1 and len(req["camera"]["K"]) == 3
            camera = req["camera"]
            print(json.dumps({"ok": True, "protocol": 1}), flush=True)
            continue
        if camera is None:
            print(json.dumps({"ok": False, "error": "frame before reset"}), flush=True)
            continue
        b, g, r = (int(v) for v in cv2.imread(req["image"])[0, 0])
        d = ((r << 16) | (g << 8) | b) / 1000.0
        reply = {"ok": True, "index": req["index"], "distance": d, "marker_id": "0"}
        if d == 0.5:
            reply = {"ok": False, "error": "bad frame"}
        elif d == 1.0:
            time.sleep(60)
        elif d == 2.0:
            os._exit(3)
        elif d == 5.0:
            print("debug output on stdout", flush=True)
            continue
        elif d == 3.0:
            reply["distance"] = float("nan")          # json writes NaN
        elif d == 8.0:
            reply["T_cam_dock"] = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
        elif d == 10.0:
            reply["index"] = 999
        elif d == 0.3:
            reply = {"ok": False}
        print(json.dumps(reply), flush=True)
""")

EXT_EXPECTED = {
    0.5: "exception: ExternalError: bad frame",
    1.0: "timeout",
    2.0: "crash: exit code 3",
    5.0: "protocol: reply is not JSON: 'debug output on stdout'",
    3.0: "nan",
    8.0: "bad_shape",
    10.0: "protocol: reply for frame 999 while waiting for 4",
    0.3: "none",
}


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return Dataset.open(write_fake_dataset(tmp_path_factory.mktemp("iso") / "ds"))


@pytest.fixture(scope="module")
def py_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("loc") / "faulty_loc.py"
    path.write_text(PY_FAULTY)
    return path


def _check(df, expected):
    f = df.set_index("d_true")
    for d, reason in expected.items():
        assert f.loc[d, "fail_reason"] == reason, (d, f.loc[d, "fail_reason"])
        assert not f.loc[d, "detected"] and np.isnan(f.loc[d, "d_est"])
    ok = f[~f.index.isin(list(expected))]
    assert ok["detected"].all(), ok[["fail_reason"]]
    assert np.allclose(ok.index, ok["d_est"])


def test_isolated_python_faults_cost_one_frame_each(ds, py_file):
    loc = assemble.build(f"{py_file}:Faulty", {}, isolate=True, timeout_s=TIMEOUT)
    assert isinstance(loc, IsolatedLocalizer)
    t0 = time.perf_counter()
    df = runner.evaluate(ds, [("faulty", loc)], progress=False)
    assert time.perf_counter() - t0 < 20.0  # the 60 s hang was cut at the timeout
    expected = dict(PY_EXPECTED)
    expected[10.0] = "bad_type"  # unpicklable result
    _check(df, expected)
    ms = df.set_index("d_true")["ms"]
    assert TIMEOUT * 1e3 <= ms[1.0] < TIMEOUT * 1e3 + 500  # the exchange, not the restart
    assert loc.n_restarts_total == 3  # hang, exit, segfault


def test_isolated_matches_in_process(ds, py_file):
    cols = ["localizer", "sequence", "index", "detected", "d_est", "e_abs", "e_rel", "marker_id", "fail_reason"]
    inproc = runner.evaluate(ds, [("o", assemble.build(f"{py_file}:Oracle", isolate=False))], progress=False)
    iso = runner.evaluate(ds, [("o", assemble.build(f"{py_file}:Oracle", isolate=True))], progress=False)
    assert inproc[cols].equals(iso[cols])


def test_timeout_alone_turns_isolation_on(py_file):
    assert isinstance(assemble.build(f"{py_file}:Oracle", timeout_s=2.0), IsolatedLocalizer)
    assert not isinstance(assemble.build(f"{py_file}:Oracle", isolate=False), IsolatedLocalizer)
    assert isinstance(assemble.build(f"{py_file}:Oracle"), IsolatedLocalizer)  # default: plugins isolated
    assert not isinstance(assemble.build("aruco"), IsolatedLocalizer)  # default: built-ins in process


def test_isolated_reset_failure_and_bad_spec(ds, py_file):
    loc = assemble.build(f"{py_file}:BadReset", isolate=True, timeout_s=TIMEOUT)
    df = runner.evaluate(ds, [("bad", loc)], progress=False, sequences=["clear_001"])
    assert (df["fail_reason"] == "exception: RuntimeError: no camera for me (in reset)").all()
    with pytest.raises(RegistryError, match="cannot build localizer .*unexpected keyword argument .bogus."):
        assemble.build(f"{py_file}:Oracle", {"bogus": 1}, isolate=True)
    with pytest.raises(RegistryError, match="not found"):
        assemble.build("nowhere/x.py:Y", isolate=True)


def test_external_faults_cost_one_frame_each(ds, tmp_path):
    script = tmp_path / "faulty_ext.py"
    script.write_text(EXT_FAULTY)
    loc = assemble.build(f"exec:{sys.executable} {script}", timeout_s=TIMEOUT)
    assert isinstance(loc, ExternalLocalizer)
    df = runner.evaluate(ds, [("ext", loc)], progress=False)
    _check(df, EXT_EXPECTED)
    assert loc.n_restarts_total == 4  # hang, exit, stdout garbage, wrong index


CRASH_EVERY_FRAME = (
    "read -r l; echo '{\"ok\":true}'; "  # answer reset, then die on the first frame
    "read -r l; exit 5"
)


def test_external_restart_limit_per_sequence(ds):
    loc = ExternalLocalizer(["sh", "-c", CRASH_EVERY_FRAME], timeout_s=TIMEOUT, max_restarts=2)
    df = runner.evaluate(ds, [("sh", loc)], progress=False)
    for _, seq in df.groupby("sequence"):
        reasons = seq["fail_reason"].tolist()
        # frame 0: first process dies; frames 1-2: restarted processes die; then give up
        assert reasons[:3] == ["crash: exit code 5"] * 3
        assert reasons[3:] == ["crash: gave up after 2 restarts in this sequence"] * 3


def test_external_reset_refused_and_missing_command(ds):
    refuse = ExternalLocalizer(["sh", "-c", 'read -r l; echo \'{"ok":false,"error":"no LED"}\''])
    df = runner.evaluate(ds, [("r", refuse)], progress=False, sequences=["clear_000"])
    assert (df["fail_reason"] == "exception: ExternalError: no LED (in reset)").all()
    newer = ExternalLocalizer(["sh", "-c", 'read -r l; echo \'{"ok":true,"protocol":2}\''])
    df = runner.evaluate(ds, [("n", newer)], progress=False, sequences=["clear_000"])
    assert df["fail_reason"].str.startswith("protocol: program speaks protocol 2").all()
    with pytest.raises(RegistryError, match="command not found"):
        assemble.build("exec:no-such-program-xyz --flag")


def test_runner_records_reason_of_inprocess_hang_flag(ds, py_file):
    # in process (no isolation) a slow call is only flagged after it returns
    loc = assemble.build(f"{py_file}:Slow", {"hang_s": 0.05}, isolate=False)
    df = runner.evaluate(ds, [("f", loc)], progress=False, frame_timeout_s=0.04, sequences=["clear_000"])
    assert df.set_index("d_true").loc[1.0, "fail_reason"] == "timeout"
