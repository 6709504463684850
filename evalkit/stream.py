"""Evaluate the sequences of a dataset while it is being written (``dockbench run``).

A render job commits its sequences one camera path at a time; each committed sequence
is evaluated here, in a worker process, before the dataset has a manifest. Each image
is read once: its sha256 (the hash the manifest will list, FORMAT.md) is taken from the
same bytes the localizers decode, then images outside the kept sample are deleted.

Per sequence, in ``WORK/`` (written atomically, hashes first, estimates last):

* ``<id>.hashes.json`` -- ``{dataset-relative image path: sha256}`` of every frame;
* ``<id>.cost.json`` -- CPU and wall seconds of this evaluation (for ``bench suite``);
* ``<id>.parquet`` -- the per-frame table of :func:`evalkit.runner.evaluate`;
* one line of ``WORK/manifest.jsonl`` -- ``{"files": {name: sha256}}`` of the files above,
  appended last: a sequence is finished when its line is there, and a resume reads a work
  file only when its bytes still have that sha256 (:func:`read_checked`; else
  :class:`StreamCacheError`, a user error naming the file).

Only data formats are read back (Parquet, JSON): a run folder handed over to resume
cannot run code. An older run folder's pickled caches (``*.pkl.gz``) are never read.

Nothing here imports blendgen: the caller passes the manifest (as ``dockbench
generate`` will write it, without ``files``) and the frames to keep.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from datasets_spec.io import (
    DatasetError,
    load_raw_image,
    path_inside,
    pixel_sha256,
    raw_image_path,
    save_json_atomic,
    sha256_file,
)
from evalkit.dataset import Dataset

RESULTS_SUFFIX = ".parquet"
PIXELS_SUFFIX = ".pixels.json"
WORK_MANIFEST = "manifest.jsonl"
LEGACY_SUFFIX = ".pkl.gz"  # pickled caches of older versions: refused, never read


class StreamCacheError(DatasetError):
    """A run folder's work file is missing from its manifest, changed since it was written
    (truncated, edited), or left by an older version (a user error: exit 2)."""


def record_files(work: Path, paths: list[Path]) -> None:
    """Append ``{"files": {WORK-relative name: sha256}}`` of ``paths`` to the work manifest
    (one ``write`` of one line on an ``O_APPEND`` file: concurrent workers do not interleave)."""
    work = Path(work)
    line = json.dumps({"files": {p.relative_to(work).as_posix(): sha256_file(p) for p in paths}}, sort_keys=True) + "\n"
    fd = os.open(work / WORK_MANIFEST, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line.encode())
    finally:
        os.close(fd)


def recorded_files(work: Path) -> dict[str, str]:
    """{WORK-relative name: sha256} of every work file recorded so far (a line cut by a
    crash or not JSON is skipped: its files count as not written)."""
    path = Path(work) / WORK_MANIFEST
    out: dict[str, str] = {}
    if not path.is_file():
        return out
    for line in path.read_text(errors="replace").splitlines():
        try:
            entry = json.loads(line)
        except (ValueError, RecursionError):
            continue
        files = entry.get("files") if isinstance(entry, dict) else None
        if isinstance(files, dict):
            out.update({str(k): str(v) for k, v in files.items()})
    return out


def read_checked(work: Path, name: str, recorded: dict[str, str] | None = None) -> bytes:
    """The bytes of work file ``name`` after checking them against the work manifest."""
    work = Path(work)
    recorded = recorded_files(work) if recorded is None else recorded
    path = work / name
    if name not in recorded:
        raise StreamCacheError(
            f"{path}: not in the run folder's {WORK_MANIFEST}; pass --overwrite to start the run over"
        )
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StreamCacheError(
            f"{path}: cannot read the run's work file ({exc.strerror}); pass --overwrite to start the run over"
        ) from None
    if hashlib.sha256(data).hexdigest() != recorded[name]:
        raise StreamCacheError(
            f"{path}: changed since the run wrote it (sha256 differs from {WORK_MANIFEST}: "
            "truncated or edited); pass --overwrite to start the run over"
        )
    return data


def refuse_legacy(work: Path) -> None:
    """:class:`StreamCacheError` when ``work`` holds pickled caches of an older version."""
    old = sorted(Path(work).glob(f"*{LEGACY_SUFFIX}"))
    if old:
        raise StreamCacheError(
            f"{old[0]}: a pickled cache of an older dockbench (never read: it could run "
            "code); pass --overwrite to start the run over"
        )


class RecordingDataset(Dataset):
    """A dataset still being written: files are read unchecked (there is no manifest
    ``files`` map yet) and the sha256 of every image read is recorded: of the PNG's bytes
    (``image_sha256``) or, for a frame not kept whose pixels the render worker left raw
    (``rgb/.<i>.npy``, never encoded), of its pixels (``pixel_sha256``, :func:`pixel_sha256`)."""

    def __init__(self, root: Path, manifest: dict):
        super().__init__(root, manifest, verify=False)
        self.image_sha256: dict[str, str] = {}
        self.pixel_sha256: dict[str, str] = {}

    def raw_path(self, frame: dict) -> Path:
        return raw_image_path(self.image_path(frame))

    def load_image(self, frame: dict) -> np.ndarray:
        raw = self.raw_path(frame)
        if raw.is_file():
            cam = self.manifest["camera"]
            img = load_raw_image(raw, cam["height"], cam["width"])
            self.pixel_sha256[frame["image"]] = pixel_sha256(img)
            return img
        path = self.checked_image_path(frame)
        data = path.read_bytes()
        self.image_sha256[frame["image"]] = hashlib.sha256(data).hexdigest()
        return self.decode_image(data, frame)

    def frame_hashes(self, frames: list[dict]) -> tuple[dict[str, str], dict[str, str]]:
        """({image: file sha256}, {image: pixel sha256}) of ``frames``; images the
        localizers did not read are read (and hashed) here."""
        for f in frames:
            if f["image"] not in self.image_sha256 and f["image"] not in self.pixel_sha256:
                if self.raw_path(f).is_file():
                    self.load_image(f)
                else:
                    self.image_sha256[f["image"]] = sha256_file(self.image_path(f))
        names = [f["image"] for f in frames]
        return (
            {n: self.image_sha256[n] for n in names if n in self.image_sha256},
            {n: self.pixel_sha256[n] for n in names if n in self.pixel_sha256},
        )


@dataclass
class SequenceTask:
    """One committed sequence to evaluate. ``keep``: frame indices whose image stays on
    disk (None: all); ``localizers``/``params``/``preprocess``: as ``dockbench evaluate``."""

    root: str
    manifest: dict
    seq_id: str
    work: str
    localizers: list[str]
    params: list[str]
    keep: list[int] | None = None
    preprocess: str | None = None


def done(work: Path, seq_id: str) -> bool:
    """True when the sequence's estimates are saved and recorded (its images may be gone)."""
    return f"{seq_id}{RESULTS_SUFFIX}" in recorded_files(work) and (Path(work) / f"{seq_id}{RESULTS_SUFFIX}").is_file()


