"""datasets_spec JSON Schemas (draft 2020-12) against FORMAT.md, the fake dataset, a dataset
written by the real writer pieces (plan -> postprocess -> DatasetWriter, synthetic passes
instead of Blender renders), and the demo dataset when it exists."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

jsonschema = pytest.importorskip("jsonschema")

from evalkit.dataset import Dataset, verify  # noqa: E402
from tests.fake_dataset import write_fake_dataset  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SPEC = ROOT / "datasets_spec"
DEMO = ROOT / "out" / "demo" / "dataset"


def _validator(name: str):
    schema = json.loads((SPEC / f"{name}.schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


MANIFEST_V = _validator("manifest")
FRAME_V = _validator("frame")


def errors(validator, doc) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(doc)]


def _no_nan(token: str):
    raise ValueError(f"non-standard JSON constant {token}")


def validate_dataset(root: Path, max_frames: int | None = None) -> int:
    """Validate manifest.json and every frames.jsonl line; returns the frames checked."""
    manifest = json.loads((root / "manifest.json").read_text(), parse_constant=_no_nan)
    assert errors(MANIFEST_V, manifest) == []
    n = 0
    for seq in manifest["sequences"]:
        lines = (root / seq["path"] / "frames.jsonl").read_text().splitlines()
        assert len(lines) == seq["n_frames"]
        last = -1
        for i, line in enumerate(lines[:max_frames]):
            frame = json.loads(line, parse_constant=_no_nan)  # strict JSON: no NaN/Infinity
            assert errors(FRAME_V, frame) == [], (seq["id"], i)
            # index order; plan.py skips frames beyond render.max_distance_m, keeping the numbering
            assert frame["index"] > last and (root / frame["image"]).is_file()
            last = frame["index"]
            for key in ("depth", "object_index"):
                assert key not in frame or (root / frame[key]).is_file()
            assert set(frame["markers"]) <= {m["id"] for m in manifest["markers"]}
            n += 1
    return n


# ------------------------------------------------------------------ FORMAT.md <-> schemas
def _format_table_keys(section: str) -> set[str]:
    """Backticked keys in the first column of the table under ``## <section>`` of FORMAT.md."""
    text = (SPEC / "FORMAT.md").read_text()
    body = text.split(f"## {section}", 1)[1].split("\n## ", 1)[0]
    keys = set()
    for line in body.splitlines():
        if line.startswith("| `"):
            keys |= set(re.findall(r"`([A-Za-z_]+)`", line.split("|")[1]))
    return keys


def test_schema_keys_match_format_md():
    m = json.loads((SPEC / "manifest.schema.json").read_text())
    f = json.loads((SPEC / "frame.schema.json").read_text())
    assert _format_table_keys("manifest.json") == set(m["properties"])
    assert _format_table_keys("frames.jsonl") == set(f["properties"])
    # the documented required keys (optional: d_min_rel_m has a default; reference_caustics is written by
    # reference renders with caustics only; effective_config is absent from datasets written before it;
    # depth/object_index may be absent; exposure_s is written with auto-exposure only)
    assert set(m["properties"]) - set(m["required"]) == {"d_min_rel_m", "reference_caustics", "effective_config"}
    assert set(f["properties"]) - set(f["required"]) == {"depth", "object_index", "exposure_s"}
    assert m["properties"]["spec_version"]["enum"] == ["1.0", "1.1", "1.2"]  # 1.2 written, 1.0 and 1.1 still read


# ------------------------------------------------------------------ datasets
def test_fake_dataset_validates(tmp_path):
    root = write_fake_dataset(tmp_path / "fake")
    assert validate_dataset(root) == 12
    root2 = write_fake_dataset(tmp_path / "fake2", d_min_rel_m=None)  # optional key absent
    assert validate_dataset(root2) == 12


def _writer_dataset(tmp_path: Path, n_frames: int = 3) -> Path:
    """A dataset from the real generation pieces, with synthetic passes instead of Blender
    (the same calls as blendgen/pipeline/frameloop.py and blendgen.pipeline.generate.generate)."""
    from blendgen.config.models import load_experiment
    from blendgen.pipeline import compose as pp
    from blendgen.pipeline import generate as gen
    from blendgen.pipeline import plan
    from blendgen.pipeline.passstore import PassStore, job_entry
    from blendgen.pipeline.writer import DatasetWriter

    cfg = yaml.safe_load((ROOT / "configs" / "quickstart.yaml").read_text())
    cfg["camera"].update(width=64, height=48, noise_std=2.0)
    cfg["conditions"] = [{"label": "clear"}, {"label": "murky", "water": {"preset": "jerlov_3C"}}]
    p = tmp_path / "cfg.yaml"
    p.write_text(yaml.safe_dump(cfg))
    exp = load_experiment(p)
    out = tmp_path / "writer_ds"
    writer = DatasetWriter(out)
    writer.prepare()
    K = plan.camera_K(exp)
    markers = plan.manifest_markers(exp)
    scene = plan.scene_description(exp, markers, gen.write_textures(exp, out))
    jobs = plan.plan_jobs(exp, scene)
    W, H = exp.camera.width, exp.camera.height
    T_wd = np.asarray(scene["dock"]["T_world_dock"], float)
    for job in jobs:
        job.frames = job.frames[:n_frames]
        handles = []
        store = PassStore.from_job({"passes": job_entry(job.key, [(writer.render_tmp_dir(job.key), True)], True, True)})
        for s in job.sequences:
            d = writer.tmp_dir(s.id)
            (d / "rgb").mkdir(parents=True, exist_ok=True)
            handles.append((s, d, open(d / "frames.jsonl", "w"), pp.SequenceState.start(s.post)))
        for fr in job.frames:
            index = np.zeros((H, W), np.uint8)
            index[10:20, 20:40] = markers[0]["object_index"]
            passes = pp.add_range(
                {
                    "rgb": np.full((H, W, 3), 0.3, np.float32),
                    "depth_z": np.full((H, W), 4.0, np.float32),
                    "index": index,
                },
                K,
            )
            rec = pp.frame_record(fr, T_wd, markers, K, W, H, passes["index"])
            pass_paths = store.write(fr["index"], passes)
            for s, d, fh, st in handles:
                seen, occluded = pp.add_particles(passes, st, K, fr["T_world_cam"])
                img = pp.camera_image(seen, st, K, fr, markers, exp.render.fidelity, occluded)
                paths = {**pp.write_image(d, f"sequences/{s.id}", fr["index"], img), **pass_paths}
                fh.write(json.dumps({**rec, **paths}) + "\n")
                st.advance()
        writer.commit_render(job.key)
        for s, _, fh, _ in handles:
            fh.close()
            writer.commit_sequence(s.id, len(job.frames))
    writer.finish(gen.manifest_base(exp, K, markers, scene, jobs))
    return out


