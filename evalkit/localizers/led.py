"""LED-array localizer: bright blobs -> reference LED(s) by colour -> ordered PnP.

The array has N >= 4 LEDs in convex position; one or more reference LEDs have another
colour, and the cyclic reference/other pattern has no rotational symmetry (blendgen
checks it), so the colour pattern fixes the order. Pipeline (640x480: ~0.5 ms + PnP):
1. brightness = max(R, G, B); threshold at ``min(threshold, rel_threshold * max)`` (not
   below ``min_threshold``) so dim (attenuated) arrays still pass; when no pose comes out
   of that level (too many blobs, or no subset passes the checks), the threshold climbs a
   ladder (``ladder``: fractions of the frame's maximum, default 0.8 and 0.97) and the search
   repeats: LED cores are the brightest things in the frame, so a high level keeps them and
   drops sunlit clutter (caustic networks on tiled walls, the surface's bright ripples:
   on the physical demo pool 823 blobs at 0.6 x max, 7-16 at 0.97 x max). Frames that
   succeed at the first level are unchanged;
2. connected components (8-connected) with area and circularity limits;
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
4. colour: the brightness-weighted mean chroma vector (opponent axes
   a = R - (G+B)/2, b = sqrt(3)/2 (G - B)) over the box, so a saturated white core adds
   nothing and the coloured halo decides; the R reference LEDs are the R blobs whose
   hue is closest to the reference colour relative to the other LEDs' colour;
5. order: angles around the centroid, counter-clockwise as seen from the camera with
   image y flipped to point up; the cyclic reference/other label sequence is matched
   against the keypoints' (dock frame, y up) at the single rotation where it agrees;
6. PnP: SOLVEPNP_IPPE on the dock-frame keypoints, both solutions checked, LM refine.

Particles and reflections (more than N blobs): an assignment search with a geometric
consistency check. The N-subsets of the ``max_candidates`` brightest blobs (N + 3 by
default) are all tried; a subset must be in convex position,
show the colour pattern at exactly one rotation, and its PnP pose must reproject all N
LEDs within ``max_reproj_px`` (RMS); the best fit wins. (The first passing subset by
brightness lost to tinted QR/ArUco patches under water light: four points in convex
position admit a strongly tilted pose within a fraction of a pixel, so the best fit, not
the brightest, separates the array from lookalikes.) Chosen over RANSAC
because N is small (C(7,4) = 35 subsets, most rejected by the cheap convexity and
colour tests before any PnP) and the search is exhaustive within the candidates, where
RANSAC's minimal samples would still need the same colour/order bookkeeping.
"""
from __future__ import annotations

from typing import Any

import itertools
import math

import cv2
import numpy as np

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
    hits = [k for k in range(len(pattern)) if np.array_equal(np.roll(labels, -k), pattern)]
    return hits[0] if len(hits) == 1 else None


