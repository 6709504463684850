"""Third-party localizers without editing dockbench, end to end through the CLI.

Routes: an entry point of an installed distribution (a dist-info made in a tmp
directory on sys.path, nothing installed globally), ``path/file.py:Class`` and
``module:attr`` with ``--param``, and ``exec:COMMAND`` (JSON-lines protocol) in
Python and POSIX sh. Also the built-ins registered here: apriltag, preprocessing.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(ROOT))
import synth_images as synth  # noqa: E402
from fake_dataset import SEQUENCES, write_fake_dataset  # noqa: E402

import cli  # noqa: E402
from evalkit import assemble, preprocess, registry, runner  # noqa: E402
from evalkit.dataset import Dataset  # noqa: E402
from evalkit.external import ExternalLocalizer  # noqa: E402
from evalkit.registry import RegistryError  # noqa: E402

pytestmark = pytest.mark.integration  # plugins end to end through the CLI, child processes

N_FRAMES = sum(len(s[3]) for s in SEQUENCES)

PLUGIN_SRC = textwrap.dedent('''
    """A third-party localizer package."""
    import numpy as np

    class Oracle:
        """Reads d_true from the fake dataset's pixels, times a scale."""
        def __init__(self, scale=1.0, tag="x"):
            self.scale, self.tag = scale, tag
        def reset(self, camera):
            assert camera["K"].shape == (3, 3) and camera["sequence"].startswith("clear_")
        def localize(self, image):
            r, g, b = (int(v) for v in image[0, 0])
            return {"distance": self.scale * ((r << 16) | (g << 8) | b) / 1000.0, "marker_id": self.tag}

    oracle = Oracle(2.0, "instance")
