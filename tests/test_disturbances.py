"""Disturbances in rendered datasets: particles, fixed obstacles, current."""

import json

import numpy as np
import pytest
import yaml

from blendgen.config.models import load_experiment
from blendgen.pipeline.generate import generate

pytestmark = pytest.mark.blender

CFG = {
    "name": "dist",
    "seed": 4,
    "scene": {
        "template": "pool_15x5x8",
        # 0.2 m above the dock's face centre (z = -1.5 m: its top, 0.5 m above the centre, at 1 m depth)
        "obstacles": [{"kind": "box", "pose": {"xyz": [6.2, 0.2, -1.3]}, "size_m": [0.1, 0.1, 0.1]}],
    },
    "camera": {"width": 160, "height": 120, "hfov_deg": 60, "fps": 10},
    "render": {"samples": 1},
    "trajectories": [{"kind": "linear", "id": "lin", "start_range_m": 3.0, "end_range_m": 2.0, "speed_mps": 2.0}],
    "conditions": [
        {"label": "clear"},
        {"label": "occ", "occlusion": {"n_total": 200000, "r_min_m": 0.01, "r_max_m": 0.03}},
    ],
}


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    d = tmp_path_factory.mktemp("dist")
    (d / "c.yaml").write_text(yaml.safe_dump(CFG))
    man = generate(load_experiment(d / "c.yaml"), d / "ds", workers=1, progress=False)
    return d / "ds", man


def frames(root, seq):
    return [json.loads(l) for l in (root / "sequences" / seq / "frames.jsonl").read_text().splitlines()]


def test_one_render_feeds_both_conditions(ds):
    root, man = ds
    assert len(list((root / ".work" / "jobs").glob("*.json"))) == 1
    assert {s["id"] for s in man["sequences"]} == {"lin-t000-clear", "lin-t000-occ"}


def test_particles_hide_markers_only_in_the_occluded_condition(ds):
    root, _ = ds
    clear, occ = frames(root, "lin-t000-clear"), frames(root, "lin-t000-occ")
    vis = lambda fs: np.mean([f["markers"]["aruco"]["visible_fraction"] for f in fs])  # noqa: E731
    assert vis(occ) < vis(clear) - 0.02
    for a, b in zip(clear, occ):  # poses are shared: only the image-space condition differs
        assert a["T_cam_dock"] == b["T_cam_dock"] and a["d_true"] == b["d_true"]


def test_fixed_obstacle_is_rendered_with_its_index(ds):
    root, man = ds
    import cv2

    names = {v: int(k) for k, v in man["object_index"].items()}
    f = frames(root, "lin-t000-clear")[0]
    index = cv2.imread(str(root / f["object_index"]), cv2.IMREAD_UNCHANGED)
    assert (index == names["obstacle_0"]).sum() > 20
    # the box sits on the sight line from the first camera pose to the top-left LED
    assert f["markers"]["led"]["visible_fraction"] <= 0.75
