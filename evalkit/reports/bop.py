"""Export a dockbench dataset in the BOP format (https://bop.felk.cvut.cz, toolkit conventions).

``dockbench export-bop DATASET -o DIR`` writes::

    DIR/camera.json                     fx, fy, cx, cy, width, height, depth_scale
    DIR/models/obj_XXXXXX.ply           one closed mesh per marker (mm, marker frame)
    DIR/models/models_info.json         diameter, min_*, size_* (mm); no symmetries
    DIR/models_eval/                    the same meshes (bop_toolkit evaluates with these)
    DIR/test_targets_bop19.json         [{scene_id, im_id, obj_id, inst_count}]: markers with
                                        visib_fract >= 0.1 (BOP's own annotation threshold)
    DIR/dockbench_objects.json          obj_id -> marker id, kind, keypoints (mm, marker frame)
    DIR/dockbench_scenes.json           scene id -> sequence id, condition, trial; dataset identity;
                                        where visib_fract came from
    DIR/<split>/<scene:06d>/            one scene per sequence (manifest order)
        scene_camera.json   per image: cam_K (row-major 9), depth_scale, cam_R_w2c, cam_t_w2c (mm)
        scene_gt.json       per image: [{obj_id, cam_R_m2c (row-major 9), cam_t_m2c (mm)}] per marker
        scene_gt_info.json  per image: [{visib_fract, bbox_obj, bbox_visib, px_count_all,
                            px_count_valid, px_count_visib}]
        rgb/<im:06d>.png    symlink to the dataset image (or a copy)
        depth/<im:06d>.png  uint16 planar depth z, ``z_mm = value * depth_scale`` (0 = no data)
        mask/<im:06d>_<gt:06d>.png        the model's silhouette (unoccluded)
        mask_visib/<im:06d>_<gt:06d>.png  its visible pixels (silhouette and the object index)

Objects are the dataset's markers (``obj_id`` = 1-based position in the manifest),
posed by the frame's ``T_cam_marker``. Models (:func:`evalkit.metrics.recall.marker_model`,
the same meshes ``evaluate`` computes MSSD/MSPD with): printed markers are plates 5 mm
deep (bop_toolkit's MSSD/MSPD use the vertices; a closed mesh also renders for VSD);
LED arrays are one cube per LED. **visib_fract** is computed from the rendered
object-index pass as in bop_toolkit's ``calc_gt_info``: the silhouette of the model in
its GT pose (convex hull of each box's projected vertices) is ``mask``
(``px_count_all``), the part of it where the index shows that marker is
``mask_visib``; ``visib_fract = px_count_visib / px_count_all``. Without an index
pass the dataset's ``visible_fraction`` is copied and ``dockbench_scenes.json`` says so.
For LED arrays the silhouette is that of the cubes around the LEDs, which the rendered
LED discs only partly fill: an unoccluded LED array reads about 0.45 on the quickstart
demo (printed markers read 1.0), still well above BOP's 0.1 target threshold.
Checked against bop_toolkit (thodan/bop_toolkit cea62d6): its ``inout`` loaders read the
export and its ``pose_error.mssd``/``mspd`` on ``models_eval`` reproduce ``evaluate``'s
per-frame MSSD/MSPD to 1e-13.
Lens distortion: BOP cameras are pinhole (``cam_K`` only). A dataset whose camera has
distortion is refused unless ``undistort=True`` (``--undistort``): then every image, the
range and the object-index pass are remapped to the pinhole camera of the same K with
OpenCV's undistortion maps (``cv2.initUndistortRectifyMap``; RGB bilinear, index and range
nearest, so labels and depths are not blended), written as files (never links), and the
ground truth is projected without distortion. Pixels whose ideal ray falls outside the
distorted image are black RGB, index 0 and no depth.
Depth: the dataset stores the *range* along each pixel ray (m); BOP wants planar
``z``: ``z = range / |K^-1 [u, v, 1]|`` (rays undistorted with OpenCV when the camera
has distortion). With ``depth_scale`` 1.0 (default) a PNG unit is 1 mm, so depths
beyond 65.535 m become 0 (no data); 0.1 gives 0.1 mm units but only 6.5 m. Image ids
are the frame indices.
"""
from __future__ import annotations

