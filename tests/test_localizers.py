"""Ground-truth oracles for the built-in marker localizers (LED, QR, ArUco) and planar PnP.

Images are drawn by tests/synth_images.py (OpenCV only) from known T_cam_dock; the
estimated distance / pose / reprojected keypoints are compared with the truth.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

sys.path.insert(0, str(Path(__file__).parent))
import synth_images as synth  # noqa: E402

from evalkit.localizers import pnp  # noqa: E402
from evalkit.localizers.aruco import ArucoLocalizer  # noqa: E402
from evalkit.localizers.led import LedLocalizer, expected_order  # noqa: E402
from evalkit.localizers.qr import QrLocalizer  # noqa: E402

W, H = 640, 480
K = synth.k_from_hfov(W, H, 60.0)
F = K[0, 0]
I4 = np.eye(4).tolist()
BLUE_GREEN, ORANGE = [0.0, 0.8, 0.6], [1.0, 0.25, 0.0]


def T_offset(x, y, yaw_deg=0.0):
    """T_dock_marker: marker in the face plane at (x, y), rotated in-plane by yaw_deg."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return [[c, -s, 0, x], [s, c, 0, y], [0, 0, 1, 0], [0, 0, 0, 1]]


def dock_keypoints(local, T_dock_marker):
    T = np.asarray(T_dock_marker, float)
    return (np.asarray(local, float) @ T[:3, :3].T + T[:3, 3]).tolist()


def led_marker(layout="rectangle", reference_index=0, size=0.6, T=I4):
    if layout == "rectangle":
        h = size / 2
        local = [[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]]
    else:  # circle: top, then clockwise as seen from the camera (blendgen.markers)
        ang = np.pi / 2 - np.arange(4) * np.pi / 2
        local = np.column_stack([size / 2 * np.cos(ang), size / 2 * np.sin(ang), np.zeros(4)]).tolist()
    colors = [list(BLUE_GREEN) for _ in range(4)]
    colors[reference_index] = list(ORANGE)
    return {
        "id": "led",
        "kind": "led_array",
        "keypoints": dock_keypoints(local, T),
        "T_dock_marker": T,
        "led_radius_m": 0.04,
        "colors": colors,
        "reference_index": reference_index,
        "layout": layout,
        "size_m": size,
    }


def square_marker(kind, size, T=I4, **extra):
    h = size / 2
    local = [[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]]
    return {
        "id": extra.pop("id", kind),
        "kind": kind,
        "keypoints": dock_keypoints(local, T),
        "T_dock_marker": T,
        "size_m": size,
        **extra,
    }


QR = square_marker("qr", 0.15, payload="DOCK-01")
ARUCO = square_marker("aruco", 0.2, dictionary="DICT_4X4_50", marker_id=7)
LED = led_marker()


def make(cls, markers, **params):
    loc = cls(**params)
    loc.reset(synth.camera_dict(K, W, H, markers))
    return loc


def rot_err_deg(T_est, T_true):
    R = np.asarray(T_est)[:3, :3].T @ np.asarray(T_true)[:3, :3]
    return math.degrees(math.acos(np.clip((np.trace(R) - 1) / 2, -1, 1)))


def keypoint_err_px(T_est, T_true, keypoints):
    uv_e, _ = synth.project(K, np.asarray(T_est), keypoints)
    uv_t, _ = synth.project(K, np.asarray(T_true), keypoints)
    return np.linalg.norm(uv_e - uv_t, axis=1)


def min_side_px(T, marker):
    uv, _ = synth.project(K, T, marker["keypoints"])
    return float(np.min(np.linalg.norm(uv - np.roll(uv, 1, axis=0), axis=1)))


def centre_of(marker):
    return tuple(np.mean(np.asarray(marker["keypoints"])[:, :2], axis=0))


# ---------------------------------------------------------------- planar PnP


def _true_pose(d, yaw, pitch, roll):
    return synth.pose_looking_at_dock(d, yaw, pitch, roll)


