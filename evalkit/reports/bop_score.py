"""The BOP Challenge 2019 average recall of a results CSV on a dockbench BOP export (no toolkit needed).

Definitions (Hodan et al., "BOP Challenge 2020 on 6D object localization", ECCVW 2020, sect. 2;
re-derived here, the BOP toolkit's ``eval_bop19_pose.py`` computes the same):

* every marker is its own object, scored on the export's ``test_targets_bop19.json`` targets
  (instances with ``visib_fract >= 0.1``); per target only the estimate with the highest
  score counts (``inst_count`` = 1), a target without one is a miss;
* **VSD** (delta 15 mm, step cost, taus 0.05..0.5 x the diameter): the model's depth is
  rendered in the GT and the estimated pose over the image (the toolkit renders ``models_eval``;
  its surface is that of ``models``, which renders the same depth from far fewer triangles), in
  the toolkit's pixel convention (:data:`evalkit.reports.bop_raster.TOOLKIT_SAMPLE_OFFSET`); visible masks by the
  BOP19 depth
  test against the test depth (the estimate's mask also takes the GT-visible pixels it
  covers); ``e = (#{inter: |d_gt - d_est| >= tau} + #(union - inter)) / #union`` (1 for an
  empty union);
* **MSSD** = max vertex distance (mm) over ``models_eval``, thresholds 0.05..0.5 x diameter;
* **MSPD** = max projected vertex distance (px) x 640 / image width, thresholds 5..50;
* a target is recalled at a threshold when the error is strictly below it; AR_VSD is the mean
  recall over the 10 taus x 10 thresholds, AR_MSSD and AR_MSPD over their 10 thresholds, all
  pooled over every target of every object; **AR_BOP19 = (AR_VSD + AR_MSSD + AR_MSPD) / 3**.

This is not dockbench's ``AR_dock`` (:mod:`evalkit.metrics.recall`: the whole dock as one object,
MSSD and MSPD only, per trajectory).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evalkit.reports.bop_gtinfo import (
    ImageView,
    crop_to_image,
    render_model_dist,
    visible_mask,
)
from evalkit.reports.bop_raster import TOOLKIT_SAMPLE_OFFSET

VSD_DELTA_MM = 15.0  # eval_bop19_pose.py: vsd_deltas (15 mm but ITODD)
VSD_TAUS = np.arange(0.05, 0.51, 0.05)  # x diameter (eval_bop19_pose.py: vsd_taus)
VSD_THS = np.arange(0.05, 0.51, 0.05)  # correct_th of vsd
MSSD_THS = np.arange(0.05, 0.51, 0.05)  # x diameter
MSPD_THS = np.arange(5, 51, 5)  # px at 640 px image width


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (N, 3), faces (F, 3))`` of an ASCII PLY as export-bop writes it."""
    lines = Path(path).read_text().splitlines()
    nv = int(next(x for x in lines if x.startswith("element vertex")).split()[-1])
    start = lines.index("end_header") + 1
    v = np.array([[float(c) for c in x.split()[:3]] for x in lines[start : start + nv]])
    f = np.array([[int(c) for c in x.split()[1:4]] for x in lines[start + nv :] if x.strip()])
    return v, f


def read_results(path: Path) -> dict[tuple[int, int, int], list[tuple[float, np.ndarray, np.ndarray]]]:
    """``(scene_id, im_id, obj_id) -> [(score, R (3, 3), t (3,) mm)]`` of a BOP19 results CSV."""
    out: dict = {}
    for line in Path(path).read_text().splitlines()[1:]:
        if not line.strip():
            continue
        s, i, o, score, R, t, _ = line.split(",")
        out.setdefault((int(s), int(i), int(o)), []).append(
            (float(score), np.array(R.split(), float).reshape(3, 3), np.array(t.split(), float))
        )
    return out


def vsd(mesh, R_est, t_est, R_gt, t_gt, view: ImageView, diameter: float) -> np.ndarray:
    """VSD errors for :data:`VSD_TAUS` (step cost, distances normalised by ``diameter``)."""

    def dist(R, t):
        patch, win = render_model_dist(*mesh, R, t, view, enlarged=False, sample_offset=TOOLKIT_SAMPLE_OFFSET)
        return crop_to_image(patch, win, view.width, view.height)

    d_gt, d_est = dist(R_gt, t_gt), dist(R_est, t_est)
    test = view.dist_mm if view.dist_mm is not None else np.zeros_like(d_gt)
    v_gt = visible_mask(test, d_gt, VSD_DELTA_MM)
    v_est = visible_mask(test, d_est, VSD_DELTA_MM) | (v_gt & (d_est > 0))
    inter, union = v_gt & v_est, v_gt | v_est
    n_union = int(union.sum())
    if n_union == 0:
        return np.ones(len(VSD_TAUS))
    d = np.abs(d_gt[inter] - d_est[inter]) / diameter
    n_comp = n_union - int(inter.sum())
    return np.array([((d >= tau).sum() + n_comp) / n_union for tau in VSD_TAUS])


def pose_errors(pts: np.ndarray, K: np.ndarray, R_est, t_est, R_gt, t_gt) -> tuple[float, float]:
    """``(MSSD mm, MSPD px)`` over the model points ``pts`` (N, 3) mm."""
    pe, pg = pts @ R_est.T + t_est, pts @ R_gt.T + t_gt
    mssd = float(np.linalg.norm(pe - pg, axis=1).max())
    ue, ug = pe @ K.T, pg @ K.T
    mspd = float(np.linalg.norm(ue[:, :2] / ue[:, 2:] - ug[:, :2] / ug[:, 2:], axis=1).max())
    return mssd, mspd


