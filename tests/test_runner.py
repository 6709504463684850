"""Dataset reading, localizer registry and the runner, on a fake dataset (no Blender)."""

from __future__ import annotations

import json
import math
import sys
import time
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from fake_dataset import SEQUENCES, decode_distance, write_fake_dataset  # noqa: E402

from evalkit import registry, runner  # noqa: E402
from evalkit.dataset import Dataset, DatasetError, verify  # noqa: E402
from evalkit.metrics import core as metrics
from evalkit.registry import RegistryError  # noqa: E402

N_FRAMES = sum(len(s[3]) for s in SEQUENCES)


@pytest.fixture
def ds_path(tmp_path):
    return write_fake_dataset(tmp_path / "ds")


@pytest.fixture
def ds(ds_path):
    return Dataset.open(ds_path)


class Oracle:
    """Reads d_true from the pixels; returns an identity-rotation pose."""

    def reset(self, camera):
        self.camera = camera

    def localize(self, image):
        d = decode_distance(image)
        T = np.eye(4)
        T[2, 3] = d
        return {"distance": d, "T_cam_dock": T, "marker_id": 0}


class Constant:
    """Always 1 m, no pose."""

    def reset(self, camera):
        pass

    def localize(self, image):
        return {"distance": 1.0}


class Faulty:
    """Misbehaves according to the encoded distance."""

    def reset(self, camera):
        pass

    def localize(self, image):
        d = decode_distance(image)
        return {
            0.5: lambda: 1 / 0,
            1.0: lambda: {"distance": float("nan")},
            2.0: lambda: "3.0 m",
            5.0: lambda: {"distance": d, "T_cam_dock": np.eye(3)},
            0.3: lambda: {"distance": -1.0},
            3.0: lambda: None,
            8.0: lambda: {"distance": d, "T_cam_dock": np.full((4, 4), np.inf)},
            10.0: lambda: {"dist": d},
            0.15: lambda: {"distance": "far"},
        }.get(d, lambda: {"distance": d})()


# -- dataset ---------------------------------------------------------------
def test_open_dataset(ds):
    assert [s["id"] for s in ds.sequences] == [s[0] for s in SEQUENCES]
    assert ds.camera["K"].shape == (3, 3) and ds.camera["dist"] is None
    assert ds.markers[0]["kind"] == "aruco"
    frames = list(ds.iter_frames("clear_000"))
    assert [f["index"] for f in frames] == list(range(6))
    img = ds.load_image(frames[2])
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    assert decode_distance(img) == frames[2]["d_true"]  # also checks RGB (not BGR) order


def test_missing_manifest(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match=r"manifest\.json: missing manifest"):
        Dataset.open(tmp_path / "empty")


def _edit_manifest(path, **changes):
    m = json.loads((path / "manifest.json").read_text())
    m.update(changes)
    (path / "manifest.json").write_text(json.dumps(m))


def test_wrong_spec_version(ds_path):
    _edit_manifest(ds_path, spec_version="2.0")
    with pytest.raises(DatasetError, match=r"manifest\.json: unsupported \"spec_version\" '2\.0'"):
        Dataset.open(ds_path)


def test_wrong_format(ds_path):
    _edit_manifest(ds_path, format="something")
    with pytest.raises(DatasetError, match="\"format\" is 'something'"):
        Dataset.open(ds_path)


def test_bad_json_line(ds_path):
    path = ds_path / "sequences/clear_001/frames.jsonl"
    lines = path.read_text().splitlines()
    lines[2] = lines[2][:-5]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"clear_001/frames\.jsonl: sha256 differs from the manifest"):
        list(Dataset.open(ds_path).iter_frames("clear_001"))  # verified: refused before parsing
    ds = Dataset.open(ds_path, verify=False)
    with pytest.raises(DatasetError, match=r"clear_001/frames\.jsonl:3: bad JSON line"):
        list(ds.iter_frames("clear_001"))


