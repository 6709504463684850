"""Planning: what is rendered once and shared, what gets its own render."""

import copy

import numpy as np
import pytest

from blendgen.config.models import Experiment
from blendgen.pipeline import plan

BASE = {
    "name": "p",
    "seed": 11,
    "scene": {"dock": {"markers": [{"kind": "led_array"}]}},
    "trajectories": [{"kind": "linear", "id": "lin", "start_range_m": 3, "end_range_m": 1, "speed_mps": 2}],
}


def jobs_for(cfg):
    exp = Experiment.model_validate(cfg)
    markers = plan.manifest_markers(exp)
    return exp, plan.plan_jobs(exp, plan.scene_description(exp, markers, {}))


def test_image_space_conditions_and_kinematic_trials_share_one_render():
    cfg = copy.deepcopy(BASE)
    cfg["trials"] = 3
    cfg["conditions"] = [
        {"label": "clear"},
        {"label": "mild", "water": {"preset": "mild"}},
        {"label": "deep", "dock_water_depth_m": 5},
        {"label": "occ", "occlusion": {"n_total": 6000}},
    ]
    exp, jobs = jobs_for(cfg)
    assert len(jobs) == 1 and len(jobs[0].sequences) == 12
    seeds = {s.post.seed for s in jobs[0].sequences}
    assert len(seeds) == 3  # one random stream per trial, shared by its conditions (paired comparisons)


def test_docking_trials_render_once_per_trial_and_per_fluid():
    cfg = copy.deepcopy(BASE)
    cfg["trajectories"] = [{"kind": "docking", "id": "d", "start": {"range_m": [2.0, 2.5]}, "max_time_s": 6}]
    cfg["trials"] = 2
    cfg["conditions"] = [
        {"label": "c0"},
        {"label": "occ", "occlusion": {"n_total": 600}},
        {"label": "cur", "fluid": {"current_mps": [0, 0.5, 0]}},
    ]
    exp, jobs = jobs_for(cfg)
    assert len(jobs) == 4  # (2 trials) x (still water, current)
    by_label = {tuple(sorted(s.condition for s in j.sequences)) for j in jobs}
    assert by_label == {("c0", "occ"), ("cur",)}
    starts = {tuple(np.round(j.frames[0]["T_world_cam"][0], 6)) for j in jobs}
    assert len(starts) >= 2  # different trials start from different random positions


def test_reference_fidelity_renders_each_water_and_skips_clear_volume():
    from blendgen.physics.water import optics

    cfg = copy.deepcopy(BASE)
    cfg["image_formation"] = "article"
    cfg["render"] = {"fidelity": "reference"}
    cfg["conditions"] = [{"label": "clear"}, {"label": "mild", "water": {"preset": "mild"}}]
    _, jobs = jobs_for(cfg)
    assert {j.sequences[0].condition: j.scene["water_volume"] for j in jobs}["clear"] is None  # no water
    cfg = copy.deepcopy(BASE)
    cfg["render"] = {"fidelity": "reference"}
    cfg["conditions"] = [{"label": "clear"}, {"label": "mild", "water": {"preset": "mild"}}]
    _, jobs = jobs_for(cfg)
    vols = {j.sequences[0].condition: j.scene["water_volume"] for j in jobs}
    assert vols["clear"]["sigma_a"] == pytest.approx(optics.get_preset("jerlov_I").sigma_a.tolist())  # physical
    assert vols["mild"]["box_max"][2] == pytest.approx(0.0)


def test_occlusion_region_defaults_to_the_600_m3_pool():
    cfg = copy.deepcopy(BASE)
    cfg["occlusion"] = {"n_total": 600}
    exp, jobs = jobs_for(cfg)
    occ = jobs[0].sequences[0].post.occlusion.model_dump()
    vol = np.prod(np.subtract(occ["region_max"], occ["region_min"]))
    assert vol == pytest.approx(600.0)


def test_frames_beyond_the_evaluation_window_are_not_rendered():
    cfg = copy.deepcopy(BASE)
    cfg["trajectories"] = [{"kind": "linear", "id": "lin", "start_range_m": 14, "end_range_m": 8, "speed_mps": 1}]
    cfg["camera"] = {"fps": 10, "T_body_cam": {"xyz": [0, 0, 0]}}
    _, jobs = jobs_for(cfg)
    idx = [f["index"] for f in jobs[0].frames]
    assert idx[0] == 40 and idx[-1] == 60  # 14 m -> 10 m at 1 m/s is 4 s = 40 frames skipped
    assert jobs[0].frames[0]["t"] == pytest.approx(4.0)
    cfg["render"] = {"max_distance_m": None}
    _, jobs = jobs_for(cfg)
    assert [f["index"] for f in jobs[0].frames] == list(range(61))


def test_no_frame_from_inside_the_dock():
    """A kinematic approach through the marker plane is a config error naming the fix; a docking
    trial ends at contact: every frame keeps the camera in front of the face (d_true > 0 is exact)."""
    from blendgen.config.models import ConfigError

    cfg = copy.deepcopy(BASE)
    cfg["trajectories"] = [{"kind": "linear", "id": "lin", "start_range_m": 3, "end_range_m": 0.5, "speed_mps": 2}]
    with pytest.raises(ConfigError, match=r"'lin'.*end_range_m must be >= 0.70"):
        jobs_for(cfg)
    cfg["trajectories"] = [{"kind": "docking", "id": "d", "start": {"range_m": [2.0, 2.5]}, "max_time_s": 20}]
    exp, jobs = jobs_for(cfg)
    T_wd = np.asarray(jobs[0].scene["dock"]["T_world_dock"])
    z = [(np.linalg.inv(T_wd) @ np.asarray(f["T_world_cam"])[:, 3])[2] for f in jobs[0].frames]
    assert min(z) >= plan.MIN_CLEARANCE_M and len(z) > 5


