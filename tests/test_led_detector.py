"""Mechanisms of the LED detector's blob stage (evalkit.localizers.led_blobs): colour from
background-subtracted pixels, the noise-aware absolute floor, LED-likeness ranking against
caustics on a captured rendered frame, and the robust background and noise estimates."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import synth_images as synth  # noqa: E402
from test_localizers import LED, K, _true_pose, make, rot_err_deg  # noqa: E402

from evalkit.localizers import led_blobs as lb  # noqa: E402
from evalkit.localizers.led import LedLocalizer  # noqa: E402

DATA = Path(__file__).parent / "data" / "sunlit_pool"
VEIL = np.array([30.0, 72.0, 66.0])  # a green-blue veil (8-bit sRGB): 72 DN, as at 8 m in moderate water (article mode)


def veiled(d: float, gain: float, seed: int = 1):
    """The LED array at ``d`` m drawn dim (``gain`` x the synthetic LEDs) over a uniform
    veil with Gaussian noise (2 DN): (image (H,W,3) uint8, true T_cam_dock)."""
    T = _true_pose(d, 15.0, -5.0, 20.0)
    leds = synth.render(K, T, [LED], background=(0, 0, 0), ss=2).astype(np.float32)
    rng = np.random.default_rng(seed)
    img = np.clip(VEIL + gain * leds + rng.normal(0.0, 2.0, leds.shape), 0, 255).astype(np.uint8)
    return img, T


@pytest.mark.parametrize("d", [4.0, 8.0])
def test_colour_finds_the_reference_led_in_a_veil_brighter_than_half_the_threshold(d):
    """The first level sits at 0.6 x max (~77 DN), so half of it (~38 DN) is below the veil
    (72 DN): averaging every pixel of a blob's box above half the threshold reads the veil's
    green-blue for every blob and finds no reference LED. The background-subtracted colour
    reads the orange reference."""
    img, T = veiled(d, gain=0.2)
    t0 = 0.6 * float(img.max())
    assert 0.5 * t0 < VEIL.max()
    est = make(LedLocalizer, [LED]).localize(img)
    assert est is not None and est["distance"] == pytest.approx(d, rel=0.01)
    assert rot_err_deg(est["T_cam_dock"], T) < 2.0  # a wrong reference LED gives >= 90 deg


def test_noise_floor_separates_the_leds_when_the_relative_level_is_below_the_veil():
    """LED peaks ~107 DN over a 72 DN veil: 0.6 x max (64 DN) is below the veil, so the
    relative level alone makes the whole frame one component. The floor (5 sigma above the
    local background) keeps only the LEDs."""
    img, T = veiled(6.0, gain=0.12)
    v = img.max(axis=2)
    t0 = 0.6 * float(v.max())
    assert np.mean(v > t0) > 0.95  # the relative level: everything
    fr = lb.prepare(img)
    assert fr.sigma == pytest.approx(2.0, rel=0.25)  # the 2 DN of noise drawn
    blobs = lb.components(fr, t0, 2000)
    assert blobs is not None and blobs.count == 4
    est = make(LedLocalizer, [LED]).localize(img)
    assert est is not None and est["distance"] == pytest.approx(6.0, rel=0.01)
    assert rot_err_deg(est["T_cam_dock"], T) < 2.0


def _captured():
    meta = json.loads((DATA / "caustics_5p75m.json").read_text())
    img = cv2.cvtColor(cv2.imread(str(DATA / "caustics_5p75m.png"), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    camera = {**meta["camera"], "markers": meta["markers"]}
    T = np.asarray(meta["T_cam_dock"], float)
    kp = np.asarray(meta["markers"][0]["keypoints"], float)
    K_ = np.asarray(camera["K"], float).reshape(3, 3)
    uv = cv2.projectPoints(kp, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K_, None)[0].reshape(-1, 2)
    return img, camera, T, uv, float(meta["d_true"])


def test_caustic_cusps_beside_the_led_array_do_not_take_its_place():
    """A rendered physical-mode frame of the sunlit pool (clear water, caustics on the
    floor, walls and dock) 5.75 m from the dock (tests/data/sunlit_pool/README.md): at
    0.6 x max the frame holds > 100 blobs and the 7 most massive include at most 3 LEDs
    (ranking by mass alone loses the array: the previous detector found no pose here).
    Ranked by LED-likeness, the 4 first coloured candidates are the 4 LEDs, and the pose
    is the dock's."""
    img, camera, T, uv, d_true = _captured()
    assert img.shape == (480, 640, 3)
    fr = lb.prepare(img)
    t0 = 0.6 * float(fr.v.max())
    blobs = lb.components(fr, t0, 2000)
    assert blobs.count > 100
    heaviest = np.argsort(blobs.mass[1:])[::-1][:7] + 1
    centres = blobs.centres[heaviest] + blobs.origin
    on_led = np.linalg.norm(centres[:, None] - uv[None], axis=2).min(axis=1) < 2.0
    assert on_led.sum() <= 3
    loc = LedLocalizer()
    loc.reset(camera)
    cands = loc.candidates(img)
    assert cands is not None
    first = cands[0][:4]
    assert np.linalg.norm(first[:, None] - uv[None], axis=2).min(axis=0).max() < 1.0
    est = loc.localize(img)
    assert est is not None and est["distance"] == pytest.approx(d_true, rel=0.01)
    assert rot_err_deg(est["T_cam_dock"], T) < 2.0


