"""Localizers in any language: an external program spoken to in JSON lines (protocol 1).

The full protocol is datasets_spec/LOCALIZER_PROTOCOL.md. In short, dockbench starts
the command once per sequence, writes one JSON object per line to its stdin and
reads exactly one JSON object per line from its stdout for each request:

* ``{"type": "reset", "protocol": 1, "sequence": "...", "camera": {"width", "height",
  "K", "dist", "markers"}, "params": {...}}`` -> ``{"ok": true}`` (optionally
  ``"protocol": 1``, ``"name": "..."``) or ``{"ok": false, "error": "..."}``;
* ``{"type": "frame", "protocol": 1, "index": i, "image": "/abs/path.png", "K": [[...]]}``
  -> ``{"ok": false}`` (nothing found), ``{"ok": false, "error": "..."}`` (recorded
  as an exception) or ``{"ok": true, "distance": d, "T_cam_dock": [[4x4]],
  "marker_id": "...", "confidence": c}`` (``distance`` required);
* end of the sequence: dockbench closes stdin; the program should exit (it is
  killed after 2 s).

stderr is passed through. Timeouts, crashes and protocol violations cost one
frame each; the program is then killed and restarted for the next frame with the
reset replayed (:class:`evalkit.process.ProcessLocalizer`). Reply lines longer than
1 MiB are a protocol error (read in bounded chunks, never buffered whole); the program's
address space is capped (``memory_limit_mb``, default 4096 MiB).
"""

from __future__ import annotations

import json
import os
import queue
import shlex
import shutil
import subprocess
import threading
from pathlib import Path
from typing import Any

from evalkit.process import (
    DEFAULT_MEMORY_LIMIT_MB,
    DEFAULT_TIMEOUT_S,
    EXIT_GRACE_S,
    ChildDead,
    ChildTimeout,
    FrameFailure,
    ProcessLocalizer,
    ProtocolError,
    kill_and_reap,
    spawn,
)

PROTOCOL_VERSION = 1
SUPPORTED_PROTOCOLS = (1,)
MAX_REPLY_BYTES = 1 << 20  # one reply line; a longer one is a protocol error (never buffered whole)
MAX_QUEUED_LINES = 64  # replies read ahead of requests (a program may answer one per request)
_TOO_LONG = object()  # reader -> parent: the current line exceeded MAX_REPLY_BYTES


def _read_replies(stream, lines: queue.Queue, stop: threading.Event) -> None:
    """Reader thread: put each reply line (bytes) on ``lines``; a line longer than
    MAX_REPLY_BYTES becomes ``_TOO_LONG`` and the rest of it is skipped in bounded chunks,
    so a program that writes gigabytes without a newline cannot grow this process.
    ``None`` marks the end of the stream."""

    def put(item) -> bool:
        while not stop.is_set():
            try:
                lines.put(item, timeout=0.5)
                return True
            except queue.Full:
                continue
        return False

    try:
        while True:
            line = stream.readline(MAX_REPLY_BYTES + 1)
            if not line:
                break
            if len(line) > MAX_REPLY_BYTES:
                if not put(_TOO_LONG):  # at once: the parent kills the program now
                    return
                while line and not line.endswith(b"\n") and not stop.is_set():
                    line = stream.readline(MAX_REPLY_BYTES)
                continue
            if not put(line):
                return
    except (OSError, ValueError):
        pass
    put(None)


