"""A small BOP export and results file whose BOP19 scores were computed once with the real BOP toolkit.

``write_fixture(dir)`` writes ``dir/dockbench`` (the BOP export of the fake dataset of
tests/test_bop.py: one plate marker, 12 images at 64 x 48 px, one truncated, one half
occluded, one hidden) and ``dir/results/pert_dockbench-test.csv`` (the GT poses perturbed by a
different, fixed amount per image; one target without an estimate). The toolkit's numbers for
them are pinned in tests/data/bop19_toolkit_scores.json with the command that made them.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

RESULTS_NAME = "pert_dockbench-test.csv"


def perturbed(scene_id: int, im_id: int, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The GT pose (R, t mm) moved by a fixed, image-dependent rotation (up to ~8 deg) and shift (up to ~60 mm)."""
    k = 1 + im_id + 6 * scene_id
    dR = cv2.Rodrigues(np.array([0.011 * k, -0.007 * k, 0.004 * k]))[0]
    return dR @ R, t + np.array([4.0 * k, -2.5 * k, 6.0 * (k % 5)])


def write_results(export: Path, out_csv: Path) -> None:
    """Perturbed GT poses of every target but the first as a BOP19 results CSV."""
    targets = json.loads((export / "test_targets_bop19.json").read_text())
    rows = ["scene_id,im_id,obj_id,score,R,t,time"]
    for tg in targets[1:]:
        s, i = tg["scene_id"], tg["im_id"]
        gt = json.loads((export / "test" / f"{s:06d}" / "scene_gt.json").read_text())[str(i)][0]
        R, t = perturbed(s, i, np.array(gt["cam_R_m2c"]).reshape(3, 3), np.array(gt["cam_t_m2c"]))
        rows.append(
            f"{s},{i},{tg['obj_id']},1,{' '.join(f'{v:.9g}' for v in R.ravel())},{' '.join(f'{v:.6f}' for v in t)},0.01"
        )
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    out_csv.write_text("\n".join(rows) + "\n")


def write_fixture(root: Path) -> tuple[Path, Path]:
    """``(export dir, results csv)`` under ``root``."""
    from fake_dataset import write_fake_dataset
    from test_bop import _enrich

    from evalkit.dataset import Dataset
    from evalkit.reports import bop

    export = root / "dockbench"
    bop.export_bop(Dataset.open(_enrich(write_fake_dataset(root / "ds"))), export, depth_scale=1.0)
    csv = root / "results" / RESULTS_NAME
    write_results(export, csv)
    return export, csv


if __name__ == "__main__":
    import sys

    print(*write_fixture(Path(sys.argv[1])))
