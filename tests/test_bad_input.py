"""Bad input through the CLI: malformed datasets (``evaluate`` and ``verify``) and bad configs
(``generate``) give one clear message, exit code 2, no traceback, and write nothing.

Complements tests/test_config.py (26 bad configs there; the cases here are different keys or
different failure kinds: NaN/inf from YAML ``.nan``/``.inf``, duplicates, cross-field rules).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import cli
from blendgen.config.models import ConfigError, load_experiment
from tests.fake_dataset import write_fake_dataset
from tests.test_config import patched

pytestmark = pytest.mark.integration  # the CLI end to end on malformed datasets and configs

SEQ = Path("sequences") / "clear_000"
NAN, INF = float("nan"), float("inf")


# ------------------------------------------------------------------ dataset corruptions
def _lines(root):
    return (root / SEQ / "frames.jsonl").read_text().splitlines()


def _write_lines(root, lines):
    (root / SEQ / "frames.jsonl").write_text("\n".join(lines) + "\n")


def _manifest(root, edit):
    m = root / "manifest.json"
    d = json.loads(m.read_text())
    edit(d)
    m.write_text(json.dumps(d))


def missing_frames(root):
    (root / SEQ / "frames.jsonl").unlink()


def bad_json_line(root):
    lines = _lines(root)
    lines[2] = lines[2][:40]
    _write_lines(root, lines)


def frame_not_object(root):
    lines = _lines(root)
    lines[1] = "[1, 2]"
    _write_lines(root, lines)


def corrupt_png(root):  # bytes flipped: sha256 mismatch and an unreadable PNG
    p = root / SEQ / "rgb" / "000001.png"
    b = bytearray(p.read_bytes())
    b[-20] ^= 0xFF
    p.write_bytes(bytes(b))


def swapped_png(root):  # a valid PNG with other pixels: only the hash tells
    cv2.imwrite(str(root / SEQ / "rgb" / "000001.png"), np.zeros((48, 64, 3), np.uint8))


def wrong_spec_version(root):
    _manifest(root, lambda d: d.update(spec_version="9.9"))


def wrong_format(root):
    _manifest(root, lambda d: d.update(format="something-else"))


def missing_image(root):
    (root / SEQ / "rgb" / "000002.png").unlink()


def truncated_manifest(root):
    t = (root / "manifest.json").read_text()
    (root / "manifest.json").write_text(t[: len(t) // 2])


def empty_manifest(root):
    (root / "manifest.json").write_text("")


def binary_manifest(root):
    (root / "manifest.json").write_bytes(b"\xff\xfe\x00garbage")


def manifest_not_object(root):
    (root / "manifest.json").write_text("[1, 2]")


def missing_manifest(root):
    (root / "manifest.json").unlink()


def missing_sequences_key(root):
    _manifest(root, lambda d: d.pop("sequences"))


def sequence_without_id(root):
    _manifest(root, lambda d: d["sequences"][0].pop("id"))


def camera_without_K(root):
    _manifest(root, lambda d: d["camera"].pop("K"))


def frame_without_d_true(root):
    lines = _lines(root)
    f = json.loads(lines[1])
    del f["d_true"]
    lines[1] = json.dumps(f)
    _write_lines(root, lines)


def nonexistent(root):
    import shutil

    shutil.rmtree(root)


# (corruption, text expected in the message)
CASES = [
    (missing_frames, "frames.jsonl"),
    (bad_json_line, "frames.jsonl"),
    (frame_not_object, "frames.jsonl"),
    (corrupt_png, "000001.png"),
    (swapped_png, "000001.png"),
    (wrong_spec_version, "spec_version"),
    (wrong_format, "format"),
    (missing_image, "000002.png"),
    (truncated_manifest, "manifest.json"),
    (empty_manifest, "manifest.json"),
    (binary_manifest, "manifest.json"),
    (manifest_not_object, "manifest.json"),
    (missing_manifest, "manifest.json"),
    (missing_sequences_key, "sequences"),
    (sequence_without_id, "id"),
    (camera_without_K, "K"),
    (frame_without_d_true, "frames.jsonl"),
    (nonexistent, "ds"),
]


def _ids(cases):
    return [c[0].__name__ for c in cases]


def _run(args):
    """Invoke the CLI; (result, stdout + stderr as the user sees them)."""
    res = CliRunner().invoke(cli.main, args)
    return res, res.output


def _check(res, out_text, expect, out_dir=None):
    assert "Traceback" not in out_text, out_text
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert res.exit_code == 2, (res.exit_code, out_text)
    assert expect in out_text, out_text
    if out_dir is not None:
        assert not out_dir.exists()


@pytest.mark.parametrize("corrupt,expect", CASES, ids=_ids(CASES))
def test_evaluate_bad_dataset(tmp_path, corrupt, expect):
    root = write_fake_dataset(tmp_path / "ds")
    corrupt(root)
    out = tmp_path / "out"
    res, text = _run(["evaluate", str(root), "-l", "aruco", "-o", str(out)])
    _check(res, text, expect, out)


@pytest.mark.parametrize("corrupt,expect", CASES, ids=_ids(CASES))
def test_verify_bad_dataset(tmp_path, corrupt, expect):
    root = write_fake_dataset(tmp_path / "ds")
    corrupt(root)
    res, text = _run(["verify", str(root)])
    _check(res, text, expect)


def test_good_dataset_passes_both(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    assert _run(["verify", str(root)])[0].exit_code == 0
    res, text = _run(["evaluate", str(root), "-l", "aruco", "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, text
    assert (tmp_path / "out" / "summary.csv").is_file()


def test_existing_output_dir_is_untouched_on_failure(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    missing_image(root)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    res, text = _run(["evaluate", str(root), "-l", "aruco", "-o", str(out)])
    _check(res, text, "folder is not empty")  # refused before anything runs
    res, text = _run(["evaluate", str(root), "-l", "aruco", "-o", str(out), "--overwrite"])
    _check(res, text, "000002.png")
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


def test_unknown_localizer_writes_nothing(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    out = tmp_path / "out"
    res, text = _run(["evaluate", str(root), "-l", "no_such_localizer", "-o", str(out)])
    _check(res, text, "no_such_localizer", out)


# ------------------------------------------------------------------ bad configs
# (dotted key, value, text expected in the message); values go through yaml.safe_dump, so
# NaN / inf reach the loader as YAML's .nan / .inf
BAD_CONFIGS = [
    ("camera.hfov_deg", NAN, "camera.hfov_deg"),
    ("camera.fps", INF, "camera.fps"),
    ("camera.latency_s", -0.1, "camera.latency_s"),
    ("camera.latency_s", NAN, "camera.latency_s"),
    ("camera.noise_std", NAN, "camera.noise_std"),
    ("render.samples", INF, "render.samples"),
    ("scene.dock.water_depth_m", NAN, "water_depth_m"),
    ("scene.dock.facing_deg", NAN, "facing_deg"),
    ("scene.sun_strength", INF, "sun_strength"),
    ("scene.pool", {"wall_color": [NAN, 0, 0]}, "wall_color"),
    ("d_min_rel_m", INF, "d_min_rel_m"),
    ("trajectories.0.lateral_m", NAN, "lateral_m"),
    ("water", {"preset": "clear", "beta": NAN}, "beta"),
    ("camera.distortion", [0.1, 0, 0, 0], "camera.distortion"),
    ("camera.width", 640.5, "camera.width"),
    ("seed", 2**32, "seed"),
    ("trials", 0, "trials"),
    ("conditions", [{"label": ""}], "label"),
    ("scene.dock.markers", [{"kind": "aruco", "id": "a"}, {"kind": "aruco", "id": "a", "marker_id": 1}], "unique"),
    ("trajectories", [{"kind": "linear", "id": "x"}, {"kind": "linear", "id": "x"}], "unique"),
    ("scene.dock.markers", [{"kind": "led_array", "reference_index": 4}], "reference_index"),
    ("occlusion", {"n_total": 1000, "n_max": 10}, "n_max"),
    ("occlusion", {"r_min_m": 0.05, "r_max_m": 0.01}, "r_min_m"),
    ("occlusion", {"region_min": [0, 0, 0]}, "region_max"),
    ("occlusion", {"n_total": NAN}, "n_total"),
    ("occlusion", {"size_slope": 7}, "size_slope"),
    ("occlusion", {"albedo": 1.5}, "albedo"),
    ("occlusion", {"size_dist": "lognormal"}, "size_dist"),
    ("camera.lens", {"focal_length_mm": 200, "focus_m": 0.1}, "focus_m"),
    ("fluid", {"current_mps": [3, 0, 0]}, "current"),
    ("fluid", {"density_kg_m3": NAN}, "density_kg_m3"),
    # NaN/inf anywhere and degenerate regions (were accepted before Strict got allow_inf_nan=False)
    ("camera.T_body_cam", {"xyz": [NAN, 0, 0]}, "xyz"),
    ("camera.T_body_cam", {"xyz": [0, 0, 0], "rpy_deg": [INF, 0, 0]}, "rpy_deg"),
    ("scene.dock.position_xy_m", [NAN, 0], "position_xy_m"),
    ("scene.dock.body_size_m", [NAN, 1, 1], "body_size_m"),
    ("camera.distortion", [NAN, 0, 0, 0, 0], "distortion"),
    ("scene.obstacles", [{"kind": "box", "pose": {"xyz": [INF, 0, 0]}}], "xyz"),
    ("fluid", {"current_mps": [NAN, 0, 0]}, "current_mps"),
    ("occlusion", {"region_min": [0, 0, 0], "region_max": [0, 1, 1]}, "region"),
]
# accepted today: unbounded float vectors take NaN/inf (spec.py Vec3 / Pose / position_xy_m /
# distortion have no finiteness check), and a zero-size occlusion region passes the config
# (occlusion._check_region only raises inside the render worker, after OUT was created)


def _cfg(tmp_path, key, value):
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(patched(key, value)))
    return p


def _needs_section(key):
    from blendgen.config.models import Experiment

    top = key.split(".")[0]
    if top not in Experiment.model_fields:
        pytest.skip(f"no {top!r} section in this spec")


@pytest.mark.parametrize("key,value,expect", BAD_CONFIGS, ids=[f"{k}={v!r}"[:48] for k, v, _ in BAD_CONFIGS])
def test_bad_config(tmp_path, key, value, expect):
    _needs_section(key)
    p = _cfg(tmp_path, key, value)
    with pytest.raises(ConfigError) as e:
        load_experiment(p)
    assert str(p) in str(e.value) and expect in str(e.value)


def test_yaml_nan_literals_reach_the_validator(tmp_path):
    p = tmp_path / "nan.yaml"
    text = yaml.safe_dump(patched("camera.hfov_deg", 60.0)).replace("hfov_deg: 60.0", "hfov_deg: .NaN")
    p.write_text(text)
    with pytest.raises(ConfigError, match="camera.hfov_deg"):
        load_experiment(p)


@pytest.mark.parametrize("key,value,expect", [BAD_CONFIGS[i] for i in (0, 2, 18, 21)])
def test_cli_generate_bad_config_exit_2_nothing_written(tmp_path, key, value, expect):
    _needs_section(key)
    p = _cfg(tmp_path, key, value)
    out = tmp_path / "out"
    res, text = _run(["generate", str(p), "-o", str(out)])
    _check(res, text, expect, out)


# ------------------------------------------------------------------ impossible scenes
# (dotted key of configs/quickstart.yaml, value, the exact one-line message): refused by the
# planner before anything is written (blendgen/pipeline/scene_check.py). Pool 15 x 5 x 8 m,
# dock face centre 1.5 m deep (its top 1 m), 7 m from the pool's centre, camera 0.65 m ahead.
IMPOSSIBLE_SCENES = [
    (
        "trajectories.0.vertical_m",
        100,
        "trajectories[0].vertical_m: 100 puts the camera 98.50 m above the water surface at t = 0.00 s "
        "('approach'); allowed -6.50 <= vertical_m <= 1.50",
    ),
    (
        "trajectories.0.vertical_m",
        -100,
        "trajectories[0].vertical_m: -100 puts the camera 93.50 m below the pool's floor at t = 0.00 s "
        "('approach'); allowed -6.50 <= vertical_m <= 1.50",
    ),
    (
        "trajectories.0.start_range_m",
        1000,
        "trajectories[0].start_range_m: 1000 puts the camera 984.85 m outside the pool's walls at t = 0.00 s "
        "('approach'); allowed 1.00 <= start_range_m <= 15.15",
    ),
    (
        "trajectories.1.height_m",
        5,
        "trajectories[1].height_m: 5 puts the camera 2.94 m above the water surface at t = 0.00 s ('circle'); "
        "allowed -5.94 <= height_m <= 2.06",
    ),
    (
        "scene.dock.water_depth_m",
        10,
        "scene.dock.water_depth_m: 10 puts the dock 3.00 m below the pool's floor; allowed 0.00 <= water_depth_m "
        "<= 7.00",
    ),
    (
        "render.max_distance_m",
        0.2,
        "render.max_distance_m: 0.2 leaves trajectories[0] ('approach') no frame (no camera pose that close to the "
        "dock before contact); allowed: max_distance_m >= 0.35",
    ),
    (
        "trajectories",
        [{"kind": "docking", "id": "d", "start": {"range_m": [1000, 1000]}}],
        "trajectories[0].start.range_m: [1000.0, 1000.0] puts a start 985.50 m outside the pool's walls ('d'); "
        "allowed range_m <= 14.50",
    ),
    (
        "trajectories",
        [{"kind": "docking", "id": "d", "start": {"vertical_m": 5}}],
        "trajectories[0].start.vertical_m: 5.0 puts a start 3.50 m above the water surface ('d'); "
        "allowed vertical_m <= 1.50",
    ),
    (
        "trajectories",
        [{"kind": "docking", "id": "d", "start": {"lateral_m": 5}}],
        "trajectories[0].start.lateral_m: 5.0 puts a start 2.50 m outside the pool's walls ('d'); "
        "allowed lateral_m <= 2.50",
    ),
]


@pytest.mark.parametrize(
    "key,value,message", IMPOSSIBLE_SCENES, ids=[f"{k}={v!r}"[:48] for k, v, _ in IMPOSSIBLE_SCENES]
)
def test_impossible_scene_refused_exit_2_nothing_written(tmp_path, key, value, message):
    p = _cfg(tmp_path, key, value)
    out = tmp_path / "out"
    res, text = _run(["generate", str(p), "-o", str(out)])
    _check(res, text, message, out)
    assert text.strip() == f"error: {message}"


def test_physical_depth_condition_puts_the_surface_below_the_camera(tmp_path):
    """Physical mode: a 0 m condition lifts nothing: the surface drops to the dock's top, and a
    path 0.6 m above the face centre (0.1 m above the top) is then in the air."""
    cfg = patched("trajectories.0.vertical_m", 0.6)
    cfg.update(
        image_formation="physical",
        conditions=[{"label": "d0", "dock_water_depth_m": 0.0}, {"label": "d1", "dock_water_depth_m": 1.0}],
    )
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(cfg))
    res, text = _run(["generate", str(p), "-o", str(tmp_path / "out")])
    _check(
        res,
        text,
        "trajectories[0].vertical_m: 0.6 puts the camera 0.10 m above the water surface at "
        "t = 0.00 s ('approach'); allowed -6.50 <= vertical_m <= 0.50",
        tmp_path / "out",
    )


@pytest.mark.parametrize(
    "water,message",
    [
        ({"secchi_m": 0.5}, "water: secchi_m 0.5 is outside the Jerlov ladder I..9C; allowed 2 <= secchi_m <= 79.9 m"),
        ({"ntu": 50}, "water: ntu 50 is outside the Jerlov ladder I..9C; allowed 0.00187 <= ntu <= 3.25 NTU"),
        ({"secchi_m": 5, "ntu": 1}, "water: give one of preset, secchi_m or ntu (a reading names the water)"),
        (
            {"secchi_m": 5, "preset": "jerlov_I"},
            "water: give one of preset, secchi_m or ntu (a reading names the water)",
        ),
    ],
)
def test_bad_turbidity_reading(tmp_path, water, message):
    p = _cfg(tmp_path, "water", water)
    res, text = _run(["generate", str(p), "-o", str(tmp_path / "out")])
    _check(res, text, f"{p}: {message}", tmp_path / "out")


def test_physical_depth_condition_above_the_pool_rim_refused(tmp_path):
    cfg = patched("image_formation", "physical")
    cfg["conditions"] = [{"label": "d1", "dock_water_depth_m": 1.0}, {"label": "d5", "dock_water_depth_m": 5.0}]
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(cfg))
    res, text = _run(["generate", str(p), "-o", str(tmp_path / "out")])
    _check(
        res,
        text,
        "conditions[1].dock_water_depth_m: 5 puts the water surface 4.00 m above the pool's rim "
        "(a depth condition moves the surface, not the dock); allowed <= scene.dock.water_depth_m "
        "(1): put the dock at the deepest condition",
        tmp_path / "out",
    )