def test_pnp_recovers_exact_pose_and_picks_the_right_ippe_solution():
    obj = np.array(QR["keypoints"])
    T = _true_pose(0.4, 40.0, -15.0, 20.0)
    uv, _ = synth.project(K, T, obj)
    for square in (True, False):
        pose = pnp.solve_planar(obj, uv, K, None, square=square)
        assert pose is not None
        assert np.allclose(pose.T_cam_target, T, atol=1e-6)
        assert pose.reproj_err_px < 1e-6 < pose.alt_reproj_err_px  # the flipped solution fits worse


def test_pose_plausibility_rejects_behind_and_facing_away():
    obj = np.array(QR["keypoints"])
    T = _true_pose(2.0, 10.0, 0.0, 0.0)
    assert pnp.pose_is_plausible(T, obj)
    behind = T.copy()
    behind[:3, 3] *= -1.0
    assert not pnp.pose_is_plausible(behind, obj)
    away = T.copy()  # target turned 180 deg about its own y: still in front, normal points away
    away[:3, :3] = T[:3, :3] @ np.diag([-1.0, 1.0, -1.0])
    assert not pnp.pose_is_plausible(away, obj)
    nan = T.copy()
    nan[0, 3] = np.nan
    assert not pnp.pose_is_plausible(nan, obj)


def test_distance_is_camera_height_over_dock_plane():
    T = _true_pose(3.0, 35.0, -20.0, 70.0)
    assert pnp.distance_to_dock_plane(T) == pytest.approx(3.0, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    d=st.floats(0.3, 10.0),
    yaw=st.floats(-50, 50),
    pitch=st.floats(-50, 50),
    roll=st.floats(-180, 180),
    size=st.floats(0.1, 0.8),
)
def test_pnp_property_noise_free_roundtrip(d, yaw, pitch, roll, size):
    obj = np.array(square_marker("qr", size)["keypoints"])
    T = _true_pose(d, yaw, pitch, roll)
    uv, _ = synth.project(K, T, obj)
    pose = pnp.solve_planar(obj, uv, K, None, square=True)
    assert pose is not None
    assert pnp.distance_to_dock_plane(pose.T_cam_target) == pytest.approx(d, rel=1e-5)
    assert rot_err_deg(pose.T_cam_target, T) < 0.05


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.float64, (4, 2), elements=st.floats(allow_nan=True, allow_infinity=True, width=64)), st.booleans())
def test_pnp_property_garbage_never_raises(img_pts, square):
    obj = np.array(QR["keypoints"])
    pose = pnp.solve_planar(obj, img_pts, K, None, square=square)
    if pose is not None:
        assert np.all(np.isfinite(pose.T_cam_target)) and np.isfinite(pose.reproj_err_px)
        assert pnp.pose_is_plausible(pose.T_cam_target, obj)


# ---------------------------------------------------------------- LED array

LED_SWEEP = [
    (d, a)
    for d in (1.5, 3.0, 5.0, 7.5, 10.0)
    for a in ((0, 0, 0), (25, 10, 30), (-40, 0, -60), (10, -35, 120), (30, 25, 180))
]


@pytest.mark.parametrize("d,angles", LED_SWEEP)
def test_led_pose_sweep(d, angles):
    T = _true_pose(d, *angles)
    img = synth.render(K, T, [LED], noise_std=3.0, seed=int(d * 10), ss=3)
    span = np.ptp(synth.project(K, T, LED["keypoints"])[0], axis=0).max()
    assert span >= 20.0
    est = make(LedLocalizer, [LED]).localize(img)
    assert est is not None
    assert est["marker_id"] == "led" and est["n_points"] == 4
    assert abs(est["distance"] - d) / d <= 0.03
    assert rot_err_deg(est["T_cam_dock"], T) < 3.0  # also proves the reference/ordering
    assert np.median(keypoint_err_px(est["T_cam_dock"], T, LED["keypoints"])) < 0.3


