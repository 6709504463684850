"""Hostile inputs: every case of tests/hostile_corpus.py through the CLI.

Config, dataset and verify cases run in this process (click's CliRunner; generation stops
where Blender would start, so an accepted config shows as "accepted"); they must exit 2
with one line naming the file and key, no traceback, and leave every folder as it was.
Localizer cases run ``dockbench evaluate`` in a child (a plugin may call os._exit): the
run must finish (rc 0) with the frames failed for the expected reason.
Run-folder, output-folder, export, stream.json, calibration and results cases run the
same way; sandbox cases run ``evaluate`` in a child with plugins that attack the dataset.
The summary table (case | rc | message) is printed at the end of the run (tests/conftest.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

import cli
from tests import hostile_corpus as hc

pytestmark = pytest.mark.integration  # every case through the CLI in a subprocess

SUMMARY: list[tuple[str, int, str]] = []
IN_PROCESS = hc.CONFIG_CASES + hc.DATASET_CASES + hc.VERIFY_CASES + hc.SURFACE_CASES
NO_BASE_IN_MESSAGE = ("cfg_out", "bop_out_proc")  # the message names the -o given, outside base


@pytest.fixture
def no_render(monkeypatch):
    """Stop `generate` where rendering would start: reaching it means the config was accepted."""
    import blendgen.pipeline.generate as gen

    def stub(*args, **kwargs):
        raise RuntimeError("config accepted: rendering reached")

    monkeypatch.setattr(gen, "_render", stub)


@pytest.mark.parametrize("case", IN_PROCESS, ids=[c.name for c in IN_PROCESS])
def test_hostile_input(tmp_path, case, no_render):
    base = tmp_path / "base"
    base.mkdir()
    argv = case.build(base)
    before = hc.files_under(base)
    res = CliRunner().invoke(cli.main, argv)
    text = res.output
    SUMMARY.append(
        (
            case.name,
            res.exit_code,
            hc.summarize(res.exit_code, text)
            if res.exception is None or isinstance(res.exception, SystemExit)
            else f"TRACEBACK {type(res.exception).__name__}: {res.exception}"[:160],
        )
    )
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in text, text
    assert res.exit_code == case.rc, text
    assert case.expect in text, text
    errors = [ln for ln in text.splitlines() if ln.startswith(("error:", "Error:"))]
    assert errors and (str(base) in errors[0] or case.name.startswith(NO_BASE_IN_MESSAGE)), text
    if case in hc.SURFACE_CASES:
        assert len(text.strip().splitlines()) == 1, text  # one line, nothing else
    assert hc.files_under(base) == before, sorted(hc.files_under(base) ^ before)


@pytest.mark.parametrize("case", hc.LOCALIZER_CASES, ids=[c.name for c in hc.LOCALIZER_CASES])
def test_hostile_localizer(tmp_path, case):
    import pandas as pd

    argv = case.build(tmp_path)
    rc, text, _ = hc.run_subprocess(argv, timeout_s=240)
    out = hc.out_dir(tmp_path)
    reasons = []
    if (out / "estimates.parquet").is_file():
        reasons = sorted(set(pd.read_parquet(out / "estimates.parquet")["fail_reason"]))
    SUMMARY.append(
        (case.name, rc, f"fail_reason: {', '.join(r[:60] for r in reasons)}" if reasons else hc.summarize(rc, text))
    )
    assert rc == case.rc, text[-2000:]
    assert any(case.expect in r for r in reasons), (reasons, text[-2000:])


@pytest.mark.parametrize("case", hc.SANDBOX_CASES, ids=[c.name for c in hc.SANDBOX_CASES])
def test_hostile_plugin_in_the_sandbox(tmp_path, case):
    """A plugin that writes into the dataset or leaves detached children: the dataset still
    verifies, the run finishes (rc 0) with the frames failed for the expected reason."""
    import pandas as pd

    from evalkit import sandbox

    if not sandbox.available():
        pytest.skip(f"no sandbox here: {sandbox.probe()[1]}")
    argv = case.build(tmp_path)
    rc, text, _ = hc.run_subprocess(argv, timeout_s=240)
    out = hc.out_dir(tmp_path)
    reasons = sorted(set(pd.read_parquet(out / "estimates.parquet")["fail_reason"])) if rc == 0 else []
    SUMMARY.append(
        (case.name, rc, f"fail_reason: {', '.join(r[:60] for r in reasons)}" if reasons else hc.summarize(rc, text))
    )
    assert rc == case.rc, text[-2000:]
    assert any(case.expect in r for r in reasons), (reasons, text[-2000:])
    assert hc.run_subprocess(["verify", str(tmp_path / "ds")])[0] == 0  # the dataset is intact


@pytest.mark.parametrize("mode", ["--in-process", "--isolate"])
def test_real_ctrl_c_still_stops_the_run(tmp_path, mode):
    """SIGINT during evaluate (a user's Ctrl-C) ends it with exit 130, although the guard
    turns a KeyboardInterrupt raised by the plugin itself into one failed frame."""
    import os
    import signal
    import subprocess
    import sys
    import time

    argv = hc._loc("slow", (mode,))(tmp_path)
    code = "import sys; sys.argv = ['dockbench'] + sys.argv[1:]; import cli; cli.main()"
    p = subprocess.Popen(
        [sys.executable, "-c", code, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONPATH": str(hc.ROOT)},
        cwd=str(hc.ROOT),
    )
    time.sleep(4.0)  # imports, child start, a few 0.3 s frames
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    SUMMARY.append(
        (f"loc_real_ctrl_c{mode.replace('--', '_').replace('-', '_')}", p.returncode, hc.summarize(p.returncode, out))
    )
    assert p.returncode == 130, out
    assert "Traceback" not in out and "interrupted" in out


def test_hostile_png_bomb_is_refused_from_its_header(tmp_path):
    """The 30000x30000 PNG is refused by its 33-byte header, never decoded."""
    from evalkit.dataset import Dataset, DatasetError

    root = hc.write_fake_dataset(tmp_path / "ds")
    (root / hc.SEQ / "rgb" / "000001.png").write_bytes(hc.png_bomb())
    hc.rehash(root)
    ds = Dataset.open(root)
    frame = list(ds.iter_frames("clear_000"))[1]
    with pytest.raises(DatasetError, match="30000x30000 px; the manifest camera is 64x48"):
        ds.load_image(frame)


def test_frame_check_agrees_with_the_schema():
    """The fast frame check (datasets_spec.validate) refuses exactly what frame.schema.json
    refuses, on the good record and on every single-key mutation below."""
    from datasets_spec.validate import frame_problem, schema_message

    root = Path(__file__).parent
    good = json.loads(hc.write_fake_dataset.__module__ and _good_frame())
    nan = float("nan")
    mutations = {
        "index": [-1, 1.5, "1", True, 2**31, None],
        "t": ["0", None, [1]],
        "d_true": [-0.1, "3", None],
        "image": ["/abs.png", "a/../b.png", "x.jpg", "a\\b.png", "", 3],
        "depth": ["d.png", "../d.npz"],
        "T_cam_dock": [[[1, 0, 0], [0, 1, 0, 0]], "eye", [[1] * 4] * 3, [[1, 0, 0, "0"]] * 4],
        "markers": [
            [],
            {"0": {"in_fov": 1, "visible_fraction": 0.5, "T_cam_marker": good["T_cam_dock"]}},
            {"0": {"in_fov": True, "visible_fraction": 1.5, "T_cam_marker": good["T_cam_dock"]}},
            {"": {"in_fov": True, "visible_fraction": 1, "T_cam_marker": good["T_cam_dock"]}},
        ],
        "extra_key": [1],
    }
    assert frame_problem(good) is None and schema_message(good) is None
    n = 0
    for key, values in mutations.items():
        for v in values:
            bad = {**good, key: v}
            assert (frame_problem(bad) is None) == (schema_message(bad) is None), (key, v, frame_problem(bad))
            n += 1
        missing = {k: v for k, v in good.items() if k != key}
        if key in good and key != "depth":
            assert frame_problem(missing) is not None and schema_message(missing) is not None, key
    # non-finite numbers: the schema cannot express them; the JSON reader refuses them first
    assert frame_problem({**good, "d_true": nan}) is not None
    assert n > 25 and root.is_dir()


def _good_frame() -> str:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        root = hc.write_fake_dataset(Path(tmp) / "ds")
        return (root / hc.SEQ / "frames.jsonl").read_text().splitlines()[1]


def test_zz_summary_table():
    """Print the table of every case run above (pytest -s shows it)."""
    if not SUMMARY:
        pytest.skip("no hostile case ran")
    width = max(len(n) for n, _, _ in SUMMARY)
    print(f"\n{'case':{width}s} | rc | message")
    for name, rc, msg in SUMMARY:
        print(f"{name:{width}s} | {rc:2d} | {msg}")
    print(f"{len(SUMMARY)} hostile cases")


# ------------------------------------------------------------------ containment, unit level
def test_path_inside_refuses_every_escape(tmp_path):
    from datasets_spec.io import DatasetError, path_inside

    root = tmp_path / "ds"
    (root / "rgb").mkdir(parents=True)
    (tmp_path / "outside.png").write_bytes(b"x")
    (root / "rgb" / "real.png").write_bytes(b"x")
    (root / "rgb" / "alias.png").symlink_to(root / "rgb" / "real.png")  # stays inside: fine
    (root / "rgb" / "leak.png").symlink_to(tmp_path / "outside.png")
    (root / "up").symlink_to(tmp_path, target_is_directory=True)
    assert path_inside(root, "rgb/alias.png") == (root / "rgb" / "real.png").resolve()
    assert path_inside(root, "rgb/new/file.png").parent.name == "new"  # not existing yet: fine
    for bad in [
        "../outside.png",
        "/etc/passwd",
        str(tmp_path / "outside.png"),
        "rgb/../../outside.png",
        "rgb/leak.png",
        "up/outside.png",
        "a\x00b",
    ]:
        with pytest.raises(DatasetError):
            path_inside(root, bad)


def test_writer_refuses_ids_that_bypass_the_schema(tmp_path):
    """Defence in depth: even an id that skipped validation cannot make the writer leave -o."""
    from blendgen.pipeline.writer import DatasetWriter
    from datasets_spec.io import DatasetError

    w = DatasetWriter(tmp_path / "out")
    w.prepare()
    for bad in ("../../x", "../x", "/abs", "a/b"):
        with pytest.raises(DatasetError, match="outside the dataset folder"):
            w.seq_dir(bad)
        with pytest.raises(DatasetError, match="outside the dataset folder"):
            w.tmp_dir(bad + "/y")
    assert w.tmp_dir("ok-t000-clear").name == ".ok-t000-clear.tmp"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_out_location_rules(tmp_path):
    from blendgen.config.models import OutputDirError
    from blendgen.pipeline.generate import check_out_location

    check_out_location(tmp_path / "new" / "deeper")  # creatable: fine
    check_out_location(hc.ROOT / "out" / "demo")  # the Makefile's place: fine
    for bad in (hc.ROOT, hc.ROOT / "blendgen" / "x", hc.ROOT / "tests", hc.ROOT / "datasets_spec" / "a" / "b"):
        with pytest.raises(OutputDirError, match="source tree"):
            check_out_location(bad)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputDirError, match="is a file"):
        check_out_location(tmp_path / "file" / "sub")


def test_yaml_limits_keep_ordinary_configs_working(tmp_path):
    """Anchors/aliases and merge keys stay usable; only their explosion is refused."""
    from blendgen.config.models import load_experiment

    p = tmp_path / "ok.yaml"
    p.write_text(
        hc._good_yaml() + "water:\n  preset: clear\nconditions:\n  - &c {label: c1}\n  - {<<: *c, label: c2}\n"
    )
    exp = load_experiment(p)
    assert [c.label for c in exp.conditions] == ["c1", "c2"]
    p.write_text("{seed: 1, seed: 2}\n")  # duplicates on one line too
    with pytest.raises(Exception, match="duplicate key 'seed'"):
        load_experiment(p)


# ------------------------------------------------------------------ a full disk (ENOSPC injected)
def _enospc(path):
    import errno
    import os

    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


@pytest.mark.parametrize("command", ["generate", "evaluate", "run"])
def test_a_full_disk_is_one_line_naming_the_path_and_the_space(tmp_path, monkeypatch, command):
    """ENOSPC while writing (in this process, or in a render worker whose log says so): one
    line with the path, the free space and the space needed; rc 2; -o as it was."""
    import blendgen.pipeline.generate as gen
    from blendgen.pipeline.executor import RenderError
    from evalkit.reports import results

    base = tmp_path / "base"
    base.mkdir()
    out = base / "out"
    if command == "generate":

        def render(*a, **k):  # a render worker's failure, as executor reports it (log tail)
            raise RenderError(
                f"render worker failed (exit 1) for job.json:\nOSError: [Errno 28] No space left "
                f"on device: '{out}/sequences/x/rgb/000001.png'"
            )

        monkeypatch.setattr(gen, "_render", render)
        argv = ["generate", str(hc._cfg_file(base)), "-o", str(out)]
    elif command == "evaluate":

        def save(df, tmp, record):
            (tmp / "estimates.parquet").write_bytes(b"x" * 4096)
            raise _enospc(tmp / "metrics.csv")

        monkeypatch.setattr(results, "save_run", save)
        argv = ["evaluate", str(hc.write_fake_dataset(base / "ds")), "-l", "aruco", "-o", str(out)]
    else:
        import blendgen.tools.apps.streamrun as sr

        def stream_run(items, req):
            raise _enospc(out / "dataset" / "sequences" / "x" / "rgb" / "000001.png")

        monkeypatch.setattr(sr, "stream_run", stream_run)
        argv = ["run", str(hc._cfg_file(base)), "-l", "aruco", "-o", str(out)]
    before = hc.files_under(base) if command != "generate" else None
    res = CliRunner().invoke(cli.main, argv)
    SUMMARY.append((f"disk_full_{command}", res.exit_code, hc.summarize(res.exit_code, res.output)))
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert "disk full" in lines[0] and "MB free" in lines[0] and "MB more needed" in lines[0], lines[0]
    assert str(out) in lines[0] and "Traceback" not in res.output
    if before is not None:
        assert hc.files_under(base) == before, sorted(hc.files_under(base) ^ before)


def test_a_temp_sibling_left_by_kill_9_is_removed_and_reported(tmp_path):
    """`kill -9` of evaluate leaves `.OUT.tmp-PID/` (and, between its two renames, `.OUT.old-PID/`);
    the next run on OUT removes it under the lock and says so on stderr."""
    root = hc.write_fake_dataset(tmp_path / "ds")
    out = tmp_path / "res"
    (tmp_path / ".res.tmp-999999").mkdir()
    (tmp_path / ".res.tmp-999998" / "plots").mkdir(parents=True)
    res = CliRunner().invoke(cli.main, ["evaluate", str(root), "-l", "aruco", "-o", str(out), "-q"])
    SUMMARY.append(("eval_stale_tmp_siblings", res.exit_code, hc.summarize(res.exit_code, res.output)))
    assert res.exit_code == 0, res.output
    assert res.output.count("left by an interrupted run") == 2, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "res"]
    (tmp_path / ".res.old-999997").mkdir()  # killed between its renames: the old results
    (tmp_path / ".res.old-999997" / "run.json").write_text("{}")
    import shutil

    shutil.rmtree(out)
    from datasets_spec.outdir import clean_stale, lock

    with lock(out, "evaluate"):
        clean_stale(out)
    assert (out / "run.json").read_text() == "{}"  # restored, not deleted


@pytest.mark.parametrize(
    "reply, ok",
    [
        (bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]), True),  # gRPC: SETTINGS
        (b"HTTP/1.1 400 Bad Request\r\n\r\n", False),  # a web server
        (b"", False),
    ],
)  # silent, then closed
def test_a_ray_address_that_is_not_ray_fails_fast(reply, ok):
    """Ray retries an address that is not a cluster for minutes, printing warnings; dockbench asks
    the HTTP/2 preface first (Ray's GCS answers it with a SETTINGS frame) and refuses at once."""
    import socket
    import threading

    from blendgen.pipeline.executor import ExecutorError, check_ray_address

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()

    def answer():
        conn, _ = server.accept()
        with conn:
            conn.recv(64)
            conn.sendall(reply)

    threading.Thread(target=answer, daemon=True).start()
    address = f"127.0.0.1:{server.getsockname()[1]}"
    try:
        if ok:
            check_ray_address(address, timeout_s=5)
        else:
            with pytest.raises(ExecutorError, match="not a Ray cluster"):
                check_ray_address(address, timeout_s=5)
    finally:
        server.close()
