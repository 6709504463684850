"""Marker capability oracles: N-LED arrays with several reference LEDs and distractors, the QR
marker description (version, ECC, quiet zone) and the zxing-cpp QR default, the shared
square-marker base (ROI search, metadata)."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

sys.path.insert(0, str(Path(__file__).parent))
import synth_images as synth  # noqa: E402
from test_localizers import ARUCO, QR, H, K, W, keypoint_err_px, make, rot_err_deg  # noqa: E402

from blendgen import markers as mk  # noqa: E402
from blendgen.config.models import LedArray, SquareMarker  # noqa: E402
from evalkit.localizers.aruco import ArucoLocalizer  # noqa: E402
from evalkit.localizers.led import LedLocalizer, match_rotation  # noqa: E402
from evalkit.localizers.led_blobs import centroid  # noqa: E402
from evalkit.localizers.qr import QrLocalizer  # noqa: E402
from evalkit.localizers.square import SquareMarkerLocalizer  # noqa: E402


def led_manifest(**kw) -> dict:
    return mk.manifest_marker(LedArray(**kw))


# ---------------------------------------------------------------- N-LED arrays


def test_circle_of_n_leds_has_n_keypoints_and_colours():
    m = led_manifest(layout="circle", count=7, size_m=0.8, reference_index=[0, 1])
    kp = np.asarray(m["keypoints"])
    assert kp.shape == (7, 3) and np.allclose(np.hypot(kp[:, 0], kp[:, 1]), 0.4)
    assert m["reference_indices"] == [0, 1] and m["reference_index"] == 0
    assert [c == list(LedArray().reference_color) for c in m["colors"]] == [True, True] + [False] * 5


@pytest.mark.parametrize(
    "kw",
    [
        dict(layout="circle", count=6, reference_index=[0, 3]),  # 180-deg symmetric colour ring
        dict(layout="circle", count=6, reference_index=[0, 2, 4]),  # 120-deg symmetric
        dict(layout="rectangle", count=6),  # a rectangle has 4 corners
        dict(layout="custom", positions_m=[[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]]),  # not convex
        dict(layout="circle", count=5, reference_index=[0, 1, 2, 3, 4]),  # no non-reference LED
        dict(layout="circle", count=5, reference_index=5),
    ],
)
def test_ambiguous_or_impossible_led_patterns_are_rejected(kw):
    with pytest.raises(ValidationError):
        LedArray(**kw)


def test_match_rotation_is_unique_or_none():
    pat = np.array([1, 1, 0, 0, 0, 0])
    assert match_rotation(np.roll(pat, 2), pat) == 2
    assert match_rotation(np.array([1, 0, 1, 0, 0, 0]), pat) is None
    assert match_rotation(np.array([1, 0, 0, 1, 0, 0]), np.array([1, 0, 0, 1, 0, 0])) is None  # symmetric


N_LED_CASES = [(d, roll, refs) for d in (2.0, 6.0) for roll in (0, 70, -150) for refs in ([0], [0, 1], [2, 3, 5])]


@pytest.mark.parametrize("d,roll,refs", N_LED_CASES)
def test_n_led_array_pose(d, roll, refs):
    m = led_manifest(layout="circle", count=6, size_m=0.7, reference_index=refs)
    T = synth.pose_looking_at_dock(d, 25.0, -10.0, roll)
    est = make(LedLocalizer, [m]).localize(synth.render(K, T, [m], noise_std=2.0, ss=3))
    assert est is not None and est["n_points"] == 6
    assert est["distance"] == pytest.approx(d, rel=0.02)
    assert rot_err_deg(est["T_cam_dock"], T) < 2.0  # a wrong order is >= 60 deg off
    assert np.median(keypoint_err_px(est["T_cam_dock"], T, m["keypoints"])) < 0.3


def _blob(img, uv, r, rgb):
    cv2.circle(img, (int(round(uv[0] * 16)), int(round(uv[1] * 16))), int(r * 16), rgb, -1, cv2.LINE_AA, 4)


@pytest.mark.parametrize("count,refs", [(4, [0]), (6, [0, 1]), (8, [0, 2])])
def test_led_pattern_resolved_among_led_coloured_distractors(count, refs):
    """Particles the colour of the LEDs, brighter and bigger than them, near the array:
    only the geometric check (convex + colour pattern + PnP reprojection) can reject them."""
    m = led_manifest(layout="circle", count=count, size_m=0.7, reference_index=refs)
    T = synth.pose_looking_at_dock(4.0, 20.0, 5.0, 30.0)
    img = synth.render(K, T, [m], noise_std=2.0, ss=2)
    uv, _ = synth.project(K, T, m["keypoints"])
    green = tuple(
        float(x) for x in 255 * synth.linear_to_srgb(m["colors"][[i for i in range(count) if i not in refs][0]])
    )
    for du, dv in ((25, 3), (-30, 40), (5, -45)):  # three distractors near the array
        p = uv.mean(axis=0) + (du, dv)
        _blob(img, p, 4.0, green)
        _blob(img, p, 2.0, (255, 255, 255))
    est = make(LedLocalizer, [m]).localize(img)
    assert est is not None and est["distance"] == pytest.approx(4.0, rel=0.02)
    assert rot_err_deg(est["T_cam_dock"], T) < 2.0


def test_core_centroid_resists_one_sided_glow():
    """A saturated LED core with a glow (half as bright) smeared to one side, as forward
    scatter plus motion blur would do: the weighted centroid moves towards the glow, the
    core's does not."""
    img = np.zeros((60, 60, 3), np.uint8)
    cv2.ellipse(img, ((36.0, 30.0), (20.0, 9.0), 0.0), (0, 130, 100), -1, cv2.LINE_AA)  # glow to the right
    cv2.circle(img, (30 * 16, 30 * 16), 3 * 16, (255, 255, 255), -1, cv2.LINE_AA, 4)  # core at (30, 30)
    v = img.max(axis=2)
    n, labels, stats, _ = cv2.connectedComponentsWithStats((v > 100).astype(np.uint8), connectivity=8)
    lab = int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) + 1
    res = {}
    for mode in ("weighted", "core"):
        res[mode] = centroid(v, labels, lab, 50.0, mode, 0, 0)
    assert abs(res["core"][0] - 30.0) < 0.1 and abs(res["core"][1] - 30.0) < 0.1
    assert res["weighted"][0] - 30.0 > 1.0


