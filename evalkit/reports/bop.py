"""Export a dockbench dataset in the BOP format (https://bop.felk.cvut.cz, toolkit conventions).

``dockbench export-bop DATASET -o DIR`` writes what the BOP toolkit's own scripts would compute
(``calc_gt_info.py``, ``calc_gt_masks.py``, ``calc_gt_coco.py``, ``calc_model_info.py``)::

    DIR/camera.json                     fx, fy, cx, cy, width, height, depth_scale
    DIR/models/obj_XXXXXX.ply           one closed mesh per marker (mm, vertex normals, origin at
                                        the bounding-box centre; :mod:`evalkit.reports.bop_models`)
    DIR/models/models_info.json         diameter, min_*, size_* (mm); no symmetries
    DIR/models_eval/                    the same surfaces densely resampled (MSSD/MSPD/VSD use these)
    DIR/test_targets_bop19.json         [{scene_id, im_id, obj_id, inst_count}]: markers with
                                        visib_fract >= 0.1 (BOP's own annotation threshold)
    DIR/dockbench_objects.json          obj_id -> marker id, kind, keypoints (mm, model frame), model
                                        origin in the marker frame (mm)
    DIR/dockbench_scenes.json           scene id -> sequence id, condition, trial; dataset identity;
                                        where visib_fract came from
    DIR/register_bop_toolkit.py         registers the export as dataset "dockbench" in a BOP
                                        toolkit clone (docs/bop.md)
    DIR/results/METHOD_dockbench-SPLIT.csv  with ``--results``: BOP19 results per pose localizer
    DIR/<split>/<scene:06d>/            one scene per sequence (manifest order)
        scene_camera.json   per image: cam_K (row-major 9), depth_scale, cam_R_w2c, cam_t_w2c (mm)
        scene_gt.json       per image: [{obj_id, cam_R_m2c (row-major 9), cam_t_m2c (mm)}] per marker
        scene_gt_info.json  per image: [{visib_fract, bbox_obj, bbox_visib, px_count_all,
                            px_count_valid, px_count_visib}]
        scene_gt_coco.json  COCO annotations of the target images (RLE of mask_visib, amodal bbox)
        rgb/<im:06d>.png    a copy of the dataset image (a relative symlink with ``symlink=True``)
        depth/<im:06d>.png  uint16 planar depth z, ``z_mm = value * depth_scale`` (0 = no data)
        mask/<im:06d>_<gt:06d>.png        the model's silhouette in the image
        mask_visib/<im:06d>_<gt:06d>.png  its visible pixels

Objects are the dataset's markers (``obj_id`` = 1-based position in the manifest), posed by
the frame's ``T_cam_marker`` moved to the model origin (``t + R c``). **scene_gt_info** is
``calc_gt_info``'s definition: the model's depth is rendered in its GT pose
(:mod:`evalkit.reports.bop_raster`: same projection and pixel convention as the renderer,
OpenCV pixel centres) on a canvas three times the image in each direction, so the part of
a marker outside the image still counts in ``px_count_all``; a pixel is visible when the
rendered distance is at most :data:`VISIB_DELTA_MM` behind the exported depth image's distance
or that depth is missing (BOP19 visibility); ``visib_fract = px_count_visib / px_count_all``;
``bbox_obj`` (of the whole silhouette, may extend past the image) and ``bbox_visib`` are
``[x, y, x_max - x, y_max - y]`` as the toolkit's ``calc_2d_bbox``, and ``[-1, -1, -1, -1]``
when nothing is visible. Without a depth pass the dataset's object-index pass decides
visibility (silhouette pixels showing the marker's index), and without that the dataset's
``visible_fraction`` is copied; ``dockbench_scenes.json`` counts each source.
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

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from datasets_spec.io import load_index, load_range
from evalkit.dataset import Dataset, DatasetError
from evalkit.metrics.recall import marker_points
from evalkit.reports.bop_coco import SceneCoco
from evalkit.reports.bop_gtinfo import ImageView, gt_info
from evalkit.reports.bop_models import EVAL_STEP_MM, ObjectModel, write_ply
from evalkit.reports.bop_raster import OPENCV_SAMPLE_OFFSET, TOOLKIT_SAMPLE_OFFSET
from evalkit.reports.bop_register import registration_script
from evalkit.runner import progress_bar

MIN_TARGET_VISIB = 0.1  # BOP19 targets: visib_fract >= 0.1 (BOP Challenge 2019 rules)
VISIB_DELTA_MM = 15.0  # the visibility test's tolerance, calc_gt_info.py's delta (BOP toolkit)
PIXEL_CONVENTIONS = {"opencv": OPENCV_SAMPLE_OFFSET, "toolkit": TOOLKIT_SAMPLE_OFFSET}
BOP_DATASET_NAME = "dockbench"  # the name results files and the toolkit's registration use (docs/bop.md)


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


def _link_or_copy(src: Path, dst: Path, copy: bool) -> None:
    """Copy ``src`` to ``dst``, or link it by a path relative to ``dst``'s folder (the export
    and the dataset can then move together)."""
    if dst.is_symlink() or dst.exists():
        dst.unlink()
    if copy:
        shutil.copy2(src, dst)
    else:
        os.symlink(os.path.relpath(src.resolve(), dst.parent.resolve()), dst)


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
    obj_ids: dict = field(default_factory=dict)  # marker id -> obj_id
    models: dict = field(default_factory=dict)  # obj_id -> ObjectModel
    meshes: dict = field(default_factory=dict)  # obj_id -> (vertices mm, faces) about the origin
    index_values: dict = field(default_factory=dict)  # marker id -> object-index value
    norms: np.ndarray | None = None
    undistort_maps: tuple | None = None  # (map_x, map_y) when undistorting
    clipped: int = 0
    visib_sources: dict = field(default_factory=lambda: {"depth_test": 0, "object_index": 0, "copied": 0})
    targets: list = field(default_factory=list)
    sample_offset: float = OPENCV_SAMPLE_OFFSET  # the silhouettes' pixel convention
    tick: Callable[[int], None] | None = None  # progress: tick(n) per n images written

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
        return cv2.remap(
            img,
            *self.undistort_maps,
            interpolation,  # type: ignore[call-overload]  # OpenCV's stubs
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=border,
        )


def has_distortion(dataset: Dataset) -> bool:
    """True when the dataset's camera has non-zero lens distortion."""
    d = dataset.camera["dist"]
    return d is not None and bool(np.any(np.asarray(d, float) != 0))


