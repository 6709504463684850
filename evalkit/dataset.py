"""Read-only access to a dockbench dataset (datasets_spec/FORMAT.md, spec_version 1.2, 1.1 and 1.0).

Never needs Blender. Units follow the format: metres, seconds, radians.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from datasets_spec.io import (  # noqa: F401  (re-exported: the reader's public names)
    DEFAULT_D_MIN_REL_M,
    FORMAT_NAME,
    MANIFEST,
    SUPPORTED_SPEC_VERSIONS,
    DatasetError,
    check_image_header,
    content_hash,
    dataset_files,
    iter_frames,
    load_manifest,
    path_inside,
    sha256_file,
)
from datasets_spec.io import (
    verify as _verify,
)


class Dataset:
    """An opened dataset. Use :meth:`Dataset.open`.

    With ``verify`` (the default) every file read through it (``frames.jsonl``,
    images) must be listed in the manifest's ``files`` with the same sha256, and the
    manifest's ``content_hash`` must match its ``files``; otherwise :class:`DatasetError`.
    """

    def __init__(self, root: Path, manifest: dict, verify: bool = True):
        self.root = Path(root)
        self.manifest = manifest
        self.verify = verify
        # set by a streamed run: its files were hashed as the run read them (images not kept are gone)
        self.streamed = False
        self._seq_by_id = {s["id"]: s for s in manifest["sequences"]}

    @classmethod
    def open(cls, path: str | Path, verify: bool = True) -> Dataset:
        """Open the dataset directory ``path``; raises :class:`DatasetError` on problems."""
        root = Path(path)
        ds = cls(root, load_manifest(root), verify)
        if verify:
            ds._check_content_hash()
        return ds

    def _check_content_hash(self) -> None:
        """The manifest's ``content_hash`` must be the hash of its ``files`` map."""
        files = self.manifest.get("files")
        if not isinstance(files, dict):
            raise DatasetError(
                f"{self.root / MANIFEST}: no 'files' map, so nothing can be verified "
                "(evaluate --no-verify reads it unchecked)"
            )
        if content_hash(files) != self.manifest.get("content_hash"):
            raise DatasetError(
                f"{self.root / MANIFEST}: content_hash does not match the 'files' "
                "entries (manifest edited after generation)"
            )

    def check_file(self, path: Path, data: bytes | None = None) -> None:
        """With ``verify``: ``path`` (under the root; ``data`` its bytes if already read) must be
        listed in the manifest with the same sha256, else :class:`DatasetError`."""
        if not self.verify:
            return
        rel = Path(path).resolve().relative_to(self.root.resolve()).as_posix()
        want = (self.manifest.get("files") or {}).get(rel)
        if want is None:
            raise DatasetError(f"{path}: not listed in the manifest's 'files', so it cannot be verified")
        if data is None and not Path(path).is_file():
            raise DatasetError(f"{path}: missing (listed in the manifest)")
        got = hashlib.sha256(data).hexdigest() if data is not None else sha256_file(Path(path))
        if got != want:
            raise DatasetError(
                f"{path}: sha256 differs from the manifest: changed after generation "
                "(dockbench verify lists every changed file)"
            )

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
            raise DatasetError(
                f"{self.root / MANIFEST}: no sequence {seq_id!r}; known: {', '.join(self._seq_by_id)}"
            ) from None

    # -- frames -----------------------------------------------------------
    def frames_path(self, seq_id: str) -> Path:
        """Path of ``frames.jsonl`` of a sequence (proven inside the dataset folder)."""
        seq = self.sequence(seq_id)
        rel = f"{seq.get('path', f'sequences/{seq_id}')}/frames.jsonl"
        path_inside(self.root, rel, "frames file")
        return self.root / rel

    def iter_frames(self, seq_id: str) -> Iterator[dict]:
        """Yield the frame dicts of a sequence in file order.

        Each record is checked against frame.schema.json (paths inside the dataset,
        4x4 poses, finite numbers, unique indices); raises :class:`DatasetError`
        naming the file, line and key.
        """
        path = self.frames_path(seq_id)
        if not path.is_file():
            raise DatasetError(f"{path}: missing frames file of sequence {seq_id!r}")
        self.check_file(path)
        yield from iter_frames(path, self.root)

    def image_path(self, frame: dict) -> Path:
        """Absolute path of a frame's RGB image, proven inside the dataset folder."""
        if "image" not in frame:
            raise DatasetError(f"frame {frame.get('index')!r}: no 'image' key")
        path_inside(self.root, frame["image"], "image")
        return self.root / frame["image"]

    def frame_file(self, frame: dict, key: str) -> Path:
        """Path of a frame's ``depth`` / ``object_index`` / ``image`` file, proven inside
        the dataset folder (no symlink leaving it); DatasetError if the key is absent."""
        if key not in frame:
            raise DatasetError(f"frame {frame.get('index')!r}: no {key!r} key")
        return path_inside(self.root, frame[key], key)

    def checked_image_path(self, frame: dict) -> Path:
        """:meth:`image_path` (resolved) after its PNG header was checked against the
        manifest camera (width x height, 8-bit RGB), without decoding a pixel."""
        if "image" not in frame:
            raise DatasetError(f"frame {frame.get('index')!r}: no 'image' key")
        return check_image_header(self.root, frame, self.manifest["camera"])

    def load_image(self, frame: dict) -> np.ndarray:
        """The frame's image as HxWx3 uint8 RGB, checked against the manifest's sha256.

        The PNG header is checked against the manifest camera before anything is
        decoded, so a huge or wrong image (a decompression bomb) is refused cheaply
        as a :class:`DatasetError`.
        """
        path = self.checked_image_path(frame)
        data = path.read_bytes()
        self.check_file(path, data)
        return self.decode_image(data, frame)

    def decode_image(self, data: bytes, frame: dict) -> np.ndarray:
        """PNG bytes of ``frame``'s image -> HxWx3 uint8 RGB of the manifest camera's size."""
        import cv2  # local: keeps `import evalkit.dataset` light

        shown = self.root / frame["image"]
        # decoded straight to RGB (OpenCV >= 4.11): the same bytes as BGR + cvtColor, one pass less
        flag = getattr(cv2, "IMREAD_COLOR_RGB", None)
        rgb = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR if flag is None else flag)
        cam = self.manifest["camera"]
        if rgb is None or rgb.shape != (cam["height"], cam["width"], 3):
            raise DatasetError(f"{shown}: unreadable image (frame {frame.get('index')!r})")
        return rgb if flag is not None else cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB)


def verify(path: str | Path) -> list[str]:
    """Check a dataset against its manifest; return human-readable problems ([] = OK)."""
    return _verify(Path(path))


def verify_before_reading(path: str | Path) -> None:
    """:func:`verify` as a gate: the first problem as a :class:`DatasetError` (one line), so a
    command that reads a dataset without decoding every image (``export-bop``) refuses what
    ``evaluate`` would: changed or unlisted files, images whose PNG header does not match the
    camera (a decompression bomb), paths leaving the dataset, no sequences."""
    problems = verify(path)
    if problems:
        first = problems[0].replace("\n", " ")
        first = first if str(path) in first else f"{path}: {first}"
        more = f" (and {len(problems) - 1} more; dockbench verify lists them)" if len(problems) > 1 else ""
        raise DatasetError(first + more)
