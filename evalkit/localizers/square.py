"""Shared code of the square-marker localizers (QR, ArUco/AprilTag).

Square markers' keypoints are their corners TL, TR, BR, BL as seen from the camera,
in the marker's own frame (-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0)
(FORMAT.md), which is OpenCV's ``SOLVEPNP_IPPE_SQUARE`` order. The pose is solved in
the marker frame and moved to the dock: ``T_cam_dock = T_cam_marker @ inv(T_dock_marker)``.
"""
from __future__ import annotations

import cv2
import numpy as np

from evalkit.localizers.pnp import estimate_dict, invert_T, solve_planar

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
_SRGB_TO_LINEAR = np.array([c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4
                            for c in np.arange(256) / 255.0], np.float32)


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
