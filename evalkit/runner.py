"""Run localizers over a dataset and collect per-frame estimates.

A localizer that raises or returns garbage on a frame makes that frame a
failure with a ``fail_reason``; the run continues. ``fail_reason`` values:

* ``""`` -- success;
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Protocol

import numpy as np
import pandas as pd

from evalkit.metrics import core as metrics
from evalkit.dataset import Dataset
from evalkit.process import FrameFailure

COLUMNS = ["localizer", "sequence", "condition", "trial", "index", "t", "d_true", "in_view",
           "success", "d_est", "e_abs", "e_rel", "marker_id", "ms", "fail_reason", "T_cam_dock_est"]


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
            if _CTRL_C.pressed:            # a real Ctrl-C stops the run (exit 130 in the CLI)
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
MAX_DISTANCE_M = 1e4   # answers beyond 10 km are not distances to a dock: "out_of_range"


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
    except OverflowError:          # an int beyond float range
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
    return {"distance": distance, "T_cam_dock": T,
            "marker_id": None if marker_id is None else str(marker_id)}, ""


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


def _in_view(frame: dict) -> bool:
    """True if any marker of the frame has ``in_fov``."""
    markers = frame.get("markers") or {}
    return any(bool(m.get("in_fov")) for m in markers.values() if isinstance(m, dict))


def _row(name: str, seq: dict, frame: dict, est: dict | None, reason: str, ms: float) -> dict:
    """One per-frame output row (errors are filled later, in bulk)."""
    return {
        "localizer": name, "sequence": seq["id"], "condition": seq.get("condition", ""),
        "trial": seq.get("trial"), "index": frame.get("index"), "t": frame.get("t"),
        "d_true": frame.get("d_true"), "in_view": _in_view(frame), "success": est is not None,
        "d_est": est["distance"] if est else math.nan,
        "marker_id": est["marker_id"] if est else None,
        "ms": ms, "fail_reason": reason,
        "T_cam_dock_est": (np.asarray(est["T_cam_dock"], float).ravel().tolist()
                           if est and est.get("T_cam_dock") is not None else None),
    }


def _run_sequence(dataset: Dataset, seq: dict, localizers: list[tuple[str, Any]],
                  executor: Executor, tick) -> list[dict]:
    """Reset every localizer, then feed each frame of ``seq`` to each of them.

    The image is read only if some localizer takes pixels; ``localize_file``
    localizers get ``(absolute path, frame index)``.
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
        for name, loc in localizers:
            if name in reset_errors:
                rows.append(_row(name, seq, frame, None, reset_errors[name], 0.0))
                continue
            if by_file[name]:
                if path is None:
                    path = dataset.checked_image_path(frame)  # DatasetError if missing/wrong
                res = executor.call(loc, "localize_file", str(path), frame.get("index"))
            else:
                if image is None:
                    image = dataset.load_image(frame)
                res = executor.call(loc, "localize", image.copy())
            est, reason = (None, res.error) if res.error else validate_estimate(res.value)
            rows.append(_row(name, seq, frame, est, reason, res.ms))
        tick(1)
    return rows


def _progress(total: int, enabled: bool):
    """A click progress bar on stderr, or a no-op context when disabled."""
    import contextlib

    if not enabled:
        return contextlib.nullcontext(lambda n: None)
    import click

    bar = click.progressbar(length=total, label="evaluating", file=sys.stderr,
                            show_pos=True, show_eta=True)

    @contextlib.contextmanager
    def ctx():
        with bar:
            yield bar.update
    return ctx()


