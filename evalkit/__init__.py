"""evalkit: evaluate localizers on dockbench datasets (never needs Blender).

Modules: ``dataset`` (read and verify a dataset), ``registry`` (find localizers),
``assemble`` (wrap them: child process, external program, preprocessing), ``process``
(child processes: spawn with a memory cap, kill and reap), ``runner`` (run them),
``metrics.core`` (judge each frame: errors, false positives, thresholded success; per trial),
``metrics.extra`` (the one path to every table: CIs, bins, usable range, runtime),
``metrics.recall`` (AR_dock, BOP-style), ``reports.tables`` / ``reports.plots`` (output),
``reports.results`` (run directories, provenance), ``reports.leaderboard`` (static HTML)
and ``reports.bop`` (BOP export).
This package imports nothing heavy at import time; the names below are
loaded lazily on first access.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "Dataset": "dataset",
    "DatasetError": "dataset",
    "verify": "dataset",
    "resolve": "registry",
    "list_localizers": "registry",
    "RegistryError": "registry",
    "build": "assemble",
    "evaluate": "runner",
    "SuccessCriteria": "metrics.core",
    "compute_all": "metrics.extra",
    "EvalSettings": "metrics.extra",
    "save_run": "reports.results",
    "load_run": "reports.results",
    "compare_runs": "reports.results",
    "evaluate_dataset": "reports.results",
    "frame_truth_table": "metrics.truth",
    "export_bop": "reports.bop",
    "build_leaderboard": "reports.leaderboard",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    """Import ``evalkit.<module>`` only when one of its public names is used."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