def _undistort_maps(dataset: Dataset) -> tuple:
    import cv2

    cam = dataset.camera
    K = np.asarray(cam["K"], float)
    return cv2.initUndistortRectifyMap(
        K, np.asarray(cam["dist"], float), None, K, (int(cam["width"]), int(cam["height"])), cv2.CV_32FC1
    )


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


def _write_models(ex: _Export) -> None:
    """models/ (box faces with normals) and models_eval/ (resampled), models_info.json, dockbench_objects.json."""
    infos, objects = {}, {}
    for sub in ("models", "models_eval"):
        (ex.out / sub).mkdir(exist_ok=True)
    for i, m in enumerate(ex.ds.markers):
        oid = ex.obj_ids[str(m["id"])] = i + 1
        model = ex.models[oid] = ObjectModel.from_marker(m)
        v, n, f = model.mesh()
        ex.meshes[oid] = (v, f)
        write_ply(ex.out / "models" / f"obj_{oid:06d}.ply", v, n, f)
        write_ply(ex.out / "models_eval" / f"obj_{oid:06d}.ply", *model.mesh(EVAL_STEP_MM))
        infos[str(oid)] = model.info()
        objects[str(oid)] = {
            "marker_id": str(m["id"]),
            "kind": m.get("kind"),
            "keypoints_mm": (marker_points(m) * 1000.0 - model.centre_mm).tolist(),
            "model_origin_in_marker_mm": model.centre_mm.tolist(),
        }
    for sub in ("models", "models_eval"):
        _json(ex.out / sub / "models_info.json", infos)
    _json(ex.out / "dockbench_objects.json", objects)


