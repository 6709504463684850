"""Calibration check (the article's Table 4): pose sampler, board geometry, and one small
rendered Zhang calibration against the ground-truth K."""

import csv
import math

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import cli
from blendgen.geometry import intrinsics_from_hfov, project, transform_points
from blendgen.tools.calibration import camera as cal

BOARD = cal.ChessBoard(9, 6, 0.05, 1)


@pytest.mark.parametrize("W,H", [(1920, 1080), (1280, 720), (640, 480)])
def test_pose_sampler_keeps_board_in_view(W, H):
    poses = cal.Poses()
    K = intrinsics_from_hfov(W, H, math.radians(60))
    for seed in range(3):
        Ts = cal.sample_poses(seed, 20, K, BOARD, W, H, poses)
        for T in Ts:
            assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
            assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
            uv = project(K, transform_points(T, BOARD.outline()))
            assert np.all(np.isfinite(uv))
            m = poses.margin_px - 0.5
            assert uv[:, 0].min() >= m and uv[:, 0].max() <= W - 1 - m
            assert uv[:, 1].min() >= m and uv[:, 1].max() <= H - 1 - m
            assert poses.fill_min <= cal.board_fill(K, T, BOARD, W, H) <= poses.fill_max
            assert cal.board_tilt_deg(T) <= poses.max_tilt_deg + 1e-6
            n_cam = T[:3, 2]
            assert n_cam @ T[:3, 3] < 0  # the printed face looks at the camera
        # seeded: same seed, same poses; tilts actually vary
        again = cal.sample_poses(seed, 20, K, BOARD, W, H, poses)
        assert all(np.array_equal(a, b) for a, b in zip(Ts, again))
        assert np.ptp([cal.board_tilt_deg(T) for T in Ts]) > 15


def test_board_texture_matches_corners():
    cells = BOARD.cells()
    assert cells.shape == (9, 12)
    assert BOARD.plate_size_m == pytest.approx((0.6, 0.45))
    assert (cells[0] == 255).all() and (cells[-1] == 255).all()
    assert (cells[:, 0] == 255).all() and (cells[:, -1] == 255).all()
    # every inner corner sits where four cells of alternating colour meet
    w, h = BOARD.plate_size_m
    for x, y, _ in BOARD.corners():
        c = (x + w / 2) / BOARD.square_m
        r = (h / 2 - y) / BOARD.square_m
        assert c == pytest.approx(round(c)) and r == pytest.approx(round(r))
        r, c = round(r), round(c)
        q = cells[r - 1 : r + 1, c - 1 : c + 1].astype(int)
        assert q[0, 0] == q[1, 1] != q[0, 1] == q[1, 0]
    # first corner is the top-left one, rows run left to right
    P = BOARD.corners()
    assert P[0, 0] < P[1, 0] and P[0, 1] > P[BOARD.cols, 1]


def test_order_like_undoes_reversal():
    truth = np.random.default_rng(0).uniform(0, 100, (54, 2))
    c, e = cal.order_like(truth[::-1] + 0.01, truth)
    assert np.allclose(c, truth + 0.01) and e == pytest.approx(0.01 * math.sqrt(2))


def test_bad_config_is_a_user_error(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("trials: 0\nbogus: 1\n")
    r = CliRunner().invoke(cli.main, ["calibrate", "--config", str(p), "-o", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert "trials" in r.output and "bogus" in r.output


@pytest.mark.blender
def test_rendered_zhang_calibration(tmp_path):
    cfg = {"resolutions": [[640, 480]], "trials": 1, "poses_per_trial": 12, "samples": 16, "seed": 1}
    p = tmp_path / "calib.yaml"
    p.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli.main, ["calibrate", "--config", str(p), "-o", str(out)])
    assert r.exit_code == 0, (r.output, r.exception)
    assert "640x480" in r.output and "fx err %" in r.output
    rows = list(csv.DictReader(open(out / "calibration_trials.csv")))
    assert len(rows) == 1
    row = rows[0]
    assert int(row["views"]) == 12
    for p_ in cal.PARAMS:
        assert float(row[f"{p_}_err_pct"]) < 1.0, row
    assert float(row["rms_px"]) < 0.2, row
    assert float(row["corner_err_px"]) < 0.2, row  # detections sit on the true projections
    assert (out / "calibration.csv").exists()
