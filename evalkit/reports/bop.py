"""Export a dockbench dataset in the BOP format (https://bop.felk.cvut.cz, toolkit conventions).

``dockbench export-bop DATASET -o DIR`` writes::

    DIR/camera.json                     fx, fy, cx, cy, width, height, depth_scale
    DIR/models/obj_XXXXXX.ply           one flat rectangle per marker (mm, marker frame)
    DIR/models/models_info.json         diameter, min_*, size_* (mm)
    DIR/dockbench_objects.json          obj_id -> marker id, kind, keypoints (mm, marker frame)
    DIR/dockbench_scenes.json           scene id -> sequence id, condition, trial; dataset identity
    DIR/<split>/<scene:06d>/            one scene per sequence (manifest order)
        scene_camera.json   per image: cam_K (row-major 9), depth_scale, cam_R_w2c, cam_t_w2c (mm)
        scene_gt.json       per image: [{obj_id, cam_R_m2c (row-major 9), cam_t_m2c (mm)}] per marker
        scene_gt_info.json  per image: [{visib_fract, bbox_obj, bbox_visib, px_count_visib}]
        rgb/<im:06d>.png    symlink to the dataset image (or a copy)
        depth/<im:06d>.png  uint16 planar depth z, ``z_mm = value * depth_scale`` (0 = no data)
        mask_visib/<im:06d>_<gt:06d>.png  visible pixels of each marker (from the object index)

Objects are the dataset's markers (``obj_id`` = 1-based position in the manifest),
posed by the frame's ``T_cam_marker``. ``visib_fract`` is the dataset's
``visible_fraction``. Depth: the dataset stores the *range* along each pixel ray
(m); BOP wants planar ``z``: ``z = range / |K^-1 [u, v, 1]|`` (rays undistorted
with OpenCV when the camera has distortion). With ``depth_scale`` 1.0 (default)
a PNG unit is 1 mm, so depths beyond 65.535 m become 0 (no data); 0.1 gives
0.1 mm units but only 6.5 m. Image ids are the frame indices.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import click
import numpy as np

from datasets_spec.io import load_index, load_range
from evalkit.dataset import Dataset, DatasetError


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


def _marker_points(marker: dict) -> np.ndarray:
    """Keypoints of a marker in its own frame (m), ``(N, 3)``."""
    kp = np.asarray(marker.get("keypoints") or [], dtype=float).reshape(-1, 3)
    T_marker_dock = _inv(np.asarray(marker.get("T_dock_marker", np.eye(4)), dtype=float))
    return kp @ T_marker_dock[:3, :3].T + T_marker_dock[:3, 3]


def _model_rectangle(marker: dict) -> np.ndarray:
    """Corners (m, marker frame) of the flat model: the keypoints' bounding rectangle in z = 0,
    grown by the LED radius for LED arrays; ``(4, 3)`` TL, TR, BR, BL."""
    pts = _marker_points(marker)
    if len(pts) == 0:
        s = float(marker.get("size_m", 0.1)) / 2
        pts = np.array([[-s, -s, 0], [s, s, 0]])
    pad = float(marker.get("led_radius_m", 0.0))
    x0, y0 = pts[:, 0].min() - pad, pts[:, 1].min() - pad
    x1, y1 = pts[:, 0].max() + pad, pts[:, 1].max() + pad
    return np.array([[x0, y1, 0], [x1, y1, 0], [x1, y0, 0], [x0, y0, 0]])


def _write_ply(path: Path, corners_mm: np.ndarray) -> None:
    """ASCII PLY of a two-sided rectangle (4 vertices, 4 triangles), mm."""
    lines = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y",
             "property float z", "element face 4", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(f"{c:.6f}" for c in p) for p in corners_mm]
    lines += ["3 0 3 2", "3 0 2 1", "3 0 1 2", "3 0 2 3"]
    path.write_text("\n".join(lines) + "\n")


def _model_info(corners_mm: np.ndarray) -> dict:
    lo, hi = corners_mm.min(axis=0), corners_mm.max(axis=0)
    diam = max(float(np.linalg.norm(a - b)) for a in corners_mm for b in corners_mm)
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


def export_bop(dataset: Dataset | str | Path, out_dir: str | Path, split: str = "test",
               copy_images: bool = False, depth_scale: float = 1.0, masks: bool = True,
               sequences: list[str] | None = None) -> dict:
    """Write ``dataset`` as a BOP dataset into ``out_dir`` (see the module docstring).

    Returns a summary ``{scenes, images, objects, depth_clipped_px}``."""
    import cv2

    ds = dataset if isinstance(dataset, Dataset) else Dataset.open(dataset)
    out = Path(out_dir)
    if depth_scale <= 0:
        raise ValueError("depth_scale must be > 0")
    cam = ds.camera
    K, dist, W, H = cam["K"], cam["dist"], cam["width"], cam["height"]
    out.mkdir(parents=True, exist_ok=True)
    _json(out / "camera.json", {"cx": float(K[0, 2]), "cy": float(K[1, 2]), "fx": float(K[0, 0]),
                                "fy": float(K[1, 1]), "width": W, "height": H,
                                "depth_scale": depth_scale})
    markers = ds.markers
    obj_ids = {str(m["id"]): i + 1 for i, m in enumerate(markers)}
    models = out / "models"
    models.mkdir(exist_ok=True)
    infos, objects, model_corners = {}, {}, {}
    for m in markers:
        oid = obj_ids[str(m["id"])]
        corners_mm = _model_rectangle(m) * 1000.0
        model_corners[oid] = corners_mm / 1000.0
        _write_ply(models / f"obj_{oid:06d}.ply", corners_mm)
        infos[str(oid)] = _model_info(corners_mm)
        objects[str(oid)] = {"marker_id": str(m["id"]), "kind": m.get("kind"),
                             "keypoints_mm": (_marker_points(m) * 1000.0).tolist()}
    _json(models / "models_info.json", infos)
    _json(out / "dockbench_objects.json", objects)
    index_values = _index_values(ds)
    norms = None
    scenes, n_images, clipped = {}, 0, 0
    for scene_id, seq in enumerate(ds.sequences):
        if sequences is not None and seq["id"] not in sequences:
            continue
        sdir = out / split / f"{scene_id:06d}"
        for sub in ("rgb", "depth", "mask_visib"):
            (sdir / sub).mkdir(parents=True, exist_ok=True)
        scenes[f"{scene_id:06d}"] = {"sequence": seq["id"], "condition": seq.get("condition"),
                                     "trial": seq.get("trial")}
        scene_camera, scene_gt, scene_gt_info = {}, {}, {}
        for frame in ds.iter_frames(seq["id"]):
            im = int(frame["index"])
            key = str(im)
            _link_or_copy(ds.image_path(frame), sdir / "rgb" / f"{im:06d}.png", copy_images)
            cam_entry = {"cam_K": [float(v) for v in K.ravel()], "depth_scale": depth_scale}
            if frame.get("T_world_cam") is not None:
                T_cam_world = _inv(np.asarray(frame["T_world_cam"], dtype=float))
                cam_entry["cam_R_w2c"] = [float(v) for v in T_cam_world[:3, :3].ravel()]
                cam_entry["cam_t_w2c"] = [float(v) * 1000.0 for v in T_cam_world[:3, 3]]
            scene_camera[key] = cam_entry
            if frame.get("depth"):
                rng = load_range(ds.root / frame["depth"])
                if norms is None:
                    norms = ray_norms(K, W, H, dist)
                img, n = range_to_depth_png(rng, norms, depth_scale)
                clipped += n
                cv2.imwrite(str(sdir / "depth" / f"{im:06d}.png"), img)
            index = None
            if frame.get("object_index"):
                index = load_index(ds.root / frame["object_index"])
            T_cam_dock = np.asarray(frame.get("T_cam_dock", np.eye(4)), dtype=float)
            fmarkers = frame.get("markers") or {}
            gts, gt_infos = [], []
            for m in markers:
                mid = str(m["id"])
                oid = obj_ids[mid]
                fm = fmarkers.get(mid) or {}
                if fm.get("T_cam_marker") is not None:
                    T = np.asarray(fm["T_cam_marker"], dtype=float)
                else:
                    T = T_cam_dock @ np.asarray(m.get("T_dock_marker", np.eye(4)), dtype=float)
                gt_id = len(gts)
                gts.append({"obj_id": oid, "cam_R_m2c": [float(v) for v in T[:3, :3].ravel()],
                            "cam_t_m2c": [float(v) * 1000.0 for v in T[:3, 3]]})
                info = {"visib_fract": float(fm.get("visible_fraction") or 0.0),
                        "bbox_obj": [-1, -1, -1, -1], "bbox_visib": [-1, -1, -1, -1]}
                corners_cam = model_corners[oid] @ T[:3, :3].T + T[:3, 3]
                uv = _project(corners_cam, K, dist)
                if uv is not None:
                    info["bbox_obj"] = _bbox(np.floor(uv[:, 0].min()), np.floor(uv[:, 1].min()),
                                             np.floor(uv[:, 0].max()), np.floor(uv[:, 1].max()))
                if index is not None and mid in index_values:
                    mask = index == index_values[mid]
                    info["px_count_visib"] = int(mask.sum())
                    if mask.any():
                        ys, xs = np.nonzero(mask)
                        info["bbox_visib"] = _bbox(xs.min(), ys.min(), xs.max(), ys.max())
                    if masks:
                        cv2.imwrite(str(sdir / "mask_visib" / f"{im:06d}_{gt_id:06d}.png"),
                                    mask.astype(np.uint8) * 255)
                gt_infos.append(info)
            scene_gt[key], scene_gt_info[key] = gts, gt_infos
            n_images += 1
        _json(sdir / "scene_camera.json", scene_camera)
        _json(sdir / "scene_gt.json", scene_gt)
        _json(sdir / "scene_gt_info.json", scene_gt_info)
    m = ds.manifest
    _json(out / "dockbench_scenes.json", {
        "dataset": {"name": m.get("name"), "version": m.get("version"),
                    "content_hash": m.get("content_hash")},
        "split": split, "depth_scale": depth_scale, "scenes": scenes})
    return {"scenes": len(scenes), "images": n_images, "objects": len(markers),
            "depth_clipped_px": clipped}


@click.command("export-bop")
@click.argument("dataset", type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="BOP dataset directory to write")
@click.option("--split", default="test", show_default=True, help="BOP split folder name")
@click.option("--copy", "copy_images", is_flag=True, help="copy RGB images instead of symlinking them")
@click.option("--depth-scale", type=click.FloatRange(min=0.0, min_open=True), default=1.0,
              show_default=True, help="mm per depth PNG unit (1.0: up to 65.5 m; 0.1: up to 6.5 m)")
@click.option("--no-masks", is_flag=True, help="do not write mask_visib PNGs")
def export_bop_cmd(dataset: Path, out: Path, split: str, copy_images: bool, depth_scale: float,
                   no_masks: bool):
    """Export DATASET in the BOP format (scene_camera/scene_gt/scene_gt_info, rgb, depth) to OUT."""
    try:
        s = export_bop(dataset, out, split=split, copy_images=copy_images, depth_scale=depth_scale,
                       masks=not no_masks)
    except DatasetError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"BOP export: {s['scenes']} scenes, {s['images']} images, {s['objects']} objects -> {out}")
    if s["depth_clipped_px"]:
        click.echo(f"note: {s['depth_clipped_px']} depth pixels beyond {65535 * depth_scale / 1000:.1f} m "
                   f"written as 0 (use a larger --depth-scale)", err=True)