def _frame_depth(ex: _Export, frame: dict, path: Path):
    """Write the frame's depth PNG; return it (uint16) or None without a depth file."""
    import cv2

    if not frame.get("depth"):
        return None
    rng = load_range(ex.ds.frame_file(frame, "depth"))  # 1.1 mm PNG or 1.0 float NPZ
    rng = ex.remap(np.asarray(rng, np.float32), nearest=True, border=float("inf"))
    if ex.norms is None:
        cam = ex.ds.camera
        ex.norms = ray_norms(ex.K, cam["width"], cam["height"], ex.dist)
    img, n = range_to_depth_png(rng, ex.norms, ex.depth_scale)
    ex.clipped += n
    cv2.imwrite(str(path), img)
    return img


def _frame_rgb(ex: _Export, frame: dict, dst: Path) -> None:
    import cv2

    if ex.undistort_maps is None:
        _link_or_copy(ex.ds.image_path(frame), dst, ex.copy_images)
    else:
        src = ex.ds.image_path(frame)
        rgb = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
        if rgb is None:
            raise DatasetError(f"{src}: missing or unreadable image")
        cv2.imwrite(str(dst), ex.remap(rgb, nearest=False))


def _camera_entry(ex: _Export, frame: dict) -> dict:
    cam_entry = {"cam_K": [float(v) for v in ex.K.ravel()], "depth_scale": ex.depth_scale}
    if frame.get("T_world_cam") is not None:
        T_cam_world = _inv(np.asarray(frame["T_world_cam"], dtype=float))
        cam_entry["cam_R_w2c"] = [float(v) for v in T_cam_world[:3, :3].ravel()]
        cam_entry["cam_t_w2c"] = [float(v) * 1000.0 for v in T_cam_world[:3, 3]]
    return cam_entry


def _marker_pose(frame: dict, marker: dict) -> np.ndarray:
    """``T_cam_marker`` (4x4, m) of ``marker`` in ``frame``."""
    fm = (frame.get("markers") or {}).get(str(marker["id"])) or {}
    if fm.get("T_cam_marker") is not None:
        return np.asarray(fm["T_cam_marker"], dtype=float)
    T_cam_dock = np.asarray(frame.get("T_cam_dock", np.eye(4)), dtype=float)
    return T_cam_dock @ np.asarray(marker.get("T_dock_marker", np.eye(4)), dtype=float)


def _object_info(ex: _Export, marker: dict, R, t_mm, view: ImageView, frame: dict):
    """scene_gt_info entry and masks (None when visibility is copied) of one marker."""
    mid, oid = str(marker["id"]), ex.obj_ids[str(marker["id"])]
    if view.dist_mm is not None or (view.index is not None and mid in ex.index_values):
        ex.visib_sources["depth_test" if view.dist_mm is not None else "object_index"] += 1
        vertices_mm, faces = ex.meshes[oid]
        return gt_info(vertices_mm, faces, R, t_mm, view, VISIB_DELTA_MM, ex.index_values.get(mid), ex.sample_offset)
    ex.visib_sources["copied"] += 1
    fm = (frame.get("markers") or {}).get(mid) or {}
    return (
        {
            "visib_fract": float(fm.get("visible_fraction") or 0.0),
            "bbox_obj": [-1, -1, -1, -1],
            "bbox_visib": [-1, -1, -1, -1],
        },
        None,
        None,
    )


