"""Evaluation on every core: one process per core, each running the localizers over a
share of the sequences; the per-frame table is the serial one (rows in the same order,
same values; only the measured ``ms`` differ) and the run record is saved as usual.

Sequences are independent (every localizer is ``reset`` at the start of each one), so
splitting by sequence changes no estimate. Each process builds its own localizers and
runs OpenCV on one thread (``cv2.setNumThreads(1)``) so N processes use N cores.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd


def build_localizers(
    names: list[str], params: list[str], isolate: bool | None, timeout_s: float | None, preprocess: str | None
) -> list[tuple[str, Any]]:
    from evalkit import assemble, registry

    kw = registry.parse_params(params)
    return [
        (
            n,
            assemble.build(
                n, registry.params_for(n, kw, names), isolate=isolate, timeout_s=timeout_s, preprocess=preprocess
            ),
        )
        for n in names
    ]


def _evaluate_share(args: tuple) -> pd.DataFrame:
    """Process body: ``(dataset_dir, names, params, isolate, timeout_s, preprocess, verify, seq_ids)``."""
    import cv2

    from evalkit import runner
    from evalkit.dataset import Dataset

    root, names, params, isolate, timeout_s, preprocess, verify, seq_ids = args
    cv2.setNumThreads(1)
    specs = build_localizers(names, params, isolate, timeout_s, preprocess)
    return runner.evaluate(
        Dataset.open(root, verify=verify), specs, frame_timeout_s=timeout_s, progress=False, sequences=seq_ids
    )


def evaluate_frames(
    dataset_dir: str | Path,
    localizers: Iterable[str],
    params: Iterable[str] = (),
    workers: int | None = None,
    isolate: bool | None = None,
    frame_timeout_s: float | None = None,
    preprocess: str | None = None,
    verify: bool = True,
) -> pd.DataFrame:
    """Per-frame table of :func:`evalkit.runner.evaluate` computed by ``workers`` processes
    (default: one per core, at most one per sequence). Parameters as
    :class:`evalkit.reports.results.EvalRequest`; ``dockbench evaluate --workers`` and
    ``reproduce`` use it through :func:`evalkit.reports.results.evaluate_dataset`."""
    from evalkit.dataset import Dataset

    ds = Dataset.open(dataset_dir, verify=verify)
    names, params = list(localizers), list(params)
    seq_ids = [s["id"] for s in ds.sequences]
    n = max(1, min(workers or os.cpu_count() or 1, len(seq_ids)))
    shares = [seq_ids[i::n] for i in range(n)]
    args = [(str(dataset_dir), names, params, isolate, frame_timeout_s, preprocess, verify, s) for s in shares]
    if n == 1:
        parts = [_evaluate_share(args[0])]
    else:
        # spawn: the workers are this process's children (their CPU shows in RUSAGE_CHILDREN)
        # and nothing is forked from a process that may run threads
        with ProcessPoolExecutor(n, mp_context=get_context("spawn")) as pool:
            parts = list(pool.map(_evaluate_share, args))
    order = {s: i for i, s in enumerate(seq_ids)}
    df = pd.concat(parts, ignore_index=True)
    df = df.iloc[np.argsort(df["sequence"].map(order).to_numpy(), kind="stable")].reset_index(drop=True)
    df.attrs.update(parts[0].attrs)
    return df