@pytest.mark.parametrize("layout", ["rectangle", "circle"])
@pytest.mark.parametrize("reference_index", [0, 2])
@pytest.mark.parametrize("roll", [0, 45, 90, 135, 180, -135, -90, -45])
def test_led_reference_ordering_under_in_plane_rotation(layout, reference_index, roll):
    m = led_marker(layout, reference_index, T=T_offset(0.1, -0.05, yaw_deg=20.0))
    T = synth.pose_looking_at_dock(4.0, 15.0, -10.0, roll, offset=centre_of(m))
    est = make(LedLocalizer, [m]).localize(synth.render(K, T, [m], ss=2))
    assert est is not None
    # a wrong reference or order gives >= 90 deg of rotation error on a 4-fold symmetric array
    assert rot_err_deg(est["T_cam_dock"], T) < 2.0
    assert est["distance"] == pytest.approx(4.0, rel=0.01)


def test_led_expected_order_matches_manifest_layouts():
    rect = led_marker("rectangle")["keypoints"]  # TL, TR, BR, BL: counter-clockwise is TL, BL, BR, TR
    assert expected_order(rect, 0).tolist() == [0, 3, 2, 1]
    circ = led_marker("circle")["keypoints"]  # top, right, bottom, left
    assert expected_order(circ, 1).tolist() == [1, 0, 3, 2]


def test_led_ignores_a_bright_distractor():
    T = _true_pose(5.0, 20.0, 0.0, 10.0)
    img = synth.render(K, T, [LED], ss=2)
    cv2.circle(img, (60, 400), 7, (255, 255, 255), -1, cv2.LINE_AA)  # bigger and brighter than the LEDs
    est = make(LedLocalizer, [LED]).localize(img)
    assert est is not None and abs(est["distance"] - 5.0) / 5.0 < 0.03
    assert rot_err_deg(est["T_cam_dock"], T) < 3.0


def test_led_dim_array_found_by_relative_threshold():
    T = _true_pose(6.0, 0.0, 0.0, 0.0)
    img = synth.render(K, T, [LED], ss=2, halo_gain=0.45)
    img = (img.astype(np.float32) * 0.5).astype(np.uint8)  # LED cores ~128, halos ~60
    est = make(LedLocalizer, [LED]).localize(img)
    assert est is not None and abs(est["distance"] - 6.0) / 6.0 < 0.03


def test_led_missing_led_gives_none():
    m3 = dict(LED, keypoints=LED["keypoints"][:3], colors=LED["colors"][:3])
    img = synth.render(K, _true_pose(4.0, 0, 0, 0), [m3], ss=2)  # only 3 LEDs drawn
    assert make(LedLocalizer, [LED]).localize(img) is None


# ---------------------------------------------------------------- ArUco

ARUCO_SWEEP = [(d, a) for d in (0.5, 1.0, 2.0, 2.5) for a in ((0, 0, 0), (30, 10, 25), (-40, -15, -100))]


@pytest.mark.parametrize("d,angles", ARUCO_SWEEP)
def test_aruco_pose_sweep(d, angles):
    m = square_marker("aruco", 0.2, T=T_offset(-0.2, 0.1, 30.0), dictionary="DICT_4X4_50", marker_id=7)
    T = synth.pose_looking_at_dock(d, *angles, offset=centre_of(m))
    est = make(ArucoLocalizer, [LED, m]).localize(synth.render(K, T, [m], noise_std=2.0))
    assert est is not None and est["marker_id"] == "aruco"
    big = min_side_px(T, m) >= 40.0  # below ~40 px the corners are only good to ~0.5 px
    assert abs(est["distance"] - d) / d <= (0.01 if big else 0.03)
    assert np.median(keypoint_err_px(est["T_cam_dock"], T, m["keypoints"])) <= (0.3 if big else 1.0)
    assert rot_err_deg(est["T_cam_dock"], T) < 3.0  # incl. the IPPE flip at 40 deg


def test_aruco_other_id_or_dictionary_gives_none():
    T = _true_pose(1.0, 0, 0, 0)
    img = synth.render(K, T, [dict(ARUCO, marker_id=8)], ss=2)
    assert make(ArucoLocalizer, [ARUCO]).localize(img) is None
    assert make(ArucoLocalizer, [ARUCO], marker_id="nope").localize(img) is None