def test_tampered_ground_truth_is_refused(ds_path):
    """A GT edit (d_true + 1 m) that keeps the JSON valid is caught by the sha256 check."""
    import json

    path = ds_path / "sequences/clear_000/frames.jsonl"
    frames = [json.loads(x) for x in path.read_text().splitlines()]
    frames[2]["d_true"] += 1.0
    path.write_text("".join(json.dumps(f) + "\n" for f in frames))
    with pytest.raises(DatasetError, match="frames.jsonl: sha256 differs from the manifest"):
        runner.evaluate(Dataset.open(ds_path), [("o", Oracle())], progress=False)
    df = runner.evaluate(Dataset.open(ds_path, verify=False), [("o", Oracle())], progress=False)
    assert df.loc[(df.sequence == "clear_000") & (df["index"] == 2), "d_true"].item() == 2.0


def test_unlisted_and_relisted_files_are_refused(ds_path):
    import json

    m = json.loads((ds_path / "manifest.json").read_text())
    del m["files"]["sequences/clear_000/rgb/000001.png"]  # not listed, hash recomputed
    from datasets_spec.io import content_hash

    m["content_hash"] = content_hash(m["files"])
    (ds_path / "manifest.json").write_text(json.dumps(m))
    ds = Dataset.open(ds_path)
    frame = list(ds.iter_frames("clear_000"))[1]
    with pytest.raises(DatasetError, match="000001.png: not listed in the manifest"):
        ds.load_image(frame)
    m["content_hash"] = "0" * 64  # manifest edited by hand
    (ds_path / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(DatasetError, match="content_hash does not match"):
        Dataset.open(ds_path)


def test_missing_image(ds_path):
    (ds_path / "sequences/clear_000/rgb/000001.png").unlink()
    ds = Dataset.open(ds_path)
    frame = list(ds.iter_frames("clear_000"))[1]
    with pytest.raises(DatasetError, match=r"000001\.png: missing image"):
        ds.load_image(frame)


def test_verify(ds_path):
    assert verify(ds_path) == []
    png = ds_path / "sequences/clear_000/rgb/000003.png"
    data = bytearray(png.read_bytes())
    data[len(data) // 2] ^= 0x01
    png.write_bytes(bytes(data))
    (ds_path / "sequences/clear_001/rgb/000000.png").unlink()
    (ds_path / "stray.txt").write_text("x")
    problems = verify(ds_path)
    assert "sequences/clear_000/rgb/000003.png: sha256 mismatch" in problems
    assert "sequences/clear_001/rgb/000000.png: missing (listed in manifest)" in problems
    assert "stray.txt: extra file not in manifest" in problems
    assert len(problems) == 3


def test_verify_content_hash(ds_path):
    m = json.loads((ds_path / "manifest.json").read_text())
    m["content_hash"] = "0" * 64
    (ds_path / "manifest.json").write_text(json.dumps(m))
    assert verify(ds_path) == ["manifest.json: content_hash does not match the 'files' entries"]


# -- registry --------------------------------------------------------------
LOCALIZER_SRC = '''
class Const:
    """Always the same distance."""
    def __init__(self, d=1.0):
        self.d = d
    def reset(self, camera):
        pass
    def localize(self, image):
        return {"distance": self.d}

instance = Const(2.5)
'''


def test_resolve_file_target(tmp_path):
    f = tmp_path / "my_loc.py"
    f.write_text(LOCALIZER_SRC)
    loc = registry.resolve(f"{f}:Const", {"d": 4.0})
    assert loc.localize(None) == {"distance": 4.0}


def test_resolve_module_target(tmp_path, monkeypatch):
    (tmp_path / "third_party_loc.py").write_text(LOCALIZER_SRC)
    monkeypatch.syspath_prepend(str(tmp_path))
    assert registry.resolve("third_party_loc:Const", {}).d == 1.0
    assert registry.resolve("third_party_loc:instance", {}).d == 2.5
    with pytest.raises(RegistryError, match="no attribute 'Nope'"):
        registry.resolve("third_party_loc:Nope", {})
    with pytest.raises(RegistryError, match="cannot build"):
        registry.resolve("third_party_loc:Const", {"bogus": 1})


def test_resolve_entry_point(tmp_path, monkeypatch):
    (tmp_path / "ep_loc.py").write_text(LOCALIZER_SRC)
    monkeypatch.syspath_prepend(str(tmp_path))
    eps = {
        "const": EntryPoint("const", "ep_loc:Const", registry.ENTRY_POINT_GROUP),
        "broken": EntryPoint("broken", "no_such_module_xyz:X", registry.ENTRY_POINT_GROUP),
    }
    monkeypatch.setattr(registry, "_entry_points", lambda: eps)
    assert registry.resolve("const", {"d": 3}).d == 3
    listing = {name: (target, doc) for name, target, doc in registry.list_localizers()}
    assert listing["const"] == ("ep_loc:Const", "Always the same distance.")
    assert listing["broken"][1].startswith("unavailable: ")
    assert {"led", "qr", "aruco"} <= set(listing)


def test_unknown_localizer():
    with pytest.raises(RegistryError, match="unknown localizer 'nope'; known: led, qr, aruco"):
        registry.resolve("nope", {})
    with pytest.raises(RegistryError, match="not found"):
        registry.resolve("does/not/exist.py:X", {})


def test_list_localizers_tolerates_failures():
    rows = registry.list_localizers()  # built-ins may not be importable yet
    assert [r[0] for r in rows][:3] == ["led", "qr", "aruco"]
    assert all(isinstance(doc, str) for _, _, doc in rows)


def test_parse_params():
    assert registry.parse_params(
        ["a=1", "b=2.5", "c=true", "d=hello", "e=", "f=1e-3", "g=a=b", "h=null", "i=-3", "j=[1, 2]"]
    ) == {"a": 1, "b": 2.5, "c": True, "d": "hello", "e": "", "f": 0.001, "g": "a=b", "h": None, "i": -3, "j": [1, 2]}
    with pytest.raises(RegistryError, match="key=value"):
        registry.parse_params(["novalue"])


# -- runner ----------------------------------------------------------------
def test_oracle_and_constant(ds):
    oracle = Oracle()
    const = Constant()
    df = runner.evaluate(ds, [("oracle", oracle), ("const", const)], progress=False)
    assert list(df.columns) == runner.COLUMNS
    assert len(df) == 2 * N_FRAMES
    assert df["detected"].all() and (df["fail_reason"] == "").all()
    o = df[df.localizer == "oracle"]
    assert (o["success"] == o["in_view"]).all()  # exact; the out-of-view answer is a false positive
    assert o["fp"].sum() == 1
    assert np.allclose(o["d_est"], o["d_true"]) and np.allclose(o["e_abs"], 0.0)
    assert o["e_rel"].isna().sum() == 2  # d_true 0.1 and 0.15 m
    assert (o["marker_id"] == "0").all()
    assert o["in_view"].sum() == N_FRAMES - 1
    assert oracle.camera["markers"][0]["id"] == "0" and oracle.camera["K"].shape == (3, 3)
    summary, cond = metrics.summarize(df)
    assert summary["n_total"].tolist() == [5, 5, 5, 5]  # 12.0 and 10.5 m excluded
    assert summary["n_detect"].tolist() == [5, 5, 5, 5]
    # const 1.0 m is right (within 10 % / 5 cm) only at d_true 1.0 m:
    # clear_000 counted frames 0.1 0.5 1 2 5 -> one success; clear_001 0.15 0.3 3 8 10 -> none
    assert summary["n_succ"].tolist() == [1, 0, 5, 5]
    cond = cond.set_index("localizer")
    assert cond.loc["oracle", "E_rel_mean"] == pytest.approx(0.0, abs=1e-12)
    # const 1.0 m on clear_000: 0.5 1 2 5 -> e_rel 1, 0, .5, .8 (0.1 m has none)
    c0 = summary[(summary.localizer == "const") & (summary.sequence == "clear_000")].iloc[0]
    assert c0.e_rel_mean == pytest.approx((1 + 0 + 0.5 + 0.8) / 4)
    assert c0.e_abs_mean == pytest.approx((0.9 + 0.5 + 0 + 1 + 4) / 5)


def test_faulty_localizer_is_isolated(ds):
    df = runner.evaluate(ds, [("faulty", Faulty()), ("oracle", Oracle())], progress=False)
    assert df[df.localizer == "oracle"]["detected"].all()
    f = df[df.localizer == "faulty"].set_index("d_true")
    expected = {
        0.5: "exception: ZeroDivisionError: division by zero",
        1.0: "nan",
        2.0: "bad_type",
        5.0: "bad_shape",
        0.3: "negative",
        3.0: "none",
        8.0: "nan",
        10.0: "no_distance",
        0.15: "bad_type",
    }
    for d, reason in expected.items():
        assert f.loc[d, "fail_reason"] == reason, d
        assert not f.loc[d, "detected"] and math.isnan(f.loc[d, "d_est"])
    ok = f[~f.index.isin(list(expected))]
    assert ok["detected"].all() and (ok["fail_reason"] == "").all() and len(ok) == 3


def test_reset_failure_fails_all_frames(ds):
    class BadReset(Oracle):
        def reset(self, camera):
            raise RuntimeError("no camera for me")

    df = runner.evaluate(ds, [("bad", BadReset())], progress=False)
    assert not df["detected"].any()
    assert (df["fail_reason"] == "exception: RuntimeError: no camera for me (in reset)").all()


def test_timeout_hook(ds):
    class Slow(Oracle):
        def localize(self, image):
            time.sleep(0.01)
            return super().localize(image)

    df = runner.evaluate(ds, [("slow", Slow())], frame_timeout_s=0.001, progress=False, sequences=["clear_000"])
    assert len(df) == 6 and (df["fail_reason"] == "timeout").all()

    class Recording:
        calls = []

        def call(self, localizer, method, *args):
            self.calls.append(method)
            return runner.CallResult(value={"distance": 1.0}, ms=1.0)

    ex = Recording()
    df = runner.evaluate(ds, [("o", Oracle())], progress=False, executor=ex)
    assert ex.calls.count("localize") == N_FRAMES and ex.calls.count("reset") == 2
    assert df["detected"].all()


def test_progress_to_stderr(ds, capsys):
    runner.evaluate(ds, [("o", Oracle())], progress=True)
    captured = capsys.readouterr()
    assert captured.out == ""


def test_run_record_on_disk(ds, tmp_path):
    from evalkit.metrics.extra import EvalSettings
    from evalkit.reports import results

    df = runner.evaluate(ds, [("oracle", Oracle()), ("faulty", Faulty())], progress=False)
    paths, _ = results.save_run(
        df, tmp_path / "out", results.RunRecord(ds, ["oracle", "faulty"], EvalSettings(n_boot=50), make_plots=False)
    )
    if paths["estimates"].suffix == ".parquet":
        back = pd.read_parquet(paths["estimates"])
    else:  # no usable parquet engine in this environment: CSV fallback
        assert paths["estimates"].name == "estimates.csv"
        back = pd.read_csv(paths["estimates"])
    assert list(back.columns)[: len(runner.COLUMNS)] == runner.COLUMNS and len(back) == len(df)
    summary = pd.read_csv(paths["summary"])
    assert list(summary.columns) == metrics.TRIAL_COLUMNS
    assert summary.set_index(["localizer", "sequence"]).loc[("oracle", "clear_000"), "P_succ"] == 1.0


def test_duplicate_names_rejected(ds):
    with pytest.raises(ValueError, match="unique"):
        runner.evaluate(ds, [("a", Oracle()), ("a", Oracle())], progress=False)


def test_evalkit_import_is_light():
    import subprocess

    code = (
        "import sys, evalkit, evalkit.dataset, evalkit.registry, evalkit.runner, "
        "evalkit.metrics.core, evalkit.reports.tables; "
        "print('bpy' in sys.modules, 'cv2' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(__file__).parents[1], check=True
    ).stdout.split()
    assert out == ["False", "False"]