from typing import Any

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from datasets_spec.io import load_index, load_range
from evalkit.dataset import Dataset, DatasetError
from evalkit.metrics.recall import marker_model, marker_points

MIN_TARGET_VISIB = 0.1


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def ray_norms(K: np.ndarray, width: int, height: int, dist: np.ndarray | None = None) -> np.ndarray:
    """``|(x, y, 1)|`` per pixel, ``(x, y)`` the normalized (undistorted) ray of pixel (u, v)."""
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    if dist is not None and np.any(np.asarray(dist, dtype=float) != 0):
        import cv2
        pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        xy = cv2.undistortPoints(pts, np.asarray(K, float), np.asarray(dist, float)).reshape(height, width, 2)
        x, y = xy[..., 0], xy[..., 1]
    else:
        Kinv = np.linalg.inv(np.asarray(K, dtype=float))
        x = Kinv[0, 0] * u + Kinv[0, 1] * v + Kinv[0, 2]
        y = Kinv[1, 0] * u + Kinv[1, 1] * v + Kinv[1, 2]
    return np.sqrt(x * x + y * y + 1.0)


def range_to_depth_png(range_m: np.ndarray, norms: np.ndarray, depth_scale: float) -> tuple[np.ndarray, int]:
    """Range (m, inf = none) to a BOP uint16 depth image; returns ``(image, n_clipped)``.

    ``value = round(z_mm / depth_scale)``; no surface, non-finite or too far
    (> 65535 units) become 0."""
    z_mm = np.asarray(range_m, dtype=float) / norms * 1000.0
    units = np.round(z_mm / depth_scale)
    valid = np.isfinite(units) & (units > 0)
    too_far = valid & (units > 65535)
    img = np.where(valid & ~too_far, units, 0).astype(np.uint16)
    return img, int(too_far.sum())


def _write_ply(path: Path, vertices_mm: np.ndarray, faces: np.ndarray) -> None:
    """ASCII PLY of a triangle mesh (mm)."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices_mm)}", "property float x",
             "property float y", "property float z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(f"{c:.6f}" for c in p) for p in vertices_mm]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")


def _model_info(vertices_mm: np.ndarray) -> dict:
    lo, hi = vertices_mm.min(axis=0), vertices_mm.max(axis=0)
    diam = float(np.max(np.linalg.norm(vertices_mm[:, None] - vertices_mm[None], axis=2)))
    return {"diameter": diam, "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}


def _index_values(dataset: Dataset) -> dict[str, int]:
    """Marker id -> value in the object-index PNG."""
    out = {}
    for value, name in (dataset.manifest.get("object_index") or {}).items():
        try:
            out[str(name)] = int(value)
        except (TypeError, ValueError):
            pass
    for m in dataset.markers:
        if "object_index" in m:
            out[str(m["id"])] = int(m["object_index"])
    return out


def _project(points_cam: np.ndarray, K: np.ndarray, dist) -> np.ndarray | None:
    """Pixel coordinates of camera-frame points, or None if any is behind the camera."""
    if np.any(points_cam[:, 2] <= 1e-9):
        return None
    if dist is not None and np.any(np.asarray(dist) != 0):
        import cv2
        uv, _ = cv2.projectPoints(points_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                  np.asarray(K, float), np.asarray(dist, float))
        return uv.reshape(-1, 2)
    p = points_cam @ np.asarray(K, float).T
    return p[:, :2] / p[:, 2:3]


def _bbox(x0: float, y0: float, x1: float, y1: float) -> list[int]:
    """BOP bbox ``[x, y, w, h]`` (ints) of the pixel range ``x0..x1, y0..y1`` inclusive."""
    return [int(x0), int(y0), int(x1) - int(x0) + 1, int(y1) - int(y0) + 1]


def _link_or_copy(src: Path, dst: Path, copy: bool) -> None:
    if dst.is_symlink() or dst.exists():
        dst.unlink()
    if copy:
        shutil.copy2(src, dst)
    else:
        os.symlink(src.resolve(), dst)


def _json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=1) + "\n")


@dataclass
class _Export:
    """What every scene of one export shares."""

    ds: Dataset
    out: Path
    split: str
    copy_images: bool
    depth_scale: float
    masks: bool
    obj_ids: dict = field(default_factory=dict)        # marker id -> obj_id
    models: dict = field(default_factory=dict)         # obj_id -> vertices (m, marker frame)
    index_values: dict = field(default_factory=dict)   # marker id -> object-index value
    norms: np.ndarray | None = None
    undistort_maps: tuple | None = None                  # (map_x, map_y) when undistorting
    clipped: int = 0
    visib_from_index: int = 0
    visib_copied: int = 0
    targets: list = field(default_factory=list)

    @property
    def K(self) -> np.ndarray:
        return self.ds.camera["K"]

    @property
    def dist(self):
        """The distortion the exported files have (None once undistorted)."""
        return None if self.undistort_maps is not None else self.ds.camera["dist"]

    def remap(self, img: np.ndarray, nearest: bool, border=0) -> np.ndarray:
        """``img`` on the pinhole camera (identity without undistortion)."""
        if self.undistort_maps is None:
            return img
        import cv2
        interpolation = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(img, *self.undistort_maps, interpolation,  # type: ignore[call-overload]  # OpenCV's stubs
                         borderMode=cv2.BORDER_CONSTANT, borderValue=border)


def has_distortion(dataset: Dataset) -> bool:
    """True when the dataset's camera has non-zero lens distortion."""
    d = dataset.camera["dist"]
    return d is not None and bool(np.any(np.asarray(d, float) != 0))


