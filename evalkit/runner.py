"""Run localizers over a dataset and collect per-frame estimates.

A localizer that raises or returns garbage on a frame makes that frame a
failure with a ``fail_reason``; the run continues. ``fail_reason`` values:

* ``""`` -- a valid answer (``detected``; whether it is *right* is ``success``, see
  :mod:`evalkit.metrics.core`);
* ``"none"`` -- the localizer returned ``None`` (it found nothing);
* ``"exception: <Type>: <message>"`` -- ``localize`` (or ``reset``) raised, including
  ``SystemExit`` and a ``KeyboardInterrupt`` the localizer raised itself (a real Ctrl-C,
  i.e. SIGINT during :func:`evaluate`, still stops the run);
* ``"bad_type"`` -- not a dict, or a distance that is not a number (a string such as
  ``"3.0"`` or a bool is not);
* ``"no_distance"`` -- the dict has no ``"distance"``;
* ``"nan"`` -- non-finite distance or non-finite ``T_cam_dock``;
* ``"negative"`` -- distance < 0;
* ``"out_of_range"`` -- distance > :data:`MAX_DISTANCE_M` (10 km);
* ``"bad_shape"`` -- ``T_cam_dock`` is not 4x4;
* ``"timeout"`` -- the call took longer than the per-frame budget (see below);
* ``"crash: exit code N"`` / ``"crash: signal SIGSEGV"`` -- the localizer's process
  died (isolated or external localizers only; it is restarted for the next frame);
* ``"crash: gave up after N restarts in this sequence"`` -- too many restarts;
* ``"protocol: <what>"`` -- an external program broke the JSON-lines protocol
  (datasets_spec/LOCALIZER_PROTOCOL.md);
* ``"... (in reset)"`` -- ``reset`` failed: every frame of the sequence fails so.

Isolation hook: every call goes through an *executor* (``call(localizer,
method, *args) -> CallResult``). :class:`InProcessExecutor` runs in this
process and can only flag slow calls after they return. Process isolation is
done by *proxy localizers* (:mod:`evalkit.isolation`, :mod:`evalkit.external`)
that run the real localizer in a child process, kill it on a timeout or crash
and restart it with ``reset`` replayed; they set ``enforces_timeout = True``,
report their own ``last_call_ms`` (the exchange, not a restart) and raise
:class:`~evalkit.process.FrameFailure` whose ``reason`` is recorded as is.
Localizers with a ``localize_file(path, index)`` method (external programs)
get the image's absolute path instead of the pixels.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import pandas as pd

from evalkit.dataset import Dataset
from evalkit.memo import FrameMemo, share
from evalkit.metrics import core as metrics
from evalkit.process import FrameFailure

# raw columns of a frame row; _finish appends metrics.SCORE_COLUMNS (errors, fp, success)
RAW_COLUMNS = [
    "localizer",
    "sequence",
    "trajectory",
    "condition",
    "trial",
    "index",
    "t",
    "d_true",
    "in_view",
    "markers_in_fov",
    "detected",
    "d_est",
    "marker_id",
    "ms",
    "fail_reason",
    "T_cam_dock_est",
    "T_cam_dock",
]
COLUMNS = RAW_COLUMNS + metrics.SCORE_COLUMNS


@dataclass
class CallResult:
    """Outcome of one localizer call: ``value`` or ``error`` text, and wall time (ms)."""

    value: Any = None
    error: str | None = None
    ms: float = 0.0


class Executor(Protocol):
    """Runs one method call of a localizer; the hook for timeouts / process isolation."""

    def call(self, localizer: Any, method: str, *args: Any) -> CallResult: ...


class InProcessExecutor:
    """Calls the localizer directly; a call slower than ``timeout_s`` is reported as timeout.

    It cannot interrupt a hung call (that needs a subprocess executor).
    """

    def __init__(self, timeout_s: float | None = None):
        self.timeout_s = timeout_s

    def call(self, localizer: Any, method: str, *args: Any) -> CallResult:
        """Call ``localizer.<method>(*args)``; exceptions become ``"exception: ..."``.

        A :class:`FrameFailure` keeps its reason. A localizer that enforces its own
        timeout (``enforces_timeout``) reports its own ``last_call_ms``.
        """
        start = time.perf_counter()
        try:
            value = getattr(localizer, method)(*args)
            error = None
        except FrameFailure as exc:
            value, error = None, exc.reason
        except KeyboardInterrupt as exc:
            if _CTRL_C.pressed:  # a real Ctrl-C stops the run (exit 130 in the CLI)
                raise
            value, error = None, f"exception: KeyboardInterrupt: {exc}"
        except BaseException as exc:  # noqa: BLE001 - SystemExit, GeneratorExit...: one failed frame
            value, error = None, f"exception: {type(exc).__name__}: {exc}"
        ms = (time.perf_counter() - start) * 1e3
        if getattr(localizer, "enforces_timeout", False):
            own = getattr(localizer, "last_call_ms", None)
            return CallResult(value, error, ms if own is None else float(own))
        if error is None and self.timeout_s is not None and ms > self.timeout_s * 1e3:
            value, error = None, "timeout"
        return CallResult(value, error, ms)


class _CtrlC:
    """Set by the SIGINT handler :func:`evaluate` installs: tells a real Ctrl-C (stop the
    run) from a KeyboardInterrupt a localizer raised itself (one failed frame)."""

    pressed = False


_CTRL_C = _CtrlC()
MAX_DISTANCE_M = 1e4  # answers beyond 10 km are not distances to a dock: "out_of_range"


def validate_estimate(value: Any) -> tuple[dict | None, str]:
    """Check a ``localize`` return value; ``(clean estimate, "")`` or ``(None, reason)``.

    The clean estimate has ``distance`` (float, m), ``T_cam_dock`` (4x4 float
    ndarray or None) and ``marker_id`` (str or None). ``distance`` must be a real
    number (int, float or a numpy number; not a string such as ``"3.0"``, not a
    bool: ``bad_type``), finite (``nan``), >= 0 (``negative``) and at most
    :data:`MAX_DISTANCE_M` (``out_of_range``).
    """
    if value is None:
        return None, "none"
    if not isinstance(value, dict):
        return None, "bad_type"
    if "distance" not in value:
        return None, "no_distance"
    raw = value["distance"]
    if isinstance(raw, (bool, np.bool_)) or not isinstance(raw, (int, float, np.integer, np.floating)):
        return None, "bad_type"
    try:
        distance = float(raw)
    except OverflowError:  # an int beyond float range
        return None, "out_of_range"
    if not math.isfinite(distance):
        return None, "nan"
    if distance < 0.0:
        return None, "negative"
    if distance > MAX_DISTANCE_M:
        return None, "out_of_range"
    T, reason = _validate_pose(value.get("T_cam_dock"))
    if reason:
        return None, reason
    marker_id = value.get("marker_id")
    return {"distance": distance, "T_cam_dock": T, "marker_id": None if marker_id is None else str(marker_id)}, ""


def _validate_pose(T: Any) -> tuple[np.ndarray | None, str]:
    """``(4x4 ndarray or None, "")`` or ``(None, "bad_shape" | "nan" | "bad_type")``."""
    if T is None:
        return None, ""
    try:
        arr = np.asarray(T, dtype=float)
    except (TypeError, ValueError):
        return None, "bad_shape"
    if arr.shape != (4, 4):
        return None, "bad_shape"
    if not np.all(np.isfinite(arr)):
        return None, "nan"
    return arr, ""


def camera_for_localizers(dataset: Dataset) -> dict:
    """Camera dict passed to ``reset``: width, height, K, dist and the manifest markers."""
    return {**dataset.camera, "markers": dataset.markers}


def _markers_in_fov(frame: dict) -> list[str]:
    """Ids of the frame's markers that have ``in_fov`` (ground truth)."""
    markers = frame.get("markers") or {}
    return [str(k) for k, m in markers.items() if isinstance(m, dict) and bool(m.get("in_fov"))]


