"""``dockbench run CONFIG -l ...``: generate and evaluate in one pass, keeping only a
sample of the images.

Render jobs run as for ``dockbench generate`` (same job function, same bytes). As soon
as a job's sequences are committed, each is evaluated by a pool of worker processes
(one per core, beside the render workers) which reads every image once: the localizers
get its pixels, the run records its sha256, then the images outside the ``--images``
sample are deleted (evalkit.stream). The render's shared passes (range, object index)
are hashed and pruned the same way. Disk therefore holds the images of the jobs in
flight, not of the whole suite.

Output folder OUT (datasets_spec/FORMAT.md, "Runs"):

* ``OUT/dataset/``  the dataset as generate writes it, minus the images and passes not
  kept; its ``manifest.json`` lists the files present;
* ``OUT/results/``  what ``dockbench evaluate`` writes (run.json, estimates.parquet,
  metrics.csv...); run.json's ``dataset.content_hash`` is the content hash of the whole
  dataset, images included: the one ``dockbench generate`` gives the same config;
* ``OUT/stream.json``  the whole dataset's ``files`` map (sha256 of every file, kept or
  not) but for the camera images not kept: the render worker never PNG-encodes those, it
  hands their pixels over raw and ``pixels`` maps them to :func:`datasets_spec.io.pixel_sha256`;
  a dataset generated later from the same config and seed is checked against both
  (:func:`evalkit.stream.check_against`: file by file, and decoded PNG by pixels);
* ``OUT/.stream/``  work files: per sequence estimates and hashes, per render the pass
  hashes. Interrupt at any point: a re-run resumes (committed sequences are not rendered
  again, evaluated ones not evaluated again).
"""

from __future__ import annotations

import json
import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path

from blendgen.pipeline import allocator
from blendgen.pipeline.passstore import PIXELS as PASS_PIXELS
from datasets_spec.io import content_hash, save_json_atomic, sha256_file
from evalkit import stream

STREAM_FORMAT, STREAM_VERSION = stream.STREAM_FORMAT, stream.STREAM_VERSION  # checked by stream.load_stream_summary
PIXELS_PREFIX = "pixels:"  # content_hash entry of an image hashed by its pixels
STREAM_JSON = "stream.json"


@dataclass
class RunRequest:
    """One ``dockbench run``: evaluate ``localizers`` (``params``: ``-p`` items) while
    generating; ``images``: ``none``, ``all`` or ``sample:N`` (per sequence);
    ``workers``: render processes (evaluation: one process per core)."""

    localizers: list[str]
    params: list[str] = field(default_factory=list)
    images: str = "sample:5"
    workers: int | None = None
    eval_workers: int | None = None
    preprocess: str | None = None
    progress: bool = True
    command: list[str] | None = None
    overwrite: bool = False


