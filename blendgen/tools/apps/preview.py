"""``dockbench preview``: contact sheet of the water presets at a glance.

Rows clear / mild / moderate; columns dock (light) depth 0 / 1 / 5 m, each as three
views of one approach: camera 8, 5 and 2 m from the dock. ``mode`` is the image
formation (``physical`` or ``article``). Rendered through the
normal pipeline (fast fidelity by default; ``--fidelity reference`` renders the
Cycles medium, one job per condition), labelled with OpenCV, written as one PNG.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from blendgen.config.bundled import bundled_file

WATERS = ("clear", "mild", "moderate")
DEPTHS = (0.0, 1.0, 5.0)
VIEWS = ((8.0, "8 m"), (5.0, "5 m"), (2.0, "2 m"))  # equally spaced: one frame each


def preview_experiment(width: int, height: int, samples: int, fidelity: str, mode: str = "physical"):
    """Quickstart pool, one approach with exactly one frame per view distance (camera to dock)."""
    from blendgen.config.models import Condition, Water, load_experiment

    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    traj = exp.trajectories[0]
    lead = exp.camera.T_body_cam.xyz[0]
    traj.start_range_m, traj.end_range_m = VIEWS[0][0] + lead, VIEWS[-1][0] + lead
    traj.speed_mps = (VIEWS[0][0] - VIEWS[1][0]) * exp.camera.fps
    exp.image_formation = mode
    exp.trajectories = [traj]
    exp.camera.width, exp.camera.height = int(width), int(height)
    exp.render.fidelity = fidelity
    exp.render.samples = exp.render.reference_samples = int(samples)
    exp.conditions = [
        Condition(label=f"{w}-d{d:g}", water=Water(preset=w), dock_water_depth_m=d) for w in WATERS for d in DEPTHS
    ]
    if mode == "physical":  # a depth condition lowers the surface over a dock at the deepest one
        exp.scene.dock.water_depth_m = max(DEPTHS)
    exp.name = f"preview-{mode}"
    return exp


def contact_sheet(ds_path: Path, width: int, height: int) -> np.ndarray:
    """(rows*H + header, cols*W, 3) uint8 RGB sheet of the rendered preview dataset."""
    import cv2

    from evalkit.dataset import Dataset

    ds = Dataset.open(ds_path)
    frames = {s["condition"]: list(ds.iter_frames(s["id"])) for s in ds.sequences}
    head = 22
    sheet = np.full((head + len(WATERS) * height, len(DEPTHS) * len(VIEWS) * width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for j, d in enumerate(DEPTHS):
        for v, (_, vlabel) in enumerate(VIEWS):
            x = (j * len(VIEWS) + v) * width
            cv2.putText(sheet, f"depth {d:g} m, {vlabel}", (x + 4, 15), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
            sheet[:, x : x + 1] = 255  # a white line between columns
    for i, w in enumerate(WATERS):
        for j, d in enumerate(DEPTHS):
            for v in range(len(VIEWS)):
                img = ds.load_image(frames[f"{w}-d{d:g}"][v])
                y, x = head + i * height, (j * len(VIEWS) + v) * width
                sheet[y : y + height, x : x + width] = img
                cv2.putText(sheet, w, (x + 4, y + height - 6), font, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return sheet


def make_preview(
    out_png: Path,
    width: int = 320,
    height: int = 240,
    samples: int = 4,
    fidelity: str = "fast",
    work: Path | None = None,
    mode: str = "physical",
) -> Path:
    import cv2

    from blendgen.pipeline.generate import generate

    work = work or out_png.with_suffix("")
    shutil.rmtree(work, ignore_errors=True)
    generate(preview_experiment(width, height, samples, fidelity, mode), work, workers=1, progress=False)
    sheet = contact_sheet(work, width, height)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_png), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    return out_png