def _export_frame(ex: _Export, sdir: Path, scene_id: int, frame: dict, coco: SceneCoco) -> tuple[dict, list, list]:
    """Write one image's files; return its ``(scene_camera, scene_gt, scene_gt_info)`` entries."""
    import cv2

    im = int(frame["index"])
    _frame_rgb(ex, frame, sdir / "rgb" / f"{im:06d}.png")
    depth = _frame_depth(ex, frame, sdir / "depth" / f"{im:06d}.png")
    index = None
    if frame.get("object_index"):
        index = ex.remap(load_index(ex.ds.frame_file(frame, "object_index")), nearest=True)
    cam = ex.ds.camera
    view = ImageView.from_depth_png(ex.K, cam["width"], cam["height"], depth, ex.depth_scale, index)
    gts: list[dict] = []
    infos: list[dict] = []
    coco_objects: list[tuple[int, float, np.ndarray, np.ndarray]] = []
    is_target = False
    for m in ex.ds.markers:
        oid = ex.obj_ids[str(m["id"])]
        R, t_mm = ex.models[oid].pose_m2c(_marker_pose(frame, m))
        gts.append({"obj_id": oid, "cam_R_m2c": [float(v) for v in R.ravel()], "cam_t_m2c": [float(v) for v in t_mm]})
        info, mask, visib = _object_info(ex, m, R, t_mm, view, frame)
        if ex.masks and mask is not None:
            name = f"{im:06d}_{len(infos):06d}.png"
            cv2.imwrite(str(sdir / "mask" / name), mask.astype(np.uint8) * 255)
            cv2.imwrite(str(sdir / "mask_visib" / name), visib.astype(np.uint8) * 255)
        if info["visib_fract"] >= MIN_TARGET_VISIB:
            ex.targets.append({"scene_id": scene_id, "im_id": im, "obj_id": oid, "inst_count": 1})
            is_target = True
        if mask is not None:
            coco_objects.append((oid, info["visib_fract"], mask, visib))
        infos.append(info)
    if is_target:
        coco.add_image(im, f"rgb/{im:06d}.png", int(cam["width"]), int(cam["height"]), coco_objects)
    return _camera_entry(ex, frame), gts, infos


def _export_scene(ex: _Export, scene_id: int, seq: dict) -> int:
    """Write one sequence as a BOP scene; returns its number of images."""
    sdir = ex.out / ex.split / f"{scene_id:06d}"
    for sub in ("rgb", "depth", "mask", "mask_visib"):
        (sdir / sub).mkdir(parents=True, exist_ok=True)
    coco = SceneCoco(sorted(ex.obj_ids.values()), BOP_DATASET_NAME, ex.split)
    scene_camera, scene_gt, scene_gt_info = {}, {}, {}
    for frame in ex.ds.iter_frames(seq["id"]):
        key = str(int(frame["index"]))
        scene_camera[key], scene_gt[key], scene_gt_info[key] = _export_frame(ex, sdir, scene_id, frame, coco)
        if ex.tick is not None:
            ex.tick(1)
    _json(sdir / "scene_camera.json", scene_camera)
    _json(sdir / "scene_gt.json", scene_gt)
    _json(sdir / "scene_gt_info.json", scene_gt_info)
    _json(sdir / "scene_gt_coco.json", coco.doc)
    return len(scene_camera)