class _Streamer:
    """generate's hooks: evaluate each committed sequence in the pool, prune passes."""

    def __init__(self, req: RunRequest, pool: ProcessPoolExecutor):
        self.req, self.pool = req, pool
        self.futures: list[Future] = []
        self._lock = threading.Lock()

    @staticmethod
    def work(target) -> Path:
        return work_dir(target.out, target.exp.name)

    def committed(self, target, job, seqs) -> None:
        keep = stream.kept_indices([f["index"] for f in job.frames], self.req.images)
        self._passes(target, job, keep)
        manifest = target.manifest_base()
        for s in seqs:
            task = stream.SequenceTask(
                str(target.out),
                manifest,
                s.id,
                str(self.work(target)),
                self.req.localizers,
                self.req.params,
                keep,
                self.req.preprocess,
            )
            if stream.done(self.work(target), s.id):
                stream.prune_sequence(task)
                continue
            with self._lock:
                self.futures.append(self.pool.submit(stream.evaluate_sequence, task))

    def _passes(self, target, job, keep) -> None:
        """Hash the render's shared passes once (``renders/<key16>.json``), then delete
        those of frames not kept (every sequence of a job has the same frames)."""
        rdir = target.writer.render_dir(job.key)
        record = self.work(target) / "renders" / f"{rdir.name}.json"
        if not rdir.is_dir():
            return
        if record.relative_to(self.work(target)).as_posix() not in stream.recorded_files(self.work(target)):
            files = {p.relative_to(target.out).as_posix(): sha256_file(p) for p in sorted(rdir.rglob("*.png"))}
            pixels = {}
            if (rdir / PASS_PIXELS).is_file():  # passes of frames not kept: never encoded
                for line in (rdir / PASS_PIXELS).read_text().splitlines():
                    pixels.update(json.loads(line))
            record.parent.mkdir(parents=True, exist_ok=True)
            save_json_atomic(record.with_name(f"{rdir.name}{stream.PIXELS_SUFFIX}"), pixels)
            save_json_atomic(record, files)
            stream.record_files(self.work(target), [record.with_name(f"{rdir.name}{stream.PIXELS_SUFFIX}"), record])
        (rdir / PASS_PIXELS).unlink(missing_ok=True)
        if keep is not None:
            kept = set(keep)
            for p in rdir.rglob("*.png"):
                if int(p.stem) not in kept:
                    p.unlink(missing_ok=True)

    def before_finish(self) -> None:
        """Wait for every evaluation; the first failure is raised."""
        left = sum(not f.done() for f in self.futures)
        if left and self.req.progress:
            import sys

            print(f"evaluating: {left} of {len(self.futures)} sequences still running", file=sys.stderr)
        for f in list(self.futures):
            f.result()

    def known_sha256(self, target) -> dict[str, str]:
        return _recorded_hashes(self.work(target))

    def raw_images(self, job) -> list[int]:
        """The frames whose camera images are not kept: handed to the evaluator as raw
        pixels, never PNG-encoded (their PNG would be decoded once, hashed, deleted)."""
        indices = [f["index"] for f in job.frames]
        keep = stream.kept_indices(indices, self.req.images)
        return [] if keep is None else sorted(set(indices) - set(keep))


def _recorded_hashes(work: Path) -> dict[str, str]:
    """{path: sha256} of every image and pass hashed during the run."""
    out: dict[str, str] = {}
    work = Path(work)
    recorded = stream.recorded_files(work)
    renders = [p for p in sorted((work / "renders").glob("*.json")) if not p.name.endswith(stream.PIXELS_SUFFIX)]
    for p in sorted(work.glob("*.hashes.json")) + renders:
        out.update(stream.read_json_checked(work, p.relative_to(work).as_posix(), recorded))
    return out


def stream_run(items: list[tuple], req: RunRequest) -> list[dict]:
    """Generate and evaluate each ``(experiment, OUT)`` (jobs shared between them are
    rendered once); returns, per item, ``{"out", "manifest", "stream", "paths"}`` where
    ``paths`` are the results files (as :func:`evalkit.reports.results.save_run`)."""
    from blendgen.pipeline.generate import generate_many

    stream.parse_images(req.images)
    for e, o in items:
        _stamp_work(e, Path(o), req)
    n_eval = req.eval_workers or os.cpu_count() or 1
    # spawn: the workers are this process's children (their CPU shows in RUSAGE_CHILDREN);
    # they keep their freed heap as the render workers do (one suite trial: 1.14 M -> 0.22 M
    # minor page faults in all, ~1 s less kernel time)
    with ProcessPoolExecutor(n_eval, mp_context=get_context("spawn"), initializer=allocator.keep_heap) as pool:
        streamer = _Streamer(req, pool)
        try:
            manifests = generate_many(
                [(e, Path(o) / "dataset") for e, o in items], workers=req.workers, progress=req.progress, hooks=streamer
            )
        except BaseException:
            for f in streamer.futures:
                f.cancel()
            raise
    return [_finish(Path(o), m, work_dir(Path(o) / "dataset", e.name), req) for (e, o), m in zip(items, manifests)]