def _undistort_maps(dataset: Dataset) -> tuple:
    import cv2
    cam = dataset.camera
    K = np.asarray(cam["K"], float)
    return cv2.initUndistortRectifyMap(K, np.asarray(cam["dist"], float), None, K,
                                       (int(cam["width"]), int(cam["height"])), cv2.CV_32FC1)


def _write_models(ex: _Export) -> None:
    """models/ and models_eval/ (PLY + models_info.json) and dockbench_objects.json."""
    infos, objects = {}, {}
    for i, m in enumerate(ex.ds.markers):
        oid = ex.obj_ids[str(m["id"])] = i + 1
        vertices, faces = marker_model(m)
        ex.models[oid] = vertices
        for sub in ("models", "models_eval"):
            (ex.out / sub).mkdir(exist_ok=True)
            _write_ply(ex.out / sub / f"obj_{oid:06d}.ply", vertices * 1000.0, faces)
        infos[str(oid)] = _model_info(vertices * 1000.0)
        objects[str(oid)] = {"marker_id": str(m["id"]), "kind": m.get("kind"),
                             "keypoints_mm": (marker_points(m) * 1000.0).tolist()}
    for sub in ("models", "models_eval"):
        _json(ex.out / sub / "models_info.json", infos)
    _json(ex.out / "dockbench_objects.json", objects)


def _silhouette(vertices: np.ndarray, T: np.ndarray, K: np.ndarray, dist, shape: tuple[int, int]):
    """Pixels covered by the model (boxes of 8 vertices, m) in pose ``T`` (4x4, marker to
    camera): a bool ``(H, W)`` mask, or None when a vertex is behind the camera."""
    import cv2
    uv = _project(vertices @ T[:3, :3].T + T[:3, 3], K, dist)
    if uv is None:
        return None
    canvas = np.zeros(shape, np.uint8)
    for box in uv.reshape(-1, 8, 2):
        hull = cv2.convexHull(np.round(box * 16).astype(np.int32))   # 4 bits of sub-pixel precision
        cv2.fillConvexPoly(canvas, hull, 1, lineType=cv2.LINE_8, shift=4)
    return canvas.astype(bool)


