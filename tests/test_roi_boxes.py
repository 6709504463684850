"""Per-marker ROIs (render.roi_regions: markers): boxes cover what localizers read, are
disjoint, capped in number; render settings of the fast fidelity (light tree off)."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from blendgen.config.models import load_experiment
from blendgen.geometry import project, transform_points
from blendgen.pipeline import groundtruth as gt
from blendgen.pipeline import plan

ROOT = Path(__file__).resolve().parent.parent

box = st.tuples(st.integers(0, 600), st.integers(0, 440), st.integers(1, 80), st.integers(1, 80)).map(
    lambda t: (t[0], t[1], t[0] + t[2], t[1] + t[3])
)


def covered(b, boxes) -> bool:
    return any(o[0] <= b[0] and o[1] <= b[1] and b[2] <= o[2] and b[3] <= o[3] for o in boxes)


@given(st.lists(box, max_size=12), st.integers(1, 8))
def test_merged_boxes_cover_inputs_are_disjoint_and_capped(boxes, cap):
    out = gt.merge_boxes(boxes, cap)
    assert len(out) <= max(1, cap) or not boxes
    assert all(covered(b, out) for b in boxes)
    for i, a in enumerate(out):
        for b in out[i + 1 :]:
            assert not gt._overlap(a, b), (a, b)


def test_merge_examples():
    assert gt.merge_boxes([(0, 0, 10, 10), (5, 5, 20, 20), (30, 30, 40, 40)], 6) == [(0, 0, 20, 20), (30, 30, 40, 40)]
    assert gt.merge_boxes([(0, 0, 10, 10), (12, 0, 20, 10), (300, 300, 310, 310)], 2) == [
        (0, 0, 20, 10),
        (300, 300, 310, 310),
    ]
    assert gt.merge_boxes([], 3) == []


@pytest.fixture(scope="module")
def turbidity():
    exp = load_experiment(ROOT / "configs" / "paper_turbidity.yaml")
    return exp, plan.manifest_markers(exp), plan.camera_K(exp)


@pytest.mark.parametrize("quiet_zone", [True, False])
def test_regions_are_each_marker_plate_and_led(turbidity, quiet_zone):
    exp, markers, _ = turbidity
    regions = plan.marker_regions(markers, quiet_zone)
    n_leds = sum(len(m["keypoints"]) for m in markers if m["kind"] == "led_array")
    assert len(regions) == n_leds + sum(m["kind"] != "led_array" for m in markers) == 6
    for m in markers:  # every keypoint lies inside its region's x-y extent
        for kp in m["keypoints"]:
            assert any(
                np.all(r.min(0)[:2] <= np.asarray(kp)[:2]) and np.all(np.asarray(kp)[:2] <= r.max(0)[:2])
                for r in regions
            )


@pytest.mark.parametrize("z", [0.6, 1.5, 4.0, 9.0])
def test_marker_rois_hold_every_keypoint_and_are_smaller_than_dock_box(turbidity, z):
    exp, markers, K = turbidity
    T_cd = np.eye(4)
    T_cd[:3, :3] = np.diag([1.0, -1.0, -1.0])  # camera looking at the marker plane
    T_cd[:3, 3] = [0.05, -0.02, z]
    W, H = exp.camera.width, exp.camera.height
    boxes = gt.marker_rois(T_cd, K, W, H, plan.marker_regions(markers))
    for m in markers:
        uv = project(K, transform_points(T_cd, np.asarray(m["keypoints"], float)))
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        for u, v in uv[inside]:
            assert any(b[0] <= u < b[2] and b[1] <= v < b[3] for b in boxes), (m["id"], u, v, boxes)
    dock = gt.dock_roi(T_cd, K, W, H, plan.dock_corners(exp))
    area = sum((b[2] - b[0]) * (b[3] - b[1]) for b in boxes)
    assert area < (dock[2] - dock[0]) * (dock[3] - dock[1])


def test_marker_rois_out_of_view_and_behind(turbidity):
    exp, markers, K = turbidity
    regions = plan.marker_regions(markers)
    away = np.eye(4)
    away[:3, 3] = [0, 0, -3.0]  # the dock behind the camera: nothing to render at samples
    assert gt.marker_rois(away, K, 640, 480, regions) == []
    straddle = np.eye(4)
    straddle[:3, :3] = np.diag([1.0, -1.0, -1.0])
    straddle[:3, 3] = [0.0, 0.0, 0.0]  # corners on both sides of the camera: the whole image
    assert gt.marker_rois(straddle, K, 640, 480, regions) == [(0, 0, 640, 480)]


def test_fast_settings_turn_light_tree_off_reference_keeps_it(turbidity):
    exp = turbidity[0]
    fast = plan.render_settings(exp, 1)
    assert fast["light_tree"] is False and fast["roi"] and fast["roi_max_fraction"] == exp.render.roi_max_fraction
    ref = exp.model_copy(update={"render": exp.render.model_copy(update={"fidelity": "reference"})})
    assert plan.render_settings(ref, 1)["light_tree"] is True
    on = exp.model_copy(update={"render": exp.render.model_copy(update={"light_tree": True})})
    assert plan.render_settings(on, 1)["light_tree"] is True


def test_frames_carry_marker_rois_or_dock_roi(turbidity):
    exp = turbidity[0].model_copy(update={"trials": 1})
    scene = plan.scene_description(exp, plan.manifest_markers(exp), {})
    job = plan.plan_jobs(exp, scene)[0]
    assert all("rois" in f and "roi" not in f for f in job.frames)
    assert any(len(f["rois"]) >= 2 for f in job.frames)
    dock = exp.model_copy(update={"render": exp.render.model_copy(update={"roi_regions": "dock"})})
    job = plan.plan_jobs(dock, scene)[0]
    assert all("roi" in f and "rois" not in f for f in job.frames)


def test_code_regions_are_the_code_squares_inside_the_plates(turbidity):
    markers = turbidity[1]
    plates, codes = plan.marker_regions(markers, True), plan.marker_regions(markers, False)
    for m, p, c in zip([m for m in markers if m["kind"] != "led_array"], plates[4:], codes[4:]):
        assert np.ptp(c[:, 0]) == pytest.approx(m["size_m"]) and np.ptp(p[:, 0]) == pytest.approx(m["plate_size_m"])
        assert np.all(p.min(0) <= c.min(0)) and np.all(c.max(0) <= p.max(0))
    np.testing.assert_array_equal(np.array(plates[:4]), np.array(codes[:4]))  # LED discs unchanged