def work_dir(dataset: Path, name: str) -> Path:
    """``OUT/.stream/<experiment name>`` for the dataset ``OUT/dataset``."""
    return Path(dataset).parent / ".stream" / name


class RunDirError(FileExistsError):
    """OUT holds a run of other localizers (a user error: exit 2)."""


def _stamp_work(exp, out: Path, req: RunRequest) -> None:
    """Work files of another config or other localizers are never mixed in: with
    ``overwrite`` they are dropped with the dataset (its images may be pruned), else
    :class:`RunDirError`."""
    import shutil

    from blendgen.pipeline.generate import config_digest

    work = work_dir(Path(out) / "dataset", exp.name)
    stamp = json.dumps(
        {
            "config": config_digest(exp),
            "localizers": req.localizers,
            "params": req.params,
            "preprocess": req.preprocess,
        },
        sort_keys=True,
    )
    f = work / "stamp.json"
    if f.is_file() and f.read_text() != stamp:
        if not req.overwrite:
            raise RunDirError(
                f"{out} holds a run of other localizers, params or config (its images may "
                "be gone); choose a new -o or pass --overwrite to start over"
            )
        shutil.rmtree(work)
        shutil.rmtree(Path(out) / "dataset", ignore_errors=True)
    if req.overwrite and any(work.glob(f"*{stream.LEGACY_SUFFIX}")):
        shutil.rmtree(work)
        shutil.rmtree(Path(out) / "dataset", ignore_errors=True)
    stream.refuse_legacy(work)
    work.mkdir(parents=True, exist_ok=True)
    f.write_text(stamp)


def _finish(out: Path, manifest: dict, work: Path, req: RunRequest) -> dict:
    """The run's results folder and stream.json from the per-sequence work files."""
    from evalkit import registry
    from evalkit.reports.outdir import results_dir
    from evalkit.reports.provenance import localizer_record
    from evalkit.reports.results import EvalSettings, RunRecord, save_run

    seq_ids = [s["id"] for s in manifest["sequences"]]
    df, _ = stream.load_results(work, seq_ids)
    pixels = stream.recorded_pixels(work)
    files = {**_recorded_hashes(work), **manifest["files"]}
    every = {**files, **{p: f"{PIXELS_PREFIX}{h}" for p, h in pixels.items()}}
    full = {**manifest, "files": dict(sorted(every.items())), "content_hash": content_hash(every)}
    kw = registry.parse_params(list(req.params))
    records = [localizer_record(n, registry.params_for(n, kw, req.localizers)) for n in req.localizers]
    ds = stream.run_record_dataset(out / "dataset", full)
    settings = EvalSettings(d_min_rel_m=ds.d_min_rel_m)
    options = {
        "params": list(req.params),
        "isolate": None,
        "frame_timeout_s": None,
        "preprocess": req.preprocess,
        "verify": True,
        "images": req.images,
        "streamed": True,
    }
    cpu0 = time.process_time()
    with results_dir(out / "results", overwrite=True) as tmp:
        paths, _ = save_run(df, tmp, RunRecord(ds, records, settings, req.command, options))
    paths = {k: out / "results" / p.relative_to(tmp) for k, p in paths.items()}
    summary = {
        "format": STREAM_FORMAT,
        "format_version": STREAM_VERSION,
        "name": manifest["name"],
        "version": manifest["version"],
        "images": req.images,
        "content_hash": full["content_hash"],
        "kept_content_hash": manifest["content_hash"],
        "n_files": len(every),
        "n_kept": len(manifest["files"]),
        "files": dict(sorted(files.items())),
        "pixels": dict(sorted(pixels.items())),
    }
    save_json_atomic(out / STREAM_JSON, summary)
    return {
        "out": out,
        "manifest": manifest,
        "stream": summary,
        "paths": paths,
        "finish_cpu_s": time.process_time() - cpu0,
    }
