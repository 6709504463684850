"""Depth rendering of small triangle meshes for the BOP export and its scores (no GPU, no Blender).

BOP's ground-truth info (``scene_gt_info``: visible fraction, boxes) and its VSD error both
render the object model's depth in a pose. The BOP toolkit does this with OpenGL; dockbench
does it here with a z-buffer over the model's triangles, in the *renderer's* pixel convention:
pixel ``(u, v)`` (column, row) is covered when the point ``(u, v)`` of the image plane -- the
pixel centre in OpenCV's convention, where ``K`` maps a ray to ``u = fx x + cx`` -- lies inside
a projected triangle (edges inclusive). The depth there is the planar ``z`` of the triangle's
plane along that pixel's ray (exact, no interpolation error).

The BOP toolkit's OpenGL renderers (``renderer_vispy``, ``renderer_py``: the projection matrix of
``_calc_calib_proj``) put ``K``'s coordinate ``u`` at the *edge* of window pixel ``u``, so their pixel
``(i, j)`` samples the point ``(i + 0.5, j + 0.5)``: half a pixel off OpenCV's convention.
``sample_offset`` selects that convention (:data:`TOOLKIT_SAMPLE_OFFSET`) where dockbench must
reproduce the toolkit's numbers (:mod:`evalkit.reports.bop_score`); the export itself follows the
renderer (offset 0), whose depth and index passes it is tested against.

A triangle with a vertex at or behind ``NEAR_MM`` is skipped (the exported objects are markers
in front of the camera; a marker crossing the image plane has no meaningful silhouette).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEAR_MM = 1.0
OPENCV_SAMPLE_OFFSET = 0.0  # pixel (i, j) samples (i, j): dockbench's renderer, OpenCV
TOOLKIT_SAMPLE_OFFSET = 0.5  # pixel (i, j) samples (i + 0.5, j + 0.5): the BOP toolkit's OpenGL renderers


@dataclass(frozen=True)
class Window:
    """A pixel window ``x0 <= u < x1, y0 <= v < y1`` of an image plane (px, ints; may be negative)."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def shape(self) -> tuple[int, int]:
        return max(self.y1 - self.y0, 0), max(self.x1 - self.x0, 0)


def render_depth(
    vertices_cam: np.ndarray,
    faces: np.ndarray,
    K: np.ndarray,
    window: Window,
    sample_offset: float = OPENCV_SAMPLE_OFFSET,
) -> np.ndarray:
    """Planar depth of the mesh over ``window``: ``(H, W)`` float64 in the vertices' unit, 0 = no surface.

    ``vertices_cam``: ``(N, 3)`` camera-frame points (OpenCV axes, z forward, mm);
    ``faces``: ``(F, 3)`` vertex indices; ``K``: 3x3 intrinsics (px); pixel ``(u, v)`` samples the
    image point ``(u + sample_offset, v + sample_offset)``."""
    depth = np.full(window.shape, np.inf)
    tri = np.asarray(vertices_cam, float)[np.asarray(faces, int)]  # (F, 3, 3)
    ok = (tri[:, :, 2] > NEAR_MM).all(axis=1)
    for t in tri[ok]:
        _draw_triangle(depth, t, np.asarray(K, float), window, sample_offset)
    depth[~np.isfinite(depth)] = 0.0
    return depth


def _draw_triangle(depth: np.ndarray, t: np.ndarray, K: np.ndarray, win: Window, off: float) -> None:
    """z-buffer one camera-frame triangle ``t`` (3, 3) into ``depth`` (the window's pixels)."""
    p = t @ K.T
    uv = p[:, :2] / p[:, 2:3] - off  # pixel indices whose sample point is the vertex
    area = (uv[1, 0] - uv[0, 0]) * (uv[2, 1] - uv[0, 1]) - (uv[2, 0] - uv[0, 0]) * (uv[1, 1] - uv[0, 1])
    if abs(area) < 1e-12:
        return  # seen edge-on: no pixel
    x0 = max(int(np.ceil(uv[:, 0].min())), win.x0)
    x1 = min(int(np.floor(uv[:, 0].max())), win.x1 - 1)
    y0 = max(int(np.ceil(uv[:, 1].min())), win.y0)
    y1 = min(int(np.floor(uv[:, 1].max())), win.y1 - 1)
    if x1 < x0 or y1 < y0:
        return
    u, v = np.meshgrid(np.arange(x0, x1 + 1, dtype=float), np.arange(y0, y1 + 1, dtype=float))
    w = [
        (
            (uv[(i + 2) % 3, 0] - uv[(i + 1) % 3, 0]) * (v - uv[(i + 1) % 3, 1])
            - (uv[(i + 2) % 3, 1] - uv[(i + 1) % 3, 1]) * (u - uv[(i + 1) % 3, 0])
        )
        / area
        for i in range(3)
    ]
    inside = (w[0] >= 0) & (w[1] >= 0) & (w[2] >= 0)
    if not inside.any():
        return
    inv_z = w[0] / t[0, 2] + w[1] / t[1, 2] + w[2] / t[2, 2]  # perspective-correct 1/z
    z = np.where(inside, 1.0 / np.where(inside, inv_z, 1.0), np.inf)
    patch = depth[y0 - win.y0 : y1 - win.y0 + 1, x0 - win.x0 : x1 - win.x0 + 1]
    np.minimum(patch, z, out=patch)


def projected_window(vertices_cam: np.ndarray, K: np.ndarray, bounds: Window) -> Window:
    """The pixels the projected vertices span (and one more each side, for any sample offset), clipped to ``bounds``
    (an empty window when
    every vertex is behind ``NEAR_MM``)."""
    pts = np.asarray(vertices_cam, float)
    pts = pts[pts[:, 2] > NEAR_MM]
    if not len(pts):
        return Window(bounds.x0, bounds.y0, bounds.x0, bounds.y0)
    p = pts @ np.asarray(K, float).T
    uv = p[:, :2] / p[:, 2:3]
    return Window(
        max(int(np.floor(uv[:, 0].min())) - 1, bounds.x0),
        max(int(np.floor(uv[:, 1].min())) - 1, bounds.y0),
        min(int(np.ceil(uv[:, 0].max())) + 1, bounds.x1),
        min(int(np.ceil(uv[:, 1].max())) + 1, bounds.y1),
    )


def depth_to_dist(depth: np.ndarray, K: np.ndarray, x0: int = 0, y0: int = 0) -> np.ndarray:
    """Distance from the camera centre per pixel from planar depth ``(H, W)`` (same unit);
    ``(x0, y0)``: the pixel coordinates of ``depth[0, 0]``. 0 stays 0."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(x0, x0 + w, dtype=float), np.arange(y0, y0 + h, dtype=float))
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    d = depth.astype(np.float64)
    return np.sqrt((x * d) ** 2 + (y * d) ** 2 + d**2)