# ---------------------------------------------------------------- QR marker description


def test_qr_manifest_records_version_ecc_modules_and_iso_quiet_zone():
    spec = SquareMarker(kind="qr", id="qr", size_m=0.15, payload="DOCK-01")
    m = mk.manifest_marker(spec)
    assert (m["qr_version"], m["error_correction"], m["modules"], m["quiet_zone_modules"]) == (1, "M", 21, 4)
    assert m["module_size_m"] == pytest.approx(0.15 / 21)
    tex = mk.texture_for(spec)
    assert tex.cells.shape == (29, 29) and tex.plane_size_m == pytest.approx(0.15 * 29 / 21)
    assert np.all(tex.cells[:4] == 255) and np.all(tex.cells[:, -4:] == 255)


def test_qr_error_correction_and_quiet_zone_are_configurable():
    spec = SquareMarker(
        kind="qr", id="qr", size_m=0.2, payload="DOCKING-STATION-0042", error_correction="H", quiet_zone_modules=2
    )
    m = mk.manifest_marker(spec)
    import segno

    v = segno.make_qr("DOCKING-STATION-0042", error="h", boost_error=False).version
    assert m["qr_version"] == v > 1 and m["modules"] == 17 + 4 * v and m["error_correction"] == "H"
    assert mk.texture_for(spec).cells.shape == (m["modules"] + 4,) * 2
    aruco = SquareMarker(kind="aruco", id="a", dictionary="DICT_4X4_50")
    assert aruco.quiet_zone_modules == 1 and mk.texture_for(aruco).cells.shape == (8, 8)


# ---------------------------------------------------------------- QR decoders


def _px_per_module(d):
    return K[0, 0] * 0.15 / 21 / d


@pytest.mark.parametrize("d,rel", [(0.6, 0.01), (1.2, 0.01), (1.8, 0.02)])
def test_zxing_default_decodes_small_modules_and_gives_the_pose(d, rel):
    """Down to 2.2 px/module (1.8 m); the distance error grows as the code shrinks (a
    0.15 m code is ~46 px wide at 1.8 m, oblique here)."""
    qr = dict(QR, modules=21, quiet_zone_modules=4)
    T = synth.pose_looking_at_dock(d, 15.0, 5.0, 20.0)
    img = synth.render(K, T, [qr], noise_std=2.0, ss=4)
    est = make(QrLocalizer, [qr]).localize(img)
    assert est is not None, f"{_px_per_module(d):.2f} px/module"
    assert est["distance"] == pytest.approx(d, rel=rel)
    assert rot_err_deg(est["T_cam_dock"], T) < 3.0


