"""One object's BOP ``scene_gt_info`` entry and masks, as the BOP toolkit's ``calc_gt_info.py`` defines them.

The model is rendered in its GT pose on a canvas of three image widths by three image heights
centred on the image (the toolkit's enlarged canvas), so ``px_count_all`` and ``bbox_obj``
include the part of the silhouette outside the image. Visibility (BOP19 mode): a silhouette
pixel is visible when ``dist_model - dist_test <= delta`` or the test depth is missing
(``dist_test == 0``), distances from the camera centre in mm. Boxes are ``[x, y, x_max - x,
y_max - y]`` (the toolkit's ``calc_2d_bbox``); both are ``[-1, -1, -1, -1]`` when no pixel is
visible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evalkit.reports.bop_raster import (
    OPENCV_SAMPLE_OFFSET,
    Window,
    depth_to_dist,
    projected_window,
    render_depth,
)

NO_BOX = [-1, -1, -1, -1]


@dataclass(frozen=True)
class ImageView:
    """What one exported image offers a visibility test.

    ``K``: 3x3 (px); ``width``, ``height`` (px); ``dist_mm``: ``(H, W)`` distance image of the
    exported depth (0 = no data) or None; ``index``: ``(H, W)`` object-index pass or None."""

    K: np.ndarray
    width: int
    height: int
    dist_mm: np.ndarray | None = None
    index: np.ndarray | None = None

    @classmethod
    def from_depth_png(
        cls,
        K,
        width: int,
        height: int,
        depth_png: np.ndarray | None,
        depth_scale: float,
        index: np.ndarray | None = None,
    ) -> ImageView:
        """The view of an exported uint16 depth image (``z_mm = value * depth_scale``)."""
        dist = (
            None
            if depth_png is None
            else depth_to_dist(depth_png.astype(np.float64) * depth_scale, np.asarray(K, float))
        )
        return cls(np.asarray(K, float), int(width), int(height), dist, index)


def render_model_dist(
    vertices_mm: np.ndarray,
    faces: np.ndarray,
    R: np.ndarray,
    t_mm: np.ndarray,
    view: ImageView,
    enlarged: bool = True,
    sample_offset: float = OPENCV_SAMPLE_OFFSET,
) -> tuple[np.ndarray, Window]:
    """Distance image (mm, 0 = no surface) of the posed model over the pixels it covers, on the
    enlarged canvas (or the image), and the window those pixels are (``sample_offset``: see
    :func:`evalkit.reports.bop_raster.render_depth`; distances use the pixel's own ray)."""
    cam = np.asarray(vertices_mm, float) @ np.asarray(R, float).T + np.asarray(t_mm, float)
    w, h = view.width, view.height
    bounds = Window(-w, -h, 2 * w, 2 * h) if enlarged else Window(0, 0, w, h)
    win = projected_window(cam, view.K, bounds)
    depth = render_depth(cam, faces, view.K, win, sample_offset)
    return depth_to_dist(depth, view.K, win.x0, win.y0), win


def crop_to_image(patch: np.ndarray, win: Window, width: int, height: int) -> np.ndarray:
    """``patch`` (over ``win``) as a full ``(height, width)`` image, 0 outside the patch."""
    out = np.zeros((height, width), patch.dtype)
    x0, y0, x1, y1 = max(win.x0, 0), max(win.y0, 0), min(win.x1, width), min(win.y1, height)
    if x1 > x0 and y1 > y0:
        out[y0:y1, x0:x1] = patch[y0 - win.y0 : y1 - win.y0, x0 - win.x0 : x1 - win.x0]
    return out


def visible_mask(dist_test: np.ndarray, dist_model: np.ndarray, delta_mm: float) -> np.ndarray:
    """BOP19 visibility: model pixels no more than ``delta_mm`` behind the test surface, or
    with no test depth (float32 differences, as the toolkit)."""
    diff = dist_model.astype(np.float32) - dist_test.astype(np.float32)
    return ((diff <= delta_mm) | (dist_test == 0)) & (dist_model > 0)


def calc_2d_bbox(xs: np.ndarray, ys: np.ndarray) -> list[int]:
    """``[x, y, x_max - x, y_max - y]`` of pixel coordinates (the toolkit's convention, not +1)."""
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def gt_info(
    vertices_mm: np.ndarray,
    faces: np.ndarray,
    R: np.ndarray,
    t_mm: np.ndarray,
    view: ImageView,
    delta_mm: float,
    index_value: int | None = None,
    sample_offset: float = OPENCV_SAMPLE_OFFSET,
) -> tuple[dict, np.ndarray, np.ndarray]:
    """``(scene_gt_info entry, mask, mask_visib)`` of one posed model; masks are ``(H, W)`` bool.

    Visibility from ``view.dist_mm`` (the depth test); without it from ``view.index ==
    index_value``; raises ValueError with neither. ``sample_offset``: the pixel convention
    (:func:`evalkit.reports.bop_raster.render_depth`)."""
    patch, win = render_model_dist(vertices_mm, faces, R, t_mm, view, sample_offset=sample_offset)
    dist_gt = crop_to_image(patch, win, view.width, view.height)
    mask = dist_gt > 0
    if view.dist_mm is not None:
        visib = visible_mask(view.dist_mm, dist_gt, delta_mm)
        n_valid = int((view.dist_mm[mask] > 0).sum())
    elif view.index is not None and index_value is not None:
        visib = mask & (view.index == index_value)
        n_valid = int(mask.sum())
    else:
        raise ValueError("no depth and no object index to test visibility with")
    n_all, n_visib = int((patch > 0).sum()), int(visib.sum())
    info = {
        "px_count_all": n_all,
        "px_count_valid": n_valid,
        "px_count_visib": n_visib,
        "visib_fract": n_visib / n_all if n_all else 0.0,
        "bbox_obj": NO_BOX,
        "bbox_visib": NO_BOX,
    }
    if n_visib:
        ys, xs = np.nonzero(patch > 0)
        info["bbox_obj"] = calc_2d_bbox(xs + win.x0, ys + win.y0)
        ys, xs = np.nonzero(visib)
        info["bbox_visib"] = calc_2d_bbox(xs, ys)
    return info, mask, visib
