"""Per-frame ground truth of a dataset as a table (for metrics that need more than ``d_true``).

Units: metres, seconds. ``T_cam_dock`` is stored flattened row-major (16 floats)
so the table writes to parquet/CSV as is; :func:`as_matrices` turns such a
column back into an ``(N, 4, 4)`` array (NaN where missing).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from evalkit.dataset import Dataset
from evalkit.metrics.core import as_matrices  # noqa: F401  (re-exported)

BASE_COLUMNS = ["sequence", "condition", "trial", "index", "t", "d_true", "T_cam_dock", "in_view", "markers_in_fov"]


def in_fov_column(marker_id: str) -> str:
    """Name of the per-marker ``in_fov`` column (bool)."""
    return f"in_fov:{marker_id}"


def visible_fraction_column(marker_id: str) -> str:
    """Name of the per-marker ``visible_fraction`` column (0..1)."""
    return f"visible_fraction:{marker_id}"


def _flat_pose(T) -> list[float] | None:
    """A 4x4 nested list as 16 floats (row-major), or None if absent/malformed."""
    if T is None:
        return None
    arr = np.asarray(T, dtype=float)
    if arr.shape != (4, 4):
        return None
    return [float(v) for v in arr.ravel()]


def frame_truth_table(dataset: Dataset, sequences: Iterable[str] | None = None) -> pd.DataFrame:
    """One row per frame of ``dataset``: the ground truth the metrics need.

    Columns: ``sequence, condition, trial, index, t`` (s), ``d_true`` (m),
    ``T_cam_dock`` (16 floats, row-major, metres; None if the frame has none),
    ``in_view`` (any marker ``in_fov``), ``markers_in_fov`` (ids joined with
    ``","``) and for every manifest marker ``in_fov:<id>`` (bool) and
    ``visible_fraction:<id>`` (float, 0 when not in view). ``sequences``
    restricts the table to these ids. Does not read images.
    """
    wanted = None if sequences is None else set(sequences)
    marker_ids = [str(m["id"]) for m in dataset.markers]
    rows = []
    for seq in dataset.sequences:
        if wanted is not None and seq["id"] not in wanted:
            continue
        for frame in dataset.iter_frames(seq["id"]):
            markers = frame.get("markers") or {}
            ids = list(dict.fromkeys(marker_ids + [str(k) for k in markers]))
            row = {
                "sequence": seq["id"],
                "condition": seq.get("condition", ""),
                "trial": seq.get("trial"),
                "index": frame.get("index"),
                "t": frame.get("t"),
                "d_true": frame.get("d_true"),
                "T_cam_dock": _flat_pose(frame.get("T_cam_dock")),
            }
            in_fov = []
            for mid in ids:
                m = markers.get(mid) or {}
                fov = bool(m.get("in_fov", False))
                row[in_fov_column(mid)] = fov
                row[visible_fraction_column(mid)] = float(m.get("visible_fraction") or 0.0)
                if fov:
                    in_fov.append(mid)
            row["in_view"] = bool(in_fov)
            row["markers_in_fov"] = ",".join(in_fov)
            rows.append(row)
    df = pd.DataFrame(rows)
    if df.empty:
        df = pd.DataFrame(columns=BASE_COLUMNS)
    extra = [c for c in df.columns if c not in BASE_COLUMNS]
    df = df[BASE_COLUMNS + extra]
    return df.astype({"d_true": float, "t": float, "in_view": bool})
