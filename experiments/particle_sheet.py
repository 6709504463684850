"""Contact sheet of small obstacles: 600 / 6000 / 60000 in the pool at 8 / 5 / 2 m from the dock,
lamp off and on (docs/evidence/README.md). Rendered through the normal pipeline (fast fidelity)
from the occlusion paper config; one approach with one frame per view distance."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from blendgen.config.bundled import bundled_file

COUNTS = (600, 6000, 60000)
VIEWS = ((8.0, "8 m"), (5.0, "5 m"), (2.0, "2 m"))


def sheet_experiment(width: int, height: int, lamp: bool, mode: str | None = None, size_dist: str | None = None):
    """The occlusion paper config reduced to one straight approach with a frame at 8, 5, 2 m."""
    from blendgen.config.models import Condition, Lamp, load_experiment
    from blendgen.tools.apps.preview import preview_experiment

    exp = load_experiment(bundled_file("configs", "paper_occlusion.yaml"))
    pre = preview_experiment(width, height, 4, "fast", mode or exp.image_formation)
    exp.trajectories, exp.camera.fps = pre.trajectories, pre.camera.fps
    exp.camera.width, exp.camera.height = int(width), int(height)
    exp.image_formation = mode or exp.image_formation
    exp.trials = 1
    # the sheet's camera jumps 3 m per frame (30 m/s): a 1/3000 s exposure (responsivity x30,
    # same brightness) gives the particle streaks of a 1 m/s approach at the default 10 ms
    speed = pre.trajectories[0].speed_mps
    from blendgen.pipeline.plan import resolved_sensor

    sen = resolved_sensor(exp)
    exp.camera.sensor = sen.model_copy(
        update={"exposure_s": sen.exposure_s / speed, "responsivity_e_per_s": sen.responsivity_e_per_s * speed}
    )
    exp.vehicle.lamps = [Lamp(power_w=20.0, offset_m=[0.0, 0.2, 0.0], half_angle_deg=35.0)] if lamp else []
    conds = []
    for n in COUNTS:
        occ = exp.conditions[0].occlusion.model_copy(update={"n_total": float(n)})
        if size_dist is not None:
            occ = type(occ).model_validate({**occ.model_dump(exclude={"r_min_m", "r_max_m"}), "size_dist": size_dist})
        conds.append(Condition(label=f"n{n}", occlusion=occ))
    exp.conditions = conds
    exp.name = f"particles-{'lamp' if lamp else 'nolamp'}-{exp.image_formation}"
    return exp


def _tile(ds_path: Path, width: int, height: int) -> list[np.ndarray]:
    from evalkit.dataset import Dataset

    ds = Dataset.open(ds_path)
    frames = {s["condition"]: list(ds.iter_frames(s["id"])) for s in ds.sequences}
    return [[ds.load_image(frames[f"n{n}"][v]) for v in range(len(VIEWS))] for n in COUNTS]


def make_sheet(
    out: Path,
    width: int = 320,
    height: int = 240,
    mode: str | None = None,
    size_dist: str | None = None,
    work: Path | None = None,
) -> Path:
    """Rows 600/6000/60000; columns lamp off 8/5/2 m, lamp on 8/5/2 m. Writes ``out`` (JPG/PNG)."""
    import cv2

    from blendgen.pipeline.generate import generate

    work = work or out.with_suffix("")
    tiles = {}
    for lamp in (False, True):
        d = work / ("lamp" if lamp else "nolamp")
        shutil.rmtree(d, ignore_errors=True)
        generate(sheet_experiment(width, height, lamp, mode, size_dist), d, workers=1, progress=False)
        tiles[lamp] = _tile(d, width, height)
    head, font = 22, cv2.FONT_HERSHEY_SIMPLEX
    sheet = np.full((head + len(COUNTS) * height, 2 * len(VIEWS) * width, 3), 255, np.uint8)
    for k, lamp in enumerate((False, True)):
        for v, (_, label) in enumerate(VIEWS):
            x = (k * len(VIEWS) + v) * width
            cv2.putText(
                sheet, f"lamp {'on' if lamp else 'off'}, {label}", (x + 4, 15), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA
            )
            for i, n in enumerate(COUNTS):
                y = head + i * height
                sheet[y : y + height, x : x + width] = tiles[lamp][i][v]
                cv2.putText(sheet, f"N={n}", (x + 4, y + height - 6), font, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return out
