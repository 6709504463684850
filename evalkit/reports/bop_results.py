"""BOP results files from a dockbench run: each pose localizer's estimates, one row per marker object.

The BOP Challenge 2019+ results format (``docs/bop_challenge_2019.md`` of the BOP toolkit): a
CSV named ``METHOD_DATASET-SPLIT.csv`` with the header ``scene_id,im_id,obj_id,score,R,t,time``;
``R`` the 9 row-major entries of the model-to-camera rotation and ``t`` the translation (mm),
space-separated; ``time`` the seconds the method spent on the whole image (the same for every
row of one image; -1 when unknown). The toolkit parses METHOD as the text before the first
``_`` and DATASET up to the next ``-``, so localizer names lose their underscores
(``qr_track`` -> ``qr-track``).

A localizer answers with the dock's pose ``T_cam_dock``; every marker's estimate follows from it
(``T_cam_dock T_dock_marker``, then moved to the BOP model origin as the export's GT is), so a
frame with a pose gives one row per object. Frames without a pose give none (a missed target).
dockbench localizers report no confidence: ``score`` is 1.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from evalkit.metrics import core
from evalkit.reports.bop_models import ObjectModel

HEADER = "scene_id,im_id,obj_id,score,R,t,time"


def method_name(localizer: str) -> str:
    """A localizer name as a BOP method name (no ``_``: the toolkit splits file names on it)."""
    return str(localizer).replace("_", "-")


def results_filename(localizer: str, dataset_name: str, split: str) -> str:
    return f"{method_name(localizer)}_{dataset_name}-{split}.csv"


def _rows(frames: pd.DataFrame, scene_of: dict, models: dict) -> list[str]:
    """CSV rows of one localizer's frames; ``models``: obj_id -> (ObjectModel, T_dock_marker)."""
    est = core.as_matrices(frames[core.EST_POSE]) if core.EST_POSE in frames.columns else None
    if est is None:
        return []
    ok = core.detected_mask(frames).to_numpy() & np.isfinite(est).all(axis=(1, 2))
    ms = pd.to_numeric(frames.get("ms", pd.Series(np.nan, index=frames.index)), errors="coerce").to_numpy()
    rows = []
    for i in np.flatnonzero(ok):
        scene = scene_of.get(str(frames["sequence"].iloc[i]))
        if scene is None:
            continue
        t_s = ms[i] / 1000.0 if np.isfinite(ms[i]) else -1.0
        for oid, (model, T_dock_marker) in sorted(models.items()):
            R, t = model.pose_m2c(est[i] @ T_dock_marker)
            rows.append(
                f"{scene},{int(frames['index'].iloc[i])},{oid},1,{' '.join(f'{v:.9g}' for v in R.ravel())},"
                f"{' '.join(f'{v:.6f}' for v in t)},{t_s:.6f}"
            )
    return rows


def write_results(estimates: pd.DataFrame, markers: list[dict], export_dir: Path, out_dir: Path) -> dict[str, Path]:
    """Write one results CSV per localizer of ``estimates`` (a run's estimates.parquet) that returned
    a pose, for the BOP export in ``export_dir``; returns ``{localizer: path}``."""
    info = json.loads((Path(export_dir) / "dockbench_scenes.json").read_text())
    scene_of = {s["sequence"]: int(k) for k, s in info["scenes"].items()}
    objects = json.loads((Path(export_dir) / "dockbench_objects.json").read_text())
    by_marker = {str(m["id"]): m for m in markers}
    models = {
        int(oid): (
            ObjectModel.from_marker(by_marker[o["marker_id"]]),
            np.asarray(by_marker[o["marker_id"]].get("T_dock_marker", np.eye(4)), float),
        )
        for oid, o in objects.items()
    }
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = {}
    for name, frames in estimates.groupby("localizer", sort=True):
        rows = _rows(frames.reset_index(drop=True), scene_of, models)
        if rows:
            path = out_dir / results_filename(str(name), info.get("bop_name", "dockbench"), info["split"])
            path.write_text("\n".join([HEADER, *rows]) + "\n")
            written[str(name)] = path
    return written


def pooled_dock_ar(estimates: pd.DataFrame, markers: list[dict], camera: dict) -> dict[str, float]:
    """dockbench's ``AR_dock`` per localizer pooled over all counted in-view frames of the run
    (``evaluate``'s tables give it per trajectory), for a side-by-side with the BOP19 AR."""
    from evalkit.metrics import recall

    model = recall.DockModel.from_markers(markers, camera["K"], int(camera["width"]))
    out: dict[str, float] = {}
    if model is None:
        return out
    for name, frames in estimates.groupby("localizer", sort=True):
        e = recall.mssd_mspd(frames, model)
        t = (
            core.counted_mask(frames["d_true"], core.D_MAX_M) & frames["in_view"].fillna(False).astype(bool)
        ).to_numpy()
        if e["mssd_m"].notna().any():
            out[str(name)] = (
                recall.average_recall(e["mssd_m"].to_numpy()[t], model.mssd_thresholds())
                + recall.average_recall(e["mspd_px"].to_numpy()[t], model.mspd_thresholds())
            ) / 2
    return out
