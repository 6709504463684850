"""Bundled templates and configs: package data in a wheel, the top-level folders in a source tree.

The repository keeps ``templates/`` and ``configs/`` at its top level (the user's design card);
``pyproject.toml`` maps them into the wheel as ``blendgen.bundled.templates`` and
``blendgen.bundled.configs``. Both routes give real files on disk (no zip imports).
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

KINDS = ("templates", "configs")
_SOURCE_ROOT = Path(__file__).resolve().parents[2]


def bundled_dir(kind: str) -> Path:
    """Folder of the bundled ``kind`` ('templates' or 'configs') as a filesystem path."""
    if kind not in KINDS:
        raise ValueError(f"unknown bundled data {kind!r} (known: {', '.join(KINDS)})")
    try:
        root = resources.files(f"blendgen.bundled.{kind}")
    except ModuleNotFoundError:  # source tree or editable install
        return _SOURCE_ROOT / kind
    return Path(str(next(iter(root.iterdir())))).parent


def bundled_file(kind: str, name: str) -> Path:
    """Path of one bundled file, e.g. ``bundled_file('configs', 'quickstart.yaml')``."""
    return bundled_dir(kind) / name


def bundled_names(kind: str, suffix: str = ".yaml") -> list[str]:
    """Sorted stems of the bundled files of ``kind`` with ``suffix``."""
    return sorted(p.stem for p in bundled_dir(kind).glob(f"*{suffix}"))
