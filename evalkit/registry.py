"""Find localizers by name, entry point, file path or import path.

A localizer is any object with

* ``reset(camera: dict)`` -- ``width``, ``height`` (px), ``K`` (3x3), ``dist``
  (OpenCV k1 k2 p1 p2 k3 or None) and ``markers`` (the manifest marker list);
* ``localize(image: np.ndarray) -> None | dict`` -- ``image`` is HxWx3 uint8
  RGB; the dict has at least ``"distance"`` (m), optionally ``"T_cam_dock"``
  (4x4, metres) and ``"marker_id"``.

Third-party localizers register an entry point in the group
``dockbench.localizers`` (``name = "package.module:Class"``), are named as
``path/to/file.py:Class`` or ``package.module:attr``, or are any program
speaking the JSON-lines protocol: ``exec:COMMAND``
(datasets_spec/LOCALIZER_PROTOCOL.md, :mod:`evalkit.external`).

This module only looks localizers up and builds them; wrapping them (process
isolation, external programs' defaults, preprocessing) is :func:`evalkit.assemble.build`,
what the CLI uses.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import inspect
import re
import sys
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

ENTRY_POINT_GROUP = "dockbench.localizers"
BUILTINS = {
    "led": "evalkit.localizers.led:LedLocalizer",
    "qr": "evalkit.localizers.qr:QrLocalizer",
    "aruco": "evalkit.localizers.aruco:ArucoLocalizer",
    "apriltag": "evalkit.localizers.apriltag:AprilTagLocalizer",
    "hybrid": "evalkit.localizers.hybrid:HybridLocalizer",
    "qr_track": "evalkit.localizers.qr:QrTrackLocalizer",
}
EXEC_PREFIX = "exec:"


class RegistryError(Exception):
    """A localizer spec cannot be resolved or instantiated."""


def _entry_points() -> dict[str, Any]:
    """Entry points of the ``dockbench.localizers`` group by name."""
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known_names() -> list[str]:
    """Built-in names followed by entry-point names."""
    return list(BUILTINS) + sorted(n for n in _entry_points() if n not in BUILTINS)


def _load_file_target(target: str) -> Any:
    """Load ``path/to/file.py:Attr`` as a fresh module and return ``Attr``."""
    file_part, _, attr = target.rpartition(":")
    path = Path(file_part).expanduser().resolve()
    if not path.is_file():
        raise RegistryError(f"localizer file not found: {path}")
    mod_name = f"dockbench_user_localizer_{abs(hash(str(path)))}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise RegistryError(f"cannot load {path} as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        sys.modules.pop(mod_name, None)
        raise RegistryError(f"error importing {path}: {type(exc).__name__}: {exc}") from exc
    return _getattr(module, attr, str(path))


def _getattr(obj: Any, dotted: str, where: str) -> Any:
    """``obj.a.b`` for ``dotted="a.b"`` with a clear error."""
    for part in dotted.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise RegistryError(f"{where} has no attribute {dotted!r}") from None
    return obj


def _load_module_target(target: str) -> Any:
    """Import ``package.module:attr`` and return ``attr``."""
    mod_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(mod_name)
    except Exception as exc:
        raise RegistryError(f"cannot import {mod_name!r}: {type(exc).__name__}: {exc}") from exc
    return _getattr(module, attr, mod_name) if attr else module


def _is_file_target(spec: str) -> bool:
    """True for ``something.py:Attr`` (or a path with a separator)."""
    file_part = spec.rpartition(":")[0]
    return file_part.endswith(".py") or "/" in file_part or "\\" in file_part


def load_target(spec: str) -> Any:
    """The object (usually a class) a spec names, without instantiating it."""
    if spec in BUILTINS:
        return _load_module_target(BUILTINS[spec])
    eps = _entry_points()
    if spec in eps:
        try:
            return eps[spec].load()
        except Exception as exc:
            raise RegistryError(
                f"entry point {spec!r} ({eps[spec].value}) failed to load: {type(exc).__name__}: {exc}"
            ) from exc
    if ":" in spec and _is_file_target(spec):
        return _load_file_target(spec)
    if ":" in spec:
        return _load_module_target(spec)
    raise RegistryError(
        f"unknown localizer {spec!r}; known: {', '.join(known_names())}; "
        f"or give 'path/to/file.py:Class', 'package.module:Class' or 'exec:COMMAND'"
    )


def resolve(spec: str, params: dict | None = None) -> Any:
    """Instantiate the localizer named by ``spec`` with keyword ``params``.

    ``spec`` is a built-in name (``led``, ``qr``, ``aruco``), an entry point
    of group ``dockbench.localizers``, ``path/to/file.py:Class`` or
    ``package.module:attr``, or ``exec:COMMAND`` (an external program, see
    :class:`evalkit.external.ExternalLocalizer`; ``params`` go to its constructor,
    unknown ones to the program). A class or factory is called with ``**params``;
    an already-built object is returned as is (then ``params`` must be empty).
    Constructor errors (TypeError, ValueError, ImportError such as a missing
    optional dependency) become :class:`RegistryError`.
    """
    params = dict(params or {})
    if spec.startswith(EXEC_PREFIX):
        from evalkit.external import ExternalLocalizer

        target = functools.partial(ExternalLocalizer, spec[len(EXEC_PREFIX) :])
    else:
        target = load_target(spec)
    obj: Any
    if callable(target) and not _is_localizer(target):
        try:
            obj = target(**params)
        except (TypeError, ValueError, ImportError) as exc:
            raise RegistryError(f"cannot build localizer {spec!r} with params {params}: {exc}") from exc
    else:
        if params:
            raise RegistryError(f"{spec!r} is an instance; it takes no params (got {params})")
        obj = target
    if not _is_localizer(obj):
        raise RegistryError(f"{spec!r} gave {type(obj).__name__}, which lacks reset()/localize()")
    if spec in BUILTINS and not hasattr(obj, "memo_config"):  # what evalkit.memo shares calls by
        from evalkit.memo import config_key

        obj.memo_config = config_key(spec, params)
    return obj


def _is_localizer(obj: Any) -> bool:
    """An instance (not a class) with callable ``reset`` and ``localize``."""
    return (
        not inspect.isclass(obj) and callable(getattr(obj, "reset", None)) and callable(getattr(obj, "localize", None))
    )


def _first_doc_line(obj: Any) -> str:
    """First non-empty line of a docstring, or ''."""
    doc = inspect.getdoc(obj) or ""
    return next((ln.strip() for ln in doc.splitlines() if ln.strip()), "")


def list_localizers() -> list[tuple[str, str, str]]:
    """``(name, target, one-line doc)`` for built-ins and entry points.

    Import failures are tolerated: the doc then reads ``"unavailable: reason"``.
    """
    rows = []
    eps = _entry_points()
    items = list(BUILTINS.items()) + [(n, eps[n].value) for n in sorted(eps) if n not in BUILTINS]
    for name, target in items:
        try:
            doc = _first_doc_line(load_target(name))
        except Exception as exc:  # noqa: BLE001 - listing must not crash
            cause = exc.__cause__ or exc
            doc = f"unavailable: {type(cause).__name__}: {cause}"
        rows.append((name, target, doc))
    return rows


_FLOAT_RE = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def parse_value(text: str) -> Any:
    """Type a CLI value like YAML: int, float (``1e-3`` too), bool, null, else the string.

    An empty value is the empty string; YAML lists/maps (``[1, 2]``) are kept.
    """
    import yaml  # local: light import of evalkit

    if not text.strip():
        return text
    if _FLOAT_RE.fullmatch(text.strip()) and not text.strip().lstrip("+-").isdigit():
        return float(text)  # PyYAML (YAML 1.1) reads 1e-3 as a string
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(value, (int, float, bool, str, list, dict)) or value is None:
        return value
    return text  # dates and other YAML types stay strings


def params_for(name: str, params: dict[str, Any], names: list[str]) -> dict[str, Any]:
    """The constructor arguments of localizer ``name``: every unscoped ``key`` plus its own
    ``name.key`` entries (``-p led.threshold=120`` reaches only ``-l led``)."""
    out = {k: v for k, v in params.items() if not any(k.startswith(f"{n}.") for n in names)}
    prefix = f"{name}."
    out.update({k[len(prefix) :]: v for k, v in params.items() if k.startswith(prefix)})
    return out


def parse_params(items: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``["k=v", ...]`` -> ``{k: typed v}``; raises :class:`RegistryError` on a missing ``=``."""
    params: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise RegistryError(f"bad localizer parameter {item!r}: expected key=value")
        params[key.strip()] = parse_value(value)
    return params