def test_aruco_refine_options():
    T = _true_pose(1.0, 20, 0, 0)
    img = synth.render(K, T, [ARUCO], ss=2)
    for refine in ("none", "subpix", "contour"):
        est = make(ArucoLocalizer, [ARUCO], refine=refine).localize(img)
        assert est is not None and abs(est["distance"] - 1.0) < 0.05
    with pytest.raises(ValueError):
        ArucoLocalizer(refine="bogus")


# ---------------------------------------------------------------- QR

QR_SWEEP = [(d, a) for d in (0.3, 0.5, 0.7) for a in ((0, 0, 0), (30, 10, 25), (-40, -10, -100))]


@pytest.mark.parametrize("refine", ["ecc", "finders"])
@pytest.mark.parametrize("d,angles", QR_SWEEP)
def test_qr_pose_sweep(d, angles, refine):
    m = square_marker("qr", 0.15, T=T_offset(0.25, -0.1, 0.0), payload="DOCK-01")
    T = synth.pose_looking_at_dock(d, *angles, offset=centre_of(m))
    est = make(QrLocalizer, [LED, m], refine=refine).localize(synth.render(K, T, [m], noise_std=2.0))
    assert est is not None and est["marker_id"] == "qr"
    # finders: the finder-pattern corners, not the extrapolated BR corner; ecc: the aligned code's 4 corners
    assert est["n_points"] >= (8 if refine == "finders" else 4)
    assert abs(est["distance"] - d) / d <= 0.01
    assert np.median(keypoint_err_px(est["T_cam_dock"], T, m["keypoints"])) <= 0.4
    assert rot_err_deg(est["T_cam_dock"], T) < 3.0


def test_qr_far_code_falls_back_to_four_corners():
    T = synth.pose_looking_at_dock(1.3, 20, 0, 10)  # ~2.5 px modules: decodes, finders unreliable
    est = make(QrLocalizer, [QR], allow_undecoded=True).localize(synth.render(K, T, [QR], noise_std=2.0))
    assert est is not None and abs(est["distance"] - 1.3) / 1.3 <= 0.05  # 4 corners, BR extrapolated


def test_qr_payload_must_match():
    T = synth.pose_looking_at_dock(0.5, 10, 0, 0)
    img = synth.render(K, T, [dict(QR, payload="SOMETHING-ELSE")], ss=2)
    assert make(QrLocalizer, [QR]).localize(img) is None


def test_qr_detector_and_refine_options():
    T = synth.pose_looking_at_dock(0.5, 20, 0, 10)
    img = synth.render(K, T, [QR], ss=2)
    for detector in ("zxing", "aruco", "classic"):
        for refine in ("ecc", "finders", "subpix", "none"):
            est = make(QrLocalizer, [QR], detector=detector, refine=refine).localize(img)
            assert est is not None and abs(est["distance"] - 0.5) / 0.5 < 0.03, (detector, refine)


# ---------------------------------------------------------------- robustness

ALL = [LED, QR, ARUCO]
CLASSES = [LedLocalizer, QrLocalizer, ArucoLocalizer]
_rng = np.random.default_rng(0)
JUNK = {
    "black": np.zeros((H, W, 3), np.uint8),
    "white": np.full((H, W, 3), 255, np.uint8),
    "noise": _rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
    "gauss": np.clip(_rng.normal(40, 60, (H, W, 3)), 0, 255).astype(np.uint8),
    "sparse": ((_rng.random((H, W, 3)) > 0.999) * 255).astype(np.uint8),
    "empty_scene": synth.render(K, np.eye(4), [], ss=1, noise_std=5.0),
    "tiny": _rng.integers(0, 256, (8, 8, 3), dtype=np.uint8),
    "1x1": np.zeros((1, 1, 3), np.uint8),
    "0x0": np.zeros((0, 0, 3), np.uint8),
}


@pytest.mark.parametrize("cls", CLASSES)
@pytest.mark.parametrize("name", list(JUNK))
def test_none_on_junk_images(cls, name):
    assert make(cls, ALL).localize(JUNK[name]) is None


