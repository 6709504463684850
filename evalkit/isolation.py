"""Process isolation of localizers: timeouts that really stop a hung call, and crashes.

A *process proxy* looks like a localizer (``reset`` / ``localize``) but runs the
real one in a child process. Every request waits at most its timeout; then the
child is killed. A child that dies (crash, ``os._exit``, segfault, killed) or
times out costs only that frame: the next request starts a new child and replays
the sequence's ``reset`` first. Failures raise :class:`FrameFailure`, whose
``reason`` the runner records verbatim (``"timeout"``, ``"crash: exit code 3"``,
``"crash: signal SIGSEGV"``, ``"exception: Type: message"``, ``"protocol: ..."``).

Two proxies share :class:`ProcessLocalizer`:

* :class:`IsolatedLocalizer` -- any Python localizer spec (built-in, entry point,
  ``file.py:Class``, ``module:attr``) built *inside* a child interpreter (a fresh
  ``sys.executable``, like multiprocessing's spawn but without re-importing the
  caller's ``__main__``); images and results travel pickled over two pipes
  (about 1 ms per 640x480 frame). The child lives across sequences (like an in-process
  localizer) and is restarted only after a timeout or crash.
* :class:`evalkit.external.ExternalLocalizer` -- any program speaking the
  JSON-lines protocol (datasets_spec/LOCALIZER_PROTOCOL.md).

Only the standard library is imported here (children start fast).
"""
from __future__ import annotations

import signal
import time
from typing import Any

DEFAULT_TIMEOUT_S = 60.0        # per frame, when isolation is on without --frame-timeout
DEFAULT_RESET_TIMEOUT_S = 120.0  # reset (may load models)
DEFAULT_START_TIMEOUT_S = 120.0  # starting a child and building the localizer
DEFAULT_MAX_RESTARTS = 10        # per sequence; afterwards frames fail fast


EXIT_GRACE_S = 2.0  # s a child gets to exit after stdin/pipe close before it is killed


