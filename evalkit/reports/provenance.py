"""What run.json needs so a reader can rerun an evaluation: versions, code, inputs.

* :func:`environment` -- Python, platform, package versions (numpy, OpenCV, pandas,
  scipy, zxing-cpp, dockbench, bpy if installed: read from the installed
  distributions, bpy is never imported) and the git commit of the dockbench source;
* :func:`localizer_record` -- a localizer as the user gave it: spec, constructor
  arguments *as given* (not the object's state after the run), class, and the
  sha256 of the code that ran (plugin file, module file, or external program and
  the files on its command line);
* :func:`disk_content_hash` -- the dataset content hash recomputed from the bytes on
  disk (used with ``--no-verify``, so an unverified run never borrows the
  manifest's hash).
"""

from __future__ import annotations

import importlib.util
import platform
import shlex
import shutil
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from datasets_spec.io import content_hash, sha256_file

PACKAGES = [
    "dockbench",
    "numpy",
    "opencv-python",
    "opencv-python-headless",
    "opencv-contrib-python",
    "pandas",
    "pyarrow",
    "scipy",
    "zxing-cpp",
    "pupil-apriltags",
    "bpy",
]
SOURCE_ROOT = Path(__file__).resolve().parents[2]


def package_versions() -> dict[str, str]:
    """Installed versions of :data:`PACKAGES` (absent ones left out) plus ``python``
    and ``cv2`` (the OpenCV the evaluation imported, whatever its wheel's name)."""
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    cv2 = sys.modules.get("cv2")
    if cv2 is not None:
        out["cv2"] = str(getattr(cv2, "__version__", "unknown"))
    return out


def git_state(root: Path = SOURCE_ROOT) -> dict | None:
    """``{commit, dirty}`` of the git checkout holding the dockbench source, or None
    (not a checkout, or no git)."""
    if not (root / ".git").exists() or shutil.which("git") is None:
        return None
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "dirty": bool(dirty)}


def environment() -> dict:
    """Python, platform, package versions and git state."""
    return {
        "python": sys.version.split()[0],
        "implementation": platform.python_implementation(),
        "platform": platform.platform(),
        "packages": package_versions(),
        "git": git_state(),
    }


def _file_entry(path: Path, role: str) -> dict:
    return {"role": role, "path": str(path), "sha256": sha256_file(path)}


def _module_file(module: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    origin = getattr(spec, "origin", None)
    return Path(origin) if origin and Path(origin).is_file() else None


def code_artifacts(spec: str) -> list[dict]:
    """sha256 of the code a ``-l`` spec runs: ``[{role, path, sha256}]``.

    ``exec:COMMAND``: the program (found on PATH) and every command-line argument that
    is an existing file (scripts, models); ``file.py:Class``: the file; built-ins,
    entry points and ``module:attr``: the module's source file."""
    from evalkit import registry

    if spec.startswith(registry.EXEC_PREFIX):
        words = shlex.split(spec[len(registry.EXEC_PREFIX) :])
        out = []
        program = shutil.which(words[0]) if words else None
        if program:
            out.append(_file_entry(Path(program).resolve(), "program"))
        out += [_file_entry(Path(w).resolve(), "argument") for w in words[1:] if Path(w).is_file()]
        return out
    target = registry.BUILTINS.get(spec)
    if target is None:
        ep = registry._entry_points().get(spec)
        target = ep.value if ep is not None else spec
    mod = target.rpartition(":")[0] if ":" in target else target
    if registry._is_file_target(target):
        path = Path(mod).expanduser().resolve()
        return [_file_entry(path, "plugin file")] if path.is_file() else []
    module_path = _module_file(mod)
    return [_file_entry(module_path, "module")] if module_path else []


def localizer_record(spec: str, params: dict, obj: Any = None) -> dict:
    """A localizer for run.json: ``{name, params (as given), class, code}``."""
    cls = type(obj) if obj is not None else None
    inner = getattr(obj, "spec", None)
    return {
        "name": spec,
        "params": dict(params),
        "class": f"{cls.__module__}:{cls.__qualname__}" if cls is not None else None,
        "wrapped": inner if isinstance(inner, str) else None,
        "code": code_artifacts(spec),
    }


def first_changed_file(root: Path, files: dict[str, str]) -> str | None:
    """The first listed file (sorted) whose bytes on disk are missing or differ from its sha256
    in ``files``, or None: a verified run's content hash then describes every file of the
    dataset, not only those the localizers read (depth and index passes, assets...)."""
    from datasets_spec.io import DatasetError, path_inside

    for rel in sorted(files):
        try:
            path = path_inside(root, rel, "manifest file")
        except DatasetError:
            return rel
        if not path.is_file() or sha256_file(path) != files[rel]:
            return rel
    return None


def disk_content_hash(root: Path, files: dict[str, str]) -> str:
    """The dataset content hash over the sha256 of the files on disk (``missing`` for absent ones)."""
    actual = {rel: (sha256_file(root / rel) if (root / rel).is_file() else "missing") for rel in files}
    return content_hash(actual)