def test_writer_pieces_dataset_validates(tmp_path):
    root = _writer_dataset(tmp_path)
    assert validate_dataset(root) == 3 * 2 * 2  # frames x trajectories x conditions
    assert verify(root) == []
    ds = Dataset.open(root)
    assert {m["kind"] for m in ds.markers} == {"led_array", "qr", "aruco"}


@pytest.mark.skipif(not (DEMO / "manifest.json").is_file(), reason="no demo dataset (make demo)")
def test_demo_dataset_validates():
    assert validate_dataset(DEMO, max_frames=20) > 0


# ------------------------------------------------------------------ the schemas reject
@pytest.fixture(scope="module")
def good(tmp_path_factory):
    root = write_fake_dataset(tmp_path_factory.mktemp("good") / "ds")
    manifest = json.loads((root / "manifest.json").read_text())
    frame = json.loads((root / "sequences" / "clear_000" / "frames.jsonl").read_text().splitlines()[0])
    return manifest, frame


def _set(doc, path: str, value):
    doc = copy.deepcopy(doc)
    node = doc
    keys = [int(k) if k.isdigit() else k for k in path.split(".")]
    for k in keys[:-1]:
        node = node[k]
    if value is _DEL:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return doc


_DEL = object()
BAD_MANIFESTS = [
    ("spec_version", "2.0"),
    ("spec_version", 1.0),
    ("format", "other"),
    ("files", _DEL),
    ("content_hash", "abc"),
    ("seed", -1),
    ("camera.K", [[1, 0, 0], [0, 1, 0]]),
    ("camera.fps", 0),
    ("camera.distortion", [0.1, 0.0]),
    ("camera.width", 64.5),
    ("dock.T_world_dock", [[1, 0, 0, 0]] * 3),
    ("markers.0.kind", "barcode"),
    ("markers.0.dictionary", _DEL),
    ("markers.0.keypoints", [[0, 0]]),
    ("object_index", {"x": "dock"}),
    ("sequences.0.n_frames", -1),
    ("sequences.0.path", "/abs/clear_000"),
    ("sequences.0.path", "sequences/../../etc"),
    ("sequences.0.extra", 1),
    ("unknown_key", 1),
    ("files", {"../outside.png": "0" * 64}),
    ("files", {"a.png": "ABC"}),
    ("d_min_rel_m", -0.1),
]
BAD_FRAMES = [
    ("d_true", _DEL),
    ("d_true", -1.0),
    ("index", -1),
    ("index", 1.5),
    ("image", "rgb/000000.jpg"),
    ("image", "/abs/x.png"),
    ("depth", "a/b.exr"),
    ("T_cam_dock", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
    ("markers.0.visible_fraction", 1.5),
    ("markers.0.in_fov", "yes"),
    ("markers.0.T_cam_marker", _DEL),
    ("markers.0.extra", 0),
    ("extra_key", 1),
    ("t", "0.1"),
]


@pytest.mark.parametrize("path,value", BAD_MANIFESTS, ids=[p for p, _ in BAD_MANIFESTS])
def test_manifest_schema_rejects(good, path, value):
    assert errors(MANIFEST_V, good[0]) == []
    assert errors(MANIFEST_V, _set(good[0], path, value)) != []


@pytest.mark.parametrize("path,value", BAD_FRAMES, ids=[p for p, _ in BAD_FRAMES])
def test_frame_schema_rejects(good, path, value):
    frame = good[1]
    assert errors(FRAME_V, frame) == []
    if path.startswith("markers.0."):  # marker ids are string keys
        bad = copy.deepcopy(frame)
        bad["markers"]["0"] = _set(frame["markers"]["0"], path.split(".", 2)[2], value)
    else:
        bad = _set(frame, path, value)
    assert errors(FRAME_V, bad) != []


def test_nan_is_not_strict_json(good):
    # JSON Schema cannot exclude NaN (comparisons are false), and json.dumps writes it as a
    # bare NaN token: validate_dataset therefore parses strictly and refuses it
    line = json.dumps({**good[1], "d_true": float("nan")})
    with pytest.raises(ValueError, match="NaN"):
        json.loads(line, parse_constant=_no_nan)