def _gt_info(ex: _Export, mid: str, T: np.ndarray, frame_marker: dict, index, depth) -> tuple[dict, tuple]:
    """scene_gt_info entry of one marker in one image and its ``(mask, mask_visib)`` (or Nones)."""
    oid = ex.obj_ids[mid]
    info: dict[str, Any] = {"bbox_obj": [-1, -1, -1, -1], "bbox_visib": [-1, -1, -1, -1]}
    uv = _project(ex.models[oid] @ T[:3, :3].T + T[:3, 3], ex.K, ex.dist)
    if uv is not None:
        info["bbox_obj"] = _bbox(np.floor(uv[:, 0].min()), np.floor(uv[:, 1].min()),
                                 np.floor(uv[:, 0].max()), np.floor(uv[:, 1].max()))
    if index is None or mid not in ex.index_values:
        ex.visib_copied += 1
        return {**info, "visib_fract": float(frame_marker.get("visible_fraction") or 0.0)}, (None, None)
    ex.visib_from_index += 1
    sil = _silhouette(ex.models[oid], T, ex.K, ex.dist, index.shape[:2])
    if sil is None:
        sil = np.zeros(index.shape[:2], bool)
    visib = sil & (index == ex.index_values[mid])
    n_all, n_visib = int(sil.sum()), int(visib.sum())
    info.update(px_count_all=n_all, px_count_valid=int((sil & (depth > 0)).sum()) if depth is not None else n_all,
                px_count_visib=n_visib, visib_fract=n_visib / n_all if n_all else 0.0)
    if n_visib:
        ys, xs = np.nonzero(visib)
        info["bbox_visib"] = _bbox(xs.min(), ys.min(), xs.max(), ys.max())
    return info, (sil, visib)


def _frame_depth(ex: _Export, frame: dict, path: Path):
    """Write the frame's depth PNG; return it (uint16) or None without a depth file."""
    import cv2
    if not frame.get("depth"):
        return None
    rng = load_range(ex.ds.frame_file(frame, "depth"))      # 1.1 mm PNG or 1.0 float NPZ
    rng = ex.remap(np.asarray(rng, np.float32), nearest=True, border=float("inf"))
    if ex.norms is None:
        cam = ex.ds.camera
        ex.norms = ray_norms(ex.K, cam["width"], cam["height"], ex.dist)
    img, n = range_to_depth_png(rng, ex.norms, ex.depth_scale)
    ex.clipped += n
    cv2.imwrite(str(path), img)
    return img


def _export_frame(ex: _Export, sdir: Path, scene_id: int, frame: dict) -> tuple[dict, list, list]:
    """Write one image's files; return its ``(scene_camera, scene_gt, scene_gt_info)`` entries."""
    import cv2
    im = int(frame["index"])
    if ex.undistort_maps is None:
        _link_or_copy(ex.ds.image_path(frame), sdir / "rgb" / f"{im:06d}.png", ex.copy_images)
    else:
        rgb = cv2.imread(str(ex.ds.image_path(frame)), cv2.IMREAD_UNCHANGED)
        if rgb is None:
            raise OSError(f"cannot read {ex.ds.image_path(frame)}")
        cv2.imwrite(str(sdir / "rgb" / f"{im:06d}.png"), ex.remap(rgb, nearest=False))
    cam_entry = {"cam_K": [float(v) for v in ex.K.ravel()], "depth_scale": ex.depth_scale}
    if frame.get("T_world_cam") is not None:
        T_cam_world = _inv(np.asarray(frame["T_world_cam"], dtype=float))
        cam_entry["cam_R_w2c"] = [float(v) for v in T_cam_world[:3, :3].ravel()]
        cam_entry["cam_t_w2c"] = [float(v) * 1000.0 for v in T_cam_world[:3, 3]]
    depth = _frame_depth(ex, frame, sdir / "depth" / f"{im:06d}.png")
    index = None
    if frame.get("object_index"):
        index = ex.remap(load_index(ex.ds.frame_file(frame, "object_index")), nearest=True)
    T_cam_dock = np.asarray(frame.get("T_cam_dock", np.eye(4)), dtype=float)
    fmarkers = frame.get("markers") or {}
    gts: list[dict] = []
    infos: list[dict] = []
    for m in ex.ds.markers:
        mid = str(m["id"])
        fm = fmarkers.get(mid) or {}
        T = (np.asarray(fm["T_cam_marker"], dtype=float) if fm.get("T_cam_marker") is not None
             else T_cam_dock @ np.asarray(m.get("T_dock_marker", np.eye(4)), dtype=float))
        gts.append({"obj_id": ex.obj_ids[mid], "cam_R_m2c": [float(v) for v in T[:3, :3].ravel()],
                    "cam_t_m2c": [float(v) * 1000.0 for v in T[:3, 3]]})
        info, (sil, visib) = _gt_info(ex, mid, T, fm, index, depth)
        if ex.masks and sil is not None:
            name = f"{im:06d}_{len(infos):06d}.png"
            cv2.imwrite(str(sdir / "mask" / name), sil.astype(np.uint8) * 255)
            cv2.imwrite(str(sdir / "mask_visib" / name), visib.astype(np.uint8) * 255)
        if info["visib_fract"] >= MIN_TARGET_VISIB:
            ex.targets.append({"scene_id": scene_id, "im_id": im, "obj_id": ex.obj_ids[mid], "inst_count": 1})
        infos.append(info)
    return cam_entry, gts, infos


