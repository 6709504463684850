"""QR-code localizer: OpenCV QR detector, payload check, finder-corner refinement, planar PnP.

OpenCV returns the code's outer corners TL, TR, BR, BL, but BR has no finder pattern and
is extrapolated (1-3 px off on clean synthetic images). When the module count n of the code
is known (from the payload with segno, as blendgen makes it, or the ``modules`` param),
the 12 outer corners of the three finder patterns are predicted through the detected quad,
refined with cornerSubPix and used for PnP (SOLVEPNP_IPPE + disambiguation + LM refine).
Otherwise (or when the refinement does not fit) the 4 detected corners go to IPPE_SQUARE.
"""
from __future__ import annotations

import cv2
import numpy as np

from evalkit.localizers.pnp import camera_matrices, estimate_dict, invert_T, solve_planar
from evalkit.localizers.square import (SUBPIX_CRITERIA, find_marker, linear_gray, refine_corners, square_pose_estimate,
                                        to_gray, valid_quad)


def qr_modules(payload: str) -> int | None:
    """Modules per side of the QR code blendgen makes for ``payload`` (segno, error level M,
    smallest version), or None if segno is unavailable."""
    try:
        import segno
        return 17 + 4 * int(segno.make_qr(payload, error="m", boost_error=False).version)
    except Exception:  # noqa: BLE001 - segno missing or payload not encodable
        return None


def finder_module_corners(n: int) -> np.ndarray:
    """Outer corners (12,2) of the three 7x7 finder patterns in module coordinates
    (x right, y down, the code spanning [0, n]^2): TL, TR and BL finders, each TL, TR, BR, BL."""
    sq = np.array([[0, 0], [7, 0], [7, 7], [0, 7]], float)
    return np.vstack([sq, sq + [n - 7, 0], sq + [0, n - 7]])


def module_to_marker(pts_mod: np.ndarray, n: int, size_m: float) -> np.ndarray:
    """Module coordinates (N,2) -> marker-frame points (N,3), metres (y up, z = 0)."""
    s = size_m / n
    return np.column_stack([-size_m / 2 + pts_mod[:, 0] * s, size_m / 2 - pts_mod[:, 1] * s,
                            np.zeros(len(pts_mod))])


def refine_finder_corners(gray: np.ndarray, quad: np.ndarray, n: int,
                          min_module_px: float = 2.0) -> tuple[np.ndarray, np.ndarray] | None:
    """Sub-pixel finder-pattern corners predicted from the detected quad (4,2) px.

    Returns (module coordinates (M,2), refined pixels (M,2)) of the M >= 8 corners that
    agree with one homography (RANSAC), or None when modules are smaller than
    ``min_module_px`` or too few corners agree."""
    code = np.array([[0, 0], [n, 0], [n, n], [0, n]], np.float32)
    module_px = float(np.min(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1))) / n
    if module_px < min_module_px:
        return None
    win = int(np.clip(np.floor(0.5 * module_px), 2, 5))  # stays inside the finder's 1-module ring
    H0 = cv2.getPerspectiveTransform(code, quad.astype(np.float32))
    mod = finder_module_corners(n)
    pred = cv2.perspectiveTransform(mod.reshape(-1, 1, 2).astype(np.float32), H0)
    h, w = gray.shape
    p = pred.reshape(-1, 2)
    if np.any(p < win + 1) or np.any(p[:, 0] >= w - win - 1) or np.any(p[:, 1] >= h - win - 1):
        return None
    ref = pred.copy()  # gray: linear intensity (square.linear_gray) for unbiased corners
    cv2.cornerSubPix(gray, ref, (win, win), (-1, -1), SUBPIX_CRITERIA)
    ref = ref.reshape(-1, 2).astype(np.float64)
    keep = np.all(np.isfinite(ref), axis=1) & (np.linalg.norm(ref - p, axis=1) <= 1.5 * win)
    if keep.sum() < 8:
        return None
    H, inl = cv2.findHomography(mod[keep], ref[keep], cv2.RANSAC, max(0.5, 0.1 * module_px))
    if H is None or inl is None or int(inl.sum()) < 8:
        return None
    idx = np.nonzero(keep)[0][inl.ravel().astype(bool)]
    return mod[idx], ref[idx]