''')

EXT_ORACLE = textwrap.dedent("""
    import json, os, sys
    import cv2
    params = None
    process_id = os.urandom(8).hex()     # not the pid: a sandboxed program has its own PID namespace
    for line in sys.stdin:
        req = json.loads(line)
        if req["type"] == "reset":
            params = req["params"]
            ok = (req["protocol"] == 1 and req["camera"]["width"] == 64 and req["sequence"].startswith("clear")
                  and req["camera"]["markers"][0]["kind"] == "aruco")
            print(json.dumps({"ok": ok, "protocol": 1, "name": "oracle"}), flush=True)
            continue
        assert os.path.isabs(req["image"]) and len(req["K"]) == 3
        b, g, r = (int(v) for v in cv2.imread(req["image"])[0, 0])
        d = ((r << 16) | (g << 8) | b) / 1000.0
        T = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, d], [0, 0, 0, 1]]
        print(json.dumps({"ok": True, "index": req["index"], "distance": d * params.get("scale", 1.0),
                          "T_cam_dock": T, "marker_id": process_id, "confidence": 0.5}), flush=True)
""")


@pytest.fixture(scope="module")
def ds_path(tmp_path_factory):
    return write_fake_dataset(tmp_path_factory.mktemp("plugins") / "ds")


def _evaluate(ds_path, out, *args):
    r = CliRunner().invoke(cli.main, ["evaluate", str(ds_path), "-o", str(out), *args])
    assert r.exit_code == 0, (r.output, r.exception)
    est = out / "estimates.parquet"
    df = pd.read_parquet(est) if est.exists() else pd.read_csv(out / "estimates.csv")
    assert (out / "summary.csv").exists()
    return df


def _assert_oracle(df, scale=1.0, tag=None):
    assert len(df) == N_FRAMES and df["detected"].all()
    assert np.allclose(df["d_est"], scale * df["d_true"])
    if tag is not None:
        assert (df["marker_id"] == tag).all()


def test_entry_point_from_a_dist_info_on_sys_path(ds_path, tmp_path, monkeypatch):
    site = tmp_path / "site"
    (site / "acme_dock_loc-1.0.dist-info").mkdir(parents=True)
    (site / "acme_dock_loc.py").write_text(PLUGIN_SRC)
    (site / "acme_dock_loc-1.0.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: acme-dock-loc\nVersion: 1.0\n"
    )
    (site / "acme_dock_loc-1.0.dist-info" / "entry_points.txt").write_text(
        "[dockbench.localizers]\nacme = acme_dock_loc:Oracle\n"
    )
    monkeypatch.syspath_prepend(str(site))
    assert "acme" in registry.known_names()
    r = CliRunner().invoke(cli.main, ["localizers"])
    assert r.exit_code == 0 and "acme" in r.output and "Reads d_true" in r.output
    df = _evaluate(ds_path, tmp_path / "out", "-l", "acme", "-p", "scale=1.5", "-p", "tag=ep")
    _assert_oracle(df, 1.5, "ep")
    assert (df["localizer"] == "acme").all()


def test_file_target_with_params(ds_path, tmp_path):
    f = tmp_path / "my_loc.py"
    f.write_text(PLUGIN_SRC)
    df = _evaluate(ds_path, tmp_path / "out", "-l", f"{f}:Oracle", "-p", "scale=0.5", "-p", "tag=file")
    _assert_oracle(df, 0.5, "file")


def test_module_attr_instance_and_class(ds_path, tmp_path, monkeypatch):
    (tmp_path / "third_party_dock.py").write_text(PLUGIN_SRC)
    monkeypatch.syspath_prepend(str(tmp_path))
    df = _evaluate(ds_path, tmp_path / "out", "-l", "third_party_dock:oracle", "-l", "third_party_dock:Oracle")
    _assert_oracle(df[df.localizer == "third_party_dock:oracle"], 2.0, "instance")
    _assert_oracle(df[df.localizer == "third_party_dock:Oracle"], 1.0, "x")


def test_unknown_localizer_is_a_user_error(ds_path, tmp_path):
    r = CliRunner().invoke(cli.main, ["evaluate", str(ds_path), "-o", str(tmp_path / "o"), "-l", "nope"])
    assert r.exit_code == 2 and "exec:COMMAND" in r.output


def test_exec_python_program_through_the_cli(ds_path, tmp_path):
    script = tmp_path / "ext_oracle.py"
    script.write_text(EXT_ORACLE)
    spec = f"exec:{sys.executable} {script}"
    df = _evaluate(ds_path, tmp_path / "out", "-l", spec, "-p", "scale=2.0")
    _assert_oracle(df, 2.0)
    # one process per sequence: the same process id within a sequence, another in the next one
    pids = df.groupby("sequence")["marker_id"].nunique()
    assert (pids == 1).all() and df["marker_id"].nunique() == 2


def test_exec_persistent_process_and_pixels(ds_path, tmp_path):
    script = tmp_path / "ext_oracle.py"
    script.write_text(EXT_ORACLE)
    loc = registry.resolve(f"exec:{sys.executable} {script}", {"persistent": True})
    df = runner.evaluate(Dataset.open(ds_path), [("p", loc)], progress=False)
    _assert_oracle(df)
    assert df["marker_id"].nunique() == 1  # one process for both sequences
    # localize(pixels) goes through a temporary PNG (used when a preprocess step comes first)
    loc.reset(
        {
            "width": 64,
            "height": 48,
            "K": np.eye(3),
            "dist": None,
            "sequence": "clear_x",
            "markers": Dataset.open(ds_path).markers,
        }
    )
    from fake_dataset import encode_distance

    est = loc.localize(encode_distance(3.25))
    assert est["distance"] == 3.25 and est["confidence"] == 0.5 and np.shape(est["T_cam_dock"]) == (4, 4)
    loc.close()


@pytest.mark.skipif(shutil.which("sh") is None, reason="no POSIX sh")
def test_exec_posix_shell_example(ds_path, tmp_path):
    df = _evaluate(ds_path, tmp_path / "out", "-l", f"exec:sh {ROOT / 'examples/external_localizer.sh'} 2.5")
    assert df["detected"].all() and (df["d_est"] == 2.5).all()


def test_python_example_program_on_a_rendered_aruco(tmp_path):
    W, H = 640, 480
    K = synth.k_from_hfov(W, H, 60.0)
    h = 0.1
    marker = {
        "id": "tag",
        "kind": "aruco",
        "dictionary": "DICT_4X4_50",
        "marker_id": 7,
        "size_m": 0.2,
        "T_dock_marker": np.eye(4).tolist(),
        "keypoints": [[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]],
    }
    T = synth.pose_looking_at_dock(1.5, 20.0, -10.0, 30.0)
    img = synth.render(K, T, [marker], W, H, ss=2)
    loc = ExternalLocalizer([sys.executable, str(ROOT / "examples/external_localizer.py")], timeout_s=20)
    loc.reset(synth.camera_dict(K, W, H, [marker]))
    est = loc.localize(img)
    loc.close()
    assert est["marker_id"] == "tag" and est["distance"] == pytest.approx(1.5, rel=0.02)


# -- the newer built-ins (apriltag, hybrid, ...) ------------------------------
def test_builtins_registered_and_listed():
    names = [r[0] for r in registry.list_localizers()]
    assert names[:5] == ["led", "qr", "aruco", "apriltag", "hybrid"]


APRILTAG = {
    "id": "at",
    "kind": "apriltag",
    "dictionary": "DICT_APRILTAG_36h11",
    "marker_id": 3,
    "size_m": 0.2,
    "T_dock_marker": [[1, 0, 0, 0.1], [0, 1, 0, -0.05], [0, 0, 1, 0], [0, 0, 0, 1]],
}
APRILTAG["keypoints"] = [[0.0, 0.05, 0], [0.2, 0.05, 0], [0.2, -0.15, 0], [0.0, -0.15, 0]]  # dock frame


@pytest.mark.parametrize(
    "d,angles", [(1.0, (0, 0, 0)), (2.0, (25, -10, 30)), (3.0, (-35, 15, 150)), (4.0, (10, 30, -100))]
)
def test_apriltag_localizer_pose(d, angles):
    pytest.importorskip("pupil_apriltags")
    W, H = 640, 480
    K = synth.k_from_hfov(W, H, 60.0)
    T = synth.pose_looking_at_dock(d, *angles, offset=(0.1, -0.05))
    img = synth.render(K, T, [APRILTAG], W, H, ss=2, noise_std=2.0, seed=int(d))
    loc = registry.resolve("apriltag", {})
    loc.reset(synth.camera_dict(K, W, H, [APRILTAG]))
    est = loc.localize(img)
    assert est is not None and est["marker_id"] == "at"
    assert est["distance"] == pytest.approx(d, rel=0.03)  # small oblique tags: ~1-2 %
    R = np.asarray(est["T_cam_dock"])[:3, :3].T @ T[:3, :3]
    assert math.degrees(math.acos(np.clip((np.trace(R) - 1) / 2, -1, 1))) < 5.0  # a wrong corner order: >= 90
    assert loc.localize(np.zeros((480, 640, 3), np.uint8)) is None


def test_apriltag_missing_dependency_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "pupil_apriltags", None)  # import fails
    with pytest.raises(RegistryError, match=r"pip install 'dockbench\[apriltag\]'"):
        registry.resolve("apriltag", {})


def test_apriltag_family_mapping():
    from evalkit.localizers.apriltag import family_of

    assert family_of({"dictionary": "DICT_APRILTAG_36h11"}) == "tag36h11"
    assert family_of({"dictionary": "DICT_APRILTAG_16h5"}) == "tag16h5"
    assert family_of({"dictionary": "DICT_4X4_50"}) is None
    assert family_of({"family": "tagStandard41h12"}) == "tagStandard41h12"


# -- preprocessing -------------------------------------------------------------
def test_parse_preprocess_spec():
    steps = preprocess.parse_steps("median:k=5, clahe:clip=3:tile=4,grayworld,")
    assert [s.name for s in steps] == ["median", "clahe", "grayworld"]
    assert steps[0].params == {"k": 5} and steps[1].params == {"clip": 3, "tile": 4}
    for bad, msg in (
        ("sharpen", "unknown preprocessing step 'sharpen'"),
        ("median:q=3", "bad parameter"),
        ("clahe:clip", "bad parameter"),
    ):
        with pytest.raises(ValueError, match=msg):
            preprocess.parse_steps(bad)
    with pytest.raises(RegistryError, match="bad --preprocess"):
        assemble.build("qr", preprocess="nope")


def test_preprocess_steps_are_deterministic_images():
    rng = np.random.default_rng(0)
    img = np.clip(rng.normal([60, 110, 140], 20, (48, 64, 3)), 0, 255).astype(np.uint8)
    for name in preprocess.STEPS:
        out = preprocess.apply_steps(img, preprocess.parse_steps(name))
        assert out.shape == img.shape and out.dtype == np.uint8, name
        assert np.array_equal(out, preprocess.apply_steps(img, preprocess.parse_steps(name))), name
    balanced = preprocess.grayworld(img).reshape(-1, 3).mean(axis=0)
    assert np.ptp(balanced) < 1.5  # gray world: equal channel means
    grey = np.repeat(np.linspace(50, 150, 64 * 48).reshape(48, 64, 1), 3, axis=2).astype(np.uint8)
    stretched = preprocess.stretch(grey, low=0, high=100)
    assert stretched.min() == 0 and stretched.max() == 255  # percentiles -> 0 / 255


def test_preprocessed_wrapper_feeds_processed_images(ds_path):
    seen = []

    class Spy:
        def reset(self, camera):
            seen.clear()

        def localize(self, image):
            seen.append(image.copy())
            return {"distance": 1.0}

    loc = preprocess.Preprocessed(Spy(), "gain:alpha=2")
    df = runner.evaluate(Dataset.open(ds_path), [("spy", loc)], progress=False, sequences=["clear_000"])
    assert df["detected"].all() and loc.name == "Spy+gain"
    raw = Dataset.open(ds_path)
    frame = next(raw.iter_frames("clear_000"))
    expected = np.clip(2.0 * raw.load_image(frame).astype(float), 0, 255).astype(np.uint8)
    assert np.array_equal(seen[0], expected)


def test_preprocess_in_isolated_child(ds_path, tmp_path):
    f = tmp_path / "my_loc.py"
    f.write_text(PLUGIN_SRC)
    # gain alpha=1 beta=0 is the identity: the oracle still reads the exact distance
    loc = assemble.build(f"{f}:Oracle", {}, isolate=True, preprocess="gain:alpha=1:beta=0")
    df = runner.evaluate(Dataset.open(ds_path), [("o", loc)], progress=False)
    _assert_oracle(df)
    assert json.loads(json.dumps(preprocess.parse_steps("gain:alpha=1")[0].params)) == {"alpha": 1}


def test_new_modules_import_light():
    import subprocess

    code = (
        "import sys, evalkit.isolation, evalkit.external, evalkit.registry; "
        "light = not any(m in sys.modules for m in ('cv2', 'numpy', 'pandas', 'bpy')); "
        "import evalkit.preprocess, evalkit.localizers.hybrid, evalkit.localizers.apriltag; "
        "print(light, 'bpy' in sys.modules, 'pupil_apriltags' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True
    ).stdout.split()
    assert out == ["True", "False", "False"]


def test_params_scoped_to_one_localizer():
    from evalkit.registry import params_for

    kw = {"threshold": 100, "led.min_area_px": 3, "qr.refine": "none"}
    names = ["led", "qr"]
    assert params_for("led", kw, names) == {"threshold": 100, "min_area_px": 3}
    assert params_for("qr", kw, names) == {"threshold": 100, "refine": "none"}
