"""Read-only access to a dockbench dataset (datasets_spec/FORMAT.md, spec_version 1.0).

Never needs Blender. Units follow the format: metres, seconds, radians.
"""
from __future__ import annotations

import hashlib
import os
import json
from pathlib import Path
from typing import Iterator

import numpy as np

FORMAT_NAME = "dockbench-dataset"
SUPPORTED_SPEC_VERSIONS = ("1.0",)
MANIFEST = "manifest.json"
DEFAULT_D_MIN_REL_M = 0.2


class DatasetError(Exception):
    """A dataset is missing, malformed or of an unsupported version."""


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def content_hash(files: dict[str, str]) -> str:
    """sha256 over the sorted ``files`` entries as ``"path sha256\\n"`` lines (FORMAT.md)."""
    blob = "".join(f"{p} {files[p]}\n" for p in sorted(files))
    return hashlib.sha256(blob.encode()).hexdigest()


def dataset_files(root: Path) -> list[str]:
    """Relative paths of every dataset file, sorted, without manifest.json and without
    dot-names (work files and partial ``.tmp`` sequences are not part of a dataset)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for f in filenames:
            rel = Path(dirpath, f).relative_to(root).as_posix()
            if not f.startswith(".") and rel != MANIFEST:
                out.append(rel)
    return sorted(out)


def _read_manifest(root: Path) -> dict:
    """Load and validate the top-level keys of ``root/manifest.json``."""
    path = root / MANIFEST
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory")
    if not path.is_file():
        raise DatasetError(f"{path}: missing manifest (dataset incomplete or not a dockbench dataset)")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: invalid JSON: {exc}") from None
    if not isinstance(manifest, dict):
        raise DatasetError(f"{path}: top level must be a JSON object")
    if manifest.get("format") != FORMAT_NAME:
        raise DatasetError(f"{path}: \"format\" is {manifest.get('format')!r}, expected {FORMAT_NAME!r}")
    version = manifest.get("spec_version")
    if version not in SUPPORTED_SPEC_VERSIONS:
        raise DatasetError(f"{path}: unsupported \"spec_version\" {version!r}; "
                           f"supported: {', '.join(SUPPORTED_SPEC_VERSIONS)}")
    for key in ("camera", "sequences"):
        if key not in manifest:
            raise DatasetError(f"{path}: missing key {key!r}")
    _check_schema(manifest, path)
    return manifest


SCHEMA_DIR = Path(__file__).resolve().parent.parent / "datasets_spec"


def _check_schema(manifest: dict, path: Path) -> None:
    """Validate against datasets_spec/manifest.schema.json; the first problem names its key path."""
    import jsonschema
    schema = json.loads((SCHEMA_DIR / "manifest.schema.json").read_text())
    err = jsonschema.exceptions.best_match(jsonschema.Draft202012Validator(schema).iter_errors(manifest))
    if err is not None:
        where = ".".join(str(p) for p in err.absolute_path) or "<root>"
        raise DatasetError(f"{path}: {where}: {err.message}")


FRAME_KEYS = {"index": int, "image": str, "d_true": (int, float), "T_cam_dock": list}


def _check_frame(frame: dict, where: str) -> None:
    """The keys evaluation relies on must be present with the right JSON types."""
    for key, typ in FRAME_KEYS.items():
        if not isinstance(frame.get(key), typ) or isinstance(frame.get(key), bool):
            raise DatasetError(f"{where}: frame needs {key!r} ({getattr(typ, '__name__', 'number')}), "
                               f"got {frame.get(key)!r}")


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
        return cls(root, _read_manifest(root))

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
        with open(path, encoding="utf-8") as f:
            for lineno, line in enumerate(f, start=1):
                if not line.strip():
                    continue
                try:
                    frame = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise DatasetError(f"{path}:{lineno}: bad JSON line: {exc.msg}") from None
                if not isinstance(frame, dict):
                    raise DatasetError(f"{path}:{lineno}: frame must be a JSON object")
                _check_frame(frame, f"{path}:{lineno}")
                yield frame

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
    """Check a dataset against its manifest; return human-readable problems ([] = OK).

    Reports: manifest errors, files listed but missing, sha256 mismatches,
    files on disk not listed in the manifest (dot-named work files aside), and a
    wrong ``content_hash``.
    """
    root = Path(path)
    try:
        manifest = _read_manifest(root)
    except DatasetError as exc:
        return [str(exc)]
    ds = Dataset(root, manifest)
    try:
        for seq in manifest["sequences"]:
            for _ in ds.iter_frames(seq["id"]):  # every frame line parses and has its keys
                pass
    except DatasetError as exc:
        return [str(exc)]
    files = manifest.get("files")
    if not isinstance(files, dict):
        return [f"{root / MANIFEST}: missing or invalid 'files' map"]
    problems = []
    for rel, digest in sorted(files.items()):
        fpath = root / rel
        if not fpath.is_file():
            problems.append(f"{rel}: missing (listed in manifest)")
        elif sha256_file(fpath) != digest:
            problems.append(f"{rel}: sha256 mismatch")
    for rel in sorted(set(dataset_files(root)) - set(files)):
        problems.append(f"{rel}: extra file not in manifest")
    expected = manifest.get("content_hash")
    if expected is not None and expected != content_hash(files):
        problems.append(f"{MANIFEST}: content_hash does not match the 'files' entries")
    return problems
