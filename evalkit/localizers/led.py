"""LED-array localizer: bright blobs -> reference LED(s) by colour -> ordered PnP.

The array has N >= 4 LEDs in convex position; one or more reference LEDs have another
colour, and the cyclic reference/other pattern has no rotational symmetry (blendgen
checks it), so the colour pattern fixes the order. Pipeline (blob stage in
:mod:`evalkit.localizers.led_blobs`):
1. brightness v = max(R, G, B), its local background (median over 160 px at 640 px) and
   the frame's noise sigma (robust, from neighbour differences). A pixel is bright when
   v exceeds the relative level ``min(threshold, rel_threshold * max)`` (not below
   ``min_threshold``) *and* its local background by 5 sigma (the absolute, noise-aware
   floor: in a veil brighter than 0.6 x max the relative level alone merges the frame
   into one component). When no pose comes out of that level the threshold climbs a
   ladder (``ladder``: fractions of the frame's maximum, default 0.8 and 0.97) and the
   search repeats (a caustic line touching an LED separates higher up);
2. connected components (8-connected) with area and circularity limits, ranked by
   LED-likeness: first the blobs within the gate of an LED projected with the previous
   frame's pose (``prior``), then by compactness^2 x excess mass (compactness = fill x
   aspect, 1 for a disc; caustic filaments and networks 0.05-0.3). By mass alone, on the
   sunlit pool at 5.75 m (tests/data/sunlit_pool) the 7 heaviest of 256 blobs hold 0-3
   LEDs; by LED-likeness the 4 LEDs come first;
3. centroid of each blob (``centroid=``): ``core`` (default: intensity-weighted over
   the pixels above the middle of the blob's range, (threshold/2 + peak)/2, i.e. the
   saturated core and its anti-aliased rim; glow around the LED then cannot pull it) or
   ``weighted`` (intensity above half the threshold over the whole blob box, other blobs
   masked out). On the quickstart demo (``dockbench bench localizers``, 624 LED images)
   the core centroid is 0.084 px from the true centre (median; p95 0.199) against 0.092
   (0.223) weighted, 0.106 vs 0.124 beyond 4 m; a one-sided glow moves the weighted
   centroid by pixels and the core one by < 0.1 px (test oracle). An unweighted centroid
   of the saturated pixels only was also measured: same on the demo, but quantised on
   small (2-3 px) cores, 3-6 deg rotation errors at 5-10 m on the synthetic oracles;
4. colour: the chroma (opponent axes a = R - (G+B)/2, b = sqrt(3)/2 (G - B)) of the
   blob's pixels and its halo above the floor, each minus the local background colour,
   leaving out white-clipped pixels (colour lost): the veil adds nothing, so a reference
   LED in a bright veil still reads as itself (the former mean over the blob's box, veil
   included, read every blob as the veil's green). A blob must be saturated enough
   (``min_saturation``) and of the reference or the other LEDs' hue to be a candidate;
   candidates are measured lazily, most LED-like first, until ``max_candidates``;
5. order: angles around the centroid, counter-clockwise as seen from the camera with
   image y flipped to point up; the cyclic reference/other label sequence is matched
   against the keypoints' (dock frame, y up) at the single rotation where it agrees;
6. PnP: SOLVEPNP_IPPE on the dock-frame keypoints, both solutions checked, LM refine.

Search window: with a previous pose, steps 1-6 run first on the window around the LEDs it
projects (``roi``), with the whole image's threshold levels (fractions of its maximum) and
background cell size; the whole image when the window gives no pose. On a sunlit pool
the window leaves most caustic blobs out, which is where the time went (the blob stage
and the measured candidates scale with the pixels searched).

Particles, caustics and reflections (more than N blobs): the N most LED-like candidates
are solved first; when they do not fit within ``accept_px``, an assignment search with a
geometric consistency check over the ``max_candidates`` candidates (N + 3 by default):
N-subsets in order of summed LED-likeness rank, each in convex position, showing the
colour pattern at exactly one rotation, with blobs not far below the LED disc size the
subset's span implies (``min_size_frac``), seen within ``max_view_deg`` and reprojecting
all N LEDs within ``max_reproj_px`` (RMS); the first within ``accept_px`` ends the
search, otherwise the best fit wins. (The first passing subset by brightness lost to
tinted QR/ArUco patches under water light: four points in convex position admit a
strongly tilted pose within a fraction of a pixel, so fit and view angle, not
brightness, separate the array from lookalikes.) Chosen over RANSAC because N is small
(C(7,4) = 35 subsets, most rejected by the cheap convexity, colour and size tests before
any PnP), where RANSAC's minimal samples would still need the same colour/order
bookkeeping.

Parameters
----------
The keywords of :class:`LedLocalizer` (``-p led.NAME=VALUE`` on the command line):

threshold: brightness (max channel, 0-255) that LED cores exceed; lowered to
rel_threshold * image max (not below min_threshold) for dim images.
min_area_px / max_area_frac: blob area limits (px / fraction of the image).
min_circularity: area / (pi (max(w,h)/2)^2) for blobs of >= 12 px.
ref_hue: reference LED hue in degrees (None: from the marker's colours).
max_candidates: most LED-like coloured blobs considered (None: N + 3); max_blobs:
give up above this many blobs (the sunlit demo pool holds 200-370 at 0.6 x max; blob
statistics are vectorised, so only the measured candidates cost).
max_reproj_px: RMS reprojection error (px) above
which a blob set is rejected. min_saturation: chroma / brightness of a blob's
background-subtracted colour (0 grey, ~0.9 the LEDs' own colours) it needs to
count as a coloured LED, so white/grey highlights are not taken for LEDs (measured
on the sunlit frame of tests/data/sunlit_pool: LEDs 1.2-1.8, caustics 0.4-0.7;
0.2 rejects only near-grey blobs, shape and geometry do the rest).
max_hue_err_deg: hue distance allowed between a blob and its expected LED
colour. centroid: "core" or "weighted" (see the module docstring).
max_view_deg: largest angle (deg) between the array's normal and the line of sight
to it that a pose may have; flat LED discs seen beyond ~70 deg are foreshortened
below a third of their width, and lookalike blob sets (tinted marker plates plus two
LEDs) fit only at ~78 deg (measured on the physical-mode demo).
ladder: higher thresholds (fractions of the frame's max brightness) tried in turn
when the first level gives no pose (module docstring, step 1); () disables it.
prior: rank the blobs near the LEDs projected with the previous frame's pose first
(False: every frame alone); prior_gate_px: smallest gate radius (px) of that (8 px:
1 deg of yaw between frames moves the image by f x 0.017 = 9.7 px at f = 554 px).
measure_factor: at most measure_factor x max_candidates blobs are measured (colour,
centroid), most LED-like first, which bounds the time spent on clutter.
accept_px: a blob set fitting within this RMS reprojection error (px) ends the
search (2.5 x the p95 centroid error of the core centroid, module docstring step 3).
min_size_frac: a blob's diameter must be at least this fraction of the LED disc's
image diameter the set's span implies, less 1.5 px (``_sizes_fit``; 0.4: a
blurred disc cut at 0.97 of its peak by the ladder keeps about half its diameter).
max_solves: PnP solves per threshold level at most (35 = every 4-subset of 7).
roi: with a previous pose, search first only the window around the LEDs it
projects (``_window``), the whole image when that gives no pose; roi_margin: the
window's margin around the projected LEDs as a fraction of their span (0.5: the
array may move by half its own size between frames), at least roi_min_margin_px
(48 px: 5 deg of yaw at f = 554 px); roi_max_frac: above this share of the image the
window saves too little, the whole image is searched at once.
Reason for > 8 params: every threshold of the blob pipeline is a documented knob.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import cv2
import numpy as np

from evalkit.localizers import led_blobs as lb
from evalkit.localizers.pnp import camera_matrices, estimate_dict, solve_planar

_SQ3_2 = math.sqrt(3.0) / 2.0


def srgb_from_linear(c) -> np.ndarray:
    """Linear RGB in [0,1] (N,3) -> sRGB in [0,1]."""
    c = np.clip(np.asarray(c, float), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def hue_deg(rgb) -> np.ndarray:
    """Opponent-space hue (deg, [0, 360)) of RGB triples (N,3): ~HSV hue (0 red, 120 green)."""
    rgb = np.asarray(rgb, float).reshape(-1, 3)
    a = rgb[:, 0] - 0.5 * (rgb[:, 1] + rgb[:, 2])
    b = _SQ3_2 * (rgb[:, 1] - rgb[:, 2])
    return np.degrees(np.arctan2(b, a)) % 360.0


def ccw_order(keypoints: np.ndarray) -> np.ndarray:
    """Keypoint indices counter-clockwise (dock x right, y up) around their centroid."""
    kp = np.asarray(keypoints, float)[:, :2]
    ang = np.arctan2(kp[:, 1] - kp[:, 1].mean(), kp[:, 0] - kp[:, 0].mean())
    return np.argsort(ang, kind="stable")


def expected_order(keypoints: np.ndarray, reference_index: int) -> np.ndarray:
    """Keypoint indices counter-clockwise (dock x right, y up) around their centroid,
    starting at the reference LED."""
    o = ccw_order(keypoints)
    k = int(np.nonzero(o == reference_index)[0][0])
    return np.roll(o, -k)


def image_order(uv: np.ndarray, ref: int | None = None) -> np.ndarray:
    """Blob indices counter-clockwise as seen in the image (y flipped up) around the
    centroid of the blobs (N,2), starting at blob ``ref`` (None: at the smallest angle)."""
    ang = np.arctan2(-(uv[:, 1] - uv[:, 1].mean()), uv[:, 0] - uv[:, 0].mean())
    start = 0.0 if ref is None else ang[ref]
    return np.argsort((ang - start) % (2 * np.pi), kind="stable")


def match_rotation(labels: np.ndarray, pattern: np.ndarray) -> int | None:
    """The unique k with roll(labels, -k) == pattern (cyclic sequences of 0/1), or None."""
    n = len(pattern)
    twice = np.concatenate((labels, labels))  # twice[k : k + n] == roll(labels, -k)
    hits = [k for k in range(n) if np.array_equal(twice[k : k + n], pattern)]
    return hits[0] if len(hits) == 1 else None


class LedLocalizer:
    """LED array (N >= 4): noise-aware threshold, LED-like blobs, reference LEDs by colour, pattern order, IPPE PnP."""

    name = "led"
    outputs = ("distance", "T_cam_dock", "marker_id")

    # fmt: off
    def __init__(self, marker_id: str | None = None, threshold: float = 200.0,
                 rel_threshold: float = 0.6, min_threshold: float = 40.0,
                 min_area_px: int = 1, max_area_frac: float = 0.05, min_circularity: float = 0.4,
                 ref_hue: float | None = None, max_candidates: int | None = None, max_blobs: int = 2000,
                 max_reproj_px: float = 3.0, min_saturation: float = 0.2, max_hue_err_deg: float = 60.0,
                 centroid: str = "core", max_view_deg: float = 70.0, ladder: tuple = (0.8, 0.97),
                 prior: bool = True, prior_gate_px: float = 8.0, measure_factor: int = 3,
                 accept_px: float = 0.5, min_size_frac: float = 0.4, max_solves: int = 35,
                 roi: bool = True, roi_margin: float = 0.5, roi_min_margin_px: float = 48.0,
                 roi_max_frac: float = 0.5):
        """The keywords are documented in the module docstring, section "Parameters"."""
        if centroid not in ("weighted", "core"):
            raise ValueError(f"centroid must be weighted or core, got {centroid!r}")
        self.marker_id = marker_id
        self.threshold = float(threshold)
        self.rel_threshold = float(rel_threshold)
        self.min_threshold = float(min_threshold)
        self.min_area_px = int(min_area_px)
        self.max_area_frac = float(max_area_frac)
        self.min_circularity = float(min_circularity)
        self.ref_hue = None if ref_hue is None or str(ref_hue) in ("None", "") else float(ref_hue)
        self.max_candidates = (None if max_candidates is None or str(max_candidates) in ("None", "")
                               else int(max_candidates))
        self.max_blobs = int(max_blobs)
        self.max_reproj_px = float(max_reproj_px)
        self.min_saturation = float(min_saturation)
        self.prior = str(prior).lower() not in ("false", "0", "no", "off")
        self.prior_gate_px = float(prior_gate_px)
        self.measure_factor = max(1, int(measure_factor))
        self.accept_px = float(accept_px)
        self.min_size_frac = float(min_size_frac)
        self.max_solves = max(1, int(max_solves))
        self.roi = str(roi).lower() not in ("false", "0", "no", "off")
        self.roi_margin = float(roi_margin)
        self.roi_min_margin_px = float(roi_min_margin_px)
        self.roi_max_frac = float(roi_max_frac)
        self.cos_hue = math.cos(math.radians(float(max_hue_err_deg)))
        self.centroid = centroid
        self.cos_view = math.cos(math.radians(float(max_view_deg)))
        if isinstance(ladder, str):          # from ``-p led.ladder=0.8,0.97``
            ladder = [x for x in ladder.replace("(", "").replace(")", "").split(",") if x.strip()]
        self.ladder = tuple(sorted(float(f) for f in ladder))
        if any(not 0.0 < f <= 1.0 for f in self.ladder):
            raise ValueError(f"ladder fractions must be in (0, 1], got {self.ladder}")
        self._marker: Any = None            # the manifest's LED marker dict, set by reset()
        self._prev_T: np.ndarray | None = None
    # fmt: on

    def reset(self, camera: dict) -> None:
        """Pick the LED marker; precompute its keypoint order, colour pattern and colour axis."""
        self._K, self._dist = camera_matrices(camera)
        self._prev_T = None
        markers = list(camera.get("markers") or [])
        if self.marker_id is not None:
            m = next((x for x in markers if str(x.get("id")) == str(self.marker_id)), None)
        else:
            m = next((x for x in markers if x.get("kind") == "led_array"), None)
        self._marker = m if m is not None and m.get("kind") == "led_array" else None
        if m is None or self._marker is None:
            return
        self._kp = np.asarray(m["keypoints"], np.float64).reshape(-1, 3)
        self._n = len(self._kp)
        refs = sorted({int(i) for i in m.get("reference_indices", [m.get("reference_index", 0)])})
        self._kp_ccw = ccw_order(self._kp)
        self._pattern = np.isin(self._kp_ccw, refs).astype(int)  # 1 = reference, CCW order
        self._n_ref = len(refs)
        colors = srgb_from_linear(np.asarray(m.get("colors", [[1, 1, 1]] * self._n), float))
        h_ref = self.ref_hue if self.ref_hue is not None else float(hue_deg(colors[refs[0]])[0])
        others = [i for i in range(self._n) if i not in refs]
        u_other = np.mean([_unit(hue_deg(colors[i])[0]) for i in others], axis=0) if others else np.zeros(2)
        self._colour_axis = _unit(h_ref) - u_other  # score = chroma_dir . axis
        self._u_ref = _unit(h_ref)
        self._u_other = u_other / max(np.linalg.norm(u_other), 1e-9)
        span_m = float(np.max(np.linalg.norm(self._kp[:, None] - self._kp[None], axis=2)))
        r_led = float(m.get("led_radius_m") or 0.0)
        self._disc_per_span = 2.0 * r_led / span_m if span_m > 0 else 0.0

    # one call per frame is shared with the hybrid's LED (evalkit.memo): the state is the prior
    def memo_state(self) -> bytes:
        """The previous frame's pose (the candidate ranking's prior), as bytes."""
        return b"-" if self._prev_T is None else self._prev_T.tobytes()

    def memo_after(self):
        return None if self._prev_T is None else self._prev_T.copy()

    def memo_apply(self, before, after, est) -> None:
        """Take the prior the memoised call left (its pose, or None)."""
        self._prev_T = None if after is None else np.array(after, np.float64)

    def forget_prior(self) -> None:
        """Drop the previous pose (a caller that skipped frames: it is no longer the
        previous frame's)."""
        self._prev_T = None

    def localize(self, image: np.ndarray) -> dict | None:
        """Dock pose from one RGB uint8 image (H,W,3), or None. Remembers the pose (or
        None) as the prior of the next frame's candidate ranking."""
        if self._marker is None:
            return None
        a = np.asarray(image)
        if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 8:
            return None
        try:
            est = self._tracked(a)
            if est is None:
                est = self._localize(lb.prepare(a), self._vmax(a))
        except (cv2.error, ValueError, FloatingPointError, np.linalg.LinAlgError):
            est = None
        if self.prior:
            self._prev_T = None if est is None else np.array(est["T_cam_dock"], np.float64)
        return est

    def _tracked(self, image: np.ndarray) -> dict | None:
        """Pose from the search window around the LEDs projected with the previous
        frame's pose (:meth:`_window`), or None (no prior, window too large, or no pose in it:
        the caller then searches the whole image)."""
        win = self._window(image.shape[:2]) if self.roi and self._prev_T is not None else None
        if win is None:
            return None
        return self._localize(lb.prepare(image, win), self._vmax(image))

    def _window(self, shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
        """Search window (x0, y0, x1, y1) px: the bounding box of the LEDs projected with
        the previous frame's pose, grown by ``roi_margin`` x the predicted array span (at
        least ``roi_min_margin_px``) and snapped outwards to the background grid's cells
        (so its background cells are the whole image's). None when the LEDs project
        behind the camera or the window would cover more than ``roi_max_frac`` of the image."""
        pred = self._predicted_uv()
        if pred is None:
            return None
        h, w = shape
        cell = lb.background_cell(w)
        span = float(np.ptp(pred, axis=0).max())
        m = max(self.roi_min_margin_px, self.roi_margin * span)
        x0, y0 = np.floor((pred.min(axis=0) - m) / cell).astype(int) * cell
        x1, y1 = np.ceil((pred.max(axis=0) + m) / cell).astype(int) * cell
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        if x1 - x0 < 2 * cell or y1 - y0 < 2 * cell or (x1 - x0) * (y1 - y0) > self.roi_max_frac * h * w:
            return None
        return int(x0), int(y0), int(x1), int(y1)

    @staticmethod
    def _vmax(image: np.ndarray) -> float:
        """Largest channel value (0-255) of the whole image (the threshold levels'
        reference, also when only a window is searched)."""
        return float(cv2.minMaxLoc(image.reshape(image.shape[0], -1))[1])

    def _localize(self, fr: lb.Frame, vmax: float) -> dict | None:
        """Threshold levels in turn (module docstring, step 1) until one gives a pose."""
        for t in self._levels(vmax):
            est = self._pose_at(fr, t)
            if est is not None:
                return est
        return None

    def _pose_at(self, fr: lb.Frame, t: float) -> dict | None:
        """Pose at level ``t``: the N most LED-like coloured blobs alone first (one PnP on
        a clean frame); when they give no fit within ``accept_px``, the assignment search
        over the ``max_candidates`` most LED-like."""
        meas = self._measured(fr, t)
        taken = list(itertools.islice(meas, self._n))
        if len(taken) < self._n:
            return None
        est = self._best_pose(*_columns(taken))
        if est is not None and est["reproj_err_px"] <= self.accept_px:
            return est
        taken += list(itertools.islice(meas, self._k() - self._n))
        return est if len(taken) == self._n else self._best_pose(*_columns(taken))

    def _k(self) -> int:
        return self.max_candidates if self.max_candidates is not None else self._n + 3

    def candidates(self, image: np.ndarray):
        """The candidate blobs of ``image`` (H,W,3 uint8) at the first threshold level, as
        the pose search sees them: centroids (M,2) px, masses (M,), unit chroma (M,2),
        diameters (M,) px; or None (for benches of the blob stage)."""
        if self._marker is None:
            return None
        fr = lb.prepare(np.asarray(image))
        levels = self._levels(self._vmax(np.ascontiguousarray(image)))
        return self._blobs(fr, levels[0]) if levels else None

    def _levels(self, vmax: float) -> list[float]:
        """Brightness thresholds (0-255) to try in turn: the first level, then the ladder
        above it (levels at or below the maximum brightness find nothing and are dropped)."""
        t0 = max(self.min_threshold, min(self.threshold, self.rel_threshold * vmax))
        levels = [t0] + [f * vmax for f in self.ladder if f * vmax > t0]
        return [t for t in levels if t < vmax]

    def _blobs(self, fr: lb.Frame, t: float):
        """Candidate blobs at level ``t``, most LED-like first (module docstring, steps
        2-4): centroids (M,2) px, masses (M,), unit chroma directions (M,2), blob
        diameters (M,) px, M <= max_candidates; None if fewer than N."""
        taken = list(itertools.islice(self._measured(fr, t), self._k()))
        return _columns(taken) if len(taken) >= self._n else None

    def _measured(self, fr: lb.Frame, t: float):
        """The coloured blobs at level ``t`` (:class:`led_blobs.BlobMeasure`), measured
        lazily in LED-likeness order (at most measure_factor x max_candidates measured);
        a blob counts when saturated enough and of the reference or the other LEDs' hue."""
        blobs = lb.components(fr, t, self.max_blobs)
        if blobs is None or blobs.count < self._n:
            return
        for lab in self._ranked(blobs, fr)[: self.measure_factor * self._k()]:
            m = lb.measure(fr, blobs, int(lab), t, self.centroid)
            if m is None or m.saturation < self.min_saturation:
                continue
            if max(float(m.chroma @ self._u_ref), float(m.chroma @ self._u_other)) < self.cos_hue:
                continue  # neither the reference LEDs' colour nor the others'
            yield m

    def _ranked(self, blobs: lb.Blobs, fr: lb.Frame) -> np.ndarray:
        """Labels of the blobs that pass the area and circularity limits, most LED-like
        first: those within the gate of an LED predicted by the previous frame's pose,
        then by compactness^2 x excess mass (a compact bright spot beats a caustic
        filament of the same mass by 10-400x)."""
        st = blobs.stats[1:]
        area = st[:, cv2.CC_STAT_AREA]
        w, h = st[:, cv2.CC_STAT_WIDTH], st[:, cv2.CC_STAT_HEIGHT]
        circ = area / (np.pi * (np.maximum(w, h) / 2.0) ** 2)
        ok = (area >= self.min_area_px) & (area <= self.max_area_frac * fr.image_px)
        ok &= (area < 12) | (circ >= self.min_circularity)
        score = blobs.compact[1:] ** 2 * blobs.mass[1:]
        near = self._near_prior(blobs.centres[1:] + blobs.origin + fr.origin)
        idx = np.nonzero(ok)[0]
        order = idx[np.lexsort((-score[idx], ~near[idx]))]
        return order + 1

    def _near_prior(self, uv: np.ndarray) -> np.ndarray:
        """(M,) bool: blob centres (M,2) px within the gate of an LED projected with the
        previous frame's pose (all False without one). Gate: a quarter of the smallest
        predicted LED spacing, at least ``prior_gate_px``."""
        pred = self._predicted_uv() if len(uv) else None
        if pred is None:
            return np.zeros(len(uv), bool)
        gaps = np.linalg.norm(pred[:, None] - pred[None], axis=2)[np.triu_indices(len(pred), 1)]
        gate = max(self.prior_gate_px, 0.25 * float(gaps.min()))
        d = np.linalg.norm(uv[:, None, :] - pred[None, :, :], axis=2).min(axis=1)
        return d <= gate

    def _predicted_uv(self) -> np.ndarray | None:
        """The LEDs (N,2) px projected with the previous frame's pose; None without one or
        when an LED is not in front of the camera."""
        T = self._prev_T
        if T is None or np.any((self._kp @ T[:3, :3].T + T[:3, 3])[:, 2] <= 0):
            return None
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        return cv2.projectPoints(self._kp.reshape(-1, 1, 3), rvec, T[:3, 3], self._K, self._dist)[0].reshape(-1, 2)

    def _best_pose(self, cents, masses, chroma, sizes=None):
        """The assignment search of the module docstring over the candidates (most
        LED-like first; ``masses`` is not used, ``sizes`` (M,) px blob diameters or None):
        N-subsets in order of their candidates' summed rank, each checked for convexity,
        colour pattern, blob size against the range its span implies, view angle and
        reprojection; the first within ``accept_px`` wins at once, otherwise the best fit."""
        best, best_c, solves = None, None, 0
        combos = sorted(itertools.combinations(range(len(cents)), self._n), key=sum)
        for combo in combos:
            c = list(combo)
            if sizes is not None and not self._sizes_fit(cents[c], sizes[c]):
                continue
            if solves == self.max_solves:
                break
            solves += 1
            est = self._solve(cents[c], chroma[c], refine=solves == 1)
            if est is not None and (best is None or est["reproj_err_px"] < best["reproj_err_px"]):
                best, best_c = est, c
                if best["reproj_err_px"] <= self.accept_px:
                    break
        self.last_solves = solves
        if best_c is None or best_c == list(combos[0]):  # none, or the first set (refined)
            return best
        return self._solve(cents[best_c], chroma[best_c], refine=True)

    def _sizes_fit(self, uv: np.ndarray, diam: np.ndarray) -> bool:
        """Blob diameters (N,) px not far below the LED discs' image diameter at the range
        the subset's span implies (the array's span S m seen over the subset's largest
        image distance s px: disc diameter 2 r s / S px, an upper bound on the range and a
        lower bound on the disc for a tilted array). Catches clutter sets spanning more
        pixels than their blobs' size allows (a close array has big LEDs). Without the
        LED radius in the manifest: True."""
        if self._disc_per_span <= 0:
            return True
        span = float(np.max(np.linalg.norm(uv[:, None] - uv[None], axis=2)))
        return bool(np.all(diam >= self.min_size_frac * self._disc_per_span * span - 1.5))

    def _solve(self, uv, chroma, refine: bool = True):
        """Pose from N blob centroids (N,2) and their chroma directions (N,2), or None;
        ``refine``: Levenberg-Marquardt after IPPE (the search ranks unrefined fits)."""
        if not _convex(uv):
            return None
        score = chroma @ self._colour_axis
        refs = np.argsort(score)[::-1][: self._n_ref]
        is_ref = np.zeros(self._n, bool)
        is_ref[refs] = True
        if np.any(score[refs] <= 0.0) or np.any(chroma[refs] @ self._u_ref < self.cos_hue):
            return None
        if np.any(chroma[~is_ref] @ self._u_other < self.cos_hue):
            return None  # a blob whose colour is not the LEDs'
        ccw = image_order(uv)
        k = match_rotation(is_ref[ccw].astype(int), self._pattern)
        if k is None:
            return None
        img_pts = np.empty((self._n, 2))
        img_pts[self._kp_ccw] = uv[np.roll(ccw, -k)]
        pose = solve_planar(self._kp, img_pts, self._K, self._dist, refine=refine)
        if pose is None or pose.reproj_err_px > self.max_reproj_px or not self._seen_frontally(pose.T_cam_target):
            return None
        return estimate_dict(pose.T_cam_target, self._marker["id"], pose)

    def _seen_frontally(self, T_cam_target: np.ndarray) -> bool:
        """The array's normal within ``max_view_deg`` of the line of sight to its centre."""
        centre = T_cam_target[:3, :3] @ self._kp.mean(axis=0) + T_cam_target[:3, 3]
        cos_view = float(-T_cam_target[:3, 2] @ centre) / max(float(np.linalg.norm(centre)), 1e-12)
        return cos_view >= self.cos_view


def _columns(meas: list) -> tuple:
    """Measured blobs -> (centroids (M,2) px, masses (M,), unit chroma (M,2), diameters (M,) px)."""
    return (
        np.array([m.centre for m in meas]),
        np.array([m.mass for m in meas]),
        np.array([m.chroma for m in meas]),
        np.array([m.diameter for m in meas]),
    )


def _unit(h_deg: float) -> np.ndarray:
    """Unit vector of a hue angle (deg) in the opponent (a, b) plane."""
    r = math.radians(h_deg)
    return np.array([math.cos(r), math.sin(r)])


def _convex(uv: np.ndarray) -> bool:
    """True if the points (N,2), taken in angular order around their centroid, form a
    strictly convex polygon with no coincident points."""
    c = uv - uv.mean(axis=0)
    p = uv[np.argsort(np.arctan2(c[:, 1], c[:, 0]))]
    e = np.concatenate((p[1:], p[:1])) - p  # edge i: vertex i -> i + 1 (cyclic)
    if np.min(np.hypot(e[:, 0], e[:, 1])) < 1.0:
        return False
    e_next = np.concatenate((e[1:], e[:1]))
    cross = e[:, 0] * e_next[:, 1] - e[:, 1] * e_next[:, 0]
    return bool(np.all(cross > 0) or np.all(cross < 0))
