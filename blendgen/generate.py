"""``dockbench generate``: config -> versioned dataset on disk.

Validation happens before anything is written. Finished sequences of an earlier,
interrupted run are kept and not rendered again.
"""
from __future__ import annotations

import json
import math
import os
import platform
import shutil
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path

import numpy as np

from blendgen import executor as ex, markers as mk, plan
from blendgen.spec import Experiment
from blendgen.writer import FORMAT, SPEC_VERSION, DatasetWriter


def versions() -> dict:
    """Generator versions recorded in the manifest (read from metadata: no bpy import)."""
    def v(name):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None
    return {"dockbench": v("dockbench"), "bpy": v("bpy"), "opencv": v("opencv-contrib-python-headless"),
            "numpy": v("numpy"), "python": platform.python_version()}


def write_textures(exp: Experiment, root: Path) -> dict[str, str]:
    """Marker textures into ``assets/`` (part of the dataset: printable); id -> absolute path."""
    out = {}
    for spec in exp.scene.dock.markers:
        tex = mk.texture_for(spec)
        if tex is not None:
            p = root / "assets" / f"marker_{spec.id}.png"
            mk.write_texture(tex, p)
            out[spec.id] = str(p.resolve())
    return out


def _job_dict(job: plan.RenderJob, exp: Experiment, K: np.ndarray, render: dict, markers: list[dict],
              writer: DatasetWriter, work: Path, seqs: list) -> dict:
    """The worker's job file; ``seqs`` are the job's sequences still to write (a
    resumed job whose render is shared may have committed some already)."""
    c = exp.camera
    return {
        "scene": job.scene, "fidelity": exp.render.fidelity, "render": render, "frames": job.frames,
        "camera": {"width": c.width, "height": c.height, "hfov_rad": math.radians(c.hfov_deg), "K": K.tolist()},
        "gt": {"T_world_dock": job.scene["dock"]["T_world_dock"], "markers": markers},
        "outputs": [{"seq_dir": str(writer.tmp_dir(s.id).resolve()), "rel": f"sequences/{s.id}", "post": s.post}
                    for s in seqs],
        "log": str((work / "logs" / f"{job.sequences[0].id}.blender.log").resolve()),
        "timing_out": str((work / "timing" / f"{job.sequences[0].id}.json").resolve()),
    }


def manifest_base(exp: Experiment, K: np.ndarray, markers: list[dict], scene: dict,
                  jobs: list[plan.RenderJob]) -> dict:
    c = exp.camera
    seqs = [{"id": s.id, "path": f"sequences/{s.id}", "condition": s.condition,
             "conditions": {"label": s.condition, **s.conditions}, "trial": s.trial,
             "trajectory": s.trajectory, "n_frames": len(j.frames)} for j in jobs for s in j.sequences]
    return {"format": FORMAT, "spec_version": SPEC_VERSION, "name": exp.name, "version": exp.version,
            "generator": versions(), "config": exp.model_dump(mode="json"), "seed": exp.seed,
            "camera": {"width": c.width, "height": c.height, "K": K.tolist(), "fps": c.fps,
                       "latency_s": c.latency_s, "hfov_deg": c.hfov_deg, "distortion": c.distortion},
            "dock": {"T_world_dock": scene["dock"]["T_world_dock"]},
            "markers": markers, "object_index": plan.object_index_names(markers, exp),
            "d_min_rel_m": exp.d_min_rel_m, "sequences": seqs}


def generate(exp: Experiment, out: Path, workers: int | None = None, progress: bool = True,
             executor: str = "local", ray_address: str | None = None) -> dict:
    """Render the whole experiment into ``out``; returns the manifest.

    ``executor``: ``"local"`` (process pool on this machine; ``workers`` processes)
    or ``"ray"`` (Ray tasks; ``ray_address`` of a cluster, or None for a local Ray
    instance; ``workers`` caps the tasks in flight). Both run the same job
    function and write the same bytes. Safe to interrupt (Ctrl-C, SIGTERM, kill):
    finished sequences are kept and a re-run resumes."""
    if executor not in ex.EXECUTORS:
        raise ex.ExecutorError(f"unknown executor {executor!r}; choose one of {', '.join(ex.EXECUTORS)}")
    if executor == "ray":
        ex.require_ray()                       # user errors before anything is written
        if ray_address:
            ex.check_ray_address(ray_address)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with _exclusive(out), ex.sigterm_as_interrupt():
        return _generate(exp, out, workers, progress, executor, ray_address)