def export_bop(
    dataset: Dataset | str | Path,
    out_dir: str | Path,
    split: str = "test",
    copy_images: bool = True,
    depth_scale: float = 1.0,
    masks: bool = True,
    sequences: list[str] | None = None,
    undistort: bool = False,
    pixels: str = "opencv",
    progress: bool = False,
) -> dict:
    """Write ``dataset`` as a BOP dataset into ``out_dir`` (see the module docstring); images are
    copied unless ``copy_images=False`` (relative symlinks). ``pixels``: the silhouettes' pixel
    convention, ``"opencv"`` (the renderer's, default) or ``"toolkit"`` (the BOP toolkit's OpenGL
    renderers, half a pixel off: ``scene_gt_info`` then equals its ``calc_gt_info.py``).
    ``progress``: a progress bar over the images on stderr.
    A camera with lens distortion raises :class:`DatasetError` unless ``undistort``.

    Returns a summary ``{scenes, images, objects, depth_clipped_px, undistorted}``."""
    ds = dataset if isinstance(dataset, Dataset) else Dataset.open(dataset)
    distorted = _check_export_args(ds, depth_scale, pixels, undistort)
    ex = _Export(
        ds,
        Path(out_dir),
        split,
        copy_images,
        depth_scale,
        masks,
        index_values=_index_values(ds),
        undistort_maps=_undistort_maps(ds) if distorted else None,
        sample_offset=PIXEL_CONVENTIONS[pixels],
    )
    ex.out.mkdir(parents=True, exist_ok=True)
    _write_camera(ex, depth_scale)
    _write_models(ex)
    scenes, n_images = {}, 0
    chosen = [(i, q) for i, q in enumerate(ds.sequences) if sequences is None or q["id"] in sequences]
    with progress_bar(sum(int(q.get("n_frames") or 0) for _, q in chosen), progress, "export-bop: images") as tick:
        ex.tick = tick
        for scene_id, seq in chosen:
            scenes[f"{scene_id:06d}"] = {
                "sequence": seq["id"],
                "condition": seq.get("condition"),
                "trajectory": seq.get("trajectory"),
                "trial": seq.get("trial"),
            }
            n_images += _export_scene(ex, scene_id, seq)
    _json(ex.out / "test_targets_bop19.json", ex.targets)
    _write_scenes_doc(ex, scenes, split, depth_scale, pixels, distorted)
    cam = ds.camera
    (ex.out / "register_bop_toolkit.py").write_text(
        registration_script(
            BOP_DATASET_NAME,
            sorted(ex.obj_ids.values()),
            [int(k) for k in scenes],
            cam["width"],
            cam["height"],
            VISIB_DELTA_MM,
        )
    )
    return {
        "scenes": len(scenes),
        "images": n_images,
        "objects": len(ds.markers),
        "depth_clipped_px": ex.clipped,
        "undistorted": distorted,
    }


def _check_export_args(ds: Dataset, depth_scale: float, pixels: str, undistort: bool) -> bool:
    """Validate :func:`export_bop`'s arguments; returns whether the camera has lens distortion."""
    if depth_scale <= 0:
        raise ValueError("depth_scale must be > 0")
    if pixels not in PIXEL_CONVENTIONS:
        raise ValueError(f"pixels must be one of {sorted(PIXEL_CONVENTIONS)}, got {pixels!r}")
    distorted = has_distortion(ds)
    if distorted and not undistort:
        raise DatasetError(
            f"{ds.root}: the camera has lens distortion {ds.camera['dist'].tolist()} but BOP "
            "cameras are pinhole (cam_K only); export with --undistort (undistort=True) to "
            "remap images, depth and masks to the pinhole camera of the same K"
        )
    return distorted


def _write_camera(ex: _Export, depth_scale: float) -> None:
    """``camera.json``: the pinhole intrinsics (px) and the depth scale (mm per depth unit)."""
    cam = ex.ds.camera
    _json(
        ex.out / "camera.json",
        {
            "cx": float(ex.K[0, 2]),
            "cy": float(ex.K[1, 2]),
            "fx": float(ex.K[0, 0]),
            "fy": float(ex.K[1, 1]),
            "width": cam["width"],
            "height": cam["height"],
            "depth_scale": depth_scale,
        },
    )


def _write_scenes_doc(ex: _Export, scenes: dict, split: str, depth_scale: float, pixels: str, distorted: bool) -> None:
    """``dockbench_scenes.json``: which dataset sequence each BOP scene is, and how visibility was computed."""
    m, cam = ex.ds.manifest, ex.ds.camera
    doc = {
        "dataset": {"name": m.get("name"), "version": m.get("version"), "content_hash": m.get("content_hash")},
        "bop_name": BOP_DATASET_NAME,
        "split": split,
        "depth_scale": depth_scale,
        "scenes": scenes,
        "width": int(cam["width"]),
        "height": int(cam["height"]),
        "undistorted_from": cam["dist"].tolist() if distorted else None,
        "visib_fract": {
            "from_depth_test": ex.visib_sources["depth_test"],
            "from_object_index": ex.visib_sources["object_index"],
            "copied_from_dataset": ex.visib_sources["copied"],
            "delta_mm": VISIB_DELTA_MM,
            "pixel_convention": pixels,
        },
    }
    _json(ex.out / "dockbench_scenes.json", doc)
