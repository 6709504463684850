"""Child processes of evaluation: start with a memory limit, kill and reap, and the
base of the process proxies (timeouts, crash detection, restart with reset replay).

Used by :mod:`evalkit.isolation` (Python localizers in a child interpreter) and
:mod:`evalkit.external` (programs speaking the JSON-lines protocol); neither copies
the other. Only the standard library is imported here (children start fast).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from typing import Any

# Budgets of a misbehaving child, sized so that a plugin that hangs on every frame costs
# minutes per evaluation, not hours: at most (1 + DEFAULT_MAX_RESTARTS_TOTAL) frame timeouts
# = 11 x 30 s = 5.5 min per localizer and evaluation process (then its frames fail at once).
# 30 s per frame is 300x the 0.1 s frame period of the benchmark's 10 fps camera (configs/
# quickstart.yaml camera.fps), room for a first call that compiles or loads a model; a
# localizer that needs longer says so with --frame-timeout.
DEFAULT_TIMEOUT_S = 30.0  # per frame, when isolation is on without --frame-timeout
DEFAULT_RESET_TIMEOUT_S = 120.0  # reset (may load models)
DEFAULT_START_TIMEOUT_S = 120.0  # starting a child and building the localizer
DEFAULT_MAX_RESTARTS = 3  # per sequence; afterwards that sequence's frames fail fast
DEFAULT_MAX_RESTARTS_TOTAL = 10  # per localizer and evaluation process; afterwards every frame fails fast


EXIT_GRACE_S = 2.0  # s a child gets to exit after stdin/pipe close before it is killed


# address space of a localizer child (RLIMIT_AS, MiB); 0 = unlimited. DOCKBENCH_MEMORY_LIMIT_MB
# overrides it (e.g. for GPU frameworks, which reserve large virtual ranges)
def _memory_limit_from_env(default_mb: int = 4096) -> int:
    text = os.environ.get("DOCKBENCH_MEMORY_LIMIT_MB", "").strip()
    return int(text) if text.isdigit() else default_mb


DEFAULT_MEMORY_LIMIT_MB = _memory_limit_from_env()


class FrameFailure(Exception):
    """A localizer call failed in a way the runner records as ``reason`` (verbatim)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class ChildTimeout(Exception):
    """The child did not answer within its budget."""


class ChildDead(Exception):
    """The child is gone (or could not start)."""


class ProtocolError(Exception):
    """The child's reply broke the protocol (what, in the message)."""


def exit_reason(code: int | None) -> str:
    """``"crash: exit code N"`` or ``"crash: signal NAME"`` for a process return code."""
    if code is None:
        return "crash: process gone"
    if code < 0:
        try:
            return f"crash: signal {signal.Signals(-code).name}"
        except ValueError:
            return f"crash: signal {-code}"
    return f"crash: exit code {code}"


def limit_memory(pid: int, memory_limit_mb: int | None) -> None:
    """Cap the address space (RLIMIT_AS, soft and hard) of process ``pid`` at
    ``memory_limit_mb`` MiB; an allocation beyond it fails in the child (Python:
    MemoryError) instead of exhausting the machine. No-op for None/0 or off Linux."""
    if not memory_limit_mb:
        return
    import resource

    limit = int(memory_limit_mb) << 20
    if pid == os.getpid():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    elif hasattr(resource, "prlimit"):
        try:
            resource.prlimit(pid, resource.RLIMIT_AS, (limit, limit))
        except (OSError, ValueError):  # the child already ended: its exit status tells
            pass


def spawn(argv: list[str], memory_limit_mb: int | None = DEFAULT_MEMORY_LIMIT_MB, **popen_kw: Any) -> subprocess.Popen:
    """Start ``argv`` (subprocess.Popen keywords pass through) with its memory capped by
    :func:`limit_memory` right after the start; raise :class:`ChildDead` if it cannot start."""
    try:
        proc = subprocess.Popen(argv, **popen_kw)
    except OSError as exc:
        raise ChildDead(f"{type(exc).__name__}: {exc}") from None
    limit_memory(proc.pid, memory_limit_mb)
    return proc


