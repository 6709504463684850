"""Config validation: every user error names the file, the key path and the range; exit 2; nothing written."""

from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

import cli
from blendgen.config.models import ConfigError, load_experiment

ROOT = Path(__file__).resolve().parent.parent
GOOD = yaml.safe_load((ROOT / "configs" / "quickstart.yaml").read_text())


def write(tmp_path, cfg, name="bad.yaml"):
    p = tmp_path / name
    p.write_text(cfg if isinstance(cfg, str) else yaml.safe_dump(cfg))
    return p


def patched(path, value):
    """Deep copy of the good config with ``path`` (dotted, list indices as ints) set to value."""
    import copy

    cfg = copy.deepcopy(GOOD)
    node = cfg
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
    last = keys[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return cfg


def test_quickstart_is_valid():
    exp = load_experiment(ROOT / "configs" / "quickstart.yaml")
    assert exp.camera.width == 640 and len(exp.scene.dock.markers) == 3
    assert {m.kind for m in exp.scene.dock.markers} == {"led_array", "qr", "aruco"}


BAD = [
    # (dotted key, value, text expected in the message)
    ("camera.hfov_deg", 180, "camera.hfov_deg"),
    ("camera.hfov_deg", "wide", "camera.hfov_deg"),
    ("camera.width", 0, "camera.width"),
    ("camera.height", -480, "camera.height"),
    ("camera.fps", 0, "camera.fps"),
    ("camera.noise_std", 300, "less than or equal to 256"),
    ("camera.lens", 35, "camera.lens"),  # unknown key
    ("render.samples", 0, "render.samples"),
    ("render.fidelity", "ultra", "render.fidelity"),
    ("water", {"preset": "mild", "beta": -0.1}, "beta"),
    ("water", {"preset": "no-such-water"}, "no-such-water"),
    ("water", {"sigma_a": [0.1, 0.2]}, "sigma_a"),
    ("seed", -1, "seed"),
    ("name", "has spaces", "name"),
    ("trajectories", [], "trajectories"),
    ("trajectories.0.speed_mps", -1, "speed_mps"),
    ("trajectories.0.end_range_m", 20, "end_range_m"),
    ("trajectories.0.kind", "spiral", "kind"),
    ("scene.template", "no_such_template", "no template"),
    ("scene.dock.water_depth_m", -1, "water_depth_m"),
    ("scene.pool", {"length_m": -15}, "length_m"),
    ("scene.obstacles", [{"kind": "box", "size_m": [1, -1, 1]}], "size_m"),
    (
        "scene.dock.markers",
        [{"kind": "aruco", "id": "a", "marker_id": 99, "dictionary": "DICT_4X4_50"}],
        "out of range",
    ),
    ("scene.dock.markers", [{"kind": "qr", "id": "q"}], "payload"),
    ("scene.dock.markers", [{"kind": "led_array", "led_radius_m": 0}], "led_radius_m"),
    ("conditions", [{"label": "a"}, {"label": "a"}], "unique"),
]


@pytest.mark.parametrize("key,value,expect", BAD, ids=[f"{k}={v!r}"[:40] for k, v, _ in BAD])
def test_bad_config_message(tmp_path, key, value, expect):
    p = write(tmp_path, patched(key, value))
    with pytest.raises(ConfigError) as e:
        load_experiment(p)
    msg = str(e.value)
    assert str(p) in msg and expect in msg


def test_yaml_syntax_error_names_line(tmp_path):
    p = write(tmp_path, "name: x\ncamera: {width: 640\n")
    with pytest.raises(ConfigError, match=r"line \d+.*YAML syntax error"):
        load_experiment(p)


def test_not_a_mapping_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="mapping"):
        load_experiment(write(tmp_path, "- 1\n- 2\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_experiment(tmp_path / "nope.yaml")


@pytest.mark.parametrize("key,value,expect", BAD[:6] + BAD[-6:])
def test_cli_generate_exits_2_and_writes_nothing(tmp_path, key, value, expect):
    p = write(tmp_path, patched(key, value))
    out = tmp_path / "out"
    res = CliRunner().invoke(cli.main, ["generate", str(p), "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and expect in res.output
    assert not out.exists()


def test_cli_refuses_foreign_output_dir(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    res = CliRunner().invoke(cli.main, ["generate", str(ROOT / "configs" / "quickstart.yaml"), "-o", str(out)])
    assert res.exit_code == 2 and "not a dockbench dataset" in res.output
    assert (out / "thesis.tex").read_text() == "precious" and len(list(out.iterdir())) == 1
