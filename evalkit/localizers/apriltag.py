"""AprilTag localizer: pupil-apriltags (the AprilTag 3 C library) + IPPE_SQUARE PnP.

Optional dependency: ``pip install 'dockbench[apriltag]'`` (pupil-apriltags). It is
imported when the localizer is built, so listing localizers never needs it.

Markers: kind ``apriltag`` (or ``aruco`` with an AprilTag dictionary); the OpenCV
dictionary name maps to the AprilTag family (``DICT_APRILTAG_36h11`` -> ``tag36h11``;
16h5, 25h9, 36h11 are supported by both libraries), or the marker's ``family`` field.
pupil-apriltags puts pixel centres at +0.5 and lists the corners in the order
TR, TL, BL, BR of FORMAT.md's TL, TR, BR, BL; both are converted here. The pose comes
from the shared square-marker code (:mod:`evalkit.localizers.square`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from evalkit.localizers.square import SquareMarkerLocalizer, linear_gray, refine_corners, square_pose_estimate

FAMILIES = {
    "DICT_APRILTAG_16h5": "tag16h5",
    "DICT_APRILTAG_16H5": "tag16h5",
    "DICT_APRILTAG_25h9": "tag25h9",
    "DICT_APRILTAG_25H9": "tag25h9",
    "DICT_APRILTAG_36h10": "tag36h10",
    "DICT_APRILTAG_36H10": "tag36h10",
    "DICT_APRILTAG_36h11": "tag36h11",
    "DICT_APRILTAG_36H11": "tag36h11",
}
PUPIL_FAMILIES = (
    "tag36h11",
    "tag25h9",
    "tag16h5",
    "tagCircle21h7",
    "tagCircle49h12",
    "tagStandard41h12",
    "tagStandard52h13",
    "tagCustom48h12",
)
_TO_FORMAT_ORDER = [1, 0, 3, 2]  # pupil TR, TL, BL, BR -> TL, TR, BR, BL
INSTALL_HINT = "the 'apriltag' localizer needs pupil-apriltags: pip install 'dockbench[apriltag]'"


def family_of(marker: dict) -> str | None:
    """AprilTag family of a manifest marker (``family`` field or its OpenCV dictionary), or None."""
    if marker.get("family"):
        return str(marker["family"])
    return FAMILIES.get(str(marker.get("dictionary", "")))


def _pick_marker(markers, marker_id):
    markers = list(markers or [])
    if marker_id is not None:
        return next((m for m in markers if str(m.get("id")) == str(marker_id)), None)
    for m in markers:
        if m.get("kind") == "apriltag":
            return m
    return next((m for m in markers if m.get("kind") == "aruco" and family_of(m)), None)


def _import_pupil():
    try:
        import pupil_apriltags
    except ImportError as exc:
        raise ImportError(f"{INSTALL_HINT} ({exc})") from None
    return pupil_apriltags


class AprilTagLocalizer(SquareMarkerLocalizer):
    """AprilTag (pupil-apriltags detector) -> corners -> IPPE_SQUARE pose of the dock."""

    name = "apriltag"
    kinds = ("apriltag", "aruco")

    def __init__(
        self,
        marker_id: str | None = None,
        refine: str = "linear",
        quad_decimate: float = 1.0,
        quad_sigma: float = 0.0,
        decode_sharpening: float = 0.25,
        max_hamming: int = 1,
        max_shift_px: float = 1.0,
        nthreads: int = 1,
        roi: bool = True,
    ):
        """marker_id: manifest id (None: first apriltag marker, else an aruco marker with an
        AprilTag dictionary). refine: "linear" (cornerSubPix on sRGB-decoded intensity,
        accepted per corner within max_shift_px of the detector's corner) or "none"
        (the detector's edge-refined corners). quad_decimate, quad_sigma,
        decode_sharpening, nthreads: pupil-apriltags detector settings.
        max_hamming: corrected bits accepted. roi: see SquareMarkerLocalizer."""
        if str(refine) not in ("linear", "none"):
            raise ValueError(f"refine must be linear or none, got {refine!r}")
        self._pa = _import_pupil()
        super().__init__(marker_id, roi)
        self.refine = str(refine)
        self.quad_decimate = float(quad_decimate)
        self.quad_sigma = float(quad_sigma)
        self.decode_sharpening = float(decode_sharpening)
        self.max_hamming = int(max_hamming)
        self.max_shift_px = float(max_shift_px)
        self.nthreads = int(nthreads)
        self._detectors: dict[str, Any] = {}  # pupil_apriltags.Detector per family
        self._family: str | None = None

    def reset(self, camera: dict) -> None:
        """Pick the marker (an apriltag, else an aruco marker with an AprilTag dictionary)."""
        cam = dict(camera)
        if self.marker_id is None:
            m = _pick_marker(camera.get("markers"), None)
            cam["markers"] = [] if m is None else [m]
        super().reset(cam)

    def setup(self, marker: dict) -> dict | None:
        """The marker's family; the detector is built once per family."""
        self._family = family_of(marker)
        if self._family is None:
            return None
        if self._family not in PUPIL_FAMILIES:
            raise ValueError(
                f"marker {marker.get('id')!r}: AprilTag family {self._family!r} is not "
                f"supported by pupil-apriltags ({', '.join(PUPIL_FAMILIES)})"
            )
        if self._family not in self._detectors:
            self._detectors[self._family] = self._pa.Detector(
                families=self._family,
                nthreads=self.nthreads,
                quad_decimate=self.quad_decimate,
                quad_sigma=self.quad_sigma,
                refine_edges=1,
                decode_sharpening=self.decode_sharpening,
            )
        return marker

    def detect(self, gray: np.ndarray) -> list[np.ndarray]:
        """Quads (4,2) TL, TR, BR, BL of the wanted tag id within max_hamming."""
        want = int(self._marker["marker_id"])
        if self._family is None:
            return []
        return [
            np.asarray(det.corners, np.float64).reshape(4, 2)[_TO_FORMAT_ORDER] - 0.5
            for det in self._detectors[self._family].detect(np.ascontiguousarray(gray))
            if int(det.tag_id) == want and int(det.hamming) <= self.max_hamming
        ]

    def quad_pose(self, gray: np.ndarray, quad: np.ndarray) -> dict | None:
        """IPPE_SQUARE; with refine=linear each corner moves to its cornerSubPix position
        when that is within max_shift_px."""
        c = quad
        if self.refine == "linear":
            r = refine_corners(linear_gray(gray), c)
            ok = np.linalg.norm(r - c, axis=1) <= self.max_shift_px
            c = np.where(ok[:, None], r, c)
        return square_pose_estimate(c, self._marker, self._K, self._dist)