_RLIMIT_SHIM = (
    "import os, resource, sys; n = int(sys.argv[1]) << 20; "
    "n and resource.setrlimit(resource.RLIMIT_AS, (n, n)); os.execvp(sys.argv[2], sys.argv[2:])"
)


def sandboxed_argv(
    argv: list[str], scratch: str | None, cwd: str | None = None, memory_limit_mb: int | None = None
) -> tuple[list[str], str | None]:
    """``(argv to start, scratch folder)``: ``argv`` inside the bubblewrap sandbox
    (:mod:`evalkit.sandbox`) with a scratch folder (``scratch`` reused, else a new temporary
    one), or ``argv`` unchanged where there is no sandbox (said once on stderr). With
    ``memory_limit_mb`` the program's address space is capped inside the sandbox, before it
    starts (RLIMIT_AS is inherited through ``exec``; a limit set on bwrap from outside would
    race its fork)."""
    import sys
    import tempfile

    from evalkit import sandbox

    if not sandbox.available():
        sandbox.warn_once_unavailable()
        return argv, scratch
    scratch = scratch or tempfile.mkdtemp(prefix="dockbench-plugin-")
    if memory_limit_mb:
        argv = [sys.executable, "-c", _RLIMIT_SHIM, str(int(memory_limit_mb)), *argv]
    return sandbox.wrap(argv, scratch, cwd), scratch


def remove_scratch(scratch: str | None) -> None:
    """Delete a scratch folder of :func:`sandboxed_argv` (None: nothing)."""
    if scratch:
        import shutil

        shutil.rmtree(scratch, ignore_errors=True)


def kill_and_reap(proc: subprocess.Popen | None, wait_s: float = 5.0) -> int | None:
    """Kill ``proc`` if it still runs and wait for it (no zombie); its return code or None."""
    if proc is None:
        return None
    if proc.poll() is None:
        try:
            proc.kill()
        except OSError:
            pass
    try:
        return proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        return None


