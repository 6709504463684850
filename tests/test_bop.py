"""BOP export of the fake dataset: poses, projections, depth (range -> planar z), gt info."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from fake_dataset import HEIGHT, WIDTH, K, write_fake_dataset

import cli
from evalkit.dataset import Dataset
from evalkit.reports import bop

KM = np.array(K)


def _rot(ax, ay, az):
    return cv2.Rodrigues(np.array([ax, ay, az], float))[0]


SQUARE = np.array([[-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0], [-0.1, -0.1, 0]])
OFFSET = np.array([0.05, -0.02, 0.0])  # the marker in the dock frame
U, V = np.meshgrid(np.arange(WIDTH, dtype=float), np.arange(HEIGHT, dtype=float))
RAY_NORM = np.sqrt(((U - KM[0, 2]) / KM[0, 0]) ** 2 + ((V - KM[1, 2]) / KM[1, 1]) ** 2 + 1)
TRUNCATED = ("clear_001", 1)  # hangs over the left image edge
OCCLUDED_LEFT = ("clear_000", 2)  # left half behind an occluder at 0.3 m
HIDDEN = ("clear_000", 5)  # behind an occluder over the whole image


def _corners_uv(T_cam_marker) -> np.ndarray:
    """OpenCV's projection of the plate's 8 corners (0.2 m square, 5 mm deep) in the marker frame."""
    corners = np.vstack([SQUARE, SQUARE - [0, 0, 0.005]])
    rvec = cv2.Rodrigues(np.asarray(T_cam_marker)[:3, :3])[0]
    uv, _ = cv2.projectPoints(corners, rvec, np.asarray(T_cam_marker)[:3, 3], KM, None)
    return uv.reshape(-1, 2).astype(np.float32)


def _silhouette(T_cam_marker, x0=0, y0=0, w=WIDTH, h=HEIGHT, off=0.0) -> np.ndarray:
    """Pixels (u, v) in ``[x0, x0 + w) x [y0, y0 + h)`` whose sample point ``(u + off, v + off)`` is inside or
    on the convex hull of the projected corners (cv2.pointPolygonTest: the oracle of the rasterised
    silhouette; ``off`` 0.5 is the BOP toolkit's OpenGL convention)."""
    hull = cv2.convexHull(_corners_uv(T_cam_marker))
    uu, vv = np.meshgrid(np.arange(x0, x0 + w) + off, np.arange(y0, y0 + h) + off)
    inside = [cv2.pointPolygonTest(hull, (float(a), float(b)), False) >= 0 for a, b in zip(uu.ravel(), vv.ravel())]
    return np.array(inside).reshape(h, w)


def _pose(seq_id, i, d):
    T = np.eye(4)
    T[:3, :3] = _rot(0.2, -0.3 + 0.05 * i, 0.1)
    T[:3, 3] = [-0.35 if (seq_id, i) == TRUNCATED else 0.1 * i - 0.2, 0.05, d]
    return T


def _planar_z(T_cam_marker, seq_id, i, d) -> np.ndarray:
    """The scene's planar depth (m): a sloped wall 0.5 m or more behind the dock (at ``d``), the
    plate's front face where its silhouette is, occluders at 0.3 m."""
    z = d + 0.5 + 0.01 * U + 0.02 * V
    n, p0 = T_cam_marker[:3, 2], T_cam_marker[:3, 3]
    plate = (n @ p0) / (n[0] * (U - KM[0, 2]) / KM[0, 0] + n[1] * (V - KM[1, 2]) / KM[1, 1] + n[2])
    sil = _silhouette(T_cam_marker)
    z = np.where(sil & (plate > 0), np.minimum(z, plate), z)
    if (seq_id, i) == OCCLUDED_LEFT:
        xs = np.nonzero(sil.any(axis=0))[0]
        z[:, : (xs.min() + xs.max() + 1) // 2] = 0.3
    if (seq_id, i) == HIDDEN:
        z[:] = 0.3
    return z


def _marker_pixels(T_cam_marker) -> np.ndarray:
    """An object-index image of the marker plate: value 1 on its silhouette."""
    return _silhouette(T_cam_marker).astype(np.uint8)


def _rehash(root):
    """List every file in the manifest again (the enriched dataset is a valid, verified one)."""
    from datasets_spec.io import content_hash, dataset_files, sha256_file

    man = json.loads((root / "manifest.json").read_text())
    man["files"] = {rel: sha256_file(root / rel) for rel in dataset_files(root)}
    man["content_hash"] = content_hash(man["files"])
    (root / "manifest.json").write_text(json.dumps(man))


def _enrich(root):
    """Give the fake dataset rotated poses, an offset marker, range NPZs and object-index PNGs."""
    man = json.loads((root / "manifest.json").read_text())
    T_dock_marker = np.eye(4)
    T_dock_marker[:3, 3] = OFFSET
    man["markers"][0]["T_dock_marker"] = T_dock_marker.tolist()
    man["markers"][0]["keypoints"] = (SQUARE + OFFSET).tolist()
    (root / "manifest.json").write_text(json.dumps(man))
    for seq in man["sequences"]:
        sdir = root / seq["path"]
        (sdir / "depth").mkdir()
        (sdir / "index").mkdir()
        lines = []
        for line in (sdir / "frames.jsonl").read_text().splitlines():
            f = json.loads(line)
            i, d = f["index"], max(f["d_true"], 0.5)
            T = _pose(seq["id"], i, d)
            f["T_cam_dock"] = T.tolist()
            f["markers"]["0"]["T_cam_marker"] = (T @ T_dock_marker).tolist()
            rng = (_planar_z(T @ T_dock_marker, seq["id"], i, d) * RAY_NORM).astype(np.float32)
            rng[0, 0] = np.inf  # no surface
            f["depth"] = f"{seq['path']}/depth/{i:06d}.npz"
            np.savez_compressed(root / f["depth"], range_m=rng)
            idx = np.zeros((HEIGHT, WIDTH), np.uint8)
            if (seq["id"], i) != HIDDEN:
                idx = _marker_pixels(T @ T_dock_marker)  # value 1 = the marker ("1" -> "0")
            if (seq["id"], i) == OCCLUDED_LEFT:
                xs = np.nonzero(idx.any(axis=0))[0]
                idx[:, : (xs.min() + xs.max() + 1) // 2] = 0
            f["object_index"] = f"{seq['path']}/index/{i:06d}.png"
            cv2.imwrite(str(root / f["object_index"]), idx)
            lines.append(json.dumps(f))
        (sdir / "frames.jsonl").write_text("\n".join(lines) + "\n")
    _rehash(root)
    return root


@pytest.fixture
def exported(tmp_path):
    ds = Dataset.open(_enrich(write_fake_dataset(tmp_path / "ds")))
    summary = bop.export_bop(ds, tmp_path / "bop", depth_scale=1.0)
    return ds, tmp_path / "bop", summary


def test_layout_and_camera(exported):
    ds, out, summary = exported
    assert summary == {"scenes": 2, "images": 12, "objects": 1, "depth_clipped_px": 0, "undistorted": False}
    cam = json.loads((out / "camera.json").read_text())
    assert (cam["fx"], cam["cx"], cam["width"], cam["height"]) == (50.0, 31.5, WIDTH, HEIGHT)
    scenes = json.loads((out / "dockbench_scenes.json").read_text())
    assert scenes["scenes"]["000001"]["sequence"] == "clear_001"
    assert scenes["dataset"]["content_hash"] == ds.manifest["content_hash"]
    sdir = out / "test" / "000000"
    sc = json.loads((sdir / "scene_camera.json").read_text())
    assert sc["3"]["cam_K"] == pytest.approx(KM.ravel().tolist()) and sc["3"]["depth_scale"] == 1.0
    rgb = sdir / "rgb" / "000003.png"
    assert not rgb.is_symlink() and cv2.imread(str(rgb)) is not None  # copies by default
    ply = (out / "models" / "obj_000001.ply").read_text()
    assert ply.startswith("ply") and "element vertex 24" in ply and "element face 12" in ply
    assert "property float nx" in ply
    ev = (out / "models_eval" / "obj_000001.ply").read_text()
    n_eval = int(ev.split("element vertex ")[1].split()[0])
    assert n_eval > 2 * 41 * 41  # 200 mm faces on a <= 5 mm grid
    info = json.loads((out / "models" / "models_info.json").read_text())["1"]
    assert info["diameter"] == pytest.approx(math.sqrt(200**2 + 200**2 + 5**2))  # 5 mm plate
    assert info["size_z"] == pytest.approx(5.0)
    for ax in "xyz":  # origin at the bounding-box centre
        assert info[f"min_{ax}"] == pytest.approx(-info[f"size_{ax}"] / 2)
    assert json.loads((out / "models_eval" / "models_info.json").read_text())["1"] == info


def _ply(path):
    """Vertices, normals and faces of an ASCII PLY with normals."""
    lines = path.read_text().splitlines()
    nv = int(next(x for x in lines if x.startswith("element vertex")).split()[-1])
    start = lines.index("end_header") + 1
    vn = np.array([[float(c) for c in x.split()] for x in lines[start : start + nv]])
    faces = np.array([[int(c) for c in x.split()[1:]] for x in lines[start + nv :]])
    return vn[:, :3], vn[:, 3:], faces


def test_models_normals_point_outward_and_faces_wind_with_them(exported):
    _, out, _ = exported
    for sub in ("models", "models_eval"):
        v, n, f = _ply(out / sub / "obj_000001.ply")
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
        assert (np.einsum("ij,ij->i", n, v) > 0).all()  # outward from the centre (origin)
        tri = v[f]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert (np.einsum("ij,ij->i", fn, n[f[:, 0]]) > 0).all()  # counter-clockwise seen from outside
        area = np.linalg.norm(fn, axis=1).sum() / 2  # closed box: 2 x 200^2 + 4 x 200 x 5 mm^2
        assert area == pytest.approx(2 * 200**2 + 4 * 200 * 5, rel=1e-6)


def test_projection_matches_manifest(exported):
    ds, out, _ = exported
    objects = json.loads((out / "dockbench_objects.json").read_text())
    kp_model_mm = np.array(objects["1"]["keypoints_mm"])
    kp_dock = np.array(ds.markers[0]["keypoints"])
    for scene, seq in (("000000", "clear_000"), ("000001", "clear_001")):
        gt = json.loads((out / "test" / scene / "scene_gt.json").read_text())
        sc = json.loads((out / "test" / scene / "scene_camera.json").read_text())
        for f in ds.iter_frames(seq):
            g = gt[str(f["index"])][0]
            assert g["obj_id"] == 1
            R = np.array(g["cam_R_m2c"]).reshape(3, 3)
            t = np.array(g["cam_t_m2c"])  # mm
            Kb = np.array(sc[str(f["index"])]["cam_K"]).reshape(3, 3)
            p = (kp_model_mm @ R.T + t) @ Kb.T
            uv_bop = p[:, :2] / p[:, 2:]
            T = np.array(f["T_cam_dock"])
            q = (kp_dock @ T[:3, :3].T + T[:3, 3]) @ KM.T
            uv_manifest = q[:, :2] / q[:, 2:]
            np.testing.assert_allclose(uv_bop, uv_manifest, atol=1e-6)
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)


def test_depth_is_planar_z(exported):
    ds, out, _ = exported
    depth = cv2.imread(str(out / "test" / "000000" / "depth" / "000002.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and depth.shape == (HEIGHT, WIDTH)
    z_mm = depth.astype(float) * 1.0
    f = next(f for f in ds.iter_frames("clear_000") if f["index"] == 2)
    expected = _planar_z(np.array(f["markers"]["0"]["T_cam_marker"]), "clear_000", 2, 1.0) * 1000
    assert depth[0, 0] == 0  # inf range -> no data
    np.testing.assert_allclose(z_mm.ravel()[1:], expected.ravel()[1:], atol=0.5 + 1e-6)  # 1 mm units


def _frame(ds, seq, i):
    return next(f for f in ds.iter_frames(seq) if f["index"] == i)


def _info(out, scene, im):
    return json.loads((out / "test" / scene / "scene_gt_info.json").read_text())[str(im)][0]


def test_gt_info_by_the_depth_test(exported):
    """Unoccluded: every silhouette pixel is visible (the plate's depth is the scene's); the silhouette
    is the pixel centres inside the projected box (an independent point-in-polygon oracle); the left
    half behind an occluder 0.3 m away is invisible; a marker behind an occluder has no boxes."""
    ds, out, _ = exported
    T1 = np.array(_frame(ds, "clear_000", 1)["markers"]["0"]["T_cam_marker"])
    full, half, hidden = _info(out, "000000", 1), _info(out, "000000", 2), _info(out, "000000", 5)
    own = _silhouette(T1)
    assert full["px_count_all"] == int(own.sum()) == full["px_count_visib"] and full["visib_fract"] == 1.0
    ys, xs = np.nonzero(own)
    assert full["bbox_obj"] == full["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
    T2 = np.array(_frame(ds, "clear_000", 2)["markers"]["0"]["T_cam_marker"])
    sil = _silhouette(T2)
    xs = np.nonzero(sil.any(axis=0))[0]
    right = sil.copy()
    right[:, : (xs.min() + xs.max() + 1) // 2] = False
    assert half["px_count_visib"] == int(right.sum()) and half["px_count_all"] == int(sil.sum())
    mask = cv2.imread(str(out / "test" / "000000" / "mask_visib" / "000002_000000.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(mask > 0, right)
    assert hidden["visib_fract"] == 0.0 and hidden["px_count_all"] > 0
    assert hidden["bbox_obj"] == hidden["bbox_visib"] == [-1, -1, -1, -1]
    targets = json.loads((out / "test_targets_bop19.json").read_text())
    keys = {(t["scene_id"], t["im_id"]) for t in targets}
    assert (0, 1) in keys and (0, 2) in keys and (0, 5) not in keys  # visib_fract >= 0.1 only
    assert all(t["obj_id"] == 1 and t["inst_count"] == 1 for t in targets)
    scenes = json.loads((out / "dockbench_scenes.json").read_text())
    assert scenes["visib_fract"]["from_depth_test"] == 12 and scenes["visib_fract"]["delta_mm"] == 15.0


def test_truncated_silhouette_counts_outside_the_image(exported):
    """calc_gt_info renders on a canvas 3x the image: the part of the plate left of the image counts in
    px_count_all and bbox_obj (x < 0) but not in mask or px_count_visib."""
    ds, out, _ = exported
    T = np.array(_frame(ds, *TRUNCATED)["markers"]["0"]["T_cam_marker"])
    whole = _silhouette(T, -WIDTH, -HEIGHT, 3 * WIDTH, 3 * HEIGHT)
    inside = whole[HEIGHT : 2 * HEIGHT, WIDTH : 2 * WIDTH]
    assert 0 < inside.sum() < whole.sum()
    info = _info(out, "000001", TRUNCATED[1])
    assert info["px_count_all"] == int(whole.sum()) and info["px_count_visib"] == int(inside.sum())
    ys, xs = np.nonzero(whole)
    assert info["bbox_obj"] == [xs.min() - WIDTH, ys.min() - HEIGHT, xs.max() - xs.min(), ys.max() - ys.min()]
    assert info["bbox_obj"][0] < 0
    mask = cv2.imread(str(out / "test" / "000001" / "mask" / f"{TRUNCATED[1]:06d}_000000.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(mask > 0, inside)


def test_toolkit_pixel_convention(tmp_path):
    """--pixels toolkit: silhouettes sample (u + 0.5, v + 0.5) as the toolkit's OpenGL renderers do."""
    ds = Dataset.open(_enrich(write_fake_dataset(tmp_path / "ds")))
    bop.export_bop(ds, tmp_path / "b", pixels="toolkit")
    T = np.array(_frame(ds, *TRUNCATED)["markers"]["0"]["T_cam_marker"])
    info = _info(tmp_path / "b", "000001", TRUNCATED[1])
    shifted = _silhouette(T, -WIDTH, -HEIGHT, 3 * WIDTH, 3 * HEIGHT, off=0.5)
    assert (
        info["px_count_all"] == int(shifted.sum()) != int(_silhouette(T, -WIDTH, -HEIGHT, 3 * WIDTH, 3 * HEIGHT).sum())
    )
    with pytest.raises(ValueError, match="pixels"):
        bop.export_bop(ds, tmp_path / "c", pixels="gl")


def _decode_rle(rle):
    h, w = rle["size"]
    flat, value, pos = np.zeros(h * w, bool), False, 0
    for run in rle["counts"]:
        flat[pos : pos + run] = value
        pos, value = pos + run, not value
    return flat.reshape(w, h).T


def test_scene_gt_coco(exported):
    _, out, _ = exported
    coco = json.loads((out / "test" / "000000" / "scene_gt_coco.json").read_text())
    targets = {t["im_id"] for t in json.loads((out / "test_targets_bop19.json").read_text()) if t["scene_id"] == 0}
    assert {im["id"] for im in coco["images"]} == targets and coco["categories"][0]["id"] == 1
    ann = next(a for a in coco["annotations"] if a["image_id"] == 2)
    visib = cv2.imread(str(out / "test" / "000000" / "mask_visib" / "000002_000000.png"), cv2.IMREAD_UNCHANGED) > 0
    assert np.array_equal(_decode_rle(ann["segmentation"]), visib) and ann["area"] == int(visib.sum())
    full = cv2.imread(str(out / "test" / "000000" / "mask" / "000002_000000.png"), cv2.IMREAD_UNCHANGED) > 0
    ys, xs = np.nonzero(full)
    assert ann["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
    assert ann["ignore"] is False and ann["category_id"] == 1


def test_symlinks_are_relative(tmp_path):
    import shutil

    root = write_fake_dataset(tmp_path / "ds")
    bop.export_bop(root, tmp_path / "bop", copy_images=False)
    link = tmp_path / "bop" / "test" / "000000" / "rgb" / "000000.png"
    assert link.is_symlink() and not Path(link.readlink()).is_absolute()
    shutil.move(tmp_path, tmp_path.parent / (tmp_path.name + "_moved"))
    moved = tmp_path.parent / (tmp_path.name + "_moved") / "bop" / "test" / "000000" / "rgb" / "000000.png"
    assert cv2.imread(str(moved)) is not None


def test_range_to_depth_clipping():
    norms = np.ones((1, 3))
    img, n = bop.range_to_depth_png(np.array([[1.0, 70.0, np.nan]]), norms, 1.0)
    assert img.tolist() == [[1000, 0, 0]] and n == 1


def test_cli(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    res = CliRunner().invoke(cli.main, ["export-bop", str(root), "-o", str(tmp_path / "b"), "--symlink"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "b" / "test" / "000000" / "rgb" / "000000.png").is_symlink()
    res = CliRunner().invoke(cli.main, ["export-bop", str(tmp_path / "nope"), "-o", str(tmp_path / "c")])
    assert res.exit_code == 2 and "error:" in res.output


def _distorted(root, dist):
    """The enriched dataset as a camera with ``dist`` would have recorded it: index and range
    passes distorted with the generator's own lens model, the camera's distortion in the manifest."""
    from blendgen.physics.camera.sensor import distort_image

    man = json.loads((root / "manifest.json").read_text())
    man["camera"]["distortion"] = list(dist)
    (root / "manifest.json").write_text(json.dumps(man))
    for seq in man["sequences"]:
        for line in (root / seq["path"] / "frames.jsonl").read_text().splitlines():
            f = json.loads(line)
            p = root / f["object_index"]
            cv2.imwrite(
                str(p),
                distort_image(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), KM, dist, interpolation=cv2.INTER_NEAREST),
            )
            d = root / f["depth"]
            np.savez_compressed(
                d, range_m=distort_image(np.load(d)["range_m"], KM, dist, interpolation=cv2.INTER_NEAREST)
            )
    _rehash(root)
    return root


def test_distorted_dataset_is_refused_or_undistorted(tmp_path):
    """A camera with distortion: export-bop refuses (exit 2, names --undistort); with
    --undistort the exported masks line up with the pinhole cam_K projection again: the
    unoccluded frames' visib_fract (silhouette from cam_K vs undistorted index) is as high
    as the pinhole dataset's, and the depth matches the pinhole export within 1 mm."""
    dist = [-0.3, 0.08, 0.0, 0.0, 0.0]
    ref_root = _enrich(write_fake_dataset(tmp_path / "pin"))
    ref = bop.export_bop(Dataset.open(ref_root), tmp_path / "bop_pin", depth_scale=0.1)
    root = _distorted(_enrich(write_fake_dataset(tmp_path / "ds")), dist)
    res = CliRunner().invoke(cli.main, ["export-bop", str(root), "-o", str(tmp_path / "b")])
    assert res.exit_code == 2 and "--undistort" in res.output and "distortion" in res.output
    res = CliRunner().invoke(
        cli.main, ["export-bop", str(root), "-o", str(tmp_path / "b"), "--undistort", "--depth-scale", "0.1"]
    )
    assert res.exit_code == 0, res.output
    assert ref["undistorted"] is False
    info = {
        k: json.loads((tmp_path / d / "test" / "000000" / "scene_gt_info.json").read_text())
        for k, d in (("pin", "bop_pin"), ("und", "b"))
    }
    for im in ("0", "1", "3", "4"):
        assert info["und"][im][0]["visib_fract"] > 0.97 * info["pin"][im][0]["visib_fract"] > 0.5
    for im in ("0", "3"):
        a, b = (
            cv2.imread(
                str(tmp_path / d / "test" / "000000" / "depth" / f"{int(im):06d}.png"), cv2.IMREAD_UNCHANGED
            ).astype(float)
            for d in ("bop_pin", "b")
        )
        both = (a > 0) & (b > 0)
        both[:6], both[-6:], both[:, :6], both[:, -6:] = False, False, False, False
        assert both.sum() > 1000 and np.median(np.abs(a - b)[both]) <= 10  # 0.1 mm units
    scenes = json.loads((tmp_path / "b" / "dockbench_scenes.json").read_text())
    assert scenes["undistorted_from"] == dist


def test_undistort_names_an_unreadable_image(tmp_path):
    """--undistort reads each image to remap it: one that is not an image is a DatasetError
    naming it (not OpenCV's error about an empty source)."""
    root = _distorted(_enrich(write_fake_dataset(tmp_path / "ds")), [-0.3, 0.08, 0.0, 0.0, 0.0])
    ds = Dataset.open(root)
    seq = ds.sequences[0]["id"]
    bad = ds.image_path(next(iter(ds.iter_frames(seq))))
    bad.write_bytes(b"not a png")
    with pytest.raises(bop.DatasetError, match="unreadable image") as exc:
        bop.export_bop(ds, tmp_path / "b", depth_scale=0.1, undistort=True)
    assert str(bad) in str(exc.value)