def _generate(exp: Experiment, out: Path, workers: int | None, progress: bool, kind: str,
              ray_address: str | None) -> dict:
    writer = DatasetWriter(out)
    writer.prepare()
    stamp_config(exp, out)
    work = out / ".work"
    for sub in ("jobs", "logs", "timing"):
        (work / sub).mkdir(parents=True, exist_ok=True)
    K = plan.camera_K(exp)
    markers = plan.manifest_markers(exp)
    scene = plan.scene_description(exp, markers, write_textures(exp, out))
    all_jobs = plan.plan_jobs(exp, scene, plan.render_settings(exp, 1))
    pending = {j.sequences[0].id: [s for s in j.sequences if not writer.is_done(s.id)] for j in all_jobs}
    todo = [j for j in all_jobs if pending[j.sequences[0].id]]
    n_workers, threads = ex.slots(kind, len(todo), workers, exp.render.threads)
    render = plan.render_settings(exp, threads)
    files = {}
    for j in todo:
        seqs = pending[j.sequences[0].id]
        for s in seqs:
            shutil.rmtree(writer.tmp_dir(s.id), ignore_errors=True)
        jf = ex.write_job(_job_dict(j, exp, K, render, markers, writer, work, seqs),
                          work / "jobs" / f"{j.sequences[0].id}.json")
        files[jf] = (j, seqs)

    def on_done(jf: Path):
        j, seqs = files[jf]
        for s in seqs:
            writer.commit_sequence(s.id, len(j.frames))

    def count() -> int:
        return sum(_lines(writer.tmp_dir(s.id) / "frames.jsonl") + _lines(out / "sequences" / s.id / "frames.jsonl")
                   for j, seqs in files.values() for s in seqs[:1])

    def run():
        if kind == "ray":
            ex.run_ray(list(files), work / "logs", on_done, ray_address, threads, n_workers)
        else:
            ex.run_local(list(files), work / "logs", n_workers, on_done)

    total = sum(len(j.frames) for j in todo)
    if total and progress:
        with ex.Progress(total, count, "rendering" if kind == "local" else "rendering (ray)"):
            run()
    elif total:
        run()
    return writer.finish(manifest_base(exp, K, markers, scene, all_jobs))


@contextmanager
def _exclusive(out: Path):
    """One generate per output directory: a second one fails at once (user error).
    The lock is released when the process ends, however it ends."""
    import fcntl
    (out / ".work").mkdir(parents=True, exist_ok=True)
    with open(out / ".work" / "lock", "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            raise FileExistsError(f"{out} is being written by another dockbench generate "
                                  f"(pid {fh.read().strip() or '?'}); wait for it or stop it") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


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
    import hashlib
    return hashlib.sha256(json.dumps(exp.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()


def check_out_dir(exp: Experiment, out: Path, overwrite: bool) -> None:
    """Refuse to mix datasets: OUT must be new, empty, or made from the same config.

    Raises FileExistsError (a user error) before anything is written; with
    ``overwrite`` an existing dockbench dataset is removed first."""
    out = Path(out)
    if not out.exists() or not any(out.iterdir()):
        return
    stamp = out / ".work" / "config.sha256"
    ours = stamp.exists() or (out / "manifest.json").exists()
    same = stamp.exists() and stamp.read_text().strip() == config_digest(exp)
    if same:
        return
    if ours and overwrite:
        with _exclusive(out):               # never delete a dataset another run is writing
            pass
        shutil.rmtree(out)
        return
    what = "a dataset made from a different config" if ours else "files that are not a dockbench dataset"
    raise FileExistsError(f"{out} holds {what}; choose a new -o directory"
                          + (" or pass --overwrite" if ours else ""))


def stamp_config(exp: Experiment, out: Path) -> None:
    (out / ".work").mkdir(parents=True, exist_ok=True)
    (out / ".work" / "config.sha256").write_text(config_digest(exp) + "\n")
