"""Standard streams of a worker process (no Blender, no pipeline): Blender's C-level chatter
to a log file, JSON-line replies on the process's original stdout, resident memory.

Shared by the dataset worker (:mod:`blendgen.pipeline.frameloop`), the warm render server
(:mod:`blendgen.blender.serve`) and the calibration worker.
"""

from __future__ import annotations

import json
import os
import sys


def quiet_stdout(log_path: str) -> None:
    """Send C-level stdout (Blender's render log) to the log file."""
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.close(fd)


def log_to(log_path: str) -> None:
    """Send C-level stdout and stderr (tracebacks) to ``log_path`` (the executor's log of
    the job; the job then sends stdout on to its own Blender log)."""
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


def rss_mb() -> float:
    """Resident memory of this process (MB), from /proc (0 where there is none)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        return 0.0


def reply_channel():
    """``reply(dict)`` writing JSON lines to the process's original stdout (a duplicate of
    fd 1, taken before fd 1 is redirected to a log)."""
    proto = os.fdopen(os.dup(1), "w", buffering=1)

    def reply(msg: dict) -> None:
        proto.write(json.dumps(msg) + "\n")
        proto.flush()

    return reply
