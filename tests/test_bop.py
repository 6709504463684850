"""BOP export of the fake dataset: poses, projections, depth (range -> planar z), gt info."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

import cli

from evalkit.reports import bop
from evalkit.dataset import Dataset

from fake_dataset import K, WIDTH, HEIGHT, write_fake_dataset

KM = np.array(K)


def _rot(ax, ay, az):
    return cv2.Rodrigues(np.array([ax, ay, az], float))[0]


SQUARE = np.array([[-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0], [-0.1, -0.1, 0]])


def _marker_pixels(T_cam_marker) -> np.ndarray:
    """An object-index image of the marker plate (0.2 m square, 5 mm deep) drawn with OpenCV's own
    projection: value 1 inside the convex hull of the 8 projected corners."""
    corners = np.vstack([SQUARE, SQUARE - [0, 0, 0.005]])
    rvec = cv2.Rodrigues(np.asarray(T_cam_marker)[:3, :3])[0]
    uv, _ = cv2.projectPoints(corners, rvec, np.asarray(T_cam_marker)[:3, 3], KM, None)
    idx = np.zeros((HEIGHT, WIDTH), np.uint8)
    cv2.fillConvexPoly(idx, cv2.convexHull(np.round(uv.reshape(-1, 2)).astype(np.int32)), 1)
    return idx


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
    T_dock_marker[:3, 3] = [0.05, -0.02, 0.0]
    man["markers"][0]["T_dock_marker"] = T_dock_marker.tolist()
    man["markers"][0]["keypoints"] = (SQUARE + T_dock_marker[:3, 3]).tolist()
    (root / "manifest.json").write_text(json.dumps(man))
    u, v = np.meshgrid(np.arange(WIDTH, dtype=float), np.arange(HEIGHT, dtype=float))
    norm = np.sqrt(((u - KM[0, 2]) / KM[0, 0]) ** 2 + ((v - KM[1, 2]) / KM[1, 1]) ** 2 + 1)
    for seq in man["sequences"]:
        sdir = root / seq["path"]
        (sdir / "depth").mkdir()
        (sdir / "index").mkdir()
        lines = []
        for line in (sdir / "frames.jsonl").read_text().splitlines():
            f = json.loads(line)
            i, d = f["index"], max(f["d_true"], 0.5)
            T = np.eye(4)
            T[:3, :3] = _rot(0.2, -0.3 + 0.05 * i, 0.1)
            T[:3, 3] = [0.1 * i - 0.2, 0.05, d]
            f["T_cam_dock"] = T.tolist()
            f["markers"]["0"]["T_cam_marker"] = (T @ T_dock_marker).tolist()
            z = 2.0 + 0.01 * u + 0.02 * v + 0.1 * i                      # planar depth (m)
            rng = (z * norm).astype(np.float32)
            rng[0, 0] = np.inf                                           # no surface
            f["depth"] = f"{seq['path']}/depth/{i:06d}.npz"
            np.savez_compressed(root / f["depth"], range_m=rng)
            idx = np.zeros((HEIGHT, WIDTH), np.uint8)
            if (seq["id"], i) != ("clear_000", 5):                       # frame 5: marker not in view
                idx = _marker_pixels(T @ T_dock_marker)                    # value 1 = the marker ("1" -> "0")
            if (seq["id"], i) == ("clear_000", 2):                       # left half occluded
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
    summary = bop.export_bop(ds, tmp_path / "bop", depth_scale=0.1)
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
    assert sc["3"]["cam_K"] == pytest.approx(KM.ravel().tolist()) and sc["3"]["depth_scale"] == 0.1
    rgb = sdir / "rgb" / "000003.png"
    assert rgb.is_symlink() and cv2.imread(str(rgb)) is not None
    ply = (out / "models" / "obj_000001.ply").read_text()
    assert ply.startswith("ply") and "element vertex 8" in ply and "element face 12" in ply
    assert (out / "models_eval" / "obj_000001.ply").read_text() == ply
    info = json.loads((out / "models" / "models_info.json").read_text())["1"]
    assert info["diameter"] == pytest.approx(math.sqrt(200 ** 2 + 200 ** 2 + 5 ** 2))   # 5 mm plate
    assert info["size_z"] == pytest.approx(5.0)


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
            t = np.array(g["cam_t_m2c"])                                  # mm
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
    u, v = np.meshgrid(np.arange(WIDTH, dtype=float), np.arange(HEIGHT, dtype=float))
    depth = cv2.imread(str(out / "test" / "000000" / "depth" / "000002.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and depth.shape == (HEIGHT, WIDTH)
    z_mm = depth.astype(float) * 0.1
    expected = (2.0 + 0.01 * u + 0.02 * v + 0.2) * 1000
    assert depth[0, 0] == 0                                              # inf range -> no data
    np.testing.assert_allclose(z_mm.ravel()[1:], expected.ravel()[1:], atol=0.2)


def test_gt_info_visib_fract_from_the_index_pass(exported):
    ds, out, _ = exported
    info = json.loads((out / "test" / "000000" / "scene_gt_info.json").read_text())
    full, half, hidden = info["1"][0], info["2"][0], info["5"][0]
    assert full["visib_fract"] > 0.9                                   # unoccluded (edge pixels aside)
    own = int(_marker_pixels(np.array(next(f for f in ds.iter_frames("clear_000") if f["index"] == 1)
                                      ["markers"]["0"]["T_cam_marker"])).sum())
    assert full["px_count_all"] == pytest.approx(own, rel=0.2)         # the silhouette's area
    assert 0.3 < half["visib_fract"] < 0.7                             # left half occluded
    assert hidden["visib_fract"] == 0.0 and hidden["px_count_all"] > 0
    mask = cv2.imread(str(out / "test" / "000000" / "mask_visib" / "000002_000000.png"), cv2.IMREAD_UNCHANGED)
    assert int((mask > 0).sum()) == half["px_count_visib"]
    assert all(v >= 0 for v in full["bbox_obj"][2:]) and full["bbox_visib"][2] > 0
    targets = json.loads((out / "test_targets_bop19.json").read_text())
    keys = {(t["scene_id"], t["im_id"]) for t in targets}
    assert (0, 1) in keys and (0, 2) in keys and (0, 5) not in keys    # visib_fract >= 0.1 only
    assert all(t["obj_id"] == 1 and t["inst_count"] == 1 for t in targets)
    scenes = json.loads((out / "dockbench_scenes.json").read_text())
    assert scenes["visib_fract"] == {"from_object_index": 12, "copied_from_dataset": 0}


def test_range_to_depth_clipping():
    norms = np.ones((1, 3))
    img, n = bop.range_to_depth_png(np.array([[1.0, 70.0, np.nan]]), norms, 1.0)
    assert img.tolist() == [[1000, 0, 0]] and n == 1


def test_cli(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    res = CliRunner().invoke(cli.main, ["export-bop", str(root), "-o", str(tmp_path / "b"), "--copy"])
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "b" / "test" / "000000" / "rgb" / "000000.png").is_symlink()
    res = CliRunner().invoke(cli.main, ["export-bop", str(tmp_path / "nope"), "-o", str(tmp_path / "c")])
    assert res.exit_code == 2 and "error:" in res.output


def _distorted(root, dist):
    """The enriched dataset as a camera with ``dist`` would have recorded it: index and range
    passes distorted with the generator's own lens model, the camera's distortion in the manifest."""
    from blendgen.physics.sensor import distort_image
    man = json.loads((root / "manifest.json").read_text())
    man["camera"]["distortion"] = list(dist)
    (root / "manifest.json").write_text(json.dumps(man))
    for seq in man["sequences"]:
        for line in (root / seq["path"] / "frames.jsonl").read_text().splitlines():
            f = json.loads(line)
            p = root / f["object_index"]
            cv2.imwrite(str(p), distort_image(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), KM, dist,
                                              interpolation=cv2.INTER_NEAREST))
            d = root / f["depth"]
            np.savez_compressed(d, range_m=distort_image(np.load(d)["range_m"], KM, dist,
                                                          interpolation=cv2.INTER_NEAREST))
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
    res = CliRunner().invoke(cli.main, ["export-bop", str(root), "-o", str(tmp_path / "b"), "--undistort",
                                        "--depth-scale", "0.1"])
    assert res.exit_code == 0, res.output
    assert ref["undistorted"] is False
    info = {k: json.loads((tmp_path / d / "test" / "000000" / "scene_gt_info.json").read_text())
            for k, d in (("pin", "bop_pin"), ("und", "b"))}
    for im in ("0", "1", "3", "4"):
        assert info["und"][im][0]["visib_fract"] > 0.97 * info["pin"][im][0]["visib_fract"] > 0.5
    for im in ("0", "3"):
        a, b = (cv2.imread(str(tmp_path / d / "test" / "000000" / "depth" / f"{int(im):06d}.png"),
                           cv2.IMREAD_UNCHANGED).astype(float) for d in ("bop_pin", "b"))
        both = (a > 0) & (b > 0)
        both[:6], both[-6:], both[:, :6], both[:, -6:] = False, False, False, False
        assert both.sum() > 1000 and np.median(np.abs(a - b)[both]) <= 10          # 0.1 mm units
    scenes = json.loads((tmp_path / "b" / "dockbench_scenes.json").read_text())
    assert scenes["undistorted_from"] == dist
