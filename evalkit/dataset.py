"""Read-only access to a dockbench dataset (datasets_spec/FORMAT.md, spec_version 1.1 and 1.0).

Never needs Blender. Units follow the format: metres, seconds, radians.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterator

import numpy as np

from datasets_spec.io import (  # noqa: F401  (re-exported: the reader's public names)
    DEFAULT_D_MIN_REL_M, FORMAT_NAME, MANIFEST, SUPPORTED_SPEC_VERSIONS, DatasetError, content_hash,
    dataset_files, iter_frames, load_manifest, sha256_file, verify as _verify,
)


class Dataset:
    """An opened dataset. Use :meth:`Dataset.open`."""

    def __init__(self, root: Path, manifest: dict):
        self.root = Path(root)
        self.manifest = manifest
        self._seq_by_id = {s["id"]: s for s in manifest["sequences"]}

    @classmethod
    def open(cls, path: str | Path) -> "Dataset":
        """Open the dataset directory ``path``; raises :class:`DatasetError` on problems."""
        root = Path(path)
        return cls(root, load_manifest(root))

    # -- manifest views ---------------------------------------------------
    @property
    def camera(self) -> dict:
        """Camera dict: ``width``, ``height`` (px), ``K`` (3x3 ndarray), ``dist`` (ndarray or None)."""
        cam = self.manifest["camera"]
        dist = cam.get("distortion", cam.get("dist"))
        return {
            **cam,
            "width": int(cam["width"]),
            "height": int(cam["height"]),
            "K": np.asarray(cam["K"], dtype=float),
            "dist": None if dist is None else np.asarray(dist, dtype=float),
        }

    @property
    def markers(self) -> list[dict]:
        """Manifest marker list (keypoints in the dock frame, metres)."""
        return list(self.manifest.get("markers", []))

    @property
    def sequences(self) -> list[dict]:
        """Manifest sequence entries ``{id, path, condition, conditions, trial, ...}``."""
        return list(self.manifest["sequences"])

    @property
    def d_min_rel_m(self) -> float:
        """Minimum d_true (m) below which e_rel is not computed (manifest, default 0.2)."""
        return float(self.manifest.get("d_min_rel_m", DEFAULT_D_MIN_REL_M))

    def sequence(self, seq_id: str) -> dict:
        """Manifest entry of sequence ``seq_id``."""
        try:
            return self._seq_by_id[seq_id]
        except KeyError:
            raise DatasetError(f"{self.root / MANIFEST}: no sequence {seq_id!r}; "
                               f"known: {', '.join(self._seq_by_id)}") from None

    # -- frames -----------------------------------------------------------
    def frames_path(self, seq_id: str) -> Path:
        """Path of ``frames.jsonl`` of a sequence."""
        seq = self.sequence(seq_id)
        return self.root / seq.get("path", f"sequences/{seq_id}") / "frames.jsonl"

    def iter_frames(self, seq_id: str) -> Iterator[dict]:
        """Yield the frame dicts of a sequence in file order.

        Raises :class:`DatasetError` naming the file and line for bad JSON.
        """
        path = self.frames_path(seq_id)
        if not path.is_file():
            raise DatasetError(f"{path}: missing frames file of sequence {seq_id!r}")
        yield from iter_frames(path)

    def image_path(self, frame: dict) -> Path:
        """Absolute path of a frame's RGB image."""
        if "image" not in frame:
            raise DatasetError(f"frame {frame.get('index')!r}: no 'image' key")
        return self.root / frame["image"]

    def load_image(self, frame: dict) -> np.ndarray:
        """The frame's image as HxWx3 uint8 RGB, checked against the manifest's sha256."""
        import cv2  # local: keeps `import evalkit.dataset` light

        path = self.image_path(frame)
        if not path.is_file():
            raise DatasetError(f"{path}: missing image (frame {frame.get('index')!r})")
        data = path.read_bytes()
        want = (self.manifest.get("files") or {}).get(frame["image"])
        if want is not None and hashlib.sha256(data).hexdigest() != want:
            raise DatasetError(f"{path}: sha256 differs from the manifest: the image was changed "
                               "after generation (dockbench verify lists every such file)")
        bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DatasetError(f"{path}: unreadable image (frame {frame.get('index')!r})")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def verify(path: str | Path) -> list[str]:
    """Check a dataset against its manifest; return human-readable problems ([] = OK)."""
    return _verify(Path(path))
