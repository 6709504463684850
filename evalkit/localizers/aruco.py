"""ArUco / AprilTag localizer: cv2.aruco.ArucoDetector + IPPE_SQUARE PnP."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from evalkit.localizers.square import SquareMarkerLocalizer, linear_gray, refine_corners, square_pose_estimate

_REFINE = {
    "linear": "CORNER_REFINE_NONE",
    "none": "CORNER_REFINE_NONE",
    "subpix": "CORNER_REFINE_SUBPIX",
    "contour": "CORNER_REFINE_CONTOUR",
    "apriltag": "CORNER_REFINE_APRILTAG",
}


class ArucoLocalizer(SquareMarkerLocalizer):
    """ArUco/AprilTag fiducial (OpenCV dictionary) -> corners -> IPPE_SQUARE pose of the dock."""

    name = "aruco"
    kinds = ("aruco", "apriltag")

    def __init__(self, marker_id: str | None = None, refine: str = "linear", roi: bool = True):
        """marker_id: manifest id of the marker to use (None: first aruco, else apriltag marker).
        refine: corner refinement, one of linear (cornerSubPix on sRGB-decoded intensity,
        unbiased) | subpix (OpenCV's, on the 8-bit image) | none | contour | apriltag.
        roi: search around the previous detection first (see SquareMarkerLocalizer)."""
        if str(refine) not in _REFINE:
            raise ValueError(f"refine must be one of {sorted(_REFINE)}, got {refine!r}")
        super().__init__(marker_id, roi)
        self.refine = str(refine)
        self._detector: Any = None  # cv2.aruco.ArucoDetector, built by setup()

    def setup(self, marker: dict) -> dict | None:
        """Build the detector for the marker's dictionary."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, marker["dictionary"]))
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = getattr(cv2.aruco, _REFINE[self.refine])
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)
        return marker

    def detect(self, gray: np.ndarray) -> list[np.ndarray]:
        """Quads (4,2) of the markers with the wanted id."""
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return []
        want = int(self._marker["marker_id"])
        return [c.reshape(4, 2) for c, i in zip(corners, ids.reshape(-1)) if int(i) == want]

    def quad_pose(self, gray: np.ndarray, quad: np.ndarray) -> dict | None:
        """IPPE_SQUARE on the corners, refined on linear intensity when refine=linear."""
        if self.refine == "linear":
            quad = refine_corners(linear_gray(gray), quad)
        return square_pose_estimate(quad, self._marker, self._K, self._dist)