class QrLocalizer:
    """QR code (OpenCV detector, payload-checked) -> finder-corner PnP pose of the dock."""

    name = "qr"

    def __init__(self, marker_id: str | None = None, detector: str = "aruco",
                 allow_undecoded: bool = False, refine: str = "finders", modules: int | None = None):
        """marker_id: manifest id (None: first qr marker). detector: "aruco"
        (cv2.QRCodeDetectorAruco, finds smaller codes) or "classic" (cv2.QRCodeDetector).
        allow_undecoded: accept a detected quad whose payload did not decode.
        refine: "finders" (12 finder corners), "subpix" (cornerSubPix on the 4 corners) or "none".
        modules: modules per side (None: from the payload with segno)."""
        if detector not in ("aruco", "classic"):
            raise ValueError(f"detector must be aruco or classic, got {detector!r}")
        if refine not in ("finders", "subpix", "none"):
            raise ValueError(f"refine must be finders, subpix or none, got {refine!r}")
        self.marker_id = marker_id
        self.detector = detector
        self.allow_undecoded = _as_bool(allow_undecoded)
        self.refine = refine
        self.modules = None if modules in (None, "None", "") else int(modules)
        self._marker = None
        self._det = None
        self._n = None
        self._K = self._dist = None

    def reset(self, camera: dict) -> None:
        """Pick the QR marker and build the detector."""
        self._K, self._dist = camera_matrices(camera)
        m = find_marker(camera.get("markers"), ("qr",), self.marker_id)
        self._marker = m if m is not None and m.get("kind") == "qr" else None
        self._det = cv2.QRCodeDetectorAruco() if self.detector == "aruco" else cv2.QRCodeDetector()
        self._n = None
        if self._marker is not None:
            self._n = self.modules or qr_modules(str(self._marker.get("payload", "")))

    def localize(self, image: np.ndarray) -> dict | None:
        """Dock pose from one RGB uint8 image (H,W,3), or None."""
        if self._marker is None:
            return None
        gray = to_gray(image)
        if gray is None or min(gray.shape) < 21:
            return None
        try:
            text, pts, _ = self._det.detectAndDecode(gray)
        except cv2.error:
            return None
        if pts is None:
            return None
        quad = np.asarray(pts, np.float64).reshape(-1, 2)
        if not valid_quad(quad, gray.shape[1], gray.shape[0]):
            return None
        if text != self._marker.get("payload") and not (self.allow_undecoded and text == ""):
            return None
        try:
            return self._pose(gray, quad)
        except cv2.error:
            return None

    def _pose(self, gray: np.ndarray, quad: np.ndarray) -> dict | None:
        m = self._marker
        if self.refine == "finders" and self._n:
            found = refine_finder_corners(linear_gray(gray), quad, self._n)
            if found is not None:
                obj = module_to_marker(found[0], self._n, float(m["size_m"]))
                pose = solve_planar(obj, found[1], self._K, self._dist)
                if pose is not None:
                    T_dm = np.asarray(m.get("T_dock_marker", np.eye(4)), np.float64).reshape(4, 4)
                    return estimate_dict(pose.T_cam_target @ invert_T(T_dm), m["id"], pose)
        if self.refine == "subpix":
            quad = refine_corners(linear_gray(gray), quad)
        return square_pose_estimate(quad, m, self._K, self._dist)


def _as_bool(v) -> bool:
    """bool from a --param string ("true"/"false"/"1"/"0") or a bool."""
    if isinstance(v, str):
        return v.strip().lower() in ("1", "true", "yes", "on")
    return bool(v)
