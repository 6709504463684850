"""Atomic, resumable dataset writing (datasets_spec/FORMAT.md).

- the passes of one render (range, object index) go to ``renders/.<key16>.tmp/`` and
  are renamed into place before the sequences that reference them are committed;
- a sequence is rendered into ``sequences/.<id>.tmp/`` and renamed into place only
  when complete, so ``sequences/<id>/`` is always whole; a re-run skips it;
- leftovers of an interrupted run (``.tmp`` dirs) are removed before resuming;
- ``manifest.json`` is written last (temp file + rename) with the sha256 of every
  file; names starting with ``.`` (work files) are not part of the dataset.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from datasets_spec.io import (
    FORMAT_NAME,
    MANIFEST,
    RENDERS,
    DatasetError,
    content_hash,
    dataset_files,
    path_inside,
    render_dir_name,
    save_json_atomic,
    sha256_file,
)

FORMAT = FORMAT_NAME


class DatasetWriter:
    """Owns one dataset directory during generation."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.seq_root = self.root / "sequences"

    def prepare(self) -> None:
        """Create the layout and drop partial sequences of an interrupted run."""
        self.seq_root.mkdir(parents=True, exist_ok=True)
        for d in (*self.seq_root.glob(".*.tmp"), *(self.root / RENDERS).glob(".*.tmp")):
            shutil.rmtree(d, ignore_errors=True)
        (self.root / MANIFEST).unlink(missing_ok=True)

    def _child(self, name: str, what: str) -> Path:
        """``sequences/<name>`` resolved, proven to be a direct child of ``sequences/``."""
        path = path_inside(self.root, f"sequences/{name}", what)
        if "/" in name or "\\" in name or path.parent != self.seq_root.resolve():
            raise DatasetError(
                f"{self.seq_root / name}: {what} {name!r} is not a folder directly in "
                f"{self.seq_root}, outside the dataset folder layout"
            )
        return path

    def seq_dir(self, seq_id: str) -> Path:
        """``sequences/<id>``, proven inside the dataset folder (ids come from the config)."""
        return self._child(seq_id, "sequence folder")

    def is_done(self, seq_id: str) -> bool:
        return (self.seq_dir(seq_id) / "frames.jsonl").exists()

    def tmp_dir(self, seq_id: str) -> Path:
        """``sequences/.<id>.tmp`` (proven inside the dataset folder)."""
        return self._child(f".{seq_id}.tmp", "sequence work folder")

    def render_dir(self, render_key: str) -> Path:
        """Final directory of one render's shared passes (``renders/<key16>``)."""
        return self.root / render_dir_name(render_key)

    def render_tmp_dir(self, render_key: str) -> Path:
        d = self.render_dir(render_key)
        return d.with_name(f".{d.name}.tmp")

    def has_render(self, render_key: str) -> bool:
        return self.render_dir(render_key).is_dir()

    def commit_render(self, render_key: str) -> None:
        """Rename a finished render's temp pass dir into place (no-op if it was not written)."""
        tmp = self.render_tmp_dir(render_key)
        if tmp.is_dir() and not self.has_render(render_key):
            os.replace(tmp, self.render_dir(render_key))
        elif tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)

    def commit_sequence(self, seq_id: str, n_frames: int) -> None:
        """Check the temp sequence is whole, then rename it into place."""
        tmp = self.tmp_dir(seq_id)
        lines = (tmp / "frames.jsonl").read_text().splitlines()
        if len(lines) != n_frames:
            raise RuntimeError(f"sequence {seq_id}: {len(lines)} of {n_frames} frames written")
        os.replace(tmp, self.seq_dir(seq_id))

    def finish(self, manifest: dict, known_sha256: dict[str, str] | None = None) -> dict:
        """Hash every file and write manifest.json last; returns the manifest.

        ``known_sha256``: hashes already taken from the files' bytes in this run (``dockbench
        run`` hashes each image as the localizers read it), not computed twice."""
        known = known_sha256 or {}
        files = {p: known.get(p) or sha256_file(self.root / p) for p in dataset_files(self.root)}
        manifest = {**manifest, "content_hash": content_hash(files), "files": files}
        save_json_atomic(self.root / MANIFEST, manifest)
        return manifest
