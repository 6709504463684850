"""Rendered truth: what Blender draws is where K and T_cam_dock say it is.

Renders a tiny dataset through the real CLI once per session (640x480, 4 spp, a
short close approach plus an oblique pass) and checks geometry against the
manifest's ground truth, the dataset format, resume and verify.
"""

import importlib.metadata
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import cli
from blendgen.geometry import project, transform_points
from datasets_spec.io import load_index, load_range
from evalkit.dataset import Dataset
from evalkit.localizers.square import linear_gray

pytestmark = pytest.mark.blender
ROOT = Path(__file__).resolve().parent.parent

TINY = {
    "name": "tiny",
    "version": "1.0.0",
    "seed": 3,
    "scene": {"template": "pool_15x5x8"},
    "camera": {"width": 640, "height": 480, "hfov_deg": 60, "fps": 10},
    "render": {"fidelity": "fast", "samples": 4},
    "water": {"preset": "clear"},
    "trajectories": [
        {
            "kind": "linear",
            "id": "near",
            "start_range_m": 2.2,
            "end_range_m": 0.75,
            "speed_mps": 2.0,
            "lateral_m": 0.1,
            "vertical_m": 0.05,
        },
        {"kind": "circle", "id": "arc", "radius_m": 1.5, "start_deg": -35, "end_deg": 35, "speed_mps": 2.5},
    ],
}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("render")
    cfg = d / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    out = d / "ds"
    res = CliRunner().invoke(cli.main, ["generate", str(cfg), "-o", str(out)])
    assert res.exit_code == 0, res.output + repr(res.exception)
    return cfg, out


def frames(ds):
    for seq in ds.sequences:
        yield from ds.iter_frames(seq["id"])


def test_manifest_and_frames_follow_format(tiny):
    _, out = tiny
    man = json.loads((out / "manifest.json").read_text())
    assert man["format"] == "dockbench-dataset" and man["spec_version"] == "1.2"
    assert man["generator"]["bpy"] == importlib.metadata.version("bpy")
    K = np.array(man["camera"]["K"])
    assert K.shape == (3, 3) and K[0, 2] == 319.5 and K[1, 2] == 239.5
    kinds = {m["kind"]: m for m in man["markers"]}
    assert kinds["aruco"]["dictionary"] == "DICT_4X4_50" and kinds["qr"]["payload"]
    assert np.array(kinds["led_array"]["keypoints"]).shape == (4, 3)
    ds = Dataset.open(out)
    n = 0
    for f in frames(ds):
        T = np.array(f["T_cam_dock"])
        c_dock = np.linalg.inv(T) @ [0, 0, 0, 1]
        assert f["d_true"] == pytest.approx(abs(c_dock[2]), abs=1e-9)
        assert (out / f["image"]).exists() and (out / f["depth"]).exists()
        assert set(f["markers"]) == {"led", "qr", "aruco"}
        n += 1
    assert n == sum(s["n_frames"] for s in man["sequences"]) > 10


def test_aruco_corners_match_projection(tiny):
    """Detected ArUco corners (linear-intensity sub-pixel) vs K @ T_cam_dock @ keypoints."""
    _, out = tiny
    ds = Dataset.open(out)
    m = next(m for m in ds.markers if m["kind"] == "aruco")
    det = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 0.001)
    errs = []
    for f in frames(ds):
        uv = project(ds.camera["K"], transform_points(np.array(f["T_cam_dock"]), m["keypoints"]))
        if np.ptp(uv[:, 0]) < 40 or not f["markers"]["aruco"]["visible_fraction"] > 0.99:
            continue
        gray = cv2.cvtColor(ds.load_image(f), cv2.COLOR_RGB2GRAY)
        corners, ids, _ = det.detectMarkers(gray)
        assert ids is not None and m["marker_id"] in ids.ravel(), f["image"]
        c = corners[list(ids.ravel()).index(m["marker_id"])].reshape(-1, 1, 2)
        c = cv2.cornerSubPix(linear_gray(gray), c, (4, 4), (-1, -1), crit).reshape(4, 2)
        errs += list(np.linalg.norm(c - uv, axis=1))
    assert len(errs) >= 20
    assert np.median(errs) <= 0.3 and np.max(errs) <= 1.0, (np.median(errs), np.max(errs))


