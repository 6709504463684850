"""Render worker: ``python -m blendgen.blender.worker JOB.json``.

One process builds the scene once (persistent data keeps the BVH warm) and
renders every frame of one camera path. After each frame the clean passes are
turned into the camera image of every sequence that shares them, and each
sequence's ``frames.jsonl`` grows by one line (the parent counts those lines for
progress). Blender's own chatter on stdout is sent to the job's log file.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _quiet_stdout(log_path: str) -> None:
    """Send C-level stdout (Blender's render log) to the log file."""
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.close(fd)


class _FramesFile:
    """``frames.jsonl`` of one output sequence, opened only while a line is appended, so a
    job feeding thousands of sequences (trials x conditions) holds one file handle, not one
    per sequence (100k trials used to end in EMFILE)."""

    def __init__(self, path: Path):
        self.path = path
        path.write_text("")

    def write(self, line: str) -> None:
        with open(self.path, "a") as fh:
            fh.write(line)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


def _open_outputs(job) -> list[tuple[object, Path, object]]:
    outs = []
    for o in job.outputs:
        d = Path(o.seq_dir)
        (d / "rgb").mkdir(parents=True, exist_ok=True)    # range/index: the job's shared pass store
        outs.append((o, d, _FramesFile(d / "frames.jsonl")))
    return outs


class _Geo:
    def __init__(self, obj):
        self.obj = obj

    def move(self, positions):
        from blendgen.blender import particles
        particles.move_particles(self.obj, positions)


def _geometry_particles(job: dict, states: list):
    """Real-geometry particles of this job (validation mode), driven by the same seeded
    field as the image-space model; returns (mover, state) or None."""
    p = job.scene.get("particles")
    if not p:
        return None
    from blendgen.pipeline import compose as pp, plan
    from blendgen.blender import particles
    st = next((s for s in states if s.field is not None), None) or pp.SequenceState.start(
        states[0].post.model_copy(update={"seed": p["seed"], "fps": p["fps"], "occlusion": plan.OcclusionPost(
            **{k: v for k, v in p.items() if k not in ("seed", "fps", "object_index")})}))
    return _Geo(particles.add_particles(st.field.positions, st.field.radii, p["object_index"],
                                        color=[p.get("albedo", 0.3)] * 3)), st


def _shared_distortion(job):
    """The lens distortion of every output (the shared range/index passes are written once,
    distorted like the images they sit beside): outputs of one render must agree."""
    dists = {json.dumps(o.post.distortion) for o in job.outputs}
    if len(dists) > 1:
        raise RuntimeError("outputs of one render job have different lens distortion; their shared "
                           "range/index passes cannot match every image (render them as separate jobs)")
    return job.outputs[0].post.distortion if job.outputs else None


def _write_image(seq_dir: Path, rel: str, i: int, img: np.ndarray, raw: bool) -> dict:
    """The frame's camera image: a PNG (``compose.write_image``), or with ``raw`` its pixels
    as ``rgb/.<i>.npy`` for the streaming evaluator, which deletes them; the record names the
    PNG either way, so ``frames.jsonl`` is the one ``generate`` writes."""
    from blendgen.pipeline import compose as pp
    if not raw:
        return pp.write_image(seq_dir, rel, i, img)
    from datasets_spec.io import save_raw_image
    name = f"{i:06d}.png"
    save_raw_image(seq_dir / "rgb" / name, img)
    return {"image": f"{rel}/rgb/{name}"}


def _scene_key(job) -> str | None:
    """What the built Blender scene depends on (scene, camera, Cycles settings), or None
    when the job changes the scene while it renders (real-geometry particles)."""
    if job.scene.get("particles"):
        return None
    return json.dumps([job.scene, job.camera.model_dump(), job.render], sort_keys=True)


def _scene(job, cache: dict | None):
    """(Blender scene, camera object) for ``job``: the one in ``cache`` when the last job
    built the same scene (persistent worker), else built from factory settings."""
    from blendgen.blender import lamps, render, scene as scn
    key = _scene_key(job)
    if cache is not None and key is not None and cache.get("key") == key:
        return cache["sc"], cache["cam"], cache["caustics"]
    sc = scn.build(job.scene)                               # read_factory_settings: nothing kept
    cam = render.setup_camera(sc, job.camera.model_dump())
    lamps.add_lamps(cam, job.scene.get("lamps") or [])       # reference fidelity only
    render.setup_cycles(sc, job.render)
    caustics = None
    if (job.scene.get("water_surface") or {}).get("caustics"):   # reference: the sun as a caustic spot
        from blendgen.blender.caustic_sun import CausticSun
        caustics = CausticSun(sc, job.scene, int(job.render.get("threads") or 0))
    if cache is not None:
        cache.update(key=key, sc=sc, cam=cam, caustics=caustics)
    return sc, cam, caustics


def photon_seed(job, frame: dict) -> int:
    """The caustic photons' seed of one frame: the render seed and the frame index."""
    return (int(job.render.get("seed", 0)) * 7919 + int(frame["index"])) % (1 << 20)


def run(job, cache: dict | None = None) -> dict:
    """Render the job (a ``plan.JobRecord``); returns timing figures (s) per stage.

    ``cache`` (a persistent worker's dict) keeps the built scene for the next job."""
    from blendgen.pipeline import compose as pp
    from blendgen.pipeline.passstore import PassStore
    from blendgen.blender import render
    from blendgen.pipeline.frameshare import FrameShare
    from blendgen.pipeline.stagetimer import StageTimer

    t0 = time.perf_counter()
    sc, cam, caustics = _scene(job, cache)
    K = np.asarray(job.camera.K, float)
    W, H = job.camera.width, job.camera.height
    T_wd = np.asarray(job.gt.T_world_dock, float)
    markers = job.gt.markers
    outs = _open_outputs(job)
    store = PassStore.from_job(job)
    distortion = _shared_distortion(job)
    states = [pp.SequenceState.start(o.post) for o, _, _ in outs]
    exr = os.path.join(render.scratch_dir(), f"dockbench-{os.getpid()}.exr")
    geo = _geometry_particles(job, states)
    unkept = set(job.raw_images)        # dockbench run: images not kept are never PNG-encoded
    # "render" includes reading the EXR passes back (the ROI path: the background and one render per box);
    # "depth_to_range" turns the planar depth pass into range along each ray
    times = {"scene_build": time.perf_counter() - t0, "render": [], "depth_to_range": [], "post_write": []}
    share = FrameShare()
    clock = StageTimer()        # CPU and wall per stage (render, compose, write) for `bench suite`
    try:
        for fr in job.frames:
            t1 = time.perf_counter()
            if geo is not None:
                geo[0].move(geo[1].field.positions)
            if job.scene.get("water_surface"):
                from blendgen.blender.world import set_wave_time
                set_wave_time(fr.get("t", 0.0))
            with clock("render"):
                if caustics is not None:
                    caustics.update(photon_seed(job, fr))
                raw = render.render_roi_frame(sc, cam, fr, job.render, W, H, exr)
            t2 = time.perf_counter()
            with clock("compose"):
                passes = pp.add_ambient(pp.add_range(raw, K), job.render.get("ambient_radiance", 0.0))
            t3 = time.perf_counter()
            with clock("write"):
                pass_paths = store.write(fr["index"], pp.output_passes(passes, K, distortion)) if store else {}
            with clock("compose"):
                rec = pp.frame_record(fr, T_wd, markers, K, W, H, passes["index"])
                share.begin(passes)          # sequences that are one condition under two names: one image
            for (o, d, fh), st in zip(outs, states):
                with clock("compose"):
                    seen, occluded = pp.add_particles(passes, st, K, fr["T_world_cam"], markers, rec["T_cam_dock"],
                                                      fr["t"], water_after=job.fidelity == "fast")
                    img = share.image(st, seen, lambda: pp.camera_image(seen, st, K, fr, markers, job.fidelity,
                                                                         occluded, T_world_dock=T_wd))
                    r = rec if occluded is None else pp.with_visibility(rec, markers, K, passes["index"], occluded)
                    if st.auto_exposure is not None:
                        r = {**r, "exposure_s": st.exposure_s}
                with clock("write"):
                    paths = {**_write_image(d, o.rel, fr["index"], img, fr["index"] in unkept), **pass_paths}
                    fh.write(json.dumps({**r, **paths}) + "\n")
                    fh.flush()
                st.advance()
            if geo is not None and geo[1] not in states:
                geo[1].advance()
            times["render"].append(t2 - t1)
            times["depth_to_range"].append(t3 - t2)
            times["post_write"].append(time.perf_counter() - t3)
        times.update(clock.totals())
    finally:
        for _, _, fh in outs:
            fh.close()
        if os.path.exists(exr):
            os.remove(exr)
    return times


def run_file(job_file: str, cache: dict | None = None) -> None:
    """Run the job in ``job_file``; C-level stdout (Blender's render log) goes to the job's
    ``log``, its stage timings to its ``timing_out``."""
    from blendgen.pipeline.plan import JobRecord
    job = JobRecord.model_validate_json(Path(job_file).read_text())   # parsed once, typed from here on
    _quiet_stdout(job.log or os.devnull)
    times = run(job, cache)
    if job.timing_out:
        Path(job.timing_out).write_text(json.dumps(times))


def main(argv: list[str]) -> int:
    run_file(argv[1])
    return 0


def log_to(log_path: str) -> None:
    """Send C-level stdout and stderr (tracebacks) to ``log_path`` (the executor's log of
    the job; ``run_file`` then sends stdout on to the job's own Blender log)."""
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


def _rss_mb() -> float:
    """Resident memory of this process (MB), from /proc (0 where there is none)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        return 0.0


def serve(requests, reply) -> int:
    """Persistent worker: run one job per request line ``{"job": JOB.json, "log": LOG}``,
    bpy imported once and the scene kept while jobs share it; reply ``{"ok": true,
    "rss_mb": MB}`` when the job's sequences are complete. A failing job replies
    ``{"ok": false, "error": ...}`` (traceback in its log) and ends the worker: a fresh
    process serves the next job, so nothing half-built is carried over."""
    import traceback
    cache: dict = {}
    for line in requests:
        if not line.strip():
            continue
        req = json.loads(line)
        log_to(req.get("log") or os.devnull)
        try:
            run_file(req["job"], cache)
        except Exception as e:  # noqa: BLE001 - reported to the parent, then this worker exits
            traceback.print_exc()
            reply({"ok": False, "error": f"{type(e).__name__}: {e}"})
            return 1
        reply({"ok": True, "rss_mb": round(_rss_mb(), 1)})
    return 0


def reply_channel():
    """``reply(dict)`` writing JSON lines to the process's original stdout (a duplicate of
    fd 1, taken before fd 1 is redirected to a log); shared with ``blender.serve``."""
    proto = os.fdopen(os.dup(1), "w", buffering=1)

    def reply(msg: dict) -> None:
        proto.write(json.dumps(msg) + "\n")
        proto.flush()

    return reply


def serve_main() -> int:
    """``python -m blendgen.pipeline.executor --serve``: job requests on stdin, replies on
    the original stdout (JSON lines); Blender's output goes to each job's log."""
    return serve(sys.stdin, reply_channel())


if __name__ == "__main__":
    sys.exit(main(sys.argv))
