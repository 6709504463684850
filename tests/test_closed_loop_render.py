"""The warm render server and `dockbench dock` end to end (tiny Blender renders)."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from blendgen.geometry import project, transform_points
from blendgen.vehicle.docking import start_pose_world

pytestmark = pytest.mark.blender

CONFIG = """
name: dock_tiny
seed: 5
scene: {template: pool_15x5x8}
camera: {width: 160, height: 120, hfov_deg: 60, fps: 10}
render: {fidelity: fast, samples: 1}
image_formation: article
water: {preset: clear}
trajectories:
  - {kind: docking, id: dock, max_time_s: 1.5, start: {range_m: [3.0, 3.5], lateral_m: 0.2, vertical_m: 0.1,
     heading_error_deg: 3}}
conditions:
  - {label: clear}
"""


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    from blendgen.config.models import load_experiment
    from blendgen.tools.apps.closed_loop import Bench

    d = tmp_path_factory.mktemp("cl")
    (d / "dock.yaml").write_text(CONFIG)
    return Bench.prepare(load_experiment(d / "dock.yaml"), d / "assets"), d


def test_render_server_frame_shows_the_dock_where_geometry_puts_it(bench):
    from blendgen.pipeline import plan
    from blendgen.tools.apps.closed_loop import RenderClient, start_client

    b, d = bench
    client = start_client(b, d / "server.log", threads=1)
    try:
        # camera 3 m in front of the dock face, looking at it
        T_wb = start_pose_world(b.T_world_dock, {"range_m": 3.0 + 0.65})
        T_wc = T_wb @ b.T_body_cam
        passes = client.render(T_wc, None)
        assert passes["rgb"].shape == (120, 160, 3) and passes["index"].dtype == np.uint8
        marker = next(m for m in b.markers if m["kind"] == "led_array")
        kp = transform_points(np.linalg.inv(T_wc) @ b.T_world_dock, np.asarray(marker["keypoints"]))
        u, v = np.rint(project(b.K, kp).mean(axis=0)).astype(int)  # array centre: the dock face
        assert passes["index"][v, u] in (plan.INDEX_DOCK,) + tuple(m["object_index"] for m in b.markers)
        assert passes["depth_z"][v, u] == pytest.approx(3.0, abs=0.02)  # planar depth to the face
        again = client.render(T_wc, None)  # warm: same scene, same pixels
        np.testing.assert_array_equal(again["index"], passes["index"])
    finally:
        client.close()
    assert client.proc.returncode == 0
    assert isinstance(RenderClient, type)


def test_render_server_answers_a_bad_request_and_keeps_serving(tmp_path):
    p = subprocess.Popen(
        [sys.executable, "-m", "blendgen.blender.serve", str(tmp_path / "log")],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    out, _ = p.communicate(
        '{"cmd": "render", "T_world_cam": [], "out": "x"}\n{"cmd": "nope"}\n{"cmd": "quit"}\n', timeout=120
    )
    replies = [json.loads(line) for line in out.splitlines()]
    assert [r["ok"] for r in replies] == [False, False]
    assert "before init" in replies[0]["error"] and "unknown cmd" in replies[1]["error"]
    assert p.returncode == 0


def test_dock_command_writes_outcomes_trajectories_metrics_and_plot(bench):
    import cli

    b, d = bench
    out = d / "run"
    r = CliRunner().invoke(
        cli.main,
        ["dock", str(d / "dock.yaml"), "-l", "led", "--trials", "1", "--threads", "1", "--images", "-o", str(out)],
    )
    assert r.exit_code == 0, r.output + repr(r.exception)
    trials = pd.read_parquet(out / "trials.parquet")
    frames = pd.read_parquet(out / "frames.parquet")
    assert list(trials["localizer"]) == ["truth", "led"]
    assert set(trials["outcome"]) <= {"timeout", "docked", "lost_target", "collision", "out_of_capture", "misaligned"}
    vis = frames[frames["localizer"] == "led"]
    assert len(vis) == 16 and vis["d_true"].between(2.0, 3.5).all()  # 1.5 s at 10 Hz
    assert vis["detected"].mean() > 0.5  # the LEDs are seen at 3 m
    ok = vis[vis["detected"]]
    assert (ok["d_est"] - ok["d_true"]).abs().max() < 0.3
    images = sorted((out / "images").glob("*/*.png"))
    assert len(images) == 16
    import cv2

    assert np.abs(cv2.imread(str(images[0])).astype(int) - cv2.imread(str(images[-1]))).max() > 0  # it moved
    s = pd.read_csv(out / "summary.csv")
    assert {"success_rate", "ci_low", "ci_high", "P_detect_mean", "P_succ_mean", "E_rel_mean"} <= set(s.columns)
    loc = s[s["localizer"] == "led"].iloc[0]
    assert loc["P_detect_mean"] > 0.5 and loc["E_rel_mean"] < 0.1
    assert (out / "paths.png").stat().st_size > 10_000
    from evalkit.reports.closed_loop import load_closed_loop  # the leaderboard's interface

    doc = load_closed_loop(out).doc
    assert {(r["localizer"], r["baseline"]) for r in doc["rows"]} == {("truth", True), ("led", False)}
    assert doc["camera"]["width"] == 160 and doc["experiment"]["name"] == "dock_tiny"
    assert "closed-loop docking: dock_tiny" in leaderboard_html(out, d)


def leaderboard_html(run_dir, d) -> str:
    import cli

    r = CliRunner().invoke(cli.main, ["leaderboard", str(run_dir), "-o", str(d / "board.html")])
    assert r.exit_code == 0, r.output
    return (d / "board.html").read_text()


def test_dock_command_rejects_unknown_condition_with_exit_code_2(bench):
    import cli

    _, d = bench
    r = CliRunner().invoke(cli.main, ["dock", str(d / "dock.yaml"), "--condition", "murky", "-o", str(d / "x")])
    assert r.exit_code == 2 and "murky" in r.output
    assert not (d / "x").exists()


def test_dock_command_rejects_a_bad_compute_latency_with_exit_code_2(bench):
    import cli

    _, d = bench
    r = CliRunner().invoke(cli.main, ["dock", str(d / "dock.yaml"), "--compute-latency", "soon", "-o", str(d / "y")])
    assert r.exit_code == 2 and "--compute-latency" in r.output
    assert not (d / "y").exists()


SAME_IMAGE_CONFIG = {
    "name": "dock_same_image",
    "version": "0.0.1",
    "seed": 3,
    "scene": {"template": "pool_15x5x8", "sun_strength": 0.3},
    "camera": {"width": 96, "height": 72, "hfov_deg": 60, "fps": 10, "noise_std": 2.0},
    "vehicle": {
        "lamps": [
            {
                "id": "lamp",
                "offset_m": [0.0, 0.3, 0.0],
                "pitch_deg": 5.0,
                "half_angle_deg": 30.0,
                "edge_deg": 5.0,
                "power_w": 20.0,
            }
        ]
    },
    "render": {"fidelity": "fast", "samples": 1},
    "water": {"preset": "mild"},
    "trajectories": [{"kind": "docking", "id": "dock", "start": {"range_m": [2.5, 3.0]}, "max_time_s": 0.2}],
    "conditions": [
        {
            "label": "lit",
            "occlusion": {"n_total": 3000, "size_dist": "uniform", "r_min_m": 0.005, "r_max_m": 0.02, "mode": "lit"},
        }
    ],
}


def test_closed_loop_frame_is_the_dataset_frame_byte_for_byte(tmp_path):
    """Same pose and seed: the closed loop's camera image equals the dataset's PNG (LED- and
    lamp-lit particles, water, sensor noise, ROI boxes), because both call the same stages."""
    import cv2
    import yaml

    from blendgen.config.models import load_experiment
    from blendgen.pipeline import plan
    from blendgen.pipeline.generate import generate
    from blendgen.tools.apps.closed_loop import Bench, VisionCamera, start_client

    cfg = tmp_path / "same.yaml"
    cfg.write_text(yaml.safe_dump(SAME_IMAGE_CONFIG))
    exp = load_experiment(cfg)
    generate(exp, tmp_path / "ds", workers=1, progress=False)
    seq = next(p for p in sorted((tmp_path / "ds" / "sequences").iterdir()) if p.is_dir())
    first = json.loads((seq / "frames.jsonl").read_text().splitlines()[0])
    ds_img = cv2.cvtColor(cv2.imread(str(seq / "rgb" / "000000.png"), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
    b = Bench.prepare(load_experiment(cfg), tmp_path / "assets")
    client = start_client(b, tmp_path / "server.log", threads=1)
    try:
        cond = b.exp.conditions[0]
        cam = VisionCamera(b, client, None, None, plan.condition_post(b.exp, cond, plan.trial_seed(b.exp, 0)))
        img, _, _ = cam._image(0, float(first["t"]), np.asarray(first["T_world_cam"], float))
    finally:
        client.close()
    assert cam.state.field is not None  # particles were composited
    assert img.dtype == ds_img.dtype and img.shape == ds_img.shape
    assert np.array_equal(img, ds_img), f"max |diff| {np.abs(img.astype(int) - ds_img.astype(int)).max()}"