def test_job_record_is_typed_versioned_and_round_trips():
    """The worker's job file: written by generate, parsed once by the worker; a record of
    another version or with unknown keys is refused."""
    from pydantic import ValidationError

    exp, jobs = jobs_for(copy.deepcopy(BASE))
    post = jobs[0].sequences[0].post
    rec = plan.JobRecord(
        scene=jobs[0].scene,
        fidelity="fast",
        render=plan.render_settings(exp, 1),
        frames=jobs[0].frames,
        camera=plan.JobCamera(width=64, height=48, hfov_rad=1.0, K=np.eye(3).tolist()),
        gt=plan.JobTruth(T_world_dock=np.eye(4).tolist(), markers=[]),
        outputs=[plan.JobOutput(seq_dir="/data/x", rel="sequences/x", post=post)],
    )
    back = plan.JobRecord.model_validate_json(rec.model_dump_json())
    assert back.model_dump_json() == rec.model_dump_json() and back.version == plan.JOB_RECORD_VERSION
    assert back.outputs[0].post.water.preset == post.water.preset
    data = rec.model_dump(mode="json")
    with pytest.raises(ValidationError):
        plan.JobRecord.model_validate({**data, "version": 2})
    with pytest.raises(ValidationError):
        plan.JobRecord.model_validate({**data, "extra": 1})


def test_a_path_into_the_dock_fails_before_anything_is_written(tmp_path):
    from blendgen.config.models import ConfigError
    from blendgen.pipeline.generate import generate

    cfg = copy.deepcopy(BASE)
    cfg["trajectories"] = [{"kind": "linear", "id": "lin", "start_range_m": 3, "end_range_m": 0.5, "speed_mps": 2}]
    with pytest.raises(ConfigError, match="marker plane"):
        generate(Experiment.model_validate(cfg), tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_a_current_that_carries_the_hull_into_a_wall_ends_the_trial_there():
    """The article's current experiment: at 1.0 m/s across the approach the thrusters cannot hold
    the line, the hull reaches the pool's side wall and the trial ends there (the closed loop's
    ``collision``), instead of the camera leaving the pool or the experiment being refused."""
    from pathlib import Path

    import yaml

    from blendgen.pipeline import scene_check
    from blendgen.vehicle.contact import Hull, water_contact
    from blendgen.vehicle.dynamics import VehicleParams

    cfg = yaml.safe_load((Path(__file__).parents[1] / "configs" / "paper_current.yaml").read_text())
    cfg["trials"] = 1
    exp, jobs = jobs_for(cfg)
    T_bc = np.linalg.inv(plan.tj.T_body_cam_from_spec(exp.camera.T_body_cam))
    water, p = scene_check.water_solid(exp), VehicleParams()
    hull = Hull.from_vehicle(p.length, p.diameter)
    ends = {}
    for job in jobs:
        (label,) = {s.condition for s in job.sequences}  # each current its own path
        clear = [water_contact(water, hull, np.asarray(f["T_world_cam"]) @ T_bc).clearance_m for f in job.frames]
        assert min(clear) > 0, label  # no rendered frame has the hull in a wall
        ends[label] = job.frames[-1]["t"]
    # the strong current's trial ends at the wall, seconds before the others reach the dock
    assert ends["current_1.0"] < 0.5 * min(ends["current_0.0"], ends["current_0.5"])
    last = np.asarray(next(j for j in jobs if j.sequences[0].condition == "current_1.0").frames[-1]["T_world_cam"])
    assert water_contact(water, hull, last @ T_bc).part == "pool_wall"
    assert water_contact(water, hull, last @ T_bc).clearance_m < 0.1  # one frame (0.1 s) from the touch
    # the manifest says how each path ended (sequences[].end)
    assert {j.sequences[0].condition: j.end for j in jobs} == {
        "current_0.0": "dock",
        "current_0.5": "dock",
        "current_1.0": "pool_wall",
    }


def test_a_trial_whose_hull_touches_a_wall_at_its_first_frame_is_refused_by_its_start():
    """No frame because the hull starts in a wall: the error names the start and the wall, not
    ``render.max_distance_m`` (which would send the user to the wrong setting)."""
    from pathlib import Path

    import yaml

    from blendgen.config.models import ConfigError
    from blendgen.pipeline import scene_check

    cfg = yaml.safe_load((Path(__file__).parents[1] / "configs" / "paper_current.yaml").read_text())
    exp, _ = jobs_for({**cfg, "trials": 1})
    with pytest.raises(ConfigError, match=r"trajectories\[0\]\.start: 'dock' trial 3 starts with .* pool wall"):
        scene_check.check_frames(exp, 0, 3, [], "pool_wall")
    with pytest.raises(ConfigError, match=r"render\.max_distance_m"):
        scene_check.check_frames(exp, 0, 3, [], "path")
