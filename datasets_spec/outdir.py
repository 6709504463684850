"""The one rule of every writing command's ``-o`` folder (generate, run, evaluate,
export-bop, dock, bench, calibrate*), its lock, and its temporary siblings.

* **Where**: never inside dockbench's source tree, under ``/proc``, ``/sys`` or ``/dev``,
  through a file, or where this user cannot write (:func:`check_location`).
* **Never a dataset**: not a dataset's own folder nor anything inside one (a folder with a
  dockbench ``manifest.json``, or one ``generate`` is writing: ``.work/config.sha256``);
  only ``generate`` itself writes its dataset (:func:`refuse_dataset`).
* **Whose**: ``-o`` must be new, empty, or a folder the same command wrote (its marker
  file :data:`MARKER` names the command); anything else is refused unless ``--overwrite``
  (:func:`check`). ``evaluate`` and ``export-bop`` replace even their own earlier output
  only with ``--overwrite`` (results are replaced whole, never mixed).
* **One writer**: every command takes the same lock, an ``fcntl`` lock on the sibling
  ``.NAME.lock`` (the kernel releases it when the process dies, however it dies), so two
  commands never write one folder at once (:func:`lock`).
* **All or nothing** for results: :func:`results_dir` writes into the sibling
  ``.NAME.tmp-PID`` and renames it onto ``-o`` at the end. Siblings left by a killed run
  (``kill -9``) are removed by the next run under the lock, which says so on stderr.

Errors are :class:`OutDirError` (a ``FileExistsError``: the CLI prints it on one line and
exits 2). Only the standard library is imported here (datasets_spec: shared by generate and evaluate).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

MARKER = ".dockbench-out.json"
DATASET_MANIFEST = "manifest.json"
DATASET_FORMAT = "dockbench-dataset"
GENERATE_STAMP = (".work", "config.sha256")  # a dataset generate is writing (or was)
PSEUDO_FS = ("/proc", "/sys", "/dev")


class OutDirError(FileExistsError):
    """An output folder the rule refuses (a user error: exit 2)."""


# -- where -------------------------------------------------------------------
def source_tree() -> list[Path]:
    """Folders of dockbench's own source: the packages, and in a checkout (pyproject.toml
    beside them) its shipped folders (``out/`` stays allowed)."""
    top = Path(__file__).resolve().parents[1]
    dirs = [top / "blendgen", top / "evalkit", top / "datasets_spec"]
    if (top / "pyproject.toml").is_file():
        dirs += [top / d for d in ("tests", "configs", "templates", "examples", "constraints", ".git")]
    return dirs


def check_location(out: Path) -> None:
    """Refuse ``out`` inside the source tree or the project folder itself, under a pseudo
    file system, through a file, or unwritable -- before anything is written."""
    target = Path(out).resolve()
    top = Path(__file__).resolve().parents[1]
    inside = [d for d in source_tree() if os.path.commonpath([d, target]) == str(d)]
    if target == top and (top / "pyproject.toml").is_file():
        inside = [top]
    if inside:
        raise OutDirError(
            f"-o {out}: inside dockbench's source tree ({inside[0]}); choose a folder outside it, e.g. out/NAME"
        )
    for fs in PSEUDO_FS:
        if target == Path(fs) or Path(fs) in target.parents:
            raise OutDirError(f"-o {out}: under {fs}, a kernel pseudo file system; choose a folder on a disk")
    probe = target
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise OutDirError(f"-o {out}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutDirError(f"-o {out}: {probe} is not writable; choose a writable folder")


# -- never a dataset -----------------------------------------------------------
def is_dataset(folder: Path) -> bool:
    """True for a dockbench dataset folder, finished (its manifest names the format) or
    being generated (generate's config stamp)."""
    folder = Path(folder)
    if folder.joinpath(*GENERATE_STAMP).is_file():
        return True
    manifest = folder / DATASET_MANIFEST
    try:
        with open(manifest, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return DATASET_FORMAT.encode() in head


def dataset_around(out: Path) -> Path | None:
    """The dataset folder that is ``out`` or holds it (None: none)."""
    target = Path(out).resolve()
    for folder in (target, *target.parents):
        if folder.is_dir() and is_dataset(folder):
            return folder
    return None


def refuse_dataset(out: Path, command: str) -> None:
    """:class:`OutDirError` when ``out`` is a dataset or inside one (``generate`` may write
    its own dataset folder, never into another one)."""
    ds = dataset_around(out)
    if ds is None or (command == "generate" and ds == Path(out).resolve()):
        return
    where = "is the dataset" if ds == Path(out).resolve() else f"is inside the dataset {ds}"
    raise OutDirError(
        f"-o {out}: {where}; dockbench {command} never writes into a dataset "
        "(it would no longer verify); choose a folder outside it"
    )


# -- whose ---------------------------------------------------------------------
def owner(out: Path) -> str | None:
    """The command named by ``out``'s marker file (None: no readable marker)."""
    try:
        data = json.loads((Path(out) / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return "run" if (Path(out) / ".stream").is_dir() else None  # a run folder of an older version
    return data.get("command") if isinstance(data, dict) and isinstance(data.get("command"), str) else None


def mark(out: Path, command: str) -> None:
    """Write ``out``'s marker file: the folder was written by ``command``."""
    Path(out).mkdir(parents=True, exist_ok=True)
    (Path(out) / MARKER).write_text(json.dumps({"written_by": "dockbench", "command": command}) + "\n")


def check(out: Path, command: str, overwrite: bool, own_ok: bool = True) -> None:
    """The whole rule before anything is written: location, never a dataset, and ``out``
    new, empty or ``command``'s own (``own_ok``) unless ``overwrite``."""
    out = Path(out)
    check_location(out)
    refuse_dataset(out, command)
    if out.exists() and not out.is_dir():
        raise OutDirError(f"-o {out}: exists and is not a folder")
    if not out.is_dir() or not any(out.iterdir()) or overwrite:
        return
    who = owner(out)
    if who == command and own_ok:
        return
    held = f"the output of an earlier dockbench {who}" if who else "files dockbench did not write"
    raise OutDirError(f"-o {out}: folder is not empty ({held}); choose a new or empty folder, or pass --overwrite")


def check_file_out(path: Path | None, command: str) -> None:
    """A single output file (``leaderboard -o page.html``, ``preview -o x.png``...): its folder
    obeys :func:`check_location` and :func:`refuse_dataset`; the path is not a folder."""
    if path is None:
        return
    path = Path(path)
    if path.is_dir():
        raise OutDirError(f"-o {path}: is a folder; name the file to write")
    check_location(path.parent)
    ds = dataset_around(path.parent)
    if ds is not None:
        raise OutDirError(
            f"-o {path}: is inside the dataset {ds}; dockbench {command} never writes into a "
            "dataset (it would no longer verify); choose a file outside it"
        )


def prepare(out: Path, command: str, overwrite: bool = False) -> Path:
    """:func:`check`, then create ``out`` with ``command``'s marker (commands that write
    into ``-o`` as they go: bench, dock, calibrate); returns ``out``."""
    check(out, command, overwrite)
    try:
        mark(out, command)
    except OSError as exc:
        raise OutDirError(f"-o {out}: cannot create the folder ({exc.strerror})") from None
    return Path(out)


@contextlib.contextmanager
def writing(out: Path, command: str, overwrite: bool = False) -> Iterator[Path]:
    """:func:`prepare` and :func:`lock` around a command that writes into ``out`` as it goes;
    if it fails before writing anything, the folders it created are removed again."""
    out = Path(out)
    check(out, command, overwrite)
    created = [d for d in (*reversed(out.absolute().parents), out.absolute()) if not d.exists()]
    had_marker = (out / MARKER).exists()
    before = set(os.listdir(out)) if out.is_dir() else set()
    try:
        with lock(out, command):
            prepare(out, command, overwrite)
            yield out
    except BaseException:
        if not had_marker and out.is_dir() and set(os.listdir(out)) - {MARKER} == before:
            (out / MARKER).unlink()  # nothing written: the folder is as it was
            for d in reversed(created):  # the lock file is gone by now
                with contextlib.suppress(OSError):
                    d.rmdir()
        raise


# -- disk full ------------------------------------------------------------------
DISK_FULL_TEXT = ("No space left on device", "[Errno 28]", "Disk quota exceeded", "[Errno 122]")


def _size_mb(folder: Path) -> float:
    total = 0
    for d, _, files in os.walk(folder):
        for f in files:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(d, f)).st_size
    return total / 1e6


def disk_full_message(exc: BaseException, out: Path | None) -> str | None:
    """One line for a write that failed because the disk (or quota) is full -- in this process
    (``OSError`` ENOSPC/EDQUOT) or in a worker whose error text says so -- naming the path, the
    free space there and the space still needed; None for any other error. The need is a lower
    bound: what the command had written into ``-o`` (and its temporary sibling) when the
    disk filled, i.e. the same again at least."""
    import errno

    own = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
    if not own and not any(t in str(exc) for t in DISK_FULL_TEXT):
        return None
    import re

    named = re.search(r"(?:No space left on device|Disk quota exceeded): '([^']+)'", str(exc))
    path = Path(getattr(exc, "filename", None) or (named and named.group(1)) or out or ".")
    if out is not None:  # the user's -o, not its temporary sibling
        o = Path(out).absolute()
        parts = path.absolute().parts
        for i, part in enumerate(parts):
            if part.startswith(f".{o.name}.tmp-") and Path(*parts[:i]) == o.parent:
                path = o.joinpath(*parts[i + 1 :])
                break
    probe = path.absolute()
    while not probe.is_dir() and probe != probe.parent:
        probe = probe.parent
    free_mb = shutil.disk_usage(probe).free / 1e6
    written = float(getattr(exc, "dockbench_written_mb", 0.0))
    if out is not None:
        o = Path(out).absolute()
        for d in [o, *o.parent.glob(f".{o.name}.tmp-*")]:
            written += _size_mb(d) if d.is_dir() else 0.0
    need = max(written, 1.0)
    return (
        f"{path}: disk full (no space left on device): {free_mb:.1f} MB free on that file system, "
        f"at least {need:.1f} MB more needed (what was written before it filled); free space or "
        "choose another -o, then re-run"
    )


# -- one writer ------------------------------------------------------------------
def lock_path(out: Path) -> Path:
    out = Path(out).absolute()
    return out.parent / f".{out.name}.lock"


@contextlib.contextmanager
def lock(out: Path, command: str) -> Iterator[None]:
    """Hold the exclusive lock of ``out`` (every command uses this one), else
    :class:`OutDirError` naming the holder. The lock file is removed on release."""
    import fcntl

    path = lock_path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "?"
            raise OutDirError(
                f"{Path(out)}: being written by another dockbench {holder}; wait for it "
                f"or choose another -o (lock {path})"
            ) from None
        if not path.exists() or os.stat(path).st_ino != os.fstat(fd).st_ino:
            raise OutDirError(f"{Path(out)}: another dockbench just finished writing it; run again")
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{command} (pid {os.getpid()})".encode(), 0)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                path.unlink()
    finally:
        os.close(fd)


def clean_stale(out: Path) -> list[Path]:
    """Remove the temporary siblings of ``out`` (``.NAME.tmp-PID``, ``.NAME.old-PID``) that a
    killed run left; call under :func:`lock`. An ``old`` copy whose rename back was cut
    short is restored when ``out`` is missing. Says on stderr what it removed."""
    out = Path(out).absolute()
    found = sorted(out.parent.glob(f".{out.name}.tmp-*")) + sorted(out.parent.glob(f".{out.name}.old-*"))
    for p in found:
        if ".old-" in p.name and not out.exists():
            os.rename(p, out)
            print(f"note: restored {out} from {p.name}, left by an interrupted run", file=sys.stderr)
        else:
            shutil.rmtree(p, ignore_errors=True)
            print(f"note: removed {p}, left by an interrupted run", file=sys.stderr)
    return found


# -- all or nothing ------------------------------------------------------------------
@contextlib.contextmanager
def results_dir(out: str | Path, overwrite: bool = False, command: str = "evaluate") -> Iterator[Path]:
    """Yield an empty temporary sibling of ``out``; on success it replaces ``out`` atomically
    (rename), with ``command``'s marker. Checks the rule before (fail fast) and again under
    the lock just before the rename; a failed run leaves no trace, not even parents."""
    out = Path(out).absolute()
    check(out, command, overwrite, own_ok=False)
    created = [d for d in reversed(out.parents) if not d.exists()]
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutDirError(f"-o {out}: cannot create {out.parent} ({exc.strerror})") from None
    try:
        with lock(out, command):
            clean_stale(out)
            with _renamed_onto(out, overwrite, command) as tmp:
                yield tmp
    except BaseException:
        for d in reversed(created):
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


@contextlib.contextmanager
def _renamed_onto(out: Path, overwrite: bool, command: str) -> Iterator[Path]:
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    tmp.mkdir()
    try:
        try:
            yield tmp
        except OSError as exc:  # a full disk: how much was written (disk_full_message)
            exc.dockbench_written_mb = _size_mb(tmp)  # type: ignore[attr-defined]
            raise
        mark(tmp, command)
        check(out, command, overwrite, own_ok=False)
        if out.exists():
            os.rename(out, old)
        os.rename(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
