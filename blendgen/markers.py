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
from blendgen.physics.light.leds import led_radiance

QR_QUIET_MODULES = 4  # ISO/IEC 18004 default (config: quiet_zone_modules)
ARUCO_QUIET_CELLS = 1  # default white margin of ArUco/AprilTag, in cells


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
    """LED centres (N,3) in the marker frame for a LedArray spec, metres.

    Rectangle: TL, TR, BR, BL corners; circle: ``count`` points 360/N deg apart starting
    at the top, clockwise as seen from the camera; custom: ``positions_m``. Indices
    ``reference_index`` are the reference LEDs."""
    if spec.layout == "rectangle":
        return square_corners(1.0) * np.array([spec.size_m, spec.height_m or spec.size_m, 0.0])
    if spec.layout == "custom":
        xy = np.asarray(spec.positions_m, float).reshape(-1, 2)
        return np.column_stack([xy, np.zeros(len(xy))])
    r = spec.size_m / 2.0
    n = int(spec.count)
    ang = np.pi / 2 - np.arange(n) * 2 * np.pi / n
    return np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(n)])


def led_pattern_problem(spec) -> str:
    """Why the LED pattern cannot be identified from an image ('' when it can): the LEDs
    must be in strictly convex position (their cyclic image order is then the order
    around the polygon under any view from the front) and the cyclic sequence of
    reference / other colours around it must have no rotational symmetry (else the
    order has no unique start)."""
    p = led_positions(spec)[:, :2]
    c = p - p.mean(axis=0)
    order = np.argsort(np.arctan2(c[:, 1], c[:, 0]))
    q = p[order]
    e = np.roll(q, -1, axis=0) - q
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if np.min(np.hypot(e[:, 0], e[:, 1])) < 1e-6 or not (np.all(cross > 1e-12) or np.all(cross < -1e-12)):
        return "LED positions must be distinct and in strictly convex position (a convex polygon's corners)"
    refs = set(spec.reference_indices)
    ring = [int(i in refs) for i in order]
    if any(ring[k:] + ring[:k] == ring for k in range(1, len(ring))):
        return (
            f"reference LEDs {sorted(refs)} make a rotationally symmetric colour pattern around the array; "
            "the LED order would be ambiguous"
        )
    return ""


def make_qr(payload: str, error_correction: str = "M"):
    """The segno QR code of ``payload`` (smallest version at the given level, no boost)."""
    import segno

    return segno.make_qr(payload, error=error_correction.lower(), boost_error=False)


def qr_texture(
    payload: str, size_m: float, error_correction: str = "M", quiet_modules: int = QR_QUIET_MODULES
) -> MarkerTexture:
    """QR code cells via segno (smallest version that fits at ``error_correction``) with a
    white quiet zone of ``quiet_modules`` modules."""
    code = np.array(make_qr(payload, error_correction).matrix, dtype=np.uint8)  # 1 = dark
    n = code.shape[0]
    cells = np.pad(np.where(code > 0, 0, 255).astype(np.uint8), int(quiet_modules), constant_values=255)
    return MarkerTexture(cells, size_m * cells.shape[0] / n)


def qr_description(spec) -> dict:
    """Manifest fields of a QR marker: version, error correction, modules per side,
    module size (m) and quiet zone (modules)."""
    qr = make_qr(spec.payload, spec.error_correction)
    n = 17 + 4 * int(qr.version)
    return {
        "payload": spec.payload,
        "qr_version": int(qr.version),
        "error_correction": str(qr.error),
        "modules": n,
        "module_size_m": spec.size_m / n,
        "quiet_zone_modules": int(spec.quiet_zone_modules),
    }


def aruco_texture(
    dictionary: str, marker_id: int, size_m: float, quiet_cells: int = ARUCO_QUIET_CELLS
) -> MarkerTexture:
    """ArUco/AprilTag cells from OpenCV's dictionary, with a white quiet zone of ``quiet_cells``."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = d.markerSize + 2  # black border included in size_m
    img = cv2.aruco.generateImageMarker(d, marker_id, n, borderBits=1)
    cells = np.pad(img, int(quiet_cells), constant_values=255)
    return MarkerTexture(cells, size_m * cells.shape[0] / n)


def marker_T_dock(spec) -> np.ndarray:
    """Pose of a marker in the dock frame (4x4): in the face plane at center_m."""
    return make_T(np.eye(3), [spec.center_m[0], spec.center_m[1], 0.0])


def manifest_marker(spec) -> dict:
    """The manifest entry of a marker (FORMAT.md): keypoints in the dock frame."""
    T = marker_T_dock(spec)
    if spec.kind == "led_array":
        local = led_positions(spec)
        refs = spec.reference_indices
        colors = [list(spec.reference_color if i in refs else spec.color) for i in range(len(local))]
        extra = {
            "led_radius_m": spec.led_radius_m,
            "colors": colors,
            "reference_index": refs[0],
            "reference_indices": refs,
            "layout": spec.layout,
            "size_m": spec.size_m,
            "intensity_w_sr": spec.intensity_w_sr,
            "radiance": [led_radiance(spec.intensity_w_sr, c, spec.led_radius_m) for c in colors],
        }
    else:
        local = square_corners(spec.size_m)
        extra = {"size_m": spec.size_m}
        if spec.kind == "qr":
            extra.update(qr_description(spec))
        else:
            extra.update(
                dictionary=spec.dictionary, marker_id=spec.marker_id, quiet_zone_modules=int(spec.quiet_zone_modules)
            )
    kp = local @ T[:3, :3].T + T[:3, 3]
    return {"id": spec.id, "kind": spec.kind, "T_dock_marker": T.tolist(), "keypoints": kp.tolist(), **extra}


def texture_for(spec) -> MarkerTexture | None:
    """Texture of a square marker (None for LED arrays)."""
    if spec.kind == "qr":
        return qr_texture(spec.payload, spec.size_m, spec.error_correction, spec.quiet_zone_modules)
    if spec.kind in ("aruco", "apriltag"):
        return aruco_texture(spec.dictionary, spec.marker_id, spec.size_m, spec.quiet_zone_modules)
    return None


def write_texture(tex: MarkerTexture, path: Path) -> None:
    """Write texture cells as a PNG (one pixel per cell; the renderer samples it nearest)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), tex.cells)
