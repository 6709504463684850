"""Markers on the dock face: keypoints in the dock frame and texture images.

Dock frame (FORMAT.md): origin at the face centre, +z out of the face, +y up,
+x right as seen from in front. Every marker lies in the plane z = 0.
Square markers: keypoints are the corners TL, TR, BR, BL of the code itself
(without quiet zone), i.e. in the marker frame (-s/2, s/2), (s/2, s/2),
(s/2, -s/2), (-s/2, -s/2).

A texture is a uint8 grey image whose every pixel is one code cell (module);
the textured plane spans ``plane_size_m`` = size_m * cells_total / cells_code,
so the code's corners land exactly on the keypoints when the texture is sampled
with nearest-neighbour interpolation.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from blendgen.geometry import make_T

QR_QUIET_MODULES = 2      # OpenCV decodes with 2; ISO asks 4 (a wider plate costs nothing here)
ARUCO_QUIET_CELLS = 1


@dataclass(frozen=True)
class MarkerTexture:
    """Texture cells (H,W) uint8 (0 black, 255 white) and the plate's physical side (m)."""
    cells: np.ndarray
    plane_size_m: float


def square_corners(size_m: float) -> np.ndarray:
    """Marker-frame corners TL, TR, BR, BL (4,3), metres."""
    h = size_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def led_positions(spec) -> np.ndarray:
    """LED centres (4,3) in the marker frame for a LedArray spec, metres.

    Rectangle: TL, TR, BR, BL corners; circle: 4 points at 90 deg starting at the top,
    clockwise as seen from the camera. Index ``reference_index`` is the reference LED."""
    if spec.layout == "rectangle":
        return square_corners(1.0) * np.array([spec.size_m, spec.height_m or spec.size_m, 0.0])
    r = spec.size_m / 2.0
    ang = np.pi / 2 - np.arange(4) * np.pi / 2
    return np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(4)])


def qr_texture(payload: str, size_m: float) -> MarkerTexture:
    """QR code cells via segno (error correction M, smallest version that fits)."""
    import segno
    qr = segno.make_qr(payload, error="m", boost_error=False)
    code = np.array(qr.matrix, dtype=np.uint8)  # 1 = dark
    n = code.shape[0]
    cells = np.pad(np.where(code > 0, 0, 255).astype(np.uint8), QR_QUIET_MODULES, constant_values=255)
    return MarkerTexture(cells, size_m * cells.shape[0] / n)


def aruco_texture(dictionary: str, marker_id: int, size_m: float) -> MarkerTexture:
    """ArUco/AprilTag cells from OpenCV's dictionary, with a one-cell white quiet zone."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = d.markerSize + 2  # black border included in size_m
    img = cv2.aruco.generateImageMarker(d, marker_id, n, borderBits=1)
    cells = np.pad(img, ARUCO_QUIET_CELLS, constant_values=255)
    return MarkerTexture(cells, size_m * cells.shape[0] / n)


def marker_T_dock(spec) -> np.ndarray:
    """Pose of a marker in the dock frame (4x4): in the face plane at center_m."""
    return make_T(np.eye(3), [spec.center_m[0], spec.center_m[1], 0.0])


def manifest_marker(spec) -> dict:
    """The manifest entry of a marker (FORMAT.md): keypoints in the dock frame."""
    T = marker_T_dock(spec)
    if spec.kind == "led_array":
        local = led_positions(spec)
        colors = [list(spec.color) for _ in range(4)]
        colors[spec.reference_index] = list(spec.reference_color)
        extra = {"led_radius_m": spec.led_radius_m, "colors": colors, "reference_index": spec.reference_index,
                 "layout": spec.layout, "size_m": spec.size_m, "strength": spec.strength}
    else:
        local = square_corners(spec.size_m)
        extra = {"size_m": spec.size_m}
        if spec.kind == "qr":
            extra["payload"] = spec.payload
        else:
            extra.update(dictionary=spec.dictionary, marker_id=spec.marker_id)
    kp = local @ T[:3, :3].T + T[:3, 3]
    return {"id": spec.id, "kind": spec.kind, "T_dock_marker": T.tolist(), "keypoints": kp.tolist(), **extra}


def texture_for(spec) -> MarkerTexture | None:
    """Texture of a square marker (None for LED arrays)."""
    if spec.kind == "qr":
        return qr_texture(spec.payload, spec.size_m)
    if spec.kind in ("aruco", "apriltag"):
        return aruco_texture(spec.dictionary, spec.marker_id, spec.size_m)
    return None


def write_texture(tex: MarkerTexture, path: Path) -> None:
    """Write texture cells as a PNG (one pixel per cell; the renderer samples it nearest)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), tex.cells)
