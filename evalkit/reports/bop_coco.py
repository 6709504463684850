"""``scene_gt_coco.json`` of a BOP scene, in the layout of the BOP toolkit's ``calc_gt_coco.py``.

COCO object-detection annotations (https://cocodataset.org/#format-data) for the images that
hold a test target: one annotation per object with a visible pixel, ``segmentation`` the
uncompressed run-length encoding of ``mask_visib`` (column-major counts starting with a
background run, ``size = [H, W]``), ``bbox`` the amodal box of ``mask`` inside the image
(``[x, y, w, h]`` with ``w = x_max - x_min + 1``), ``area`` the visible pixel count and
``ignore`` when ``visib_fract < 0.1``. Category ids are the BOP obj_ids.
"""

from __future__ import annotations

from typing import Any

import numpy as np

IGNORE_BELOW_VISIB = 0.1  # calc_gt_coco.py: annotations of objects < 10 % visible are "ignore"


def rle(mask: np.ndarray) -> dict:
    """Uncompressed COCO RLE of a bool ``(H, W)`` mask."""
    flat = np.asarray(mask, bool).ravel(order="F")
    edges = np.flatnonzero(np.diff(flat.astype(np.int8))) + 1
    runs = np.diff(np.concatenate([[0], edges, [flat.size]])).tolist()
    if flat.size and flat[0]:
        runs = [0] + runs
    return {"counts": runs, "size": list(mask.shape)}


def amodal_box(mask: np.ndarray) -> list[int]:
    """``[x, y, w, h]`` of the set pixels of ``mask`` (inclusive widths)."""
    ys, xs = np.nonzero(mask)
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


class SceneCoco:
    """Collects one scene's COCO images and annotations."""

    def __init__(self, obj_ids: list[int], dataset_name: str, split: str):
        self.doc: dict[str, Any] = {
            "info": {"description": f"{dataset_name}_{split}"},
            "licenses": [],
            "categories": [{"id": i, "name": str(i), "supercategory": dataset_name} for i in obj_ids],
            "images": [],
            "annotations": [],
        }

    def add_image(
        self,
        im_id: int,
        rgb_rel: str,
        width: int,
        height: int,
        objects: list[tuple[int, float, np.ndarray, np.ndarray]],
    ) -> None:
        """One target image; ``objects``: ``(obj_id, visib_fract, mask, mask_visib)`` per GT instance."""
        self.doc["images"].append({"id": im_id, "file_name": rgb_rel, "width": width, "height": height})
        for obj_id, visib_fract, mask, visib in objects:
            if not visib.any() or not mask.any():
                continue
            self.doc["annotations"].append(
                {
                    "id": len(self.doc["annotations"]) + 1,
                    "image_id": im_id,
                    "category_id": int(obj_id),
                    "iscrowd": 0,
                    "area": int(visib.sum()),
                    "bbox": amodal_box(mask),
                    "segmentation": rle(visib),
                    "width": int(mask.shape[1]),
                    "height": int(mask.shape[0]),
                    "ignore": bool(visib_fract < IGNORE_BELOW_VISIB),
                }
            )