def _export_scene(ex: _Export, scene_id: int, seq: dict) -> int:
    """Write one sequence as a BOP scene; returns its number of images."""
    sdir = ex.out / ex.split / f"{scene_id:06d}"
    for sub in ("rgb", "depth", "mask", "mask_visib"):
        (sdir / sub).mkdir(parents=True, exist_ok=True)
    scene_camera, scene_gt, scene_gt_info = {}, {}, {}
    for frame in ex.ds.iter_frames(seq["id"]):
        key = str(int(frame["index"]))
        scene_camera[key], scene_gt[key], scene_gt_info[key] = _export_frame(ex, sdir, scene_id, frame)
    _json(sdir / "scene_camera.json", scene_camera)
    _json(sdir / "scene_gt.json", scene_gt)
    _json(sdir / "scene_gt_info.json", scene_gt_info)
    return len(scene_camera)


def export_bop(dataset: Dataset | str | Path, out_dir: str | Path, split: str = "test",
               copy_images: bool = False, depth_scale: float = 1.0, masks: bool = True,
               sequences: list[str] | None = None, undistort: bool = False) -> dict:
    """Write ``dataset`` as a BOP dataset into ``out_dir`` (see the module docstring).
    A camera with lens distortion raises :class:`DatasetError` unless ``undistort``.

    Returns a summary ``{scenes, images, objects, depth_clipped_px, undistorted}``."""
    ds = dataset if isinstance(dataset, Dataset) else Dataset.open(dataset)
    if depth_scale <= 0:
        raise ValueError("depth_scale must be > 0")
    distorted = has_distortion(ds)
    if distorted and not undistort:
        raise DatasetError(f"{ds.root}: the camera has lens distortion {ds.camera['dist'].tolist()} but BOP "
                           "cameras are pinhole (cam_K only); export with --undistort (undistort=True) to "
                           "remap images, depth and masks to the pinhole camera of the same K")
    ex = _Export(ds, Path(out_dir), split, copy_images, depth_scale, masks, index_values=_index_values(ds),
                 undistort_maps=_undistort_maps(ds) if distorted else None)
    ex.out.mkdir(parents=True, exist_ok=True)
    cam = ds.camera
    _json(ex.out / "camera.json", {"cx": float(ex.K[0, 2]), "cy": float(ex.K[1, 2]), "fx": float(ex.K[0, 0]),
                                   "fy": float(ex.K[1, 1]), "width": cam["width"], "height": cam["height"],
                                   "depth_scale": depth_scale})
    _write_models(ex)
    scenes, n_images = {}, 0
    for scene_id, seq in enumerate(ds.sequences):
        if sequences is None or seq["id"] in sequences:
            scenes[f"{scene_id:06d}"] = {"sequence": seq["id"], "condition": seq.get("condition"),
                                         "trajectory": seq.get("trajectory"), "trial": seq.get("trial")}
            n_images += _export_scene(ex, scene_id, seq)
    _json(ex.out / "test_targets_bop19.json", ex.targets)
    m = ds.manifest
    _json(ex.out / "dockbench_scenes.json", {
        "dataset": {"name": m.get("name"), "version": m.get("version"), "content_hash": m.get("content_hash")},
        "split": split, "depth_scale": depth_scale, "scenes": scenes,
        "undistorted_from": ds.camera["dist"].tolist() if distorted else None,
        "visib_fract": {"from_object_index": ex.visib_from_index, "copied_from_dataset": ex.visib_copied}})
    return {"scenes": len(scenes), "images": n_images, "objects": len(ds.markers),
            "depth_clipped_px": ex.clipped, "undistorted": distorted}