class LedLocalizer:
    """LED array (N >= 4): threshold, blobs, reference LEDs by colour, pattern order, IPPE PnP."""

    name = "led"
    outputs = ("distance", "T_cam_dock", "marker_id")

    def __init__(self, marker_id: str | None = None, threshold: float = 200.0,
                 rel_threshold: float = 0.6, min_threshold: float = 40.0,
                 min_area_px: int = 1, max_area_frac: float = 0.05, min_circularity: float = 0.4,
                 ref_hue: float | None = None, max_candidates: int | None = None, max_blobs: int = 200,
                 max_reproj_px: float = 3.0, min_chroma: float = 12.0, max_hue_err_deg: float = 60.0,
                 centroid: str = "core", max_view_deg: float = 70.0, ladder: tuple = (0.8, 0.97)):
        """threshold: brightness (max channel, 0-255) that LED cores exceed; lowered to
        rel_threshold * image max (not below min_threshold) for dim images.
        min_area_px / max_area_frac: blob area limits (px / fraction of the image).
        min_circularity: area / (pi (max(w,h)/2)^2) for blobs of >= 12 px.
        ref_hue: reference LED hue in degrees (None: from the marker's colours).
        max_candidates: brightest blobs considered (None: N + 3); max_blobs: give up above
        this many blobs. max_reproj_px: RMS reprojection error (px) above which a blob
        set is rejected. min_chroma: mean chroma (8-bit units) a blob needs to count as a
        coloured LED, so white/grey highlights (marker plates, walls) are not taken for
        LEDs. max_hue_err_deg: hue distance allowed between a blob and its expected LED
        colour. centroid: "core" or "weighted" (see the module docstring).
        max_view_deg: largest angle (deg) between the array's normal and the line of sight
        to it that a pose may have; flat LED discs seen beyond ~70 deg are foreshortened
        below a third of their width, and lookalike blob sets (tinted marker plates plus two
        LEDs) fit only at ~78 deg (measured on the physical-mode demo).
        ladder: higher thresholds (fractions of the frame's max brightness) tried in turn
        when the first level gives no pose (module docstring, step 1); () disables it.
        Reason for > 8 params: every threshold of the blob pipeline is a documented knob."""
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
        self.min_chroma = float(min_chroma)
        self.cos_hue = math.cos(math.radians(float(max_hue_err_deg)))
        self.centroid = centroid
        self.cos_view = math.cos(math.radians(float(max_view_deg)))
        if isinstance(ladder, str):          # from ``-p led.ladder=0.8,0.97``
            ladder = [x for x in ladder.replace("(", "").replace(")", "").split(",") if x.strip()]
        self.ladder = tuple(sorted(float(f) for f in ladder))
        if any(not 0.0 < f <= 1.0 for f in self.ladder):
            raise ValueError(f"ladder fractions must be in (0, 1], got {self.ladder}")
        self._marker: Any = None            # the manifest's LED marker dict, set by reset()

    def reset(self, camera: dict) -> None:
        """Pick the LED marker; precompute its keypoint order, colour pattern and colour axis."""
        self._K, self._dist = camera_matrices(camera)
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

    # stateless between frames: one call per frame is shared with the hybrid's LED (evalkit.memo)
    def memo_state(self) -> bytes:
        return b""

    def memo_after(self) -> None:
        return None

    def memo_apply(self, before, after, est) -> None:
        """Nothing to move: the result depends on the image only."""

    def localize(self, image: np.ndarray) -> dict | None:
        """Dock pose from one RGB uint8 image (H,W,3), or None."""
        if self._marker is None:
            return None
        a = np.asarray(image)
        if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 8:
            return None
        try:
            rgb = np.ascontiguousarray(a)
            v = cv2.max(cv2.max(rgb[:, :, 0], rgb[:, :, 1]), rgb[:, :, 2])
            for t in self._levels(float(v.max())):
                blobs = self._blobs(rgb, v, t)
                est = self._best_pose(*blobs) if blobs is not None else None
                if est is not None:
                    return est
            return None
        except (cv2.error, ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None

    def _levels(self, vmax: float) -> list[float]:
        """Brightness thresholds (0-255) to try in turn: the first level, then the ladder
        above it (levels at or below the maximum brightness find nothing and are dropped)."""
        t0 = max(self.min_threshold, min(self.threshold, self.rel_threshold * vmax))
        levels = [t0] + [f * vmax for f in self.ladder if f * vmax > t0]
        return [t for t in levels if t < vmax]

    def _blobs(self, rgb: np.ndarray, v: np.ndarray, t: float):
        """Candidate blobs above brightness ``t`` (``v`` the (H,W) max-channel image):
        centroids (M,2) px, masses (M,), unit chroma directions (M,2); None if too few/many."""
        mask = cv2.threshold(v, t, 255, cv2.THRESH_BINARY)[1]
        # Labelling only the box around the bright pixels (2 px margin for _measure) skips
        # the dark rest of the frame: 0.02 ms instead of ~1.9 ms at 640x480.
        x, y, bw, bh = cv2.boundingRect(mask)
        x0, y0 = max(0, x - 2), max(0, y - 2)
        x1, y1 = min(v.shape[1], x + bw + 2), min(v.shape[0], y + bh + 2)
        n, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(
            np.ascontiguousarray(mask[y0:y1, x0:x1]), 8, cv2.CV_32S, cv2.CCL_BBDT)
        if n - 1 < self._n or n - 1 > self.max_blobs:
            return None
        area = stats[1:, cv2.CC_STAT_AREA]
        w, h = stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT]
        circ = area / (np.pi * (np.maximum(w, h) / 2.0) ** 2)
        ok = (area >= self.min_area_px) & (area <= self.max_area_frac * v.size)
        ok &= (area < 12) | (circ >= self.min_circularity)
        idx = np.nonzero(ok)[0] + 1
        if len(idx) < self._n:
            return None
        rgb_c, v_c = rgb[y0:y1, x0:x1], v[y0:y1, x0:x1]
        cents, masses, chroma = [], [], []
        for lab in idx:
            c = self._measure(rgb_c, v_c, labels, stats[lab], lab, 0.5 * t)
            if c is not None:
                cents.append(c[0])
                masses.append(c[1])
                chroma.append(c[2])
        if len(cents) < self._n:
            return None
        k = self.max_candidates if self.max_candidates is not None else self._n + 3
        order = np.argsort(masses)[::-1][:k]
        return np.array(cents)[order] + (x0, y0), np.array(masses)[order], np.array(chroma)[order]

    def _measure(self, rgb, v, labels, st, lab, t_low):
        """Centroid (u, v) px, mass and unit chroma direction (2,) of blob ``lab``
        (stats row ``st``), or None for an uncoloured blob."""
        x0, y0, bw, bh = (int(s) for s in st[:4])
        m = 2
        xa, ya = max(0, x0 - m), max(0, y0 - m)
        xb, yb = min(v.shape[1], x0 + bw + m), min(v.shape[0], y0 + bh + m)
        lab_roi = labels[ya:yb, xa:xb]
        v_roi = v[ya:yb, xa:xb]
        wgt = np.clip(v_roi.astype(np.float32) - t_low, 0, None)
        wgt[(lab_roi != lab) & (lab_roi != 0)] = 0.0
        s = float(wgt.sum())
        if s <= 0:
            return None
        yy, xx = np.mgrid[ya:yb, xa:xb]
        px = rgb[ya:yb, xa:xb].astype(np.float32)
        ca = (wgt * (px[:, :, 0] - 0.5 * (px[:, :, 1] + px[:, :, 2]))).sum()
        cb = (wgt * _SQ3_2 * (px[:, :, 1] - px[:, :, 2])).sum()
        norm = math.hypot(ca, cb)
        if norm / s < self.min_chroma:  # mean chroma (8-bit units) too low: a white/grey blob
            return None
        if self.centroid == "core":  # weights above the middle of the blob's range: the core
            peak = float(v_roi[lab_roi == lab].max())
            w2 = np.clip(v_roi.astype(np.float32) - 0.5 * (t_low + peak), 0, None)
            w2[lab_roi != lab] = 0.0
            s2 = float(w2.sum())
            cu, cv_ = float((w2 * xx).sum() / s2), float((w2 * yy).sum() / s2)
        else:
            cu, cv_ = float((wgt * xx).sum() / s), float((wgt * yy).sum() / s)
        return (cu, cv_), s, np.array([ca, cb]) / norm

    def _best_pose(self, cents, masses, chroma):
        """The N-subset with the smallest reprojection error among those that pass the
        convexity, colour-pattern and reprojection checks (the assignment search of the
        module docstring). Exactly N candidates: the one subset, no search."""
        n = self._n
        best = None
        for combo in itertools.combinations(range(len(cents)), n):
            est = self._solve(cents[list(combo)], chroma[list(combo)])
            if est is not None and (best is None or est["reproj_err_px"] < best["reproj_err_px"]):
                best = est
        return best

    def _solve(self, uv, chroma):
        """Pose from N blob centroids (N,2) and their chroma directions (N,2), or None."""
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
        pose = solve_planar(self._kp, img_pts, self._K, self._dist)
        if pose is None or pose.reproj_err_px > self.max_reproj_px or not self._seen_frontally(pose.T_cam_target):
            return None
        return estimate_dict(pose.T_cam_target, self._marker["id"], pose)

    def _seen_frontally(self, T_cam_target: np.ndarray) -> bool:
        """The array's normal within ``max_view_deg`` of the line of sight to its centre."""
        centre = T_cam_target[:3, :3] @ self._kp.mean(axis=0) + T_cam_target[:3, 3]
        cos_view = float(-T_cam_target[:3, 2] @ centre) / max(float(np.linalg.norm(centre)), 1e-12)
        return cos_view >= self.cos_view


def _unit(h_deg: float) -> np.ndarray:
    """Unit vector of a hue angle (deg) in the opponent (a, b) plane."""
    r = math.radians(h_deg)
    return np.array([math.cos(r), math.sin(r)])


def _convex(uv: np.ndarray) -> bool:
    """True if the points (N,2), taken in angular order around their centroid, form a
    strictly convex polygon with no coincident points."""
    c = uv - uv.mean(axis=0)
    p = uv[np.argsort(np.arctan2(c[:, 1], c[:, 0]))]
    e = np.roll(p, -1, axis=0) - p
    if np.min(np.hypot(e[:, 0], e[:, 1])) < 1.0:
        return False
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    return bool(np.all(cross > 0) or np.all(cross < 0))