class ProcessLocalizer:
    """Base of the process proxies: timeouts, crash detection, restart with reset replay.

    Subclasses implement the transport: ``_start()`` (raise ``ChildDead`` or
    :class:`FrameFailure` on failure), ``_alive()``, ``_send(request)``,
    ``_recv(timeout_s)`` (raise ``ChildTimeout`` / ``ChildDead`` / ``ProtocolError``),
    ``_kill()`` (stop now, then reap) and ``_reply(kind, reply)``
    (turn a raw reply into a value or raise :class:`FrameFailure`), plus the
    requests ``_reset_request(camera)`` / ``_frame_request(...)``; the child process is
    ``self._proc`` (a Popen), which the base reads for the exit status.
    """

    enforces_timeout = True  # the runner must not re-check the wall time
    sandboxed = False  # set by _start: the child runs inside bwrap (evalkit.sandbox)

    def __init__(
        self,
        timeout_s: float | None = DEFAULT_TIMEOUT_S,
        reset_timeout_s: float | None = DEFAULT_RESET_TIMEOUT_S,
        start_timeout_s: float | None = DEFAULT_START_TIMEOUT_S,
        max_restarts: int = DEFAULT_MAX_RESTARTS,
        max_restarts_total: int = DEFAULT_MAX_RESTARTS_TOTAL,
    ):
        """timeout_s: per-frame budget (s; None waits forever); reset_timeout_s: for
        reset; start_timeout_s: for starting the child; max_restarts: restarts per
        sequence before the remaining frames fail at once; max_restarts_total: the same
        over this proxy's life (one evaluation process)."""
        self.timeout_s = None if timeout_s is None else float(timeout_s)
        self.reset_timeout_s = None if reset_timeout_s is None else float(reset_timeout_s)
        self.start_timeout_s = None if start_timeout_s is None else float(start_timeout_s)
        self.max_restarts = int(max_restarts)
        self.max_restarts_total = int(max_restarts_total)
        self.last_call_ms: float | None = None
        self._camera: dict | None = None
        self._restarts = 0
        self.n_restarts_total = 0

    # -- transport: implemented by the subclasses (see the class docstring) --
    def _start(self) -> None:
        raise NotImplementedError

    def _alive(self) -> bool:
        raise NotImplementedError

    def _send(self, request: Any) -> None:
        raise NotImplementedError

    def _recv(self, timeout_s: float | None) -> Any:
        raise NotImplementedError

    def _kill(self) -> None:
        raise NotImplementedError

    def _reply(self, kind: str, raw: Any) -> Any:
        raise NotImplementedError

    def _reset_request(self, camera: dict) -> Any:
        raise NotImplementedError

    # -- localizer API ------------------------------------------------------
    def reset(self, camera: dict) -> None:
        """Start (or reuse) the child and reset it for a new sequence."""
        self._camera = camera
        self._restarts = 0
        self._new_sequence()
        if not self._alive():
            self._start_child()
        self._exchange("reset", self._reset_request(camera), self.reset_timeout_s)

    def _new_sequence(self) -> None:
        """Hook: called by reset() before the child is (re)used."""

    def _request(self, kind: str, request: Any) -> Any:
        """Send one frame request, restarting a dead child first; the reply value."""
        self.last_call_ms = None
        if self._camera is None:
            raise FrameFailure("exception: RuntimeError: localize before reset")
        if not self._alive():
            self._restart()
        return self._exchange(kind, request, self.timeout_s)

    def close(self) -> None:
        """Stop the child (a later reset() starts a new one)."""
        if self._alive():
            self._stop_gracefully()
        self._kill()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    # -- machinery ----------------------------------------------------------
    def _exit_code(self):
        """The child's exit code once it has ended (waits EXIT_GRACE_S), else None."""
        import subprocess

        if self._proc is None:
            return None
        try:
            code = self._proc.wait(EXIT_GRACE_S)
        except subprocess.TimeoutExpired:
            return None
        if self.sandboxed and code is not None and 128 < code < 128 + 65:
            return 128 - code  # bwrap exits 128 + N for a program killed by signal N
        return code

    def _stop_gracefully(self) -> None:
        """Hook: ask the child to exit (default: nothing, _kill follows)."""

    def _start_child(self) -> None:
        try:
            self._start()
        except ChildDead as exc:
            self._kill()
            raise FrameFailure(f"crash: cannot start: {exc}") from None
        except FrameFailure:
            self._kill()
            raise

    def _restart(self) -> None:
        """New child for the current sequence, with reset replayed."""
        if self._restarts >= self.max_restarts:
            raise FrameFailure(f"crash: gave up after {self.max_restarts} restarts in this sequence")
        if self.n_restarts_total >= self.max_restarts_total:
            raise FrameFailure(f"crash: gave up after {self.max_restarts_total} restarts in this evaluation")
        self._restarts += 1
        self.n_restarts_total += 1
        self._start_child()
        if self._camera is None:
            raise FrameFailure("crash: restarted before any reset")
        try:
            self._exchange("reset", self._reset_request(self._camera), self.reset_timeout_s)
        except FrameFailure as exc:
            self._kill()
            raise FrameFailure(f"{exc.reason} (in reset replay)") from None
        self.last_call_ms = None

    def _exchange(self, kind: str, request: Any, timeout_s: float | None) -> Any:
        """One request/reply; on timeout, death or protocol error the child is killed."""
        start = time.perf_counter()
        try:
            self._send(request)
            raw = self._recv(timeout_s)
        except ChildTimeout:
            self._kill()
            raise FrameFailure("timeout") from None
        except ChildDead:
            reason = exit_reason(self._exit_code())  # waits briefly for the exit status
            self._kill()
            raise FrameFailure(reason) from None
        except ProtocolError as exc:
            self._kill()
            raise FrameFailure(f"protocol: {exc}") from None
        finally:
            self.last_call_ms = (time.perf_counter() - start) * 1e3
        try:
            return self._reply(kind, raw)
        except ProtocolError as exc:
            self._kill()
            raise FrameFailure(f"protocol: {exc}") from None