def _flat_pose(T: Any) -> list[float] | None:
    """A 4x4 pose as 16 floats (row-major), or None if absent/malformed."""
    if T is None:
        return None
    try:
        arr = np.asarray(T, dtype=float)
    except (TypeError, ValueError):
        return None
    return arr.ravel().tolist() if arr.shape == (4, 4) else None


def _row(name: str, seq: dict, frame: dict, est: dict | None, reason: str, ms: float) -> dict:
    """One per-frame output row with the truth it is scored against (scores are filled later, in bulk)."""
    in_fov = _markers_in_fov(frame)
    return {
        "localizer": name,
        "sequence": seq["id"],
        "trajectory": str(seq.get("trajectory", "")),
        "condition": seq.get("condition", ""),
        "trial": seq.get("trial"),
        "index": frame.get("index"),
        "t": frame.get("t"),
        "d_true": frame.get("d_true"),
        "in_view": bool(in_fov),
        "markers_in_fov": ",".join(in_fov),
        "detected": est is not None,
        "d_est": est["distance"] if est else math.nan,
        "marker_id": est["marker_id"] if est else None,
        "ms": ms,
        "fail_reason": reason,
        "T_cam_dock_est": (
            np.asarray(est["T_cam_dock"], float).ravel().tolist() if est and est.get("T_cam_dock") is not None else None
        ),
        "T_cam_dock": _flat_pose(frame.get("T_cam_dock")),
    }


