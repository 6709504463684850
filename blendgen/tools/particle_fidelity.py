"""Fast image-space particles vs real instanced spheres in the Blender render (issue 15).

Two datasets of the same seeded particle field (3000 particles, radii 1-3 cm, between the
camera and the dock), one drawn by the fast path (``geometry: image``, lit by
particle_optics) and one as smooth instanced spheres in the render (``geometry: blender``:
Blender lights them with the scene's sun, the fast path adds the ambient light field and the
water model), each with a particle-free twin condition. Both: physical image formation, no
sensor noise, a slow approach (streaks ~1 px), no lens (the reference has no depth of field),
``forward_fraction: 0`` (the reference spheres are diffuse), no lamp.

Per frame: coverage = share of pixels a particle changes by >= 3 DN (any channel) against the
twin; IoU of those masks; mean contrast = mean signed change (DN, mean of RGB) on the
reference spheres' pixels (object index); |delta| of the ground-truth visible fractions.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

CHANGE_DN = 3


def experiment(geometry: str, width: int, height: int):
    from blendgen.config.models import Experiment
    occ = {"n_total": 3000, "count_dist": "fixed", "size_dist": "uniform", "r_min_m": 0.01, "r_max_m": 0.03,
           "drift_sigma_m": 0.0, "geometry": geometry, "forward_fraction": 0.0,
           "region_min": [3.0, -1.0, -2.0], "region_max": [6.5, 1.0, 0.0]}
    return Experiment.model_validate({
        "name": f"pfid-{geometry}", "seed": 9, "scene": {"template": "pool_15x5x8"},
        "camera": {"width": width, "height": height, "hfov_deg": 60, "fps": 10,
                   "sensor": {"noise": False}},
        "render": {"samples": 4, "roi": False}, "water": {"preset": "mild"},
        "trajectories": [{"kind": "linear", "id": "lin", "start_range_m": 4.0, "end_range_m": 3.7,
                          "speed_mps": 0.5}],
        "conditions": [{"label": "none"}, {"label": "occ", "occlusion": occ}]})


def _frames(root: Path) -> dict:
    from evalkit.dataset import Dataset
    ds = Dataset.open(root)
    return ds, {s["condition"]: list(ds.iter_frames(s["id"])) for s in ds.sequences}


def compare(out: Path, width: int = 320, height: int = 240) -> list[dict]:
    """Render both datasets under ``out`` and return one row per frame (module doc)."""
    from datasets_spec.io import load_index
    from blendgen.pipeline.generate import generate
    from blendgen.pipeline.plan import INDEX_PARTICLES
    data = {}
    for g in ("image", "blender"):
        shutil.rmtree(out / g, ignore_errors=True)
        generate(experiment(g, width, height), out / g, workers=1, progress=False)
        data[g] = _frames(out / g)
    rows = []
    (dsi, fi), (dsb, fb) = data["image"], data["blender"]
    for k, (a0, a1, b0, b1) in enumerate(zip(fi["none"], fi["occ"], fb["none"], fb["occ"])):
        da = dsi.load_image(a1).astype(np.int16) - dsi.load_image(a0).astype(np.int16)
        db = dsb.load_image(b1).astype(np.int16) - dsb.load_image(b0).astype(np.int16)
        ma, mb = np.abs(da).max(axis=2) >= CHANGE_DN, np.abs(db).max(axis=2) >= CHANGE_DN
        spheres = load_index(out / "blender" / b1["object_index"]) == INDEX_PARTICLES
        vis = [abs(a1["markers"][m]["visible_fraction"] - b1["markers"][m]["visible_fraction"])
               for m in a1["markers"] if a1["markers"][m].get("in_fov")]
        rows.append({"frame": k, "coverage_fast": float(ma.mean()), "coverage_ref": float(mb.mean()),
                     "iou": float((ma & mb).sum() / max((ma | mb).sum(), 1)),
                     "contrast_fast_dn": float(da[spheres].mean()) if spheres.any() else float("nan"),
                     "contrast_ref_dn": float(db[spheres].mean()) if spheres.any() else float("nan"),
                     "max_visible_fraction_delta": float(max(vis, default=0.0))})
    return rows