def test_noise_sigma_is_robust_to_a_gradient_and_bright_spots():
    """Gaussian noise of 3 DN on a smooth ramp with a few saturated discs: sigma ~3 DN."""
    rng = np.random.default_rng(3)
    ramp = np.linspace(40, 160, 640)[None, :].repeat(480, axis=0)
    v = np.clip(ramp + rng.normal(0, 3.0, ramp.shape), 0, 255).astype(np.uint8)
    for x in (100, 300, 500):
        cv2.circle(v, (x, 240), 12, 255, -1)
    assert lb.noise_sigma(v) == pytest.approx(3.0, rel=0.1)
    assert lb.noise_sigma(np.full((48, 64), 90, np.uint8)) == lb.MIN_SIGMA_DN  # noise-free: the floor


def test_background_is_the_veil_under_a_large_led():
    """An LED disc 85 px across (the largest an LED of a fully seen array can be at 640
    px) on a 72 DN veil: the local background at its centre is the veil, so its excess
    is the LED's own brightness."""
    img = np.empty((480, 640, 3), np.uint8)
    img[:] = VEIL.astype(np.uint8)
    cv2.circle(img, (320, 240), 42, (40, 200, 170), -1)
    fr = lb.prepare(img)
    assert int(fr.excess[240, 320]) == 200 - 72
    assert np.allclose(fr.bg_at(320, 240), VEIL, atol=1)


def test_compactness_of_a_disc_a_square_and_a_filament():
    disc_area = np.pi * 10**2
    assert lb.compactness(disc_area, 20, 20) == pytest.approx(1.0, abs=0.01)
    assert lb.compactness(16, 4, 4) == pytest.approx(1.0)
    assert lb.compactness(60, 30, 2) < 0.1  # a straight filament
    assert lb.compactness(120, 40, 40) < 0.1  # a thin bent network
    assert lb.compactness(3, 2, 2) == 1.0  # too small to tell


def test_previous_pose_is_the_prior_and_shared_state():
    """The pose found becomes the prior (memo state) of the next frame; reset forgets it."""
    img, _ = veiled(5.0, gain=0.5)
    loc = make(LedLocalizer, [LED])
    assert loc.memo_state() == b"-"
    est = loc.localize(img)
    assert est is not None and loc.memo_state() == np.asarray(est["T_cam_dock"], np.float64).tobytes()
    near = loc._near_prior(np.array([[0.0, 0.0]]))
    assert not near[0]
    loc.reset({"K": K, "width": 640, "height": 480, "markers": [LED]})
    assert loc.memo_state() == b"-"
    assert make(LedLocalizer, [LED], prior=False).localize(img) is not None


def test_search_window_holds_the_predicted_leds_on_background_cells():
    """With a prior, the window is the projected LEDs' box grown by half their span (at
    least 48 px), snapped outwards to the 32 px background cells of a 640 px image."""
    img, camera, T, uv, _ = _captured()
    loc = LedLocalizer()
    loc.reset(camera)
    assert loc._window(img.shape[:2]) is None  # no prior: no window
    loc._prev_T = T.copy()
    x0, y0, x1, y1 = loc._window(img.shape[:2])
    span = float(np.ptp(uv, axis=0).max())  # 58 px at 5.75 m: margin 48 px
    margin = max(48.0, 0.5 * span)
    assert all(v % 32 == 0 for v in (x0, y0, x1, y1))
    assert x0 <= uv[:, 0].min() - margin and x1 >= uv[:, 0].max() + margin
    assert y0 <= uv[:, 1].min() - margin and y1 >= uv[:, 1].max() + margin
    assert x0 > uv[:, 0].min() - margin - 32 and x1 < uv[:, 0].max() + margin + 32
    loc._prev_T = T.copy()
    loc._prev_T[:3, 3] *= 0.2  # 1.15 m away: the array spans ~290 px, window > half the image
    assert loc._window(img.shape[:2]) is None
    behind = T.copy()
    behind[2, 3] = -5.0
    loc._prev_T = behind
    assert loc._window(img.shape[:2]) is None


def test_tracked_window_gives_the_whole_image_pose_and_falls_back_when_the_prior_is_wrong():
    """On the sunlit frame: with the true pose as prior the window search gives the same
    pose as the whole image (within 1 mm and 0.01 deg); with a prior pointing at the
    other side of the frame (no LEDs in the window) the whole image still finds the dock."""
    img, camera, T, _, d_true = _captured()
    whole = LedLocalizer(roi=False)
    whole.reset(camera)
    whole._prev_T = T.copy()
    ref = whole.localize(img)
    loc = LedLocalizer()
    loc.reset(camera)
    loc._prev_T = T.copy()
    assert loc._tracked(img) is not None
    loc._prev_T = T.copy()
    est = loc.localize(img)
    assert ref is not None and est is not None
    assert est["distance"] == pytest.approx(ref["distance"], abs=1e-3)
    assert rot_err_deg(est["T_cam_dock"], ref["T_cam_dock"]) < 0.01
    wrong = T.copy()
    wrong[0, 3] += 2.5  # the array predicted ~240 px to the side
    loc._prev_T = wrong
    assert loc._tracked(img) is None
    loc._prev_T = wrong
    est = loc.localize(img)
    assert est is not None and est["distance"] == pytest.approx(d_true, rel=0.01)