@dataclass
class _Export:
    root: Path
    split: str
    width: int
    height: int
    meshes: dict  # obj_id -> (vertices, faces) of models/ (the surface VSD renders)
    points: dict  # obj_id -> vertices of models_eval/ (MSSD, MSPD)
    diameters: dict

    @classmethod
    def open(cls, root: Path) -> _Export:
        root = Path(root)
        info = json.loads((root / "dockbench_scenes.json").read_text())
        cam = json.loads((root / "camera.json").read_text())
        models = json.loads((root / "models_eval" / "models_info.json").read_text())
        meshes = {int(o): read_ply(root / "models" / f"obj_{int(o):06d}.ply") for o in models}
        points = {int(o): read_ply(root / "models_eval" / f"obj_{int(o):06d}.ply")[0] for o in models}
        return cls(
            root,
            info["split"],
            int(cam["width"]),
            int(cam["height"]),
            meshes,
            points,
            {int(o): float(m["diameter"]) for o, m in models.items()},
        )

    def scene(self, scene_id: int) -> tuple[dict, dict]:
        d = self.root / self.split / f"{scene_id:06d}"
        return (json.loads((d / "scene_gt.json").read_text()), json.loads((d / "scene_camera.json").read_text()))

    def view(self, scene_id: int, im_id: int, cam: dict) -> ImageView:
        import cv2

        p = self.root / self.split / f"{scene_id:06d}" / "depth" / f"{im_id:06d}.png"
        depth = cv2.imread(str(p), cv2.IMREAD_UNCHANGED) if p.is_file() else None
        K = np.array(cam["cam_K"], float).reshape(3, 3)
        return ImageView.from_depth_png(K, self.width, self.height, depth, float(cam.get("depth_scale", 1.0)))


def target_errors(export_dir: Path, results_csv: Path, tick=None) -> list[dict]:
    """Per target: ``{scene_id, im_id, obj_id, vsd (10,) | None, mssd, mspd}`` (errors None = no estimate);
    ``tick(1)`` after each target when given."""
    ex = _Export.open(export_dir)
    targets = json.loads((Path(export_dir) / "test_targets_bop19.json").read_text())
    ests, rows, cache = read_results(results_csv), [], {}
    for t in targets:
        if tick is not None:
            tick(1)
        s, i, o = int(t["scene_id"]), int(t["im_id"]), int(t["obj_id"])
        row: dict[str, Any] = {"scene_id": s, "im_id": i, "obj_id": o, "vsd": None, "mssd": None, "mspd": None}
        rows.append(row)
        cand = ests.get((s, i, o))
        if not cand:
            continue
        if s not in cache:
            cache[s] = ex.scene(s)
        scene_gt, scene_cam = cache[s]
        gt = next(g for g in scene_gt[str(i)] if int(g["obj_id"]) == o)
        R_gt, t_gt = np.array(gt["cam_R_m2c"], float).reshape(3, 3), np.array(gt["cam_t_m2c"], float)
        _, R_est, t_est = max(cand, key=lambda c: c[0])
        view = ex.view(s, i, scene_cam[str(i)])
        row["mssd"], row["mspd"] = pose_errors(ex.points[o], view.K, R_est, t_est, R_gt, t_gt)
        row["mspd"] *= 640.0 / ex.width
        row["mssd"] /= ex.diameters[o]
        row["vsd"] = vsd(ex.meshes[o], R_est, t_est, R_gt, t_gt, view, ex.diameters[o])
    return rows


def bop19_scores(export_dir: Path, results_csv: Path, progress: bool = False) -> dict:
    """``{AR_BOP19, AR_VSD, AR_MSSD, AR_MSPD, n_targets}`` of one results file (NaN ARs without targets);
    ``progress``: a progress bar over the targets on stderr."""
    from evalkit.runner import progress_bar

    n = len(json.loads((Path(export_dir) / "test_targets_bop19.json").read_text()))
    with progress_bar(n, progress, f"BOP19 scores of {Path(results_csv).name}: targets") as tick:
        rows = target_errors(export_dir, results_csv, tick)
    n = len(rows)
    if not n:
        nan = float("nan")
        return {"AR_BOP19": nan, "AR_VSD": nan, "AR_MSSD": nan, "AR_MSPD": nan, "n_targets": 0}
    inf = np.inf
    vsd_e = np.array([r["vsd"] if r["vsd"] is not None else np.full(len(VSD_TAUS), inf) for r in rows])
    mssd = np.array([r["mssd"] if r["mssd"] is not None else inf for r in rows])
    mspd = np.array([r["mspd"] if r["mspd"] is not None else inf for r in rows])
    ar_vsd = float(np.mean([(vsd_e[:, k] < th).mean() for k in range(len(VSD_TAUS)) for th in VSD_THS]))
    ar_mssd = float(np.mean([(mssd < th).mean() for th in MSSD_THS]))
    ar_mspd = float(np.mean([(mspd < th).mean() for th in MSPD_THS]))
    return {
        "AR_BOP19": (ar_vsd + ar_mssd + ar_mspd) / 3.0,
        "AR_VSD": ar_vsd,
        "AR_MSSD": ar_mssd,
        "AR_MSPD": ar_mspd,
        "n_targets": n,
    }