def _jsonable(obj: Any) -> Any:
    """json.dumps ``default``: numpy arrays and scalars to lists / numbers."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def camera_message(camera: dict) -> dict:
    """The ``camera`` object of a reset request (plain JSON types)."""
    keys = ("width", "height", "K", "dist", "markers")
    return json.loads(json.dumps({k: camera.get(k) for k in keys}, default=_jsonable))


class ExternalLocalizer(ProcessLocalizer):
    """External program speaking dockbench's JSON-lines localizer protocol (any language)."""

    name = "exec"

    def __init__(
        self,
        cmd: str | list[str],
        timeout_s: float | None = DEFAULT_TIMEOUT_S,
        persistent: bool = False,
        cwd: str | None = None,
        env: dict | None = None,
        reset_timeout_s: float | None = None,
        start_timeout_s: float | None = None,
        max_restarts: int | None = None,
        max_restarts_total: int | None = None,
        memory_limit_mb: int | None = DEFAULT_MEMORY_LIMIT_MB,
        **params: Any,
    ):
        """cmd: command line (a string split like a POSIX shell, or an argv list).
        timeout_s: per-frame reply budget (s; None waits forever).
        persistent: keep one process for all sequences (each gets a new reset)
        instead of one process per sequence. cwd / env: of the process (env adds
        to os.environ). memory_limit_mb: the program's address space (RLIMIT_AS, MiB,
        set right after it starts; None = unlimited). Other keyword params are sent to
        the program in the reset request as ``"params"``."""
        kw: dict[str, Any] = {
            k: v
            for k, v in (
                ("reset_timeout_s", reset_timeout_s),
                ("start_timeout_s", start_timeout_s),
                ("max_restarts", max_restarts),
                ("max_restarts_total", max_restarts_total),
            )
            if v is not None
        }
        super().__init__(timeout_s=timeout_s, **kw)
        argv = shlex.split(cmd) if isinstance(cmd, str) else [str(c) for c in cmd]
        if not argv:
            raise ValueError("exec: empty command")
        exe = argv[0]
        where = Path(cwd or ".") / exe
        if shutil.which(exe) is None and not (os.sep in exe and where.is_file()):
            raise ValueError(f"exec: command not found: {exe!r}")
        self.argv = argv
        self.persistent = str(persistent).lower() in ("1", "true", "yes", "on")
        self.cwd = cwd
        self.env = None if env is None else {**os.environ, **{str(k): str(v) for k, v in env.items()}}
        self.params = params
        self.memory_limit_mb = memory_limit_mb
        self._stop_reader: threading.Event | None = None
        self._proc: subprocess.Popen | None = None
        self._lines: queue.Queue | None = None
        self._pending_index: Any = None
        self._counter = 0
        self._tmp: Any = None  # a tempfile.TemporaryDirectory once localize() writes an image
        self._scratch: str | None = None

    def __repr__(self) -> str:
        return f"ExternalLocalizer({shlex.join(self.argv)!r})"

    # -- localizer API ------------------------------------------------------
    def localize_file(self, path: str, index: int | None = None) -> dict | None:
        """Estimate for the image at ``path`` (absolute), frame ``index``."""
        if index is None:
            index = self._counter
        self._counter = int(index) + 1
        request = {
            "type": "frame",
            "protocol": PROTOCOL_VERSION,
            "index": index,
            "image": str(Path(path).resolve()),
            "K": (self._camera or {}).get("K"),
        }
        self._pending_index = index
        return self._request("frame", json.loads(json.dumps(request, default=_jsonable)))

    def localize(self, image) -> dict | None:
        """Estimate for an RGB uint8 array: written to a temporary PNG first."""
        import tempfile

        import cv2

        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="dockbench-exec-")
        path = Path(self._tmp.name) / f"{self._counter:06d}.png"
        if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise FrameFailure("exception: OSError: cannot write temporary image")
        return self.localize_file(str(path), self._counter)

    def reset(self, camera: dict) -> None:
        """New sequence: (re)start the program and send the reset request."""
        self._counter = 0
        super().reset(camera)

    def close(self) -> None:
        """Close stdin, wait up to 2 s for the program, then kill it."""
        super().close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        from evalkit.process import remove_scratch

        remove_scratch(self._scratch)
        self._scratch = None

    # -- transport ----------------------------------------------------------
    def _new_sequence(self) -> None:
        if not self.persistent and self._alive():
            self._stop_gracefully()
            self._kill()

    def _reset_request(self, camera: dict) -> dict:
        msg = {
            "type": "reset",
            "protocol": PROTOCOL_VERSION,
            "camera": camera_message(camera),
            "params": json.loads(json.dumps(self.params, default=_jsonable)),
        }
        if camera.get("sequence") is not None:
            msg["sequence"] = str(camera["sequence"])
        return msg

    def _start(self) -> None:
        from evalkit.process import sandboxed_argv

        argv, self._scratch = sandboxed_argv(self.argv, self._scratch, self.cwd, self.memory_limit_mb)
        self.sandboxed = argv is not self.argv
        limit = None if self.sandboxed else self.memory_limit_mb  # sandboxed: capped inside
        proc = spawn(argv, limit, stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=self.cwd, env=self.env)
        lines: queue.Queue = queue.Queue(MAX_QUEUED_LINES)
        stop = threading.Event()
        threading.Thread(
            target=_read_replies, args=(proc.stdout, lines, stop), daemon=True, name="dockbench-exec-reader"
        ).start()
        self._proc, self._lines, self._stop_reader = proc, lines, stop

    def _alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def _send(self, request: dict) -> None:
        try:
            line = json.dumps(request, default=_jsonable, separators=(",", ":")) + "\n"
            proc = self._proc
            if proc is None or proc.stdin is None:
                raise ChildDead()
            proc.stdin.write(line.encode("utf-8"))
            proc.stdin.flush()
        except (OSError, ValueError, AttributeError):
            raise ChildDead() from None

    def _recv(self, timeout_s: float | None) -> dict:
        try:
            if self._lines is None:
                raise ChildDead()
            line = self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise ChildTimeout() from None
        if line is None:
            raise ChildDead()
        if line is _TOO_LONG:
            raise ProtocolError(f"reply line longer than {MAX_REPLY_BYTES >> 20} MiB")
        text = line.decode("utf-8", errors="replace").strip()
        try:
            reply = json.loads(text)
        except (json.JSONDecodeError, RecursionError):
            raise ProtocolError(f"reply is not JSON: {text[:80]!r}") from None
        if not isinstance(reply, dict) or not isinstance(reply.get("ok"), bool):
            raise ProtocolError(f'reply is not an object with a boolean "ok": {text[:80]!r}')
        return reply

    def _reply(self, kind: str, reply: dict) -> Any:
        error = reply.get("error")
        if kind == "reset":
            version = reply.get("protocol", PROTOCOL_VERSION)
            if version not in SUPPORTED_PROTOCOLS:
                raise FrameFailure(
                    f"protocol: program speaks protocol {version!r}; dockbench speaks "
                    f"{', '.join(map(str, SUPPORTED_PROTOCOLS))}"
                )
            if not reply["ok"]:
                raise FrameFailure(f"exception: ExternalError: {error or 'reset refused'}")
            return None
        if "index" in reply and reply["index"] != self._pending_index:
            raise ProtocolError(f"reply for frame {reply['index']!r} while waiting for {self._pending_index!r}")
        if not reply["ok"]:
            if error:
                raise FrameFailure(f"exception: ExternalError: {error}")
            return None
        return {k: v for k, v in reply.items() if k not in ("ok", "index", "type", "protocol")}

    def _stop_gracefully(self) -> None:
        proc = self._proc
        if proc is None or proc.stdin is None:
            return
        try:
            proc.stdin.close()
            proc.wait(EXIT_GRACE_S)
        except Exception:  # noqa: BLE001 - _kill follows
            pass

    def _kill(self) -> None:
        proc = self._proc
        if proc is None:
            return
        kill_and_reap(proc)
        if self._stop_reader is not None:
            self._stop_reader.set()
        for stream in (proc.stdin, proc.stdout):
            try:
                if stream is not None:
                    stream.close()
            except Exception:  # noqa: BLE001
                pass
