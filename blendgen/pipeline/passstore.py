"""Passes of one render written once and shared by every sequence it feeds (FORMAT.md 1.1).

A render job feeds up to ~10 sequences (conditions that differ only in image space),
possibly in several datasets at once (``reproduce all``). Its range and object-index
passes are the same bytes for all of them, so each dataset holds them once under
``renders/<key16>/{depth,index}/<frame>.png`` and every sequence's ``frames.jsonl``
points there. The worker writes them into ``renders/.<key16>.tmp/`` of the first
dataset, hard-links the files into the other datasets' temp dirs (a copy when the
filesystem refuses links), and the parent renames each temp dir into place before it
commits the sequences (:meth:`DatasetWriter.commit_render`). A dataset that already
has the render (a resumed run) is referenced, not rewritten. Frames a streaming run does
not keep (``raw_images``) are not encoded at all: the sha256 of their pixels as the PNG
would hold them (:func:`datasets_spec.io.pixel_sha256`) goes to ``.pixels.jsonl``.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from datasets_spec import io as dsio

# {dataset path: pixel sha256} per line, of the passes of frames a streaming run does not keep
# (never encoded); a dot-name, so never part of the dataset; the run records it, then deletes it
PIXELS = ".pixels.jsonl"


@dataclass
class PassStore:
    """Where one job writes its shared passes.

    ``rel``: the dataset-relative directory (``renders/<key16>``), the same in every
    dataset; ``dirs``: absolute temp dirs still to fill (empty when every dataset has
    the render already); ``depth``/``index``: which passes are written at all."""

    rel: str
    dirs: list[Path]
    depth: bool
    index: bool
    raw: frozenset = frozenset()  # frames not kept (dockbench run): hashed, never encoded

    @classmethod
    def from_job(cls, job) -> PassStore | None:
        """The job's ``passes`` entry (a ``plan.JobRecord``, or a dict with the
        :func:`job_entry` dict), or None without passes."""
        p = job.get("passes") if isinstance(job, dict) else job.passes
        if p is not None and not isinstance(p, dict):
            p = p.model_dump()
        if not p or not (p["depth"] or p["index"]):
            return None
        raw = job.get("raw_images", []) if isinstance(job, dict) else job.raw_images
        store = cls(p["rel"], [Path(d) for d in p["dirs"]], p["depth"], p["index"], frozenset(raw))
        for d in store.dirs:
            for sub, on in (("depth", store.depth), ("index", store.index)):
                if on:
                    (d / sub).mkdir(parents=True, exist_ok=True)
        return store

    def write(self, frame_index: int, passes: dict) -> dict:
        """Write one frame's range (``passes['range_m']`` (H,W) m) and index ((H,W) uint8)
        passes; returns the frame record's ``depth`` / ``object_index`` paths."""
        name = f"{frame_index:06d}.png"
        paths, pixels = {}, {}
        for key, sub, on, save, arr in (
            ("depth", "depth", self.depth, dsio.save_range, "range_m"),
            ("object_index", "index", self.index, dsio.save_index, "index"),
        ):
            if not on:
                continue
            paths[key] = f"{self.rel}/{sub}/{name}"
            if self.dirs and frame_index in self.raw:
                pixels[paths[key]] = dsio.pixel_sha256(
                    dsio.range_to_units(passes[arr]) if sub == "depth" else passes[arr]
                )
            elif self.dirs:
                first = self.dirs[0] / sub / name
                save(first, passes[arr])
                for d in self.dirs[1:]:
                    _link_or_copy(first, d / sub / name)
        if pixels:
            for d in self.dirs:
                with open(d / PIXELS, "a") as fh:
                    fh.write(json.dumps(pixels) + "\n")
        return paths


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        if dst.exists():
            dst.unlink()
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def job_entry(render_key: str, targets: list[tuple[Path, bool]], write_depth: bool, write_index: bool) -> dict:
    """The job file's ``passes`` entry. ``targets``: (dataset's temp render dir, whether
    that dataset still needs the render written) for every dataset the job feeds."""
    return {
        "rel": dsio.render_dir_name(render_key),
        "depth": write_depth,
        "index": write_index,
        "dirs": [str(Path(d).resolve()) for d, needed in targets if needed],
    }
