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


def resolve_config(spec: str | Path) -> Path:
    """The config file ``spec`` names: the path itself when it exists, else the bundled config of
    that name (``quickstart``, ``quickstart.yaml`` or ``configs/quickstart.yaml``, which a wheel
    install has no file for), else ``spec`` unchanged (the caller reports it missing)."""
    p = Path(spec)
    if p.exists():
        return p
    stem = p.name.removesuffix(".yaml")
    short = len(p.parts) == 1 or (len(p.parts) == 2 and p.parts[0] == "configs")
    if short and stem in bundled_names("configs"):
        return bundled_file("configs", f"{stem}.yaml")
    return p


def config_summary(name: str) -> str:
    """The first comment line of a bundled config (its one-line description), or ''."""
    for line in bundled_file("configs", f"{name}.yaml").read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
        if line.strip():
            break
    return ""