def evaluate_sequence(task: SequenceTask) -> int:
    """Process body: run the localizers over one committed sequence, save its estimates
    and image hashes under ``task.work``, then delete the images not kept; returns the
    number of frames."""
    import time

    import cv2

    from evalkit import parallel, runner

    cpu0, wall0 = time.process_time(), time.perf_counter()
    cv2.setNumThreads(1)  # one process per core
    ds = RecordingDataset(Path(task.root), task.manifest)
    specs = parallel.build_localizers(task.localizers, task.params, None, None, task.preprocess)
    df = runner.evaluate(ds, specs, progress=False, sequences=[task.seq_id])
    frames = list(ds.iter_frames(task.seq_id))
    hashes, pixels = ds.frame_hashes(frames)
    work = Path(task.work)
    work.mkdir(parents=True, exist_ok=True)
    names = [f"{task.seq_id}{PIXELS_SUFFIX}", f"{task.seq_id}.hashes.json", f"{task.seq_id}.cost.json"]
    save_json_atomic(work / names[0], pixels)
    save_json_atomic(work / names[1], hashes)
    save_json_atomic(
        work / names[2],
        {"cpu_s": time.process_time() - cpu0, "wall_s": time.perf_counter() - wall0, "frames": len(frames)},
    )
    tmp = work / f".{task.seq_id}.tmp"
    df.to_parquet(tmp, index=False)
    os.replace(tmp, work / f"{task.seq_id}{RESULTS_SUFFIX}")
    record_files(work, [work / n for n in names] + [work / f"{task.seq_id}{RESULTS_SUFFIX}"])  # done
    prune_images(ds, frames, task.keep)  # after the record (again on a resume)
    return len(frames)


