"""A sandbox for isolated localizers: bubblewrap (``bwrap``), where the platform has it.

Why bubblewrap: it is the maintained, setuid-free sandbox of Flatpak (Debian package
``bubblewrap``), driven by its command line alone (no Python binding to keep in step), and
gives in one call every property the isolation needs:

* the whole file system read-only (``--ro-bind / /``: the dataset, the user's home, the
  installed package), except the plugin's own scratch folder (``--bind SCRATCH``; also its
  ``TMPDIR`` and ``HOME``) and private ``/dev/shm``;
* the plugin's whole process tree killed at the end: its own PID namespace
  (``--unshare-pid``; when the namespace's first process ends the kernel kills every other
  one, ``setsid`` or double-forked included) tied to dockbench (``--die-with-parent``);
* no network (``--unshare-net``), no System V IPC with the host (``--unshare-ipc``), no
  terminal to inject keystrokes into (``--new-session``), no capabilities (``--cap-drop ALL``).

Landlock (kernel >= 5.13) restricts files only: no PID namespace, no network before ABI 4,
and its Python bindings are young, hence bubblewrap. Where ``bwrap`` is missing or cannot
create namespaces (containers without user namespaces), :func:`probe` says why and the caller
falls back to plain child processes (the memory limit and timeouts still hold).
``DOCKBENCH_SANDBOX=0`` turns the sandbox off (e.g. a plugin that needs a GPU device or the
network); it is recorded in run.json like every other option.

Only the standard library is imported here (children start fast).
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys
from pathlib import Path

ENV_SWITCH = "DOCKBENCH_SANDBOX"
PROBE_TIMEOUT_S = 10.0


def _base_argv(bwrap: str) -> list[str]:
    return [
        bwrap,
        "--ro-bind",
        "/",
        "/",
        "--dev",
        "/dev",
        "--proc",
        "/proc",
        "--tmpfs",
        "/dev/shm",
        "--unshare-pid",
        "--unshare-net",
        "--unshare-ipc",
        "--die-with-parent",
        "--new-session",
        "--cap-drop",
        "ALL",
    ]


@functools.lru_cache(maxsize=1)
def probe() -> tuple[str | None, str]:
    """``(path of bwrap, "")`` when the sandbox works here, else ``(None, why not)``;
    tried once per process (a ``true`` inside the full set of namespaces)."""
    if os.environ.get(ENV_SWITCH, "").strip().lower() in ("0", "off", "no", "false"):
        return None, f"{ENV_SWITCH}=0"
    if not sys.platform.startswith("linux"):
        return None, f"no bubblewrap on {sys.platform}"
    bwrap = shutil.which("bwrap")
    if bwrap is None:
        return None, "bubblewrap (bwrap) is not installed (Debian/Ubuntu: apt-get install bubblewrap)"
    true = shutil.which("true") or "/bin/true"
    try:
        r = subprocess.run(
            [*_base_argv(bwrap), "--", true],
            capture_output=True,
            text=True,
            timeout=PROBE_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"bwrap does not start ({type(exc).__name__})"
    if r.returncode != 0:
        why = (r.stderr.strip().splitlines() or [f"exit code {r.returncode}"])[-1]
        return None, f"bwrap cannot create its namespaces here ({why[:120]})"
    return bwrap, ""


def available() -> bool:
    """True when :func:`wrap` confines programs on this machine."""
    return probe()[0] is not None


_WARNED: list[bool] = []


WARNED_ENV = "DOCKBENCH_SANDBOX_WARNED"


def warn_once_unavailable() -> None:
    """Say once (stderr) that isolated plugins run unsandboxed, and why: once per process and
    its later children (evaluation workers inherit :data:`WARNED_ENV`)."""
    if not available() and not _WARNED and not os.environ.get(WARNED_ENV):
        _WARNED.append(True)
        os.environ[WARNED_ENV] = "1"
        print(
            f"warning: isolated localizers run without a sandbox: {probe()[1]}; they can write "
            "wherever this user can (only memory and time are limited)",
            file=sys.stderr,
        )


def wrap(argv: list[str], scratch: str | Path, cwd: str | None = None) -> list[str]:
    """``argv`` run inside the sandbox: read-only everywhere but ``scratch`` (created by the
    caller; also TMPDIR and HOME), working directory ``cwd`` (default: the current one, read-only).
    Callers check :func:`available` first."""
    bwrap, why = probe()
    if bwrap is None:
        raise RuntimeError(f"no sandbox: {why}")
    s = str(Path(scratch).resolve())
    return [
        *_base_argv(bwrap),
        "--bind",
        s,
        s,
        "--setenv",
        "TMPDIR",
        s,
        "--setenv",
        "HOME",
        s,
        "--chdir",
        str(Path(cwd or os.getcwd()).resolve()),
        "--",
        *argv,
    ]
