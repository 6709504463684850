"""Shared code of the square-marker localizers (QR, ArUco/AprilTag).

Square markers' keypoints are their corners TL, TR, BR, BL as seen from the camera,
in the marker's own frame (-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0)
(FORMAT.md), which is OpenCV's ``SOLVEPNP_IPPE_SQUARE`` order. The pose is solved in
the marker frame and moved to the dock: ``T_cam_dock = T_cam_marker @ inv(T_dock_marker)``.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from evalkit.localizers.pnp import camera_matrices, estimate_dict, invert_T, solve_planar

SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 0.001)


def square_object_points(size_m: float) -> np.ndarray:
    """Marker-frame corners TL, TR, BR, BL (4,3) of a square of side ``size_m`` metres."""
    h = float(size_m) / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def find_marker(markers, kinds: tuple[str, ...], marker_id: str | None) -> dict | None:
    """The manifest marker with id ``marker_id`` (any of ``kinds``), or the first marker
    of the first kind in ``kinds`` present when ``marker_id`` is None."""
    markers = list(markers or [])
    if marker_id is not None:
        return next((m for m in markers if str(m.get("id")) == str(marker_id)), None)
    for kind in kinds:
        m = next((m for m in markers if m.get("kind") == kind), None)
        if m is not None:
            return m
    return None


def to_gray(image: np.ndarray) -> np.ndarray | None:
    """HxWx3 RGB (or HxW) uint8 -> HxW uint8 grey; None if the array is not an image."""
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim not in (2, 3) or a.shape[0] < 1 or a.shape[1] < 1:
        return None
    if a.ndim == 2:
        return np.ascontiguousarray(a)
    if a.shape[2] == 3:
        return cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2GRAY)
    if a.shape[2] == 1:
        return np.ascontiguousarray(a[:, :, 0])
    return None


# 8-bit sRGB code -> linear intensity (IEC 61966-2-1), for corner refinement.
_SRGB_TO_LINEAR = np.array(
    [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in np.arange(256) / 255.0], np.float32
)


def linear_gray(gray: np.ndarray) -> np.ndarray:
    """sRGB-encoded grey (H,W) uint8 -> linear intensity (H,W) float32 in [0, 1].

    Corner refinement on gamma-encoded pixels is biased: the encode brightens the
    blurred edge band, pulling dark-square corners ~0.3 px inward. On linear
    intensity a pixel is its area-weighted coverage, and the bias goes away."""
    return _SRGB_TO_LINEAR[gray]


def refine_corners(gray: np.ndarray, corners: np.ndarray, max_win: int = 4) -> np.ndarray:
    """cornerSubPix on (4,2) corners (px). The half-window is limited to max_win and to an
    eighth of the shortest side so that it never reaches the next cell corner inside
    a 4x4 ArUco (a 6-cell square: cells are side/6 wide)."""
    c = np.asarray(corners, np.float32).reshape(-1, 1, 2).copy()
    sides = np.linalg.norm(c[:, 0] - np.roll(c[:, 0], 1, axis=0), axis=1)
    win = int(min(max_win, np.floor(sides.min() / 8.0)))
    h, w = gray.shape[:2]
    inside = np.all((c[:, 0] >= win + 1) & (c[:, 0] < np.array([w, h]) - win - 1))
    if win < 2 or not inside:
        return c.reshape(-1, 2).astype(np.float64)
    try:
        cv2.cornerSubPix(gray, c, (win, win), (-1, -1), SUBPIX_CRITERIA)
    except cv2.error:
        return np.asarray(corners, np.float64).reshape(-1, 2)
    out = c.reshape(-1, 2).astype(np.float64)
    # cornerSubPix can run away on blurred corners: keep the detector's corners then.
    if not np.all(np.isfinite(out)) or np.max(np.abs(out - np.asarray(corners).reshape(-1, 2))) > win:
        return np.asarray(corners, np.float64).reshape(-1, 2)
    return out


def valid_quad(corners, width: int, height: int, min_side_px: float = 4.0) -> bool:
    """True for a finite, convex (4,2) quad with sides >= min_side_px, roughly in the image."""
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        return False
    if np.any(c < -0.5 * max(width, height)) or np.any(c > 1.5 * max(width, height)):
        return False
    e = np.roll(c, -1, axis=0) - c
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    return bool((np.all(cross > 0) or np.all(cross < 0)) and np.linalg.norm(e, axis=1).min() >= min_side_px)


def square_pose_estimate(corners, marker: dict, K, dist) -> dict | None:
    """Localizer result from image corners (4,2) TL, TR, BR, BL (px) of ``marker``:
    IPPE_SQUARE in the marker frame + LM refine, then T_cam_dock = T_cam_marker inv(T_dock_marker)."""
    obj = square_object_points(marker["size_m"])
    pose = solve_planar(obj, corners, K, dist, square=True)
    if pose is None:
        return None
    T_dock_marker = np.asarray(marker.get("T_dock_marker", np.eye(4)), np.float64).reshape(4, 4)
    T_cam_dock = pose.T_cam_target @ invert_T(T_dock_marker)
    return estimate_dict(T_cam_dock, marker["id"], pose)


# Which of the result fields a localizer fills (class attribute ``outputs``, listed by
# ``dockbench localizers``-style tools and used by the hybrid): ``distance`` only, a full
# 6-DoF ``T_cam_dock``, and ``marker_id`` (the marker that produced the estimate, whose
# identity the detector checked: QR payload, ArUco/AprilTag id, LED colour pattern).
FULL_POSE_WITH_ID = ("distance", "T_cam_dock", "marker_id")


class SquareMarkerLocalizer:
    """Square-marker localizer base: marker pick, grey image, ``detect`` hook, best pose."""

    name = ""
    kinds: tuple[str, ...] = ()  # manifest marker kinds it reads, preferred first
    outputs = FULL_POSE_WITH_ID
    roi_margin = 1.0  # ROI = previous quad's box grown by this x its size
    roi_upscale = 1.0  # ROI resampled by this factor (bicubic) before detect
    roi_keep_frames = 5  # frames without a detection before the ROI is dropped
    min_image_px = 8  # smaller images give None without detection

    def __init__(self, marker_id: str | None = None, roi: bool = True):
        """marker_id: manifest id of the marker (None: first marker of the first kind in
        ``kinds``). roi: search first in a window around the previous frame's quad (grown
        by ``roi_margin`` times its size on each side, at least 32 px, resampled by
        ``roi_upscale``; kept for ``roi_keep_frames`` frames without a detection), then in
        the whole frame if that finds nothing."""
        self.marker_id = marker_id
        self.roi = _as_bool(roi)
        self._marker: Any = None  # the manifest's marker dict, set by reset()
        self._K: Any = None  # 3x3 intrinsics and distortion, set by reset()
        self._dist: Any = None
        self._last_quad: np.ndarray | None = None
        self._misses = 0

    # ---- hooks -----------------------------------------------------------------
    def setup(self, marker: dict) -> dict | None:
        """Prepare for ``marker`` (build the detector...); return the marker or None to ignore it."""
        return marker

    def detect(self, gray: np.ndarray) -> list[np.ndarray]:
        """Corner quads (4,2) TL, TR, BR, BL (px, pixel centres at integers) of the chosen
        marker in ``gray`` (H,W uint8), identity already checked. Subclasses implement it."""
        raise NotImplementedError

    def quad_pose(self, gray: np.ndarray, quad: np.ndarray) -> dict | None:
        """Estimate from one detected quad; default: IPPE_SQUARE on the 4 corners."""
        return square_pose_estimate(quad, self._marker, self._K, self._dist)

    # ---- shared preamble -------------------------------------------------------
    def reset(self, camera: dict) -> None:
        """Camera matrices, the marker (``find_marker``) and the subclass ``setup``."""
        self._K, self._dist = camera_matrices(camera)
        m = find_marker(camera.get("markers"), self.kinds, self.marker_id)
        self._marker = self.setup(m) if m is not None and m.get("kind") in self.kinds else None
        self._last_quad, self._misses = None, 0

    def localize(self, image: np.ndarray) -> dict | None:
        """Dock pose from one RGB uint8 image (H,W,3), or None: the lowest-reprojection
        estimate over the detected quads."""
        if self._marker is None:
            return None
        gray = to_gray(image)
        if gray is None or min(gray.shape) < self.min_image_px:
            return None
        best, quad = None, None
        for q in self._detect_roi_first(gray):
            if not valid_quad(q, gray.shape[1], gray.shape[0]):
                continue
            try:
                est = self.quad_pose(gray, np.asarray(q, np.float64).reshape(4, 2))
            except cv2.error:
                est = None
            if est is not None and (best is None or est["reproj_err_px"] < best["reproj_err_px"]):
                best, quad = est, q
        if best is not None:
            self._last_quad, self._misses = np.asarray(quad, np.float64).reshape(4, 2), 0
        else:
            self._misses += 1
            if self._misses > self.roi_keep_frames:
                self._last_quad = None
        return best

    # ---- sharing one call per frame (evalkit.memo; subclasses opt in by naming these) ----
    def _roi_memo_state(self) -> bytes:
        """What the next result depends on besides the image: the ROI quad (None: whole
        frame) and, while there is one, the misses that decide when it is dropped."""
        if self._last_quad is None:
            return b"-"
        return np.asarray(self._last_quad, np.float64).tobytes() + str(self._misses).encode()

    def _roi_memo_after(self):
        return (None if self._last_quad is None else np.array(self._last_quad, np.float64), self._misses)

    def _roi_memo_apply(self, before, after, est) -> None:
        """Move this localizer's ROI state as the memoised call moved the other one's:
        the quad as left (it was part of the key), misses reset on a find, else counted on."""
        quad, misses = after
        self._last_quad = None if quad is None else quad.copy()
        self._misses = 0 if est is not None else self._misses + (misses - before[1])

    def set_roi_hint(self, T_cam_dock: np.ndarray) -> None:
        """Search the next frame first around the marker as projected with a dock pose
        (4,4) from elsewhere (the hybrid's LED estimate); ignored when roi is off or the
        marker is not in front of the camera."""
        if not self.roi or self._marker is None:
            return
        kp = np.asarray(self._marker["keypoints"], np.float64).reshape(-1, 3)
        T = np.asarray(T_cam_dock, np.float64).reshape(4, 4)
        if not np.all(kp @ T[:3, :3].T[:, 2] + T[2, 3] > 1e-3):
            return
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        uv = cv2.projectPoints(kp.reshape(-1, 1, 3), rvec, T[:3, 3], self._K, self._dist)[0].reshape(-1, 2)
        if np.all(np.isfinite(uv)):
            self._last_quad = uv

    def _detect_roi_first(self, gray: np.ndarray) -> list[np.ndarray]:
        """``detect`` in the ROI around the last quad (when enabled; resampled by
        roi_upscale), else in the whole image."""
        if self.roi and self._last_quad is not None:
            x0, y0, x1, y1 = roi_box(self._last_quad, gray.shape, self.roi_margin)
            if 0 < (x1 - x0) * (y1 - y0) < 0.5 * gray.size:
                s = float(self.roi_upscale)
                crop = np.ascontiguousarray(gray[y0:y1, x0:x1])
                if s > 1.0:
                    crop = cv2.resize(crop, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)
                try:
                    quads = self.detect(crop)
                except cv2.error:
                    quads = []
                if quads:  # resampled pixel centre j is original (j + 0.5) / s - 0.5
                    return [(np.asarray(q, np.float64).reshape(4, 2) + 0.5) / s - 0.5 + (x0, y0) for q in quads]
        try:
            return [np.asarray(q, np.float64).reshape(4, 2) for q in self.detect(gray)]
        except cv2.error:
            return []


def roi_box(quad: np.ndarray, shape: tuple[int, int], margin: float, min_margin_px: int = 32):
    """Integer window (x0, y0, x1, y1) around a quad (4,2) px grown by ``margin`` times its
    size (and at least ``min_margin_px``) on each side, clipped to the image (H, W)."""
    lo, hi = quad.min(axis=0), quad.max(axis=0)
    grow = np.maximum(margin * (hi - lo), min_margin_px)
    h, w = shape[:2]
    x0, y0 = (int(max(0, np.floor(v))) for v in lo - grow)
    x1, y1 = int(min(w, np.ceil(hi[0] + grow[0]))), int(min(h, np.ceil(hi[1] + grow[1])))
    return x0, y0, x1, y1


def _as_bool(v) -> bool:
    """bool from a --param string ("true"/"false"/"1"/"0") or a bool."""
    if isinstance(v, str):
        return v.strip().lower() in ("1", "true", "yes", "on")
    return bool(v)