def prune_sequence(task: SequenceTask) -> None:
    """Delete the not-kept images of an evaluated sequence (idempotent: a run interrupted
    between saving a sequence's estimates and pruning it finishes the pruning on resume)."""
    ds = Dataset(Path(task.root), task.manifest, verify=False)
    prune_images(ds, list(ds.iter_frames(task.seq_id)), task.keep)


def prune_images(ds: Dataset, frames: list[dict], keep: list[int] | None) -> None:
    """Delete the images of ``frames`` whose index is not in ``keep`` (None: keep all), and
    every raw image (the pixels of frames not kept, never part of the dataset)."""
    kept = None if keep is None else set(keep)
    for f in frames:
        path = ds.image_path(f)
        raw_image_path(path).unlink(missing_ok=True)
        if kept is not None and f.get("index") not in kept:
            path.unlink(missing_ok=True)


def load_results(work: Path, seq_ids: list[str]) -> tuple[pd.DataFrame, dict[str, str]]:
    """The saved per-frame tables of ``seq_ids`` (in that order) and their image hashes."""
    work = Path(work)
    recorded = recorded_files(work)
    parts = [_parquet(work, f"{s}{RESULTS_SUFFIX}", recorded) for s in seq_ids]
    hashes: dict[str, str] = {}
    for s in seq_ids:
        hashes.update(read_json_checked(work, f"{s}.hashes.json", recorded))  # pixels: recorded_pixels
    df = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    if parts:
        df.attrs.update(parts[0].attrs)
    return df, hashes


def kept_indices(indices: list[int], images: str) -> list[int] | None:
    """Frame indices whose image is kept under an ``--images`` policy: ``all`` -> None
    (every one), ``none`` -> [], ``sample:N`` -> N evenly spaced ones (first and last
    included). The policy string is checked by :func:`parse_images`."""
    n = parse_images(images)
    if n is None:
        return None
    if n == 0 or not indices:
        return []
    pos = np.unique(np.round(np.linspace(0, len(indices) - 1, min(n, len(indices)))).astype(int))
    return [indices[i] for i in pos]


class ImagesPolicyError(ValueError):
    """A bad ``--images`` value (a user error)."""


def parse_images(images: str) -> int | None:
    """``all`` -> None, ``none`` -> 0, ``sample:N`` (N >= 1) -> N; else ImagesPolicyError."""
    text = str(images).strip().lower()
    if text == "all":
        return None
    if text == "none":
        return 0
    head, _, n = text.partition(":")
    if head == "sample" and n.isdigit() and int(n) >= 1:
        return int(n)
    raise ImagesPolicyError(
        f"--images {images!r}: expected none, all or sample:N with N >= 1 (N images kept per sequence, evenly spaced)"
    )


def run_record_dataset(root: Path, manifest: dict) -> Dataset:
    """A :class:`Dataset` over ``manifest`` (with the full ``files`` map) for the run record:
    its ``content_hash`` is the one ``dockbench generate`` gives the same config. ``streamed``:
    its files were hashed as the run read them (images not kept are gone from disk)."""
    ds = Dataset(Path(root), manifest, verify=True)
    ds.streamed = True
    return ds


def recorded_pixels(work: Path) -> dict[str, str]:
    """{path: pixel sha256} of every camera image and pass of the run that was never encoded."""
    out: dict[str, str] = {}
    work = Path(work)
    recorded = recorded_files(work)
    for p in sorted(work.glob(f"*{PIXELS_SUFFIX}")) + sorted((work / "renders").glob(f"*{PIXELS_SUFFIX}")):
        out.update(read_json_checked(work, p.relative_to(work).as_posix(), recorded))
    return out


def read_json_checked(work: Path, name: str, recorded: dict[str, str]) -> dict:
    """A checked JSON work file (an object of strings)."""
    data = read_checked(work, name, recorded)
    try:
        obj = json.loads(data)
    except (ValueError, RecursionError):
        obj = None
    if not isinstance(obj, dict):
        raise StreamCacheError(f"{Path(work) / name}: not a JSON object; pass --overwrite to start over")
    return obj


def _parquet(work: Path, name: str, recorded: dict[str, str]) -> pd.DataFrame:
    """A checked Parquet work file."""
    import io

    data = read_checked(work, name, recorded)
    try:
        return pd.read_parquet(io.BytesIO(data))
    except Exception as exc:  # noqa: BLE001 - any decoder failure is the same user error
        raise StreamCacheError(
            f"{Path(work) / name}: unreadable Parquet ({type(exc).__name__}); pass --overwrite to start over"
        ) from None