@pytest.mark.parametrize("cls", CLASSES)
def test_none_without_a_matching_marker(cls):
    img = synth.render(K, _true_pose(1.0, 0, 0, 0), ALL, ss=2)
    assert make(cls, []).localize(img) is None


@pytest.mark.parametrize("cls", CLASSES)
def test_class_metadata(cls):
    assert cls.name in ("led", "qr", "aruco") and cls.__doc__ and "\n" not in cls.__doc__.strip()
    cls()  # every constructor parameter has a default


def _check(est):
    if est is not None:
        assert np.isfinite(est["distance"]) and est["distance"] > 0
        assert np.asarray(est["T_cam_dock"]).shape == (4, 4)
        assert np.all(np.isfinite(est["T_cam_dock"]))


_LOCS = {cls.name: make(cls, ALL) for cls in CLASSES}


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(
        np.uint8, hnp.array_shapes(min_dims=3, max_dims=3, min_side=1, max_side=48).map(lambda s: (s[0], s[1], 3))
    )
)
def test_property_random_images_never_raise(img):
    for loc in _LOCS.values():
        _check(loc.localize(img))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    d=st.floats(0.2, 14.0),
    yaw=st.floats(-80, 80),
    pitch=st.floats(-80, 80),
    roll=st.floats(-180, 180),
    noise=st.floats(0, 80),
    seed=st.integers(0, 2**16),
)
def test_property_rendered_scenes_never_raise(d, yaw, pitch, roll, noise, seed):
    img = synth.render(K, _true_pose(d, yaw, pitch, roll), ALL, ss=1, noise_std=noise, seed=seed)
    for loc in _LOCS.values():
        _check(loc.localize(img))


def test_led_array_not_confused_with_tinted_marker_plates():
    """Blobs measured on a physical-mode frame 9.5 m from the dock: the QR and ArUco plates,
    tinted cyan by the water's light, are brighter than the LEDs and, with two LEDs, fit a
    pose 78 deg off the line of sight within 0.02 px. The best-fitting subset seen within
    max_view_deg must win: the four LEDs (9.5 m), not the plates (1.9 m)."""
    from evalkit.localizers.led import LedLocalizer

    K = np.array([[554.2562584220408, 0.0, 319.5], [0.0, 554.2562584220408, 239.5], [0.0, 0.0, 1.0]])
    marker = {
        "id": "led",
        "kind": "led_array",
        "reference_index": 0,
        "reference_indices": [0],
        "keypoints": [[-0.3, 0.3, 0.0], [0.3, 0.3, 0.0], [0.3, -0.3, 0.0], [-0.3, -0.3, 0.0]],
        "colors": [[1.0, 0.35, 0.0], [0.0, 0.85, 0.6], [0.0, 0.85, 0.6], [0.0, 0.85, 0.6]],
    }
    loc = LedLocalizer()
    loc.reset({"width": 640, "height": 480, "K": K, "dist": None, "markers": [marker]})
    cents = np.array(
        [
            [312.43, 239.53],
            [327.59, 239.57],
            [337.0, 256.83],
            [336.91, 222.09],
            [302.0, 222.0],
            [302.0, 257.0],
            [327.25, 239.49],
        ]
    )
    masses = np.array([18199.0, 10536.0, 6708.0, 6612.0, 6482.0, 6434.0, 2215.0])
    chroma = np.array(
        [
            [-0.9799, -0.1996],
            [-0.9796, -0.2012],
            [-0.9992, -0.0404],
            [-0.9992, -0.0407],
            [0.1316, 0.9913],
            [-0.9990, -0.0436],
            [-0.9800, -0.1988],
        ]
    )
    est = loc._best_pose(cents, masses, chroma)
    assert est is not None and est["distance"] == pytest.approx(9.5, rel=0.01)
    loose = LedLocalizer(max_view_deg=89.0)
    loose.reset({"width": 640, "height": 480, "K": K, "dist": None, "markers": [marker]})
    assert loose._best_pose(cents, masses, chroma)["distance"] < 2.5  # the lookalike fits better