def _run_sequence(
    dataset: Dataset,
    seq: dict,
    localizers: list[tuple[str, Any]],
    executor: Executor,
    tick,
    memo: FrameMemo | None = None,
) -> list[dict]:
    """Reset every localizer, then feed each frame of ``seq`` to each of them.

    The image is read only if some localizer takes pixels; ``localize_file``
    localizers get ``(absolute path, frame index)``. ``memo`` (:mod:`evalkit.memo`) is
    told which frame is current, so localizers shared through it run once per frame.
    """
    camera = {**camera_for_localizers(dataset), "sequence": seq["id"]}
    by_file = {name: callable(getattr(loc, "localize_file", None)) for name, loc in localizers}
    reset_errors = {}
    for name, loc in localizers:
        res = executor.call(loc, "reset", camera)
        if res.error:
            reset_errors[name] = f"{res.error} (in reset)"
    rows = []
    for frame in dataset.iter_frames(seq["id"]):
        image = path = None
        if memo is not None:
            memo.begin((seq["id"], frame.get("index")))
        for name, loc in localizers:
            if name in reset_errors:
                rows.append(_row(name, seq, frame, None, reset_errors[name], 0.0))
                continue
            if by_file[name]:
                if path is None:
                    path = dataset.checked_image_path(frame)  # DatasetError if missing/outside
                    dataset.check_file(path)  # the program reads it: verify it first
                    path = path.resolve()
                res = executor.call(loc, "localize_file", str(path), frame.get("index"))
            else:
                if image is None:
                    image = dataset.load_image(frame)
                res = executor.call(loc, "localize", image.copy())
                if memo is not None:
                    res.ms += memo.take_credit_ms()
            est, reason = (None, res.error) if res.error else validate_estimate(res.value)
            rows.append(_row(name, seq, frame, est, reason, res.ms))
        tick(1)
    return rows


def progress_bar(total: int, enabled: bool, label: str = "evaluating"):
    """A context giving ``tick(n)``: a rich progress bar on stderr, or a no-op when disabled.

    The one progress mechanism of evalkit (no threads of its own; rich refreshes the bar)."""
    import contextlib

    if not enabled:
        return contextlib.nullcontext(lambda n: None)
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    @contextlib.contextmanager
    def ctx():
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=Console(file=sys.stderr),
            transient=True,
        ) as bar:
            task = bar.add_task(label, total=total)
            yield lambda n: bar.advance(task, n)

    return ctx()


