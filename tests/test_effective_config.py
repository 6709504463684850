"""Mode-dependent defaults are resolved once (blendgen/config/effective.py): the effective config has
no such null left, keeps what the config gives, is what the planner reads, is what
``dockbench generate --show-config`` prints, and an old dataset without it stays valid."""

from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

import cli
from blendgen.config import effective as eff
from blendgen.config.models import Experiment
from blendgen.pipeline import plan

CFG = {
    "name": "e",
    "seed": 9,
    "scene": {"dock": {"markers": [{"kind": "led_array"}]}},
    "trajectories": [{"kind": "linear", "id": "lin", "start_range_m": 3, "end_range_m": 1, "speed_mps": 2}],
}
# The documented defaults (config field descriptions): physical mode turns the complete world on,
# article mode keeps the article's flat world; one camera (noise, blooming, the beacon exposure) in
# both; the light tree follows the fidelity; seeds the experiment's.
EXPOSURE_S = 0.9 * 10500.0 / (2.23e6 * 0.1 * 1.0 / (3.141592653589793 * 0.04**2))  # 0.9 full well, brightest LED
PHYSICAL = {
    "scene.sky_fraction": 0.25,
    "scene.ambient": True,
    "scene.world.surface": True,
    "scene.world.caustics": True,
    "scene.world.textures": True,
    "scene.world.sun_glint": True,
    "camera.sensor.noise": True,
    "camera.sensor.bloom_fraction": 0.05,
    "render.light_tree": False,
    "scene.world.wave_seed": 9,
    "scene.world.texture_seed": 9,
    "camera.sensor.exposure_s": EXPOSURE_S,
}
ARTICLE = {
    **PHYSICAL,
    "scene.sky_fraction": 0.0,
    "scene.ambient": False,
    "scene.world.surface": False,
    "scene.world.caustics": False,
    "scene.world.textures": False,
    "scene.world.sun_glint": False,
}


def _exp(**over) -> Experiment:
    cfg = copy.deepcopy(CFG)
    for k, v in over.items():
        cfg[k] = v
    return Experiment.model_validate(cfg)


def _get(exp, path):
    for name in path.split("."):
        exp = getattr(exp, name)
    return exp


@pytest.mark.parametrize("mode, expected", [("physical", PHYSICAL), ("article", ARTICLE)])
def test_nulls_resolve_to_the_documented_defaults(mode, expected):
    exp = _exp(image_formation=mode)
    assert all(_get(exp, p) is None for p in expected)  # the config leaves them null
    e = eff.effective(exp)
    assert {p: _get(e, p) for p in expected} == pytest.approx(expected)
    assert set(expected) == (
        set(eff.MODE_DEFAULTS) | set(eff.FIDELITY_DEFAULTS) | set(eff.SEED_DEFAULTS) | set(eff.DERIVED_DEFAULTS)
    )
    assert eff.effective(e) == e  # idempotent
    assert {p: eff.value(exp, p) for p in expected} == pytest.approx(expected)  # the planner's reader agrees


def test_reference_fidelity_turns_the_light_tree_on_and_given_values_are_kept():
    exp = _exp(
        image_formation="article",
        render={"fidelity": "reference"},
        scene={**CFG["scene"], "ambient": True, "world": {"wave_seed": 3}},
        camera={"sensor": {"noise": True, "bloom_fraction": 0.2}},
    )
    e = eff.effective(exp)
    assert e.render.light_tree is True
    assert (e.scene.ambient, e.scene.world.wave_seed, e.camera.sensor.noise, e.camera.sensor.bloom_fraction) == (
        True,
        3,
        True,
        0.2,
    )
    assert e.scene.world.surface is False  # still the article's default


@pytest.mark.parametrize("mode", ["physical", "article"])
def test_the_planner_reads_the_effective_values(mode):
    exp = _exp(image_formation=mode)
    e = eff.effective(exp)
    post = plan.condition_post(exp, exp.conditions[0], 1)
    assert post.sensor.noise is e.camera.sensor.noise and post.sensor.bloom_fraction == e.camera.sensor.bloom_fraction
    assert plan.render_settings(exp, 1)["light_tree"] is e.render.light_tree
    assert plan.ambient_on(exp) is e.scene.ambient and plan.sky_fraction(exp) == e.scene.sky_fraction
    assert [plan.world_on(exp, w) for w in ("surface", "caustics", "textures", "sun_glint")] == [
        getattr(e.scene.world, w) for w in ("surface", "caustics", "textures", "sun_glint")
    ]
    assert plan.condition_post(e, e.conditions[0], 1) == post  # planning from either: one result


def test_one_row_changes_what_a_mode_turns_on(monkeypatch):
    """What article mode turns on is one row of MODE_DEFAULTS, read everywhere."""
    exp = _exp(image_formation="article")
    assert plan.condition_post(exp, exp.conditions[0], 1).sensor.noise is True
    monkeypatch.setitem(eff.MODE_DEFAULTS, "camera.sensor.noise", (True, False))
    assert eff.effective(exp).camera.sensor.noise is False
    assert plan.condition_post(exp, exp.conditions[0], 1).sensor.noise is False


def test_show_config_prints_the_effective_config_and_writes_nothing(tmp_path, monkeypatch):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump({**CFG, "image_formation": "article"}))
    monkeypatch.chdir(tmp_path)
    before = sorted(os.listdir(tmp_path))
    res = CliRunner().invoke(cli.main, ["generate", str(p), "--show-config"])
    assert res.exit_code == 0, res.output
    shown = yaml.safe_load(res.output)
    exp = Experiment.model_validate({**CFG, "image_formation": "article"})
    assert shown == eff.effective(exp).model_dump(mode="json")
    assert shown["camera"]["sensor"]["noise"] is True and shown["scene"]["sky_fraction"] == 0.0
    assert sorted(os.listdir(tmp_path)) == before


def test_generate_without_out_is_a_usage_error(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(CFG))
    res = CliRunner().invoke(cli.main, ["generate", str(p)])
    assert res.exit_code == 2 and "--out" in res.output
    assert sorted(os.listdir(tmp_path)) == ["c.yaml"]


def test_a_dataset_without_effective_config_stays_valid():
    from tests.test_schema import validate_dataset  # every file against the JSON schemas

    tiny = Path(__file__).parent / "data" / "tiny"
    assert "effective_config" not in (tiny / "manifest.json").read_text()
    assert validate_dataset(tiny) > 0