class FrameFailure(Exception):
    """A localizer call failed in a way the runner records as ``reason`` (verbatim)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class _Timeout(Exception):
    pass


class _Dead(Exception):
    pass


class _ProtocolError(Exception):
    pass


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


class ProcessLocalizer:
    """Base of the process proxies: timeouts, crash detection, restart with reset replay.

    Subclasses implement the transport: ``_start()`` (raise ``_Dead`` or
    :class:`FrameFailure` on failure), ``_alive()``, ``_send(request)``,
    ``_recv(timeout_s)`` (raise ``_Timeout`` / ``_Dead`` / ``_ProtocolError``),
    ``_kill()`` (stop now, then reap) and ``_reply(kind, reply)``
    (turn a raw reply into a value or raise :class:`FrameFailure`), plus the
    requests ``_reset_request(camera)`` / ``_frame_request(...)``; the child process is
    ``self._proc`` (a Popen), which the base reads for the exit status.
    """

    enforces_timeout = True  # the runner must not re-check the wall time

    def __init__(self, timeout_s: float | None = DEFAULT_TIMEOUT_S,
                 reset_timeout_s: float | None = DEFAULT_RESET_TIMEOUT_S,
                 start_timeout_s: float | None = DEFAULT_START_TIMEOUT_S,
                 max_restarts: int = DEFAULT_MAX_RESTARTS):
        """timeout_s: per-frame budget (s; None waits forever); reset_timeout_s: for
        reset; start_timeout_s: for starting the child; max_restarts: restarts per
        sequence before the remaining frames fail at once."""
        self.timeout_s = None if timeout_s is None else float(timeout_s)
        self.reset_timeout_s = None if reset_timeout_s is None else float(reset_timeout_s)
        self.start_timeout_s = None if start_timeout_s is None else float(start_timeout_s)
        self.max_restarts = int(max_restarts)
        self.last_call_ms: float | None = None
        self._camera: dict | None = None
        self._restarts = 0
        self.n_restarts_total = 0

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
            return self._proc.wait(EXIT_GRACE_S)
        except subprocess.TimeoutExpired:
            return None

    def _stop_gracefully(self) -> None:
        """Hook: ask the child to exit (default: nothing, _kill follows)."""

    def _start_child(self) -> None:
        try:
            self._start()
        except _Dead as exc:
            self._kill()
            raise FrameFailure(f"crash: cannot start: {exc}") from None
        except FrameFailure:
            self._kill()
            raise

    def _restart(self) -> None:
        """New child for the current sequence, with reset replayed."""
        if self._restarts >= self.max_restarts:
            raise FrameFailure(f"crash: gave up after {self.max_restarts} restarts in this sequence")
        self._restarts += 1
        self.n_restarts_total += 1
        self._start_child()
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
        except _Timeout:
            self._kill()
            raise FrameFailure("timeout") from None
        except _Dead:
            reason = exit_reason(self._exit_code())  # waits briefly for the exit status
            self._kill()
            raise FrameFailure(reason) from None
        except _ProtocolError as exc:
            self._kill()
            raise FrameFailure(f"protocol: {exc}") from None
        finally:
            self.last_call_ms = (time.perf_counter() - start) * 1e3
        try:
            return self._reply(kind, raw)
        except _ProtocolError as exc:
            self._kill()
            raise FrameFailure(f"protocol: {exc}") from None


# -- Python localizers in a child interpreter ----------------------------------
_CHILD_CODE = ("import sys; from evalkit.isolation import _child_main; "
               "_child_main(int(sys.argv[1]), int(sys.argv[2]))")


def _child_main(fd_in: int, fd_out: int) -> None:
    """Child process: build the localizer, then answer ``(method, arg)`` requests.

    Messages are pickled :class:`multiprocessing.connection.Connection` frames on two
    pipes (not stdin/stdout, so a localizer that prints cannot corrupt them)."""
    from multiprocessing.connection import Connection
    rx, tx = Connection(fd_in, writable=False), Connection(fd_out, readable=False)
    try:
        _, spec, params, preprocess = rx.recv()
        from evalkit import registry
        loc = registry.resolve(spec, params)
        if preprocess:
            from evalkit.preprocess import Preprocessed
            loc = Preprocessed(loc, preprocess)
    except Exception as exc:  # noqa: BLE001 - reported to the parent
        registry_error = type(exc).__name__ == "RegistryError"
        tx.send(("fail", str(exc) if registry_error else
                 f"cannot build localizer {spec!r}: {type(exc).__name__}: {exc}"))
        return
    tx.send(("ready", type(loc).__name__))
    while True:
        try:
            method, arg = rx.recv()
        except (EOFError, OSError):
            return
        if method == "close":
            return
        try:
            value = getattr(loc, method)(arg)
            status = "ok"
        except Exception as exc:  # noqa: BLE001 - a localizer's bug loses one frame
            value, status = f"exception: {type(exc).__name__}: {exc}", "fail"
        try:
            tx.send((status, value))
        except Exception:  # noqa: BLE001 - unpicklable result
            tx.send(("fail", "bad_type"))  # e.g. an unpicklable result


class IsolatedLocalizer(ProcessLocalizer):
    """A Python localizer (any registry spec) run in a child Python process.

    The child is a fresh interpreter (``sys.executable``) with this process's
    ``sys.path`` and working directory; it builds the localizer from the spec, so
    nothing needs to be picklable but images, camera dicts and results. It is
    started and the localizer built at construction, so a bad spec raises at once
    (:class:`evalkit.registry.RegistryError`).
    """

    def __init__(self, spec: str, params: dict | None = None, preprocess: str | None = None,
                 timeout_s: float | None = DEFAULT_TIMEOUT_S, **kw):
        """spec/params: as for registry.resolve (resolved in the child); preprocess:
        a preprocess spec applied in the child; timeout_s and ``**kw``: see
        :class:`ProcessLocalizer`."""
        super().__init__(timeout_s=timeout_s, **kw)
        self.spec, self.params, self.preprocess = spec, dict(params or {}), preprocess
        self.name = spec
        self._proc = None
        self._rx = self._tx = None
        from evalkit.registry import RegistryError
        try:
            self._start()
        except _Dead as exc:
            self._kill()
            raise RegistryError(f"cannot start a child process for localizer {spec!r}: {exc}") from None
        except FrameFailure as exc:  # the child could not build it: its message
            self._kill()
            raise RegistryError(exc.reason) from None

    def localize(self, image):
        """Estimate dict or None for one RGB image, computed in the child."""
        return self._request("localize", ("localize", image))

    # transport ------------------------------------------------------------
    def _start(self) -> None:
        import os
        import subprocess
        import sys
        from multiprocessing.connection import Connection

        r1, w1 = os.pipe()  # parent -> child
        r2, w2 = os.pipe()  # child -> parent
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p or ".") for p in sys.path)
        try:
            proc = subprocess.Popen([sys.executable, "-c", _CHILD_CODE, str(r1), str(w2)],
                                    pass_fds=(r1, w2), stdin=subprocess.DEVNULL, env=env)
        except OSError as exc:
            for fd in (r1, w1, r2, w2):
                os.close(fd)
            raise _Dead(f"{type(exc).__name__}: {exc}") from None
        os.close(r1)
        os.close(w2)
        self._proc = proc
        self._tx, self._rx = Connection(w1, readable=False), Connection(r2, writable=False)
        self._send(("init", self.spec, self.params, self.preprocess))
        try:
            status, info = self._recv(self.start_timeout_s)
        except _Timeout:
            raise _Dead("timed out while starting") from None
        except _Dead:
            raise _Dead(exit_reason(self._exit_code())) from None
        if status != "ready":
            raise FrameFailure(info)

    def _alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def _send(self, request) -> None:
        try:
            self._tx.send(request)
        except (OSError, EOFError, AttributeError):
            raise _Dead() from None

    def _recv(self, timeout_s):
        try:
            if not self._rx.poll(timeout_s):
                raise _Timeout()
            return self._rx.recv()
        except (EOFError, OSError, AttributeError):
            raise _Dead() from None

    def _reset_request(self, camera):
        return ("reset", camera)

    def _reply(self, kind, raw):
        status, value = raw
        if status == "ok":
            return value
        raise FrameFailure(value)

    def _stop_gracefully(self) -> None:
        try:
            self._tx.send(("close", None))
            self._proc.wait(EXIT_GRACE_S)
        except Exception:  # noqa: BLE001 - _kill follows
            pass

    def _kill(self) -> None:
        import subprocess
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                pass
        for conn in (self._tx, self._rx):
            if conn is not None:
                conn.close()
        self._tx = self._rx = None
        # the Popen object is kept until the next start so _exit_code can read it
