"""Write a tiny valid dockbench dataset (FORMAT.md 1.0) without Blender.

Each frame's image encodes its ``d_true`` in millimetres in every pixel:
``R, G, B = mm >> 16, (mm >> 8) & 255, mm & 255``, so an oracle localizer can
recover the ground truth from the pixels (and the test checks RGB order).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np

WIDTH, HEIGHT = 64, 48
K = [[50.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]]
# (seq_id, condition, trial, d_true per frame in m); 12.0 and 10.5 are beyond 10 m,
# 0.1 and 0.15 below d_min_rel = 0.2 m. Frame 5 of "clear_000" is out of view.
SEQUENCES = [
    ("clear_000", "clear", 0, [0.1, 0.5, 1.0, 2.0, 5.0, 12.0]),
    ("clear_001", "clear", 1, [0.15, 0.3, 3.0, 8.0, 10.0, 10.5]),
]
OUT_OF_VIEW = {("clear_000", 5)}


def encode_distance(d_m: float) -> np.ndarray:
    """An HxWx3 uint8 RGB image whose pixels encode ``d_m`` in millimetres."""
    mm = int(round(d_m * 1000))
    rgb = np.array([(mm >> 16) & 255, (mm >> 8) & 255, mm & 255], dtype=np.uint8)
    return np.broadcast_to(rgb, (HEIGHT, WIDTH, 3)).copy()


def decode_distance(image: np.ndarray) -> float:
    """Inverse of :func:`encode_distance` (reads pixel (0, 0)), metres."""
    r, g, b = (int(v) for v in image[0, 0])
    return ((r << 16) | (g << 8) | b) / 1000.0


def _translation(z: float) -> list[list[float]]:
    """4x4 pose with the dock ``z`` metres in front of the camera."""
    return [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, z], [0, 0, 0, 1.0]]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _write_sequence(root: Path, seq_id: str, distances: list[float], fps: float) -> list[str]:
    """Write images and frames.jsonl of one sequence; return their relative paths."""
    seq_dir = root / "sequences" / seq_id
    (seq_dir / "rgb").mkdir(parents=True)
    rel_paths, lines = [], []
    for i, d in enumerate(distances):
        rel = f"sequences/{seq_id}/rgb/{i:06d}.png"
        cv2.imwrite(str(root / rel), cv2.cvtColor(encode_distance(d), cv2.COLOR_RGB2BGR))
        rel_paths.append(rel)
        in_fov = (seq_id, i) not in OUT_OF_VIEW
        lines.append(
            json.dumps(
                {
                    "index": i,
                    "t": i / fps,
                    "t_pose": i / fps,
                    "image": rel,
                    "T_world_cam": _translation(0.0),
                    "T_cam_dock": _translation(d),
                    "d_true": d,
                    "markers": {
                        "0": {
                            "in_fov": in_fov,
                            "visible_fraction": 1.0 if in_fov else 0.0,
                            "T_cam_marker": _translation(d),
                        }
                    },
                }
            )
        )
    (seq_dir / "frames.jsonl").write_text("\n".join(lines) + "\n")
    rel_paths.append(f"sequences/{seq_id}/frames.jsonl")
    return rel_paths


def write_fake_dataset(
    root: str | Path, sequences=SEQUENCES, d_min_rel_m: float | None = 0.2, fps: float = 10.0
) -> Path:
    """Write the dataset into ``root`` (created) and return its path."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    files, seq_entries = {}, []
    for seq_id, condition, trial, distances in sequences:
        for rel in _write_sequence(root, seq_id, distances, fps):
            files[rel] = _sha(root / rel)
        seq_entries.append(
            {
                "id": seq_id,
                "path": f"sequences/{seq_id}",
                "condition": condition,
                "conditions": {"label": condition},
                "trial": trial,
                "trajectory": "straight",
                "n_frames": len(distances),
            }
        )
    manifest = {
        "format": "dockbench-dataset",
        "spec_version": "1.0",
        "name": "fake",
        "version": "0.0.1",
        "content_hash": hashlib.sha256("".join(f"{p} {files[p]}\n" for p in sorted(files)).encode()).hexdigest(),
        "generator": {"dockbench": "test"},
        "config": {},
        "seed": 0,
        "camera": {
            "width": WIDTH,
            "height": HEIGHT,
            "K": K,
            "fps": fps,
            "latency_s": 0.0,
            "hfov_deg": 65.2,
            "distortion": None,
        },
        "dock": {"T_world_dock": _translation(0.0)},
        "markers": [
            {
                "id": "0",
                "kind": "aruco",
                "T_dock_marker": _translation(0.0),
                "keypoints": [[-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0], [-0.1, -0.1, 0]],
                "dictionary": "DICT_4X4_50",
                "marker_id": 0,
                "size_m": 0.2,
            }
        ],
        "object_index": {"0": "background", "1": "0"},
        "sequences": seq_entries,
        "files": files,
    }
    if d_min_rel_m is not None:
        manifest["d_min_rel_m"] = d_min_rel_m
    (root / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return root
