"""Fast image-space particles vs real instanced spheres in the Blender render (docs/particles.md).

Two datasets of the same seeded particle fields, one drawn by the fast path (``geometry:
image``, lit by particle_optics) and one as smooth instanced spheres in the Cycles render
(``geometry: blender``: Blender lights them with the scene's sun, the fast path adds the ambient
light field and the water model on top, as for every surface), each with a particle-free twin
condition ``none`` and one condition per particle count (``occ-<N>``: N particles in the pool,
15x5x8 m = 600 m^3, radii uniform in [5, 20] mm as in the article's occlusion experiment).
Both: physical image formation, no sensor noise, a short approach toward the dock, no lens
(the reference has no depth of field), ``forward_fraction: 0`` (the reference spheres are
diffuse), no lamp, no drift, the quickstart dock (LED array, QR, ArUco).

Per frame and count: coverage = share of pixels a particle changes by >= 3 DN (any channel)
against the twin; IoU of those masks; mean contrast = mean signed change (DN, mean of RGB) on
the reference spheres' pixels (object index); |delta| of the ground-truth visible fractions.
Per localizer and condition (:func:`localization`): P_succ and E_rel on each dataset and
their differences fast - reference. The water medium stays the fast model in both: this
compares the particles, not the Cycles volume.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

CHANGE_DN = 3
COUNTS = (6000, 60000)
D_START_M, D_END_M = 5.0, 1.0  # LED range down to where QR decodes at 320x240 (< 2 m)


def experiment(geometry: str, width: int, height: int, counts=COUNTS, frames: int = 8):
    """The pair's config: the quickstart pool and dock (LED array, QR, ArUco), mild water, ``none``
    plus ``occ-<N>`` for each count; one linear approach from D_START_M to D_END_M in ``frames`` frames."""
    from blendgen.config.bundled import bundled_file
    from blendgen.config.models import Condition, Occlusion, Water, load_experiment

    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    traj = exp.trajectories[0]
    lead = exp.camera.T_body_cam.xyz[0]  # the camera sits ahead of the body: d_true = range - lead
    traj.start_range_m, traj.end_range_m, traj.speed_mps = D_START_M + lead, D_END_M + lead, 0.5
    exp.trajectories = [traj]
    exp.camera.fps = max(frames - 1, 1) * traj.speed_mps / (D_START_M - D_END_M)
    exp.camera.width, exp.camera.height = int(width), int(height)
    exp.camera.sensor.noise = False
    exp.render.samples = 4
    exp.scene.world.caustics = False
    exp.water = Water(preset="mild")
    occ = {
        "count_dist": "fixed",
        "size_dist": "uniform",
        "r_min_m": 0.005,
        "r_max_m": 0.02,
        "drift_sigma_m": 0.0,
        "geometry": geometry,
        "forward_fraction": 0.0,
    }
    exp.conditions = [Condition(label="none")] + [
        Condition(label=f"occ-{n}", occlusion=Occlusion(n_total=n, **occ)) for n in counts
    ]
    exp.name = f"pfid-{geometry}"
    return exp


def _frames(root: Path):
    from evalkit.dataset import Dataset

    ds = Dataset.open(root)
    return ds, {s["condition"]: list(ds.iter_frames(s["id"])) for s in ds.sequences}


def _frame_row(out: Path, dsi, dsb, cond: str, k: int, a0, a1, b0, b1) -> dict:
    from blendgen.pipeline.plan import INDEX_PARTICLES
    from datasets_spec.io import load_index

    da = dsi.load_image(a1).astype(np.int16) - dsi.load_image(a0).astype(np.int16)
    db = dsb.load_image(b1).astype(np.int16) - dsb.load_image(b0).astype(np.int16)
    ma, mb = np.abs(da).max(axis=2) >= CHANGE_DN, np.abs(db).max(axis=2) >= CHANGE_DN
    spheres = load_index(out / "blender" / b1["object_index"]) == INDEX_PARTICLES
    vis = [
        abs(a1["markers"][m]["visible_fraction"] - b1["markers"][m]["visible_fraction"])
        for m in a1["markers"]
        if a1["markers"][m].get("in_fov")
    ]
    return {
        "condition": cond,
        "frame": k,
        "coverage_fast": float(ma.mean()),
        "coverage_ref": float(mb.mean()),
        "iou": float((ma & mb).sum() / max((ma | mb).sum(), 1)),
        "contrast_fast_dn": float(da[spheres].mean()) if spheres.any() else float("nan"),
        "contrast_ref_dn": float(db[spheres].mean()) if spheres.any() else float("nan"),
        "max_visible_fraction_delta": float(max(vis, default=0.0)),
    }


def localization(out: Path) -> pd.DataFrame:
    """Per (localizer, condition): P_succ and E_rel (evalkit's e_rel_mean: mean relative range
    error of the detected frames) on the fast and the reference dataset, and fast - reference."""
    from blendgen.tools.bench.fidelity import localization as loc

    fast, ref = loc(out / "image"), loc(out / "blender")
    table = fast.join(ref, lsuffix="_fast", rsuffix="_ref")
    table["dP_succ"] = table["P_succ_fast"] - table["P_succ_ref"]
    table["dE_rel"] = table["e_rel_mean_fast"] - table["e_rel_mean_ref"]
    return table.reset_index()


def compare(
    out: Path, width: int = 320, height: int = 240, counts=COUNTS, frames: int = 8, render: bool = True
) -> tuple[list[dict], pd.DataFrame]:
    """Render both datasets under ``out`` (unless ``render`` is False and they exist) and return
    (one row per occ condition and frame, the localization table) (module doc)."""
    from blendgen.pipeline.generate import generate

    if render:
        for g in ("image", "blender"):
            shutil.rmtree(out / g, ignore_errors=True)
            generate(experiment(g, width, height, counts, frames), out / g, workers=1, progress=False)
    (dsi, fi), (dsb, fb) = _frames(out / "image"), _frames(out / "blender")
    rows = []
    for cond in (f"occ-{n}" for n in counts):
        for k, (a0, a1, b0, b1) in enumerate(zip(fi["none"], fi[cond], fb["none"], fb[cond])):
            rows.append(_frame_row(out, dsi, dsb, cond, k, a0, a1, b0, b1))
    return rows, localization(out)
