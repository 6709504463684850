"""Writing a results folder safely: refuse to clobber, one writer at a time, all or nothing.

:func:`results_dir` locks ``OUT`` (an ``fcntl`` lock on ``.OUT.lock`` beside it,
released by the kernel if the process dies), yields a temporary sibling folder to
write into, and renames it to ``OUT`` only when everything is written; a failed
or interrupted run leaves ``OUT`` as it was. A non-empty ``OUT`` is refused unless
``overwrite``. No pandas here (the CLI imports this for its error type).
"""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path
from typing import Iterator


class OutDirError(FileExistsError):
    """The results folder is not empty, or another writer holds it."""


def check_out_dir(out: Path, overwrite: bool) -> None:
    """Refuse a file, or a non-empty folder without ``overwrite``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutDirError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutDirError(f"{out}: folder is not empty (an earlier run?); pass --overwrite to replace it "
                          "or choose another -o")


@contextlib.contextmanager
def _lock(out: Path) -> Iterator[None]:
    """Hold an exclusive, non-blocking lock for ``out``; :class:`OutDirError` if taken."""
    import fcntl

    lock_path = out.parent / f".{out.name}.lock"
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            raise OutDirError(f"{out}: another dockbench evaluate (pid {holder}) is writing these results "
                              f"(lock {lock_path}); wait for it or choose another -o") from None
        if not lock_path.exists() or os.stat(lock_path).st_ino != os.fstat(fd).st_ino:
            raise OutDirError(f"{out}: another dockbench evaluate just finished writing these results; "
                              "run again with --overwrite to replace them")
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                lock_path.unlink()
    finally:
        os.close(fd)


@contextlib.contextmanager
def results_dir(out: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield an empty temporary folder; on success it replaces ``out`` atomically (rename).

    Checks ``out`` before (fail fast) and again under the lock just before the rename."""
    out = Path(out).absolute()
    check_out_dir(out, overwrite)
    created = [d for d in reversed(out.parents) if not d.exists()]   # removed again on failure
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        with _locked_tmp(out, overwrite) as tmp:
            yield tmp
    except BaseException:
        for d in reversed(created):          # a failed run leaves no trace, not even parents
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


@contextlib.contextmanager
def _locked_tmp(out: Path, overwrite: bool) -> Iterator[Path]:
    """Under the lock: a temporary sibling of ``out`` renamed onto it when the block succeeds."""
    with _lock(out):
        tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        try:
            yield tmp
            check_out_dir(out, overwrite)
            if out.exists():
                os.rename(out, old)
            os.rename(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
