"""Atomic, resumable dataset writing (datasets_spec/FORMAT.md).

- a sequence is rendered into ``sequences/.<id>.tmp/`` and renamed into place only
  when complete, so ``sequences/<id>/`` is always whole; a re-run skips it;
- leftovers of an interrupted run (``.tmp`` dirs) are removed before resuming;
- ``manifest.json`` is written last (temp file + rename) with the sha256 of every
  file; names starting with ``.`` (work files) are not part of the dataset.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from evalkit.dataset import content_hash, dataset_files, sha256_file

SPEC_VERSION = "1.0"
FORMAT = "dockbench-dataset"


def write_json_atomic(path: Path, obj) -> None:
    """Write JSON via a temp file in the same directory and an atomic rename."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=1, sort_keys=False) + "\n")
    os.replace(tmp, path)


class DatasetWriter:
    """Owns one dataset directory during generation."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.seq_root = self.root / "sequences"

    def prepare(self) -> None:
        """Create the layout and drop partial sequences of an interrupted run."""
        self.seq_root.mkdir(parents=True, exist_ok=True)
        for d in self.seq_root.glob(".*.tmp"):
            shutil.rmtree(d, ignore_errors=True)
        (self.root / "manifest.json").unlink(missing_ok=True)

    def is_done(self, seq_id: str) -> bool:
        return (self.seq_root / seq_id / "frames.jsonl").exists()

    def tmp_dir(self, seq_id: str) -> Path:
        return self.seq_root / f".{seq_id}.tmp"

    def commit_sequence(self, seq_id: str, n_frames: int) -> None:
        """Check the temp sequence is whole, then rename it into place."""
        tmp = self.tmp_dir(seq_id)
        lines = (tmp / "frames.jsonl").read_text().splitlines()
        if len(lines) != n_frames:
            raise RuntimeError(f"sequence {seq_id}: {len(lines)} of {n_frames} frames written")
        os.replace(tmp, self.seq_root / seq_id)

    def finish(self, manifest: dict) -> dict:
        """Hash every file and write manifest.json last; returns the manifest."""
        files = {p: sha256_file(self.root / p) for p in dataset_files(self.root)}
        manifest = {**manifest, "content_hash": content_hash(files), "files": files}
        write_json_atomic(self.root / "manifest.json", manifest)
        return manifest