STREAM_FORMAT = "dockbench-stream"
STREAM_VERSION = "2"  # 2: camera images not kept are hashed by pixels ("pixels")
SUPPORTED_STREAM_VERSIONS = ("2",)
MAX_STREAM_JSON_BYTES = 512 << 20  # ~100 bytes per file: ~5 M files


def load_stream_summary(path: Path) -> dict:
    """A run's ``stream.json``, checked before anything it names is opened: a regular file of
    at most 512 MiB, JSON (bounded nesting), ``format``/``format_version`` this version
    reads, ``files`` and ``pixels`` maps of dataset-relative paths (no ``..``, no absolute
    path, no backslash) to 64-hex sha256; else :class:`DatasetError` (one line)."""
    import re

    from datasets_spec.validate import RELPATH, RELPATH_RULE, ContentError, loads_bounded

    path = Path(path)
    if not path.is_file() or path.stat().st_size > MAX_STREAM_JSON_BYTES:
        raise DatasetError(f"--stream {path}: not a regular file of at most 512 MiB")
    try:
        doc = loads_bounded(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, ContentError) as exc:
        raise DatasetError(f"--stream {path}: not a stream.json of dockbench run ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != STREAM_FORMAT:
        raise DatasetError(
            f'--stream {path}: expected a JSON object with "format": "{STREAM_FORMAT}" '
            "(the stream.json a dockbench run writes)"
        )
    if str(doc.get("format_version")) not in SUPPORTED_STREAM_VERSIONS:
        raise DatasetError(
            f"--stream {path}: format_version {doc.get('format_version')!r}; this dockbench "
            f"reads {', '.join(SUPPORTED_STREAM_VERSIONS)}"
        )
    sha = re.compile(r"^[0-9a-f]{64}$")
    for key in ("files", "pixels"):
        entries = doc.get(key, {} if key == "pixels" else None)
        if not isinstance(entries, dict):
            raise DatasetError(f'--stream {path}: "{key}" must be an object {{path: sha256}}')
        for rel, h in entries.items():
            if not RELPATH.match(rel):
                raise DatasetError(f"--stream {path}: {key} entry {rel[:80]!r} {RELPATH_RULE}")
            if not (isinstance(h, str) and sha.match(h)):
                raise DatasetError(f"--stream {path}: {key}[{rel[:80]!r}] is not a sha256 (64 hex digits)")
    return doc


def check_against(stream_summary: dict, root: Path) -> list[str]:
    """Problems ([] = none) of the dataset at ``root`` (a later ``dockbench generate`` of the
    run's config) against a run's ``stream.json``: every path of ``files`` must have that
    sha256, every image of ``pixels`` must decode (HxWx3 uint8 RGB) to pixels of that
    :func:`pixel_sha256`, and the dataset must hold no other file."""
    from datasets_spec.io import dataset_files, load_manifest

    root = Path(root)
    files, pixels = stream_summary["files"], stream_summary.get("pixels", {})
    ds = Dataset(root, load_manifest(root), verify=False)
    for rel in [*files, *pixels]:  # confined: symlinks out of the dataset are refused too
        path_inside(root, rel, "stream.json path")
    problems = [
        f"{p}: sha256 differs" for p, h in files.items() if not (root / p).is_file() or sha256_file(root / p) != h
    ]
    for p, h in pixels.items():
        try:
            img = _decoded(ds, root, p)
        except (OSError, DatasetError) as exc:
            problems.append(f"{p}: unreadable ({exc})")
            continue
        if pixel_sha256(img) != h:
            problems.append(f"{p}: pixels differ")
    extra = set(dataset_files(root)) - set(files) - set(pixels)
    return problems + [f"{p}: not in stream.json" for p in sorted(extra)]


def _decoded(ds: Dataset, root: Path, rel: str) -> np.ndarray:
    """A PNG's pixels as hashed by a run: camera image HxWx3 uint8 RGB; range (uint16 mm) and
    index (uint8) passes HxW as stored."""
    import cv2

    if "/rgb/" in rel:
        return ds.decode_image((root / rel).read_bytes(), {"image": rel})
    a = cv2.imread(str(root / rel), cv2.IMREAD_UNCHANGED)
    if a is None:
        raise DatasetError(f"{root / rel}: missing or unreadable pass")
    return a
