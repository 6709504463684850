"""Golden content hashes of the shipped configs, rendered small: a refactoring of the frame
loop, the job records or the config resolution must leave every dataset byte-identical.

``shrink(cfg)`` turns a shipped config into a tiny one (80 x 60 pixels, 1 sample, 1 trial,
3 frames per trajectory starting at most 6 m from the dock; every condition, preset and effect
kept). ``content_hashes(root)``
hashes every file of a dataset (``.work/`` excluded: scratch) except the manifest fields that
record when and with what it was made (``created_utc``, ``generator``: they differ between two
runs of the same config; everything else of the manifest is hashed).

Record (after a deliberate change of the output) with::

    PYTHONPATH=. python -m tests.golden_datasets record OUT_DIR

which renders every config into OUT_DIR and rewrites ``tests/data/golden_hashes.json``;
``check OUT_DIR`` renders them again and prints the files whose content differs.
"""

from __future__ import annotations

import copy
import hashlib
import json
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
HASHES = ROOT / "tests" / "data" / "golden_hashes.json"
VOLATILE_MANIFEST_KEYS = ("created_utc", "generator")  # wall clock and installed versions
WIDTH, HEIGHT, FRAMES = 80, 60, 3
START_RANGE_M = 6.0  # the marker is seen from here (the shipped paths start up to 12 m away)


def _shrink_trajectory(t: dict, fps: float) -> dict:
    """The trajectory cut to FRAMES frames at ``fps`` (same start, same kind)."""
    t = dict(t)
    span = (FRAMES - 1) / fps
    if t["kind"] == "linear":
        t["start_range_m"] = min(t["start_range_m"], START_RANGE_M)  # inside render.max_distance_m
        t["end_range_m"] = t["start_range_m"] - span * t.get("speed_mps", 1.0)
    elif t["kind"] == "circle":
        import math

        step = math.degrees(span * t.get("speed_mps", 1.0) / t.get("radius_m", 1.0))
        t["end_deg"] = t.get("start_deg", 0.0) + step
    elif t["kind"] == "docking":
        t["max_time_s"] = span
        t["start"] = {**t.get("start", {}), "range_m": [START_RANGE_M - 1.0, START_RANGE_M]}
    return t


def shrink(cfg: dict) -> dict:
    """A tiny version of a dataset config (see the module docstring)."""
    cfg = copy.deepcopy(cfg)
    cam = cfg.setdefault("camera", {})
    cam["width"], cam["height"] = WIDTH, HEIGHT
    cfg.setdefault("render", {})["samples"] = 1
    cfg["trials"] = 1
    fps = float(cam.get("fps", 10))
    cfg["trajectories"] = [_shrink_trajectory(t, fps) for t in cfg["trajectories"]]
    return cfg


def template_config(template: str) -> dict:
    """The quickstart config on another scene template."""
    cfg = yaml.safe_load((ROOT / "configs" / "quickstart.yaml").read_text())
    cfg["name"] = f"template_{template}"
    cfg["scene"] = {"template": template}
    return cfg


def configs() -> dict[str, dict]:
    """name -> tiny config: every dataset config in configs/ and quickstart on every template."""
    out = {}
    for p in sorted((ROOT / "configs").glob("*.yaml")):
        cfg = yaml.safe_load(p.read_text())
        if "trajectories" in cfg:  # calibration.yaml is not a dataset config
            out[p.stem] = shrink(cfg)
    for p in sorted((ROOT / "templates").glob("*.yaml")):
        out[f"template_{p.stem}"] = shrink(template_config(p.stem))
    return out


def _manifest_bytes(path: Path) -> bytes:
    m = json.loads(path.read_text())
    for k in VOLATILE_MANIFEST_KEYS:
        m.pop(k, None)
    return json.dumps(m, sort_keys=True).encode()


def content_hashes(root: Path) -> dict[str, str]:
    """{dataset-relative path: sha256} of every file under ``root`` except ``.work/``."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        if not p.is_file() or rel.startswith(".work/"):
            continue
        data = _manifest_bytes(p) if rel == "manifest.json" else p.read_bytes()
        out[rel] = hashlib.sha256(data).hexdigest()
    return out


def render(name: str, cfg: dict, work: Path) -> Path:
    """Generate the tiny config ``cfg`` into ``work/name`` (one worker); returns the dataset root."""
    from blendgen.config.models import load_experiment
    from blendgen.pipeline.generate import generate

    work.mkdir(parents=True, exist_ok=True)
    p = work / f"{name}.yaml"
    p.write_text(yaml.safe_dump(cfg))
    out = work / name
    generate(load_experiment(p), out, workers=1, progress=False)
    return out


def diff(expected: dict[str, str], got: dict[str, str]) -> list[str]:
    """Paths whose hash differs, or that are only on one side."""
    return sorted(k for k in expected.keys() | got.keys() if expected.get(k) != got.get(k))


def main(argv: list[str]) -> int:
    verb, work = argv[1], Path(argv[2])
    names = argv[3:] or list(configs())
    recorded = json.loads(HASHES.read_text()) if HASHES.exists() else {}
    bad = 0
    for name in names:
        got = content_hashes(render(name, configs()[name], work))
        if verb == "record":
            recorded[name] = got
        else:
            d = diff(recorded.get(name, {}), got)
            bad += bool(d)
            print(f"{name}: {len(got)} files, {'identical' if not d else f'{len(d)} differ: {d[:8]}'}")
    if verb == "record":
        HASHES.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
