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
  caller's ``__main__``); requests (images) travel pickled to the child, replies come
  back as JSON (at most :data:`MAX_REPLY_BYTES`; the parent never unpickles anything a
  plugin wrote, so a sandboxed plugin cannot run code in dockbench). About 1 ms per
  640x480 frame. The child lives across sequences (like an in-process localizer) and is
  restarted only after a timeout or crash.

Both run inside the bubblewrap sandbox of :mod:`evalkit.sandbox` where the platform has
it (read-only file system but a scratch folder, own PID namespace killed with its whole
process tree, no network); elsewhere as plain children, said once on stderr.
* :class:`evalkit.external.ExternalLocalizer` -- any program speaking the
  JSON-lines protocol (datasets_spec/LOCALIZER_PROTOCOL.md).

Only the standard library is imported here (children start fast).
"""

from __future__ import annotations

import json
import os
from typing import Any

from evalkit.process import (  # noqa: F401  (FrameFailure, DEFAULT_TIMEOUT_S...: re-exported, old import path)
    DEFAULT_MAX_RESTARTS,
    DEFAULT_MEMORY_LIMIT_MB,
    DEFAULT_RESET_TIMEOUT_S,
    DEFAULT_START_TIMEOUT_S,
    DEFAULT_TIMEOUT_S,
    EXIT_GRACE_S,
    ChildDead,
    ChildTimeout,
    FrameFailure,
    ProcessLocalizer,
    ProtocolError,
    exit_reason,
    kill_and_reap,
    limit_memory,
    remove_scratch,
    sandboxed_argv,
    spawn,
)

MAX_REPLY_BYTES = 64 << 20  # one JSON reply of an isolated Python localizer (a 4x4 pose is ~0.5 kB)


def _jsonable(obj: Any) -> Any:
    """json.dumps ``default`` of the child: numpy arrays and scalars to lists / numbers."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _reply_bytes(status: str, value: Any) -> bytes:
    """A reply as JSON bytes; a value JSON cannot carry is the frame failure ``bad_type``."""
    try:
        return json.dumps([status, value], default=_jsonable, allow_nan=True).encode()
    except (TypeError, ValueError, RecursionError):
        return json.dumps(["fail", "bad_type"]).encode()


# -- Python localizers in a child interpreter ----------------------------------
_CHILD_CODE = (
    "import sys; from evalkit.isolation import _child_main; "
    "_child_main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))"
)


def _child_main(fd_in: int, fd_out: int, memory_limit_mb: int = 0) -> None:
    """Child process: cap its own memory, build the localizer, then answer ``(method, arg)``
    requests (a localizer that needs more than ``memory_limit_mb`` MiB gets MemoryError).

    Requests are pickled :class:`multiprocessing.connection.Connection` frames, replies JSON
    byte frames, on two pipes (not stdin/stdout, so a localizer that prints cannot corrupt them)."""
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
        tx.send_bytes(
            _reply_bytes(
                "fail", str(exc) if registry_error else f"cannot build localizer {spec!r}: {type(exc).__name__}: {exc}"
            )
        )
        return
    tx.send_bytes(_reply_bytes("ready", type(loc).__name__))
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
        tx.send_bytes(_reply_bytes(status, value))  # a value JSON cannot carry: "bad_type"


class IsolatedLocalizer(ProcessLocalizer):
    """A Python localizer (any registry spec) run in a child Python process.

    The child is a fresh interpreter (``sys.executable``) with this process's
    ``sys.path`` and working directory; it builds the localizer from the spec, so
    nothing needs to be picklable but images, camera dicts and results. It is
    started and the localizer built at construction, so a bad spec raises at once
    (:class:`evalkit.registry.RegistryError`).
    """

    def __init__(
        self,
        spec: str,
        params: dict | None = None,
        preprocess: str | None = None,
        timeout_s: float | None = DEFAULT_TIMEOUT_S,
        memory_limit_mb: int | None = DEFAULT_MEMORY_LIMIT_MB,
        **kw,
    ):
        """spec/params: as for registry.resolve (resolved in the child); preprocess:
        a preprocess spec applied in the child; memory_limit_mb: the child's address
        space (RLIMIT_AS, MiB; None = unlimited); timeout_s and ``**kw``: see
        :class:`~evalkit.process.ProcessLocalizer`."""
        super().__init__(timeout_s=timeout_s, **kw)
        self.memory_limit_mb = memory_limit_mb
        self.spec, self.params, self.preprocess = spec, dict(params or {}), preprocess
        self.name = spec
        self._proc: Any = None  # subprocess.Popen once started
        self._rx: Any = None  # multiprocessing Connection ends once started
        self._tx: Any = None
        self._scratch: Any = None
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
        argv = [sys.executable, "-c", _CHILD_CODE, str(r1), str(w2), str(self.memory_limit_mb or 0)]
        plain = argv
        argv, self._scratch = sandboxed_argv(argv, self._scratch)
        self.sandboxed = argv is not plain
        try:
            proc = spawn(
                argv,
                memory_limit_mb=None,  # the child sets its own limit before any import
                pass_fds=(r1, w2),
                stdin=subprocess.DEVNULL,
                env=env,
            )
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
            data = self._rx.recv_bytes(MAX_REPLY_BYTES)
        except (EOFError, AttributeError):
            raise ChildDead() from None
        except OSError as exc:
            if "too long" in str(exc):
                raise ProtocolError(f"reply longer than {MAX_REPLY_BYTES >> 20} MiB") from None
            raise ChildDead() from None
        try:
            reply = json.loads(data)
        except (ValueError, RecursionError):
            raise ProtocolError(f"reply is not JSON: {data[:60]!r}") from None
        if not (isinstance(reply, list) and len(reply) == 2 and isinstance(reply[0], str)):
            raise ProtocolError("reply is not [status, value]")
        return reply

    def close(self) -> None:
        """Stop the child and remove its scratch folder."""
        super().close()
        remove_scratch(self._scratch)
        self._scratch = None

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