@pytest.mark.parametrize("d", [0.5, 1.0, 1.8])
def test_zxing_integer_corners_become_subpixel(d):
    """zxing-cpp reports integer corners (BR 1-2 px off); ECC alignment of the known code
    brings every keypoint under 0.3 px, from 7 down to 2.2 px/module."""
    T = synth.pose_looking_at_dock(d, 25.0, -10.0, 35.0)
    img = synth.render(K, T, [QR], noise_std=2.0)
    est = make(QrLocalizer, [QR], detector="zxing").localize(img)
    assert est is not None
    assert np.max(keypoint_err_px(est["T_cam_dock"], T, QR["keypoints"])) < 0.3
    raw = make(QrLocalizer, [QR], detector="zxing", refine="none").localize(img)
    assert raw is not None and raw["n_points"] == 4


# ---------------------------------------------------------------- square base class


def test_roi_search_gives_the_full_frame_result_and_recovers_after_a_jump():
    T = synth.pose_looking_at_dock(0.8, 10.0, 0.0, 0.0)
    img = synth.render(K, T, [ARUCO], ss=2)
    loc = make(ArucoLocalizer, [ARUCO])
    full = make(ArucoLocalizer, [ARUCO], roi=False).localize(img)
    first, second = loc.localize(img), loc.localize(img)  # the second searches the ROI only
    assert loc._last_quad is not None
    for est in (first, second):
        assert np.allclose(est["T_cam_dock"], full["T_cam_dock"], atol=1e-6)
    shifted = np.roll(img, 200, axis=1)  # the marker jumps out of the ROI: full-frame fallback
    shifted[:, :200] = img[0, 0]
    assert loc.localize(shifted) is not None


@pytest.mark.parametrize("cls", [ArucoLocalizer, QrLocalizer])
def test_square_localizers_share_the_base_and_declare_outputs(cls):
    assert issubclass(cls, SquareMarkerLocalizer)
    assert set(cls.outputs) == {"distance", "T_cam_dock", "marker_id"}
    assert set(LedLocalizer.outputs) == {"distance", "T_cam_dock", "marker_id"}


def test_qr_detectors_agree_on_a_clean_code():
    T = synth.pose_looking_at_dock(0.45, -20.0, 10.0, -60.0)
    img = synth.render(K, T, [QR], ss=2)
    ests = {det: make(QrLocalizer, [QR], detector=det).localize(img) for det in ("zxing", "aruco", "classic")}
    for det, est in ests.items():
        assert est is not None, det
        assert est["distance"] == pytest.approx(0.45, rel=0.01), det
    with pytest.raises(ValueError):
        QrLocalizer(detector="bogus")
    assert W == 640 and H == 480


# ---------------------------------------------------------------- qr_track

RECEDE = [1.2, 1.8, 2.4, 2.8, 3.2, 3.6, 4.0]


def _receding(payloads=None):
    payloads = payloads or ["DOCK-01"] * len(RECEDE)
    return [
        synth.render(
            K, synth.pose_looking_at_dock(d, 10.0, 5.0, 15.0), [dict(QR, payload=p)], noise_std=2.0, seed=i, ss=3
        )
        for i, (d, p) in enumerate(zip(RECEDE, payloads))
    ]


def test_qr_track_follows_a_decoded_code_beyond_decode_range():
    from evalkit.localizers.qr import QrTrackLocalizer

    imgs = _receding()
    qr, trk = make(QrLocalizer, [QR]), make(QrTrackLocalizer, [QR])
    plain = [qr.localize(im) for im in imgs]
    tracked = [trk.localize(im) for im in imgs]
    assert plain[0] is not None and plain[-1] is None  # 4 m: 1 px/module, no decode
    assert all(e is not None for e in tracked)
    for d, e, p in zip(RECEDE, tracked, plain):
        assert e["distance"] == pytest.approx(d, rel=0.01)
        assert e.get("tracked", False) == (p is None)  # tracked exactly where qr fails
    cold = make(QrTrackLocalizer, [QR])  # never decoded in this sequence
    assert [cold.localize(im) for im in imgs[::-1]][:2] == [None, None]
    trk.reset(synth.camera_dict(K, W, H, [QR]))  # reset forgets the decode
    assert trk.localize(imgs[-1]) is None


def test_qr_track_rejects_another_code_after_a_decode():
    from evalkit.localizers.qr import QrTrackLocalizer

    imgs = _receding(["DOCK-01", "DOCK-01"] + ["DOCK-02"] * (len(RECEDE) - 2))
    trk = make(QrTrackLocalizer, [QR])
    out = [trk.localize(im) for im in imgs]
    assert out[0] is not None and out[1] is not None
    # same version, same finder patterns: the ECC check against the known modules rejects it
    assert all(e is None for e in out[2:])
