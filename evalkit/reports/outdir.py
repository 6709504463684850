"""Results folders: the rule, lock and all-or-nothing rename live in :mod:`datasets_spec.outdir`
(one module for every writing command); re-exported here under their older import path."""

from __future__ import annotations

from datasets_spec.outdir import OutDirError, check, lock, results_dir  # noqa: F401


def check_out_dir(out, overwrite: bool) -> None:
    """Refuse a file, a dataset, or a non-empty folder without ``overwrite`` (evaluate's rule)."""
    check(out, "evaluate", overwrite, own_ok=False)
