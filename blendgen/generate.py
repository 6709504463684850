"""``dockbench generate``: config -> versioned dataset on disk.

Validation happens before anything is written. Finished sequences of an earlier,
interrupted run are kept and not rendered again.
"""
from __future__ import annotations

import json
import math
import platform
import shutil
from importlib import metadata
from pathlib import Path

import numpy as np

from blendgen import executor, markers as mk, plan
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
              writer: DatasetWriter, work: Path) -> dict:
    c = exp.camera
    return {
        "scene": job.scene, "fidelity": exp.render.fidelity, "render": render, "frames": job.frames,
        "camera": {"width": c.width, "height": c.height, "hfov_rad": math.radians(c.hfov_deg), "K": K.tolist()},
        "gt": {"T_world_dock": job.scene["dock"]["T_world_dock"], "markers": markers},
        "outputs": [{"seq_dir": str(writer.tmp_dir(s.id).resolve()), "rel": f"sequences/{s.id}", "post": s.post}
                    for s in job.sequences],
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


def generate(exp: Experiment, out: Path, workers: int | None = None, progress: bool = True) -> dict:
    """Render the whole experiment into ``out``; returns the manifest."""
    out = Path(out)
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
    todo = [j for j in all_jobs if not all(writer.is_done(s.id) for s in j.sequences)]
    n_workers = workers or executor.default_workers(len(todo))
    render = plan.render_settings(exp, executor.threads_per_worker(n_workers))
    files = {}
    for j in todo:
        for s in j.sequences:
            shutil.rmtree(writer.tmp_dir(s.id), ignore_errors=True)
        files[executor.write_job(_job_dict(j, exp, K, render, markers, writer, work),
                                 work / "jobs" / f"{j.sequences[0].id}.json")] = j

    def on_done(jf: Path):
        for s in files[jf].sequences:
            writer.commit_sequence(s.id, len(files[jf].frames))

    def count() -> int:
        return sum(_lines(writer.tmp_dir(s.id) / "frames.jsonl") + _lines(out / "sequences" / s.id / "frames.jsonl")
                   for j in todo for s in j.sequences[:1])

    total = sum(len(j.frames) for j in todo)
    if total and progress:
        with executor.Progress(total, count):
            executor.run_local(list(files), work / "logs", n_workers, on_done)
    elif total:
        executor.run_local(list(files), work / "logs", n_workers, on_done)
    return writer.finish(manifest_base(exp, K, markers, scene, all_jobs))


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
        shutil.rmtree(out)
        return
    what = "a dataset made from a different config" if ours else "files that are not a dockbench dataset"
    raise FileExistsError(f"{out} holds {what}; choose a new -o directory"
                          + (" or pass --overwrite" if ours else ""))


def stamp_config(exp: Experiment, out: Path) -> None:
    (out / ".work").mkdir(parents=True, exist_ok=True)
    (out / ".work" / "config.sha256").write_text(config_digest(exp) + "\n")
