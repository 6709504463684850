"""Process isolation of localizers: timeouts that really stop a hung call, and crashes.

A *process proxy* looks like a localizer (``reset`` / ``localize``) but runs the
real one in a child process. Every request waits at most its timeout; then the
child is killed. A child that dies (crash, ``os._exit``, segfault, killed) or
times out costs only that frame: the next request starts a new child and replays
the sequence's ``reset`` first. Failures raise :class:`FrameFailure`, whose
``reason`` the runner records verbatim (``"timeout"``, ``"crash: exit code 3"``,
``"crash: signal SIGSEGV"``, ``"exception: Type: message"``, ``"protocol: ..."``).

Two proxies share :class:`evalkit.process.ProcessLocalizer`:

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

import os
from typing import Any

from evalkit.process import (  # noqa: F401  (FrameFailure, DEFAULT_TIMEOUT_S...: re-exported, old import path)
    DEFAULT_MAX_RESTARTS, DEFAULT_MEMORY_LIMIT_MB, DEFAULT_RESET_TIMEOUT_S, DEFAULT_START_TIMEOUT_S,
    DEFAULT_TIMEOUT_S, EXIT_GRACE_S, ChildDead, ChildTimeout, FrameFailure, ProcessLocalizer, exit_reason,
    kill_and_reap, limit_memory, spawn,
)


# -- Python localizers in a child interpreter ----------------------------------
_CHILD_CODE = ("import sys; from evalkit.isolation import _child_main; "
               "_child_main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))")


def _child_main(fd_in: int, fd_out: int, memory_limit_mb: int = 0) -> None:
    """Child process: cap its own memory, build the localizer, then answer ``(method, arg)``
    requests (a localizer that needs more than ``memory_limit_mb`` MiB gets MemoryError).

    Messages are pickled :class:`multiprocessing.connection.Connection` frames on two
    pipes (not stdin/stdout, so a localizer that prints cannot corrupt them)."""
    limit_memory(os.getpid(), memory_limit_mb)
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
        except (Exception, SystemExit, KeyboardInterrupt) as exc:  # noqa: BLE001 - loses one frame
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
                 timeout_s: float | None = DEFAULT_TIMEOUT_S,
                 memory_limit_mb: int | None = DEFAULT_MEMORY_LIMIT_MB, **kw):
        """spec/params: as for registry.resolve (resolved in the child); preprocess:
        a preprocess spec applied in the child; memory_limit_mb: the child's address
        space (RLIMIT_AS, MiB; None = unlimited); timeout_s and ``**kw``: see
        :class:`~evalkit.process.ProcessLocalizer`."""
        super().__init__(timeout_s=timeout_s, **kw)
        self.memory_limit_mb = memory_limit_mb
        self.spec, self.params, self.preprocess = spec, dict(params or {}), preprocess
        self.name = spec
        self._proc: Any = None              # subprocess.Popen once started
        self._rx: Any = None                # multiprocessing Connection ends once started
        self._tx: Any = None
        from evalkit.registry import RegistryError
        try:
            self._start()
        except ChildDead as exc:
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
        import subprocess
        import sys
        from multiprocessing.connection import Connection

        r1, w1 = os.pipe()  # parent -> child
        r2, w2 = os.pipe()  # child -> parent
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p or ".") for p in sys.path)
        try:
            proc = spawn([sys.executable, "-c", _CHILD_CODE, str(r1), str(w2), str(self.memory_limit_mb or 0)],
                         memory_limit_mb=None,    # the child sets its own limit before any import
                         pass_fds=(r1, w2), stdin=subprocess.DEVNULL, env=env)
        except ChildDead:
            for fd in (r1, w1, r2, w2):
                os.close(fd)
            raise
        os.close(r1)
        os.close(w2)
        self._proc = proc
        self._tx, self._rx = Connection(w1, readable=False), Connection(r2, writable=False)
        self._send(("init", self.spec, self.params, self.preprocess))
        try:
            status, info = self._recv(self.start_timeout_s)
        except ChildTimeout:
            raise ChildDead("timed out while starting") from None
        except ChildDead:
            raise ChildDead(exit_reason(self._exit_code())) from None
        if status != "ready":
            raise FrameFailure(info)

    def _alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def _send(self, request) -> None:
        try:
            self._tx.send(request)
        except (OSError, EOFError, AttributeError):
            raise ChildDead() from None

    def _recv(self, timeout_s):
        try:
            if not self._rx.poll(timeout_s):
                raise ChildTimeout()
            return self._rx.recv()
        except (EOFError, OSError, AttributeError):
            raise ChildDead() from None

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
        kill_and_reap(self._proc)
        for conn in (self._tx, self._rx):
            if conn is not None:
                conn.close()
        self._tx = self._rx = None
        # the Popen object is kept until the next start so _exit_code can read it
