"""Evaluate the sequences of a dataset while it is being written (``dockbench run``).

A render job commits its sequences one camera path at a time; each committed sequence
is evaluated here, in a worker process, before the dataset has a manifest. Each image
is read once: its sha256 (the hash the manifest will list, FORMAT.md) is taken from the
same bytes the localizers decode, then images outside the kept sample are deleted.

Per sequence, in ``WORK/`` (written atomically, hashes first, estimates last, so a
sequence with ``<id>.pkl.gz`` is finished and an interrupted run resumes from the rest):

* ``<id>.hashes.json`` -- ``{dataset-relative image path: sha256}`` of every frame;
* ``<id>.cost.json`` -- CPU and wall seconds of this evaluation (for ``bench suite``);
* ``<id>.pkl.gz`` -- the per-frame table of :func:`evalkit.runner.evaluate` (pandas
  pickle, gzip).

Nothing here imports blendgen: the caller passes the manifest (as ``dockbench
generate`` will write it, without ``files``) and the frames to keep.
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from evalkit.dataset import Dataset
from datasets_spec.io import (load_raw_image, pixel_sha256, raw_image_path, save_json_atomic, sha256_file,
                              DatasetError)


RESULTS_SUFFIX = ".pkl.gz"
PIXELS_SUFFIX = ".pixels.json"


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
        return ({n: self.image_sha256[n] for n in names if n in self.image_sha256},
                {n: self.pixel_sha256[n] for n in names if n in self.pixel_sha256})


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
    """True when the sequence's estimates are saved (its images may be gone)."""
    return (Path(work) / f"{seq_id}{RESULTS_SUFFIX}").is_file()


def evaluate_sequence(task: SequenceTask) -> int:
    """Process body: run the localizers over one committed sequence, save its estimates
    and image hashes under ``task.work``, then delete the images not kept; returns the
    number of frames."""
    import time

    import cv2
    from evalkit import parallel, runner
    cpu0, wall0 = time.process_time(), time.perf_counter()
    cv2.setNumThreads(1)                    # one process per core
    ds = RecordingDataset(Path(task.root), task.manifest)
    specs = parallel.build_localizers(task.localizers, task.params, None, None, task.preprocess)
    df = runner.evaluate(ds, specs, progress=False, sequences=[task.seq_id])
    frames = list(ds.iter_frames(task.seq_id))
    hashes, pixels = ds.frame_hashes(frames)
    work = Path(task.work)
    work.mkdir(parents=True, exist_ok=True)
    save_json_atomic(work / f"{task.seq_id}{PIXELS_SUFFIX}", pixels)
    save_json_atomic(work / f"{task.seq_id}.hashes.json", hashes)
    save_json_atomic(work / f"{task.seq_id}.cost.json",
                     {"cpu_s": time.process_time() - cpu0, "wall_s": time.perf_counter() - wall0,
                      "frames": len(frames)})
    tmp = work / f".{task.seq_id}.tmp"
    df.to_pickle(tmp, compression={"method": "gzip", "compresslevel": 1})   # ~1.6 -> ~0.3 kB per frame
    os.replace(tmp, work / f"{task.seq_id}{RESULTS_SUFFIX}")   # done; images pruned after (again on a resume)
    prune_images(ds, frames, task.keep)
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
    parts = [pd.read_pickle(work / f"{s}{RESULTS_SUFFIX}", compression="gzip") for s in seq_ids]
    hashes: dict[str, str] = {}
    for s in seq_ids:
        hashes.update(json.loads((work / f"{s}.hashes.json").read_text()))   # pixels: recorded_pixels
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
    raise ImagesPolicyError(f"--images {images!r}: expected none, all or sample:N with N >= 1 "
                            "(N images kept per sequence, evenly spaced)")


def run_record_dataset(root: Path, manifest: dict) -> Any:
    """A :class:`Dataset` over ``manifest`` (with the full ``files`` map) for the run record:
    its ``content_hash`` is the one ``dockbench generate`` gives the same config."""
    return Dataset(Path(root), manifest, verify=True)


def recorded_pixels(work: Path) -> dict[str, str]:
    """{path: pixel sha256} of every camera image and pass of the run that was never encoded."""
    out: dict[str, str] = {}
    work = Path(work)
    for p in sorted(work.glob(f"*{PIXELS_SUFFIX}")) + sorted((work / "renders").glob(f"*{PIXELS_SUFFIX}")):
        out.update(json.loads(p.read_text()))
    return out


def check_against(stream_summary: dict, root: Path) -> list[str]:
    """Problems ([] = none) of the dataset at ``root`` (a later ``dockbench generate`` of the
    run's config) against a run's ``stream.json``: every path of ``files`` must have that
    sha256, every image of ``pixels`` must decode (HxWx3 uint8 RGB) to pixels of that
    :func:`pixel_sha256`, and the dataset must hold no other file."""
    from datasets_spec.io import dataset_files, load_manifest
    root = Path(root)
    files, pixels = stream_summary["files"], stream_summary.get("pixels", {})
    ds = Dataset(root, load_manifest(root), verify=False)
    problems = [f"{p}: sha256 differs" for p, h in files.items()
                if not (root / p).is_file() or sha256_file(root / p) != h]
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
