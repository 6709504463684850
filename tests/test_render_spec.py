"""The typed records that cross to the renderer (blendgen/render_spec.py): a job file keeps the
bytes it had as plain data, for every kind of scene the planner makes, and a wrong key is a
validation error when the record is made or read (before Blender starts)."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from pydantic import ValidationError

from blendgen.config.models import Experiment
from blendgen.pipeline import plan
from blendgen.render_spec import FramePlan, RenderScene, RenderSettings

LAMP = {"id": "lamp", "offset_m": [0.0, 0.3, 0.0], "pitch_deg": 5.0, "half_angle_deg": 30.0, "power_w": 20.0}
MARKERS = [
    {"kind": "led_array", "id": "led", "size_m": 0.6, "led_radius_m": 0.04},
    {"kind": "qr", "id": "qr", "size_m": 0.15, "payload": "DOCK-01", "center_m": [-0.12, 0.0]},
    {
        "kind": "aruco",
        "id": "aruco",
        "size_m": 0.12,
        "dictionary": "DICT_4X4_50",
        "marker_id": 7,
        "center_m": [0.14, 0.0],
    },
]
BASE = {
    "name": "r",
    "seed": 5,
    "camera": {"width": 64, "height": 48},
    "scene": {"dock": {"markers": MARKERS}},
    "trajectories": [{"kind": "linear", "id": "lin", "start_range_m": 4, "end_range_m": 2, "speed_mps": 4}],
}
CASES = {
    "fast_marker_rois": {},
    "fast_dock_roi_motion_blur_lamps": {
        "render": {"roi_regions": "dock"},
        "vehicle": {"lamps": [LAMP]},
        "camera": {"width": 64, "height": 48, "sensor": {"motion_blur": True}},
    },
    "reference_surface_caustics_water_lamps": {
        "render": {"fidelity": "reference"},
        "water": {"preset": "mild"},
        "vehicle": {"lamps": [LAMP]},
    },
    "reference_open_water_article": {
        "render": {"fidelity": "reference"},
        "image_formation": "article",
        "scene": {"kind": "open_water", "dock": {"markers": MARKERS}},
    },
    "blender_particles": {"conditions": [{"label": "occ", "occlusion": {"n_total": 60, "geometry": "blender"}}]},
}


def _plain_json(value) -> str:
    """The JSON the old untyped record wrote for a plain value (key order and int/float kept)."""
    return json.dumps(value)


def _record(cfg: dict) -> tuple[plan.RenderJob, list[dict], dict, plan.JobRecord]:
    exp = Experiment.model_validate({**copy.deepcopy(BASE), **cfg})
    markers = plan.manifest_markers(exp)
    job = plan.plan_jobs(exp, plan.scene_description(exp, markers, {}))[-1]
    render = plan.render_settings(exp, 2)
    rec = plan.JobRecord(
        scene=job.scene,
        fidelity=exp.render.fidelity,
        render=render,
        frames=job.frames,
        camera=plan.JobCamera(width=64, height=48, hfov_rad=1.0, K=np.eye(3).tolist()),
        gt=plan.JobTruth(T_world_dock=job.scene["dock"]["T_world_dock"], markers=markers),
        outputs=[plan.JobOutput(seq_dir="/x", rel="sequences/x", post=job.sequences[0].post)],
    )
    return job, markers, render, rec


@pytest.mark.parametrize("case", sorted(CASES))
def test_job_file_keeps_the_plain_data_bytes(case):
    job, markers, render, rec = _record(CASES[case])
    written = json.loads(rec.model_dump_json())
    assert _plain_json(written["scene"]) == _plain_json(job.scene)
    assert _plain_json(written["render"]) == _plain_json(render)
    assert _plain_json(written["frames"]) == _plain_json(job.frames)
    assert _plain_json(written["gt"]["markers"]) == _plain_json(markers)
    assert plan.JobRecord.model_validate_json(rec.model_dump_json()).model_dump_json() == rec.model_dump_json()


def test_the_cases_reach_every_optional_key():
    """The cases above are not vacuous: together they write every optional key of the records."""
    seen: set[str] = set()
    for cfg in CASES.values():
        job, _, render, _ = _record(cfg)
        seen |= {k for k, v in job.scene.items() if v} | set(render) | {k for f in job.frames for k in f}
    assert {"lamps", "water_volume", "led_lights", "water_surface", "particles", "sky"} <= seen
    assert {"normal_pass", "sun_pass", "roi", "rois", "blur_px"} <= seen


@pytest.mark.parametrize(
    "where, edit",
    [
        ("scene", lambda d: d["scene"].update(pool_size=1)),  # unknown key
        ("scene", lambda d: d["scene"]["sun"].update(strenght=3.0)),  # misspelt nested key
        ("scene", lambda d: d["scene"]["markers"][0].pop("keypoints")),  # missing key
        ("scene", lambda d: d["scene"]["markers"][0].update(kind="led")),  # unknown marker kind
        ("render", lambda d: d["render"].update(samples="many")),  # wrong type
        ("frames", lambda d: d["frames"][0].pop("T_world_cam")),
        ("gt", lambda d: d["gt"]["markers"][0].update(size=1)),
    ],
)
def test_a_wrong_key_is_a_validation_error(where, edit):
    _, _, _, rec = _record({})
    data = json.loads(rec.model_dump_json())
    edit(data)
    with pytest.raises(ValidationError, match=where):
        plan.JobRecord.model_validate(data)


def test_records_stand_alone():
    """The renderer's records validate their own plain data (the warm render server's init)."""
    job, _, render, _ = _record(CASES["reference_surface_caustics_water_lamps"])
    assert RenderScene.model_validate(job.scene).water_surface.caustics.renders >= 1
    assert RenderSettings.model_validate(render).volume_bounces == render["volume_bounces"]
    f = FramePlan.model_validate(job.frames[0])
    assert f.plain() == job.frames[0]