def evaluate(dataset: Dataset, localizer_specs: Iterable[tuple[str, Any]],
             frame_timeout_s: float | None = None, progress: bool = True,
             executor: Executor | None = None, sequences: list[str] | None = None) -> pd.DataFrame:
    """Run each ``(name, localizer)`` on every frame; return the per-frame table.

    Columns are :data:`COLUMNS`: ``d_true``/``d_est``/``e_abs`` in metres,
    ``e_rel`` dimensionless (NaN below the dataset's ``d_min_rel_m``), ``t``
    in seconds, ``ms`` the wall time of ``localize`` in milliseconds.
    ``frame_timeout_s`` is the per-frame budget given to the default
    :class:`InProcessExecutor`; ``executor`` replaces it (isolation hook).
    ``sequences`` restricts the run to these ids. ``reset`` receives the
    camera dict plus ``"sequence"`` (the sequence id). After the run,
    ``close()`` is called on every localizer that has it (process proxies stop
    their children; they restart on the next ``reset``). ``df.attrs`` records
    ``d_min_rel_m`` and ``d_max_m`` for :func:`write_results`.

    Localizer misbehaviour never stops the run (see the module docstring);
    dataset problems (bad JSON line, missing image) do: they raise
    :class:`~evalkit.dataset.DatasetError`.
    """
    localizers = list(localizer_specs)
    names = [n for n, _ in localizers]
    if len(set(names)) != len(names):
        raise ValueError(f"localizer names must be unique, got {names}")
    executor = executor or InProcessExecutor(frame_timeout_s)
    seqs = [s for s in dataset.sequences if sequences is None or s["id"] in sequences]
    total = sum(int(s.get("n_frames", 0)) for s in seqs)
    rows: list[dict] = []
    try:
        with _progress(total, progress) as tick, _sigint_marks_ctrl_c():
            for seq in seqs:
                rows.extend(_run_sequence(dataset, seq, localizers, executor, tick))
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
    """Build the DataFrame with stable dtypes and the error columns."""
    df = pd.DataFrame(rows, columns=COLUMNS)
    df = df.astype({"d_true": float, "d_est": float, "ms": float, "t": float,
                    "success": bool, "in_view": bool})
    df[["e_abs", "e_rel"]] = metrics.frame_errors(df, d_min_rel)
    df["fail_reason"] = df["fail_reason"].fillna("").astype(str)
    df.attrs.update({"d_min_rel_m": float(d_min_rel), "d_max_m": metrics.D_MAX_M})
    return df


def write_results(df: pd.DataFrame, out_dir: str | Path, d_max: float | None = None,
                  d_min_rel: float | None = None) -> dict[str, Path]:
    """Write ``estimates.parquet``, ``summary.csv`` (per trial) and ``conditions.csv``.

    ``d_max`` / ``d_min_rel`` (m) default to ``df.attrs`` (set by
    :func:`evaluate`), else to the metrics defaults. Returns the written paths.
    """
    from evalkit.reports import tables

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    d_max = d_max if d_max is not None else df.attrs.get("d_max_m", metrics.D_MAX_M)
    d_min_rel = d_min_rel if d_min_rel is not None else df.attrs.get("d_min_rel_m", metrics.D_MIN_REL_M)
    trials = tables.summary_table(df, d_max=d_max, d_min_rel=d_min_rel)
    paths = {"estimates": out / "estimates.parquet", "summary": out / "summary.csv",
             "conditions": out / "conditions.csv"}
    paths["estimates"] = _write_estimates(df, paths["estimates"])
    tables.write_csv(trials, paths["summary"])
    tables.write_csv(tables.condition_table(trials), paths["conditions"])
    return paths


def _write_estimates(df: pd.DataFrame, path: Path) -> Path:
    """Write ``path`` (parquet); if no parquet engine imports, write CSV beside it and warn.

    Returns the path actually written, so a long run never loses its results
    to a broken optional dependency.
    """
    try:
        df.to_parquet(path, index=False)
        return path
    except ImportError as exc:
        csv_path = path.with_suffix(".csv")
        print(f"warning: cannot write {path.name} ({_parquet_problem(exc)}); "
              f"wrote {csv_path.name} instead", file=sys.stderr)
        df.to_csv(csv_path, index=False, lineterminator="\n")
        return csv_path


def _parquet_problem(exc: ImportError) -> str:
    """Short reason why parquet is unavailable (pyarrow's own import error if any)."""
    try:
        import pyarrow  # noqa: F401
    except ImportError as pa_exc:
        return f"pyarrow: {pa_exc}"
    return str(exc).strip().splitlines()[0]