def evaluate(
    dataset: Dataset,
    localizer_specs: Iterable[tuple[str, Any]],
    frame_timeout_s: float | None = None,
    progress: bool = True,
    executor: Executor | None = None,
    sequences: list[str] | None = None,
) -> pd.DataFrame:
    """Run each ``(name, localizer)`` on every frame; return the per-frame table.

    Columns are :data:`COLUMNS`: ``detected`` (a valid answer), the truth
    (``d_true`` m, ``in_view``, ``markers_in_fov``, ``T_cam_dock`` 16 floats) and the
    scores of :func:`evalkit.metrics.core.score_frames` (``success`` = thresholded);
    ``d_true``/``d_est``/``e_abs`` in metres, ``e_rel`` dimensionless (NaN below the
    dataset's ``d_min_rel_m``), ``t`` in seconds, ``ms`` the wall time of ``localize``
    in milliseconds.
    ``frame_timeout_s`` is the per-frame budget given to the default
    :class:`InProcessExecutor`; ``executor`` replaces it (isolation hook).
    ``sequences`` restricts the run to these ids. ``reset`` receives the
    camera dict plus ``"sequence"`` (the sequence id). After the run,
    ``close()`` is called on every localizer that has it (process proxies stop
    their children; they restart on the next ``reset``). ``df.attrs`` records
    ``d_min_rel_m`` and ``d_max_m``; the run record is written by
    :func:`evalkit.reports.results.save_run`.

    Localizer misbehaviour never stops the run (see the module docstring);
    dataset problems (bad JSON line, missing image) do: they raise
    :class:`~evalkit.dataset.DatasetError`.
    """
    localizers = list(localizer_specs)
    names = [n for n, _ in localizers]
    if len(set(names)) != len(names):
        raise ValueError(f"localizer names must be unique, got {names}")
    executor = executor or InProcessExecutor(frame_timeout_s)
    memo = FrameMemo()
    localizers = share(localizers, memo)  # led + qr + hybrid: LED and QR run once per frame
    seqs = [s for s in dataset.sequences if sequences is None or s["id"] in sequences]
    total = sum(int(s.get("n_frames", 0)) for s in seqs)
    rows: list[dict] = []
    try:
        with progress_bar(total, progress) as tick, _sigint_marks_ctrl_c():
            for seq in seqs:
                rows.extend(_run_sequence(dataset, seq, localizers, executor, tick, memo))
    finally:
        for _, loc in localizers:
            close = getattr(loc, "close", None)
            if callable(close):
                try:
                    close()
                except Exception:  # noqa: BLE001 - cleanup must not hide results
                    pass
    return _finish(rows, dataset.d_min_rel_m)


def _sigint_marks_ctrl_c():
    """Within the block (main thread only): SIGINT sets ``_CTRL_C.pressed`` and raises
    KeyboardInterrupt as usual, so the in-process guard lets a real Ctrl-C through."""
    import contextlib
    import signal
    import threading

    @contextlib.contextmanager
    def ctx():
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = signal.getsignal(signal.SIGINT)

        def handler(signum, frame):
            _CTRL_C.pressed = True
            raise KeyboardInterrupt

        signal.signal(signal.SIGINT, handler)
        _CTRL_C.pressed = False
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, previous)

    return ctx()


def _finish(rows: list[dict], d_min_rel: float) -> pd.DataFrame:
    """Build the DataFrame with stable dtypes and the scores under the default
    :class:`~evalkit.metrics.core.SuccessCriteria` (re-scored by
    :func:`evalkit.metrics.extra.compute_all` with the run's settings)."""
    df = pd.DataFrame(rows, columns=RAW_COLUMNS)
    df = df.astype({"d_true": float, "d_est": float, "ms": float, "t": float, "detected": bool, "in_view": bool})
    df["fail_reason"] = df["fail_reason"].fillna("").astype(str)
    df["markers_in_fov"] = df["markers_in_fov"].fillna("").astype(str)
    df = pd.concat([df, metrics.score_frames(df, d_min_rel=d_min_rel)], axis=1)
    df.attrs.update({"d_min_rel_m": float(d_min_rel), "d_max_m": metrics.D_MAX_M})
    return df
