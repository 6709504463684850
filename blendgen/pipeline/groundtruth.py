"""Per-frame ground truth from poses alone (no renderer needed).

``T_cam_dock = inv(T_world_cam) @ T_world_dock``; ``d_true`` is the distance from
the camera centre to the dock's marker plane (dock z = 0), i.e. |z| of the camera
centre expressed in the dock frame.
"""

from __future__ import annotations

import numpy as np

from blendgen.geometry import invert_T, project, transform_points


def d_true(T_world_cam: np.ndarray, T_world_dock: np.ndarray) -> float:
    """Distance (m) from the camera optical centre to the marker plane z_dock = 0."""
    c_dock = invert_T(T_world_dock) @ T_world_cam[:, 3]
    return float(abs(c_dock[2]))


def marker_in_fov(K: np.ndarray, width: int, height: int, T_cam_dock: np.ndarray, keypoints_dock: np.ndarray) -> bool:
    """True when any keypoint (N,3 dock frame) projects inside the image, in front of the camera."""
    pts = transform_points(T_cam_dock, keypoints_dock)
    uv = project(K, pts)
    ok = (
        (pts[:, 2] > 0)
        & (uv[:, 0] >= -0.5)
        & (uv[:, 0] <= width - 0.5)
        & (uv[:, 1] >= -0.5)
        & (uv[:, 1] <= height - 0.5)
    )
    return bool(np.any(ok))


def frame_truth(
    T_world_cam: np.ndarray, T_world_dock: np.ndarray, markers: list[dict], K: np.ndarray, width: int, height: int
) -> dict:
    """Pose part of a frame record: T_cam_dock, d_true and per-marker in_fov / T_cam_marker.

    ``visible_fraction`` is filled later from the rendered object-index pass."""
    T_cam_dock = invert_T(T_world_cam) @ T_world_dock
    per_marker = {}
    for m in markers:
        kp = np.asarray(m["keypoints"], float)
        per_marker[m["id"]] = {
            "in_fov": marker_in_fov(K, width, height, T_cam_dock, kp),
            "visible_fraction": 0.0,
            "T_cam_marker": (T_cam_dock @ np.asarray(m["T_dock_marker"], float)).tolist(),
        }
    return {
        "T_world_cam": T_world_cam.tolist(),
        "T_cam_dock": T_cam_dock.tolist(),
        "d_true": d_true(T_world_cam, T_world_dock),
        "markers": per_marker,
    }


def dock_roi(
    T_cam_dock: np.ndarray, K: np.ndarray, width: int, height: int, corners_dock: np.ndarray, margin_px: int = 8
) -> tuple[int, int, int, int] | None:
    """Pixel box (x0, y0, x1, y1), end-exclusive, holding the projection of the dock's
    bounding corners (N,3, dock frame) plus a margin; None when it is out of view.
    A corner behind the camera makes the whole image the box (a conservative answer)."""
    pts = transform_points(T_cam_dock, corners_dock)
    if np.all(pts[:, 2] <= 0):
        return None
    if np.any(pts[:, 2] <= 1e-3):
        return 0, 0, width, height
    uv = project(K, pts)
    x0, y0 = np.floor(uv.min(axis=0) - margin_px).astype(int)
    x1, y1 = np.ceil(uv.max(axis=0) + margin_px).astype(int) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    if x1 <= x0 or y1 <= y0:
        return None
    return int(x0), int(y0), int(x1), int(y1)


Box = tuple[int, int, int, int]


def _union(a: Box, b: Box) -> Box:
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


def _area(b: Box) -> int:
    return (b[2] - b[0]) * (b[3] - b[1])


def _overlap(a: Box, b: Box) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _merge_overlapping(boxes: list[Box]) -> list[Box]:
    out = list(boxes)
    i = 0
    while i < len(out):
        j = next((j for j in range(len(out)) if j != i and _overlap(out[i], out[j])), None)
        if j is None:
            i += 1
            continue
        out[min(i, j)] = _union(out[i], out[j])
        out.pop(max(i, j))
        i = 0
    return out


def merge_boxes(boxes: list[Box], max_boxes: int) -> list[Box]:
    """Disjoint boxes covering ``boxes`` (x0, y0, x1, y1 px, end-exclusive): overlapping
    boxes are replaced by their union until none overlap; then, while more than
    ``max_boxes`` remain, the pair whose union adds the least area is merged (and
    overlaps resolved again). Sorted."""
    out = _merge_overlapping(boxes)
    while len(out) > max(1, max_boxes):
        pairs = [(i, j) for i in range(len(out)) for j in range(i + 1, len(out))]
        i, j = min(pairs, key=lambda p: _area(_union(out[p[0]], out[p[1]])) - _area(out[p[0]]) - _area(out[p[1]]))
        out[i] = _union(out[i], out[j])
        out.pop(j)
        out = _merge_overlapping(out)
    return sorted(out)


def marker_rois(
    T_cam_dock: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    regions_dock: list[np.ndarray],
    margin_px: int = 8,
    max_boxes: int = 6,
) -> list[Box]:
    """Disjoint pixel boxes (see :func:`merge_boxes`) holding the projection of every
    region (each (N,3) corners, dock frame: a marker plate, one LED disc) plus a margin;
    regions out of view give no box, a region with a corner behind the camera gives the
    whole image (as :func:`dock_roi`)."""
    boxes = [b for c in regions_dock if (b := dock_roi(T_cam_dock, K, width, height, c, margin_px)) is not None]
    return merge_boxes(boxes, max_boxes)
