"""evalkit: evaluate localizers on dockbench datasets (never needs Blender).

Modules: ``dataset`` (read a dataset), ``registry`` (find localizers),
``assemble`` (wrap them: child process, external program, preprocessing), ``process``
(child processes: spawn with a memory cap, kill and reap), ``runner`` (run them), ``metrics`` (SPEC.md section 7), ``tables`` (output),
``truth`` / ``metrics_extra`` (pose errors, FP rate, distance bins, usable range,
bootstrap CIs, runtime), ``plots``, ``results`` (run directories), ``leaderboard``
(static HTML) and ``bop`` (BOP export).
This package imports nothing heavy at import time; the names below are
loaded lazily on first access.
"""
from __future__ import annotations

import importlib

_LAZY = {
    "Dataset": "dataset", "DatasetError": "dataset", "verify": "dataset",
    "resolve": "registry", "list_localizers": "registry", "RegistryError": "registry",
    "build": "assemble",
    "evaluate": "runner", "write_results": "runner",
    "save_run": "results", "load_run": "results", "compare_runs": "results",
    "frame_truth_table": "truth", "export_bop": "bop", "build_leaderboard": "leaderboard",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    """Import ``evalkit.<module>`` only when one of its public names is used."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
