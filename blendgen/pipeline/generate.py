"""``dockbench generate``: config -> versioned dataset on disk.

Validation happens before anything is written. Finished sequences of an earlier,
interrupted run are kept and not rendered again.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import shutil
from contextlib import ExitStack
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from blendgen import markers as mk
from blendgen.config.effective import effective
from blendgen.config.models import Experiment, OutputDirError
from blendgen.pipeline import executor as ex
from blendgen.pipeline import passstore, plan
from blendgen.pipeline.writer import FORMAT, DatasetWriter
from datasets_spec.io import SPEC_VERSION, path_inside


def versions() -> dict:
    """Generator versions recorded in the manifest (read from metadata: no bpy import)."""

    def v(name):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    return {
        "dockbench": v("dockbench"),
        "bpy": v("bpy"),
        "opencv": v("opencv-contrib-python-headless"),
        "numpy": v("numpy"),
        "python": platform.python_version(),
    }


def write_textures(exp: Experiment, root: Path) -> dict[str, str]:
    """Marker textures into ``assets/`` (part of the dataset: printable); id -> absolute path."""
    out = {}
    for spec in exp.scene.dock.markers:
        tex = mk.texture_for(spec)
        if tex is not None:
            p = path_inside(root, f"assets/marker_{spec.id}.png", "marker texture")
            mk.write_texture(tex, p)
            out[spec.id] = str(p.resolve())
    return out


def _job_record(
    t: _Target, job: plan.RenderJob, render: dict, parts: list, raw_images: list[int] | None = None
) -> plan.JobRecord:
    """The worker's job record. ``parts`` are (target, job, sequences still to write) of
    every dataset fed by this render (a resumed shared job may have committed some);
    ``raw_images``: frame indices whose camera images are not PNG-encoded (:class:`Hooks`)."""
    c = t.exp.camera
    first = job.sequences[0].id
    datasets = list({id(pt): pt for pt, _, _ in parts}.values())
    passes = passstore.job_entry(
        job.key,
        [(pt.writer.render_tmp_dir(job.key), not pt.writer.has_render(job.key)) for pt in datasets],
        render["write_depth"],
        render["write_index"],
    )
    return plan.JobRecord(
        scene=job.scene,
        fidelity=t.exp.render.fidelity,
        render=render,
        frames=job.frames,
        camera=plan.JobCamera(width=c.width, height=c.height, hfov_rad=math.radians(c.hfov_deg), K=t.K.tolist()),
        gt=plan.JobTruth(T_world_dock=job.scene["dock"]["T_world_dock"], markers=t.markers),
        outputs=[
            plan.JobOutput(seq_dir=str(pt.writer.tmp_dir(s.id).resolve()), rel=f"sequences/{s.id}", post=s.post)
            for pt, _, seqs in parts
            for s in seqs
        ],
        passes=plan.JobPasses(**passes),
        log=str(path_inside(t.work, f"logs/{first}.blender.log", "render log")),
        timing_out=str(path_inside(t.work, f"timing/{first}.json", "timing file")),
        raw_images=list(raw_images or []),
    )


def manifest_base(exp: Experiment, K: np.ndarray, markers: list[dict], scene: dict, jobs: list[plan.RenderJob]) -> dict:
    """The manifest without its ``files``: ``config`` as given (nulls kept: the config's identity),
    ``effective_config`` as rendered (config/effective.py: every mode-dependent null resolved)."""
    c = exp.camera
    seqs = [
        {
            "id": s.id,
            "path": f"sequences/{s.id}",
            "condition": s.condition,
            "conditions": {"label": s.condition, **s.post.model_dump(mode="json", exclude_none=True)},
            "trial": s.trial,
            "trajectory": s.trajectory,
            "n_frames": len(j.frames),
            "end": j.end,
        }
        for j in jobs
        for s in j.sequences
    ]
    return {
        "format": FORMAT,
        "spec_version": SPEC_VERSION,
        "name": exp.name,
        "version": exp.version,
        "generator": versions(),
        "config": exp.model_dump(mode="json"),
        "effective_config": effective(exp).model_dump(mode="json"),
        "seed": exp.seed,
        "camera": {
            "width": c.width,
            "height": c.height,
            "K": K.tolist(),
            "fps": c.fps,
            "latency_s": c.latency_s,
            "hfov_deg": c.hfov_deg,
            "distortion": c.distortion,
        },
        "dock": {"T_world_dock": scene["dock"]["T_world_dock"]},
        "markers": markers,
        "object_index": plan.object_index_names(markers, exp),
        "d_min_rel_m": exp.d_min_rel_m,
        "sequences": seqs,
        **_reference_caustics(jobs),
    }


def _reference_caustics(jobs: list[plan.RenderJob]) -> dict:
    """The reference's caustic method and photon budget, when its renders carry caustics."""
    cfg = next(
        (j.scene["water_surface"]["caustics"] for j in jobs if (j.scene.get("water_surface") or {}).get("caustics")),
        None,
    )
    if cfg is None:
        return {}
    return {
        "reference_caustics": {
            **cfg,
            "method": "per frame, the photon map of the frame's surface as the "
            "light texture of a far spot lighting pool and dock "
            "(blendgen/blender/caustic_sun.py)",
        }
    }


def generate(
    exp: Experiment,
    out: Path,
    workers: int | None = None,
    progress: bool = True,
    executor: str = "local",
    ray_address: str | None = None,
) -> dict:
    """Render the whole experiment into ``out``; returns the manifest.

    ``executor``: ``"local"`` (process pool on this machine; ``workers`` processes)
    or ``"ray"`` (Ray tasks; ``ray_address`` of a cluster, or None for a local Ray
    instance; ``workers`` caps the tasks in flight). Both run the same job
    function and write the same bytes. Safe to interrupt (Ctrl-C, SIGTERM, kill):
    finished sequences are kept and a re-run resumes."""
    return generate_many([(exp, out)], workers, progress, executor, ray_address)[0]


class Hooks:
    """What ``dockbench run`` does while a dataset is written (no-ops here).

    ``committed(target, job, seqs)``: sequences ``seqs`` (``plan`` sequences of ``job``)
    of ``target`` are complete on disk, render passes included (called from a worker
    thread, and at the start for sequences an earlier run finished); ``before_finish()``:
    every job is done, the manifests are about to be hashed and written (under the
    output lock). ``known_sha256(target)``: {dataset-relative path: sha256} already
    computed from the bytes on disk, not hashed again by the manifest."""

    def committed(self, target: _Target, job: plan.RenderJob, seqs: list) -> None:
        pass

    def before_finish(self) -> None:
        pass

    def known_sha256(self, target: _Target) -> dict[str, str]:
        return {}

    def raw_images(self, job: plan.RenderJob) -> list[int]:
        """Frame indices of ``job`` whose camera images are handed over as raw pixels, not
        PNG (``dockbench run``: the frames it does not keep); generate: none."""
        return []


def generate_many(
    items: list[tuple[Experiment, Path]],
    workers: int | None = None,
    progress: bool = True,
    executor: str = "local",
    ray_address: str | None = None,
    hooks: Hooks | None = None,
) -> list[dict]:
    """Render several datasets at once, rendering each camera path once for all of them:
    jobs of different experiments with the same scene, poses and render settings are
    merged (e.g. the article's turbidity, depth and occlusion experiments share their
    trajectories). Returns the manifests in the order of ``items``. ``hooks``: see
    :class:`Hooks` (``dockbench run`` evaluates sequences as they are committed)."""
    hooks = hooks or Hooks()
    if executor not in ex.EXECUTORS:
        raise ex.ExecutorError(f"unknown executor {executor!r}; choose one of {', '.join(ex.EXECUTORS)}")
    for exp, _ in items:
        plan.check_before_writing(exp)  # user errors before anything is written
    if executor == "ray":
        ex.require_ray()
        if ray_address:
            ex.check_ray_address(ray_address)
    else:
        ex.require_render_stack()  # the workers of this machine need bpy
    with ExitStack() as stack:
        if executor == "ray":  # connected before any folder is made (a bad address writes nothing)
            stack.enter_context(ex.ray_session(ray_address))
        for _, out in items:
            check_out_location(Path(out))
            try:
                Path(out).mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise OutputDirError(
                    f"-o {out}: cannot create the output folder ({e.strerror}); choose a writable folder"
                ) from None
            stack.enter_context(_exclusive(Path(out)))
        stack.enter_context(ex.sigterm_as_interrupt())
        targets = [_Target.prepare(exp, Path(out)) for exp, out in items]
        for t in targets:  # finished by an earlier run
            for j in t.jobs:
                done = [s for s in j.sequences if t.writer.is_done(s.id)]
                if done:
                    hooks.committed(t, j, done)
        _render(targets, workers, progress, executor, ray_address, hooks)
        hooks.before_finish()
        return [t.writer.finish(t.manifest_base(), hooks.known_sha256(t)) for t in targets]


@dataclass
class _Target:
    """One dataset being generated: its writer, work dir, planned jobs. ``exp`` is the config
    as given (manifest, resume stamp); everything rendered is planned from ``effective(exp)``."""

    exp: Experiment
    out: Path
    writer: DatasetWriter
    work: Path
    K: np.ndarray
    markers: list
    scene: dict
    jobs: list

    @classmethod
    def prepare(cls, exp: Experiment, out: Path) -> _Target:
        writer = DatasetWriter(out)
        writer.prepare()
        stamp_config(exp, out)
        work = out / ".work"
        for sub in ("jobs", "logs", "timing"):
            (work / sub).mkdir(parents=True, exist_ok=True)
        eff = effective(exp)  # mode-dependent defaults resolved once
        markers = plan.manifest_markers(eff)
        scene = plan.scene_description(eff, markers, write_textures(eff, out))
        return cls(exp, out, writer, work, plan.camera_K(eff), markers, scene, plan.plan_jobs(eff, scene))

    def manifest_base(self) -> dict:
        """The manifest of this dataset without its ``files`` map (see :func:`manifest_base`)."""
        return manifest_base(self.exp, self.K, self.markers, self.scene, self.jobs)


def _merged_jobs(targets: list[_Target]) -> dict[str, list]:
    """render key (plan.job_key, the same in every dataset that needs this render) ->
    [(target, job, sequences still to write)], finished sequences left out."""
    merged: dict[str, list] = {}
    for t in targets:
        for j in t.jobs:
            seqs = [s for s in j.sequences if not t.writer.is_done(s.id)]
            if seqs:
                merged.setdefault(j.key, []).append((t, j, seqs))
    return merged


def _render(
    targets: list[_Target], workers: int | None, progress: bool, kind: str, ray_address: str | None, hooks: Hooks
) -> None:
    merged = _merged_jobs(targets)
    n_workers, threads = ex.slots(kind, len(merged), workers, targets[0].exp.render.threads)
    files = {}
    for parts in merged.values():
        t, j, _ = parts[0]
        for pt, _, seqs in parts:
            shutil.rmtree(pt.writer.render_tmp_dir(j.key), ignore_errors=True)
            for s in seqs:
                shutil.rmtree(pt.writer.tmp_dir(s.id), ignore_errors=True)
        render = plan.render_settings(effective(t.exp), threads)
        # named by dataset and first sequence: unique across the datasets of one run
        jf = ex.write_job(
            _job_record(t, j, render, parts, hooks.raw_images(j)),
            path_inside(t.work, f"jobs/{t.exp.name}--{j.sequences[0].id}.json", "job file"),
        )
        files[jf] = parts

    def on_done(jf: Path):
        for pt, j, seqs in files[jf]:
            pt.writer.commit_render(j.key)  # before the sequences that reference it
            for s in seqs:
                pt.writer.commit_sequence(s.id, len(j.frames))
            hooks.committed(pt, j, seqs)

    def count() -> int:
        return sum(
            _lines(pt.writer.tmp_dir(s.id) / "frames.jsonl") + _lines(pt.out / "sequences" / s.id / "frames.jsonl")
            for parts in files.values()
            for pt, _, seqs in parts[:1]
            for s in seqs[:1]
        )

    def run():
        logs = targets[0].work / "logs"
        # longest camera paths first: the last jobs are the short ones, so no slot idles long at the end
        order = sorted(files, key=lambda jf: -len(files[jf][0][1].frames))
        if kind == "ray":
            ex.run_ray(order, logs, on_done, ray_address, threads, n_workers)
        else:
            ex.run_local(order, logs, n_workers, on_done)

    total = sum(len(parts[0][1].frames) for parts in files.values())
    if total and progress:
        with ex.Progress(total, count, "rendering" if kind == "local" else "rendering (ray)"):
            run()
    elif total:
        run()


def _exclusive(out: Path):
    """One writer per output directory, whatever the command (:func:`datasets_spec.outdir.lock`):
    a second one fails at once (user error). Released when the process ends, however it ends."""
    from datasets_spec.outdir import lock

    return lock(out, "generate")


def _lines(p: Path) -> int:
    try:
        with open(p, "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def timing_summary(out: Path) -> dict:
    """Median seconds per stage over every frame of the last run (from the workers' timing files)."""
    acc: dict[str, list[float]] = {}
    for p in (Path(out) / ".work" / "timing").glob("*.json"):
        t = json.loads(p.read_text())
        for k, v in t.items():
            acc.setdefault(k, []).extend(v if isinstance(v, list) else [v])
    return {k: float(np.median(v)) for k, v in acc.items()}


def config_digest(exp: Experiment) -> str:
    """sha256 of the resolved config: what a resumable output directory must match."""
    return hashlib.sha256(json.dumps(exp.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()


def check_out_location(out: Path) -> None:
    """Refuse an output folder inside dockbench's source tree, the project folder itself, a
    pseudo file system, a path through a file, an unwritable place, or inside another dataset,
    before anything is written (:class:`OutputDirError`, a user error; the rule is
    :mod:`datasets_spec.outdir`, shared by every writing command)."""
    from datasets_spec import outdir

    try:
        outdir.check_location(out)
        outdir.refuse_dataset(out, "generate")
    except outdir.OutDirError as exc:
        raise OutputDirError(str(exc)) from None


def check_out_dir(exp: Experiment, out: Path, overwrite: bool) -> None:
    """Refuse to mix datasets: OUT must be new, empty, or made from the same config.

    Raises FileExistsError (a user error) before anything is written; with
    ``overwrite`` an existing dockbench dataset is removed first."""
    out = Path(out)
    check_out_location(out)
    if not out.exists() or not any(out.iterdir()):
        return
    stamp = out / ".work" / "config.sha256"
    ours = stamp.exists() or (out / "manifest.json").exists()
    same = stamp.exists() and stamp.read_text().strip() == config_digest(exp)
    if same:
        return
    if ours and overwrite:
        with _exclusive(out):  # never delete a dataset another run is writing
            pass
        shutil.rmtree(out)
        return
    what = "a dataset made from a different config" if ours else "files that are not a dockbench dataset"
    raise FileExistsError(f"{out} holds {what}; choose a new -o directory" + (" or pass --overwrite" if ours else ""))


def stamp_config(exp: Experiment, out: Path) -> None:
    (out / ".work").mkdir(parents=True, exist_ok=True)
    (out / ".work" / "config.sha256").write_text(config_digest(exp) + "\n")
