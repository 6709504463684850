"""Every shipped config plans its full paths (not the golden datasets' 3-frame cut), in both image
formation modes: the scene checks that refuse a config (a camera outside the water, a path into the
dock) run on every simulated docking trial, so a config whose own trials break them is caught here,
before anyone renders it."""

import copy
from pathlib import Path

import pytest
import yaml

from blendgen.config.models import Experiment
from blendgen.pipeline import plan
from tests import golden_datasets as gd

ROOT = Path(__file__).parents[1]
CONFIGS = {
    **{p.stem: yaml.safe_load(p.read_text()) for p in sorted((ROOT / "configs").glob("*.yaml"))},
    **{f"template_{p.stem}": gd.template_config(p.stem) for p in sorted((ROOT / "templates").glob("*.yaml"))},
}
DATASET_CONFIGS = sorted(k for k, cfg in CONFIGS.items() if "trajectories" in cfg)  # not calibration.yaml
TRIALS = 3


@pytest.mark.parametrize("mode", ["article", "physical"])
@pytest.mark.parametrize("name", DATASET_CONFIGS)
def test_a_shipped_config_plans_its_first_trials(name, mode):
    cfg = copy.deepcopy(CONFIGS[name])
    cfg["trials"] = min(int(cfg.get("trials", 1)), TRIALS)
    cfg["image_formation"] = mode
    exp = Experiment.model_validate(cfg)
    jobs = plan.plan_jobs(exp, plan.scene_description(exp, plan.manifest_markers(exp), {}))
    planned = {(s.trajectory, s.trial, s.condition) for j in jobs for s in j.sequences}
    assert len(planned) == len(exp.trajectories) * exp.trials * max(len(exp.conditions), 1)
    assert all(j.frames for j in jobs)