def test_led_centroids_match_projection(tiny):
    """Intensity-weighted centroids of the LED blobs vs projected LED centres."""
    _, out = tiny
    ds = Dataset.open(out)
    m = next(m for m in ds.markers if m["kind"] == "led_array")
    errs = []
    for f in frames(ds):
        if f["markers"]["led"]["visible_fraction"] < 1:
            continue
        uv = project(ds.camera["K"], transform_points(np.array(f["T_cam_dock"]), m["keypoints"]))
        index = cv2.imread(str(out / f["object_index"]), cv2.IMREAD_UNCHANGED)
        mask = (index == m["object_index"]).astype(np.uint8)
        n, lab = cv2.connectedComponents(mask)
        for p in uv:
            k = lab[int(round(p[1])), int(round(p[0]))]
            ys, xs = np.nonzero(lab == k)
            if xs.size < 30 or xs.min() == 0 or ys.min() == 0 or xs.max() == 639 or ys.max() == 479:
                continue  # tiny or cut by the image border
            errs.append(math.hypot(xs.mean() - p[0], ys.mean() - p[1]))
    assert len(errs) >= 12
    # flat emitting discs: the area centroid is the projected centre to second order
    assert np.median(errs) <= 0.2 and np.max(errs) <= 0.6, (np.median(errs), np.max(errs))


def test_background_range_and_index(tiny):
    _, out = tiny
    ds = Dataset.open(out)
    f = next(frames(ds))
    r = load_range(out / f["depth"])
    index = load_index(out / f["object_index"])
    T = np.array(f["T_cam_dock"])
    centre = T[:3, 3]  # dock face centre in the camera frame
    uv = project(ds.camera["K"], centre[None])[0]
    v, u = int(round(uv[1])), int(round(uv[0]))
    assert r[v, u] == pytest.approx(np.linalg.norm(centre), rel=5e-3)
    assert ds.manifest["object_index"][str(index[v, u])] in ("dock", "led", "qr", "aruco")


def test_verify_and_resume(tiny, tmp_path):
    cfg, out = tiny
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    r = CliRunner().invoke(cli.main, ["verify", str(copy)])
    assert r.exit_code == 0, r.output
    img = next(copy.glob("sequences/*/rgb/000000.png"))
    data = bytearray(img.read_bytes())
    data[-20] ^= 0xFF
    img.write_bytes(bytes(data))
    r = CliRunner().invoke(cli.main, ["verify", str(copy)])
    assert r.exit_code == 2 and img.name in r.output
    # resume: a finished dataset re-renders nothing and ends byte-identical in ground truth
    before = {p: p.read_bytes() for p in out.glob("sequences/*/frames.jsonl")}
    r = CliRunner().invoke(cli.main, ["generate", str(cfg), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert {p: p.read_bytes() for p in out.glob("sequences/*/frames.jsonl")} == before


@pytest.mark.parametrize("regions", ["dock", "codes"])
def test_roi_composite_is_pixel_aligned(tmp_path, regions):
    """ROI rendering with a full-scale background at the same samples must reproduce the
    plain full-frame render: any border misalignment (of the dock box, or of any of the
    per-marker boxes) shows up as a shifted dock or marker."""
    from blendgen.config.models import load_experiment
    from blendgen.pipeline.generate import generate

    cfg = dict(
        TINY,
        name="roi",
        trajectories=[
            {
                "kind": "linear",
                "id": "far",
                "start_range_m": 6.0 if regions == "dock" else 3.0,
                "end_range_m": 5.0 if regions == "dock" else 2.0,
                "speed_mps": 5.0,
                "lateral_m": 0.7,
                "vertical_m": 0.3,
            }
        ],
    )
    cfg["camera"] = {"width": 320, "height": 240, "hfov_deg": 60, "fps": 10}
    images = {}
    for name, render in (
        ("roi", {"roi": True, "background_scale": 1.0, "background_samples": 4, "roi_regions": regions}),
        ("full", {"roi": False}),
    ):
        p = tmp_path / f"{name}.yaml"
        p.write_text(yaml.safe_dump({**cfg, "render": {"samples": 4, **render}}))
        generate(load_experiment(p), tmp_path / name, workers=1, progress=False)
        images[name] = [cv2.imread(str(f)) for f in sorted((tmp_path / name).glob("sequences/*/rgb/*.png"))]
    job = json.loads(next((tmp_path / "roi" / ".work" / "jobs").glob("*.json")).read_text())
    rois = [f["rois"] if regions != "dock" else [f["roi"]] for f in job["frames"]]
    assert all(r and r[0] is not None and sum((b[2] - b[0]) * (b[3] - b[1]) for b in r) < 0.5 * 320 * 240 for r in rois)
    assert regions == "dock" or max(len(r) for r in rois) >= 2
    for a, b in zip(images["roi"], images["full"]):
        diff = np.abs(a.astype(int) - b.astype(int))
        assert np.percentile(diff, 99.9) <= 2, np.percentile(diff, 99.9)


@pytest.mark.parametrize("light_tree", [False, True])
def test_setup_cycles_sets_light_tree(light_tree):
    """render.light_tree reaches Cycles (fast fidelity turns it off: one sun, LEDs unsampled)."""
    from blendgen.blender import render
    from blendgen.blender import scene as scn

    sc = scn.reset()
    render.setup_cycles(sc, {"samples": 4, "light_tree": light_tree})
    assert sc.cycles.use_light_tree is light_tree
