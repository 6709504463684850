"""ArUco / AprilTag localizer: cv2.aruco.ArucoDetector + IPPE_SQUARE PnP."""
from __future__ import annotations

import cv2
import numpy as np

from evalkit.localizers.pnp import camera_matrices
from evalkit.localizers.square import (find_marker, linear_gray, refine_corners, square_pose_estimate,
                                       to_gray, valid_quad)

_REFINE = {"linear": "CORNER_REFINE_NONE", "none": "CORNER_REFINE_NONE", "subpix": "CORNER_REFINE_SUBPIX",
           "contour": "CORNER_REFINE_CONTOUR", "apriltag": "CORNER_REFINE_APRILTAG"}


class ArucoLocalizer:
    """ArUco/AprilTag fiducial (OpenCV dictionary) -> corners -> IPPE_SQUARE pose of the dock."""

    name = "aruco"

    def __init__(self, marker_id: str | None = None, refine: str = "linear"):
        """marker_id: manifest id of the marker to use (None: first aruco, else apriltag marker).
        refine: corner refinement, one of linear (cornerSubPix on sRGB-decoded intensity,
        unbiased) | subpix (OpenCV's, on the 8-bit image) | none | contour | apriltag."""
        if str(refine) not in _REFINE:
            raise ValueError(f"refine must be one of {sorted(_REFINE)}, got {refine!r}")
        self.marker_id = marker_id
        self.refine = str(refine)
        self._marker = None
        self._detector = None
        self._K = self._dist = None

    def reset(self, camera: dict) -> None:
        """Pick the marker and build the detector for its dictionary."""
        self._K, self._dist = camera_matrices(camera)
        self._marker = find_marker(camera.get("markers"), ("aruco", "apriltag"), self.marker_id)
        self._detector = None
        if self._marker is None or self._marker.get("kind") not in ("aruco", "apriltag"):
            self._marker = None
            return
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self._marker["dictionary"]))
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = getattr(cv2.aruco, _REFINE[self.refine])
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)

    def localize(self, image: np.ndarray) -> dict | None:
        """Dock pose from one RGB uint8 image (H,W,3), or None."""
        if self._detector is None:
            return None
        gray = to_gray(image)
        if gray is None or min(gray.shape) < 8:
            return None
        try:
            corners, ids, _ = self._detector.detectMarkers(gray)
        except cv2.error:
            return None
        if ids is None:
            return None
        want = int(self._marker["marker_id"])
        h, w = gray.shape
        best = None
        lin = None
        for c, i in zip(corners, ids.reshape(-1)):
            if int(i) != want or not valid_quad(c.reshape(4, 2), w, h):
                continue
            c = c.reshape(4, 2)
            if self.refine == "linear":
                lin = linear_gray(gray) if lin is None else lin
                c = refine_corners(lin, c)
            est = square_pose_estimate(c, self._marker, self._K, self._dist)
            if est is not None and (best is None or est["reproj_err_px"] < best["reproj_err_px"]):
                best = est
        return best
