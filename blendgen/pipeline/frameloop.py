"""The dataset frame loop: ``python -m blendgen.pipeline.executor JOB.json`` runs :func:`run_file`.

One render job (:class:`blendgen.pipeline.plan.JobRecord`) is one camera path rendered once
and the sequences (conditions, trials) it feeds. The renderer (:mod:`blendgen.pipeline.renderer`)
is built once (a persistent worker keeps the built scene while jobs share it), then per frame:

1. ``renderer.render(frame)``: the clean passes (numpy arrays, same process, no copies);
2. :func:`clean_passes`: range along each ray and the ambient light field (fast fidelity);
3. the shared range/index passes written once (:mod:`blendgen.pipeline.passstore`) and the
   frame's ground truth (:func:`blendgen.pipeline.compose.frame_record`);
4. per sequence, :func:`condition_image`: particles, water, sensor -> the uint8 camera image
   (sequences that are one condition under two names share one image,
   :mod:`blendgen.pipeline.frameshare`); the PNG and one ``frames.jsonl`` line are written
   (the parent counts those lines for progress).

The closed loop (:mod:`blendgen.tools.apps.closed_loop`) runs steps 2 and 4 on passes from the
warm render server. Blender's own chatter on stdout is sent to the job's log file.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from blendgen import workerio
from blendgen.pipeline import compose as pp
from blendgen.pipeline import plan
from blendgen.pipeline import renderer as rd
from blendgen.pipeline.frameshare import CLEAN, FrameShare
from blendgen.pipeline.passstore import PassStore
from blendgen.pipeline.stagetimer import StageTimer, term
from blendgen.render_spec import FramePlan


# -- the per-frame stages (datasets and the closed loop) ----------------------------
@term("passes")
def clean_passes(raw: dict, K: np.ndarray, ambient_radiance: float) -> dict:
    """The renderer's passes with ``range_m`` (H,W) float32 m along each ray and the ambient
    light field added to ``rgb`` (0: none); in place, no copies of the other passes."""
    return pp.add_ambient(pp.add_range(raw, K), ambient_radiance)


def condition_image(
    passes: dict,
    state: pp.SequenceState,
    K: np.ndarray,
    frame: dict,
    markers: list[dict],
    fidelity: str,
    T_world_dock=None,
    T_cam_dock=None,
    particle_time: bool = True,
    share: FrameShare | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """One sequence's camera image (H,W,3) uint8 of a frame's clean passes, and the particles'
    occluder mask (H,W) bool (None without particles). ``T_cam_dock`` lets the LEDs light the
    particles (None: unlit by them); ``particle_time``: the particles' motion blur uses the
    frame time ``t`` (else one frame period); ``share``: the frame's shared images and
    water-independent parts (``FrameShare.memo``)."""
    seen, occluded = pp.add_particles(
        passes,
        state,
        K,
        frame["T_world_cam"],
        markers if T_cam_dock is not None else None,
        T_cam_dock,
        frame["t"] if particle_time else None,
        water_after=fidelity == "fast",
    )

    def image():
        # water-independent parts of the frame; a sequence with occluders uses only those made
        # from the frame's own passes (the caustics), not from its particle-composited ones
        if share is None:  # one sequence: the frame's own passes still make its caustics
            memo = None if occluded is None else {CLEAN: passes}
        else:
            memo = share.memo(seen) if occluded is None else share.frame_memo()
        return pp.camera_image(seen, state, K, frame, markers, fidelity, occluded, T_world_dock, memo)

    return (image() if share is None else share.image(state, seen, image)), occluded


# -- one job ---------------------------------------------------------------------------
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


class _Output:
    """One output sequence of the job: its folder, frames file and image-space state."""

    def __init__(self, out: plan.JobOutput):
        self.rel, self.dir = out.rel, Path(out.seq_dir)
        (self.dir / "rgb").mkdir(parents=True, exist_ok=True)  # range/index: the job's shared pass store
        self.frames = _FramesFile(self.dir / "frames.jsonl")
        self.state = pp.SequenceState.start(out.post)


def _geometry_particles(job: plan.JobRecord, renderer: rd.Renderer, states: list):
    """Real-geometry particles of this job (validation mode), driven by the same seeded
    field as the image-space model, added to the renderer's scene; returns their sequence
    state (the field moves with it), or None."""
    p = job.scene.particles
    if p is None:
        return None
    st = next((s for s in states if s.field is not None), None) or pp.SequenceState.start(
        states[0].post.model_copy(
            update={
                "seed": p.seed,
                "fps": p.fps,
                "occlusion": plan.OcclusionPost(**p.model_dump(exclude={"seed", "fps", "object_index"})),
            }
        )
    )
    renderer.add_particles(st.field.positions, st.field.radii, p.object_index, color=[p.albedo] * 3)
    return st


def _shared_distortion(job: plan.JobRecord):
    """The lens distortion of every output (the shared range/index passes are written once,
    distorted like the images they sit beside): outputs of one render must agree."""
    dists = {json.dumps(o.post.distortion) for o in job.outputs}
    if len(dists) > 1:
        raise RuntimeError(
            "outputs of one render job have different lens distortion; their shared "
            "range/index passes cannot match every image (render them as separate jobs)"
        )
    return job.outputs[0].post.distortion if job.outputs else None


def _write_image(out: _Output, i: int, img: np.ndarray, raw: bool) -> dict:
    """The frame's camera image: a PNG (``compose.write_image``), or with ``raw`` its pixels
    as ``rgb/.<i>.npy`` for the streaming evaluator, which deletes them; the record names the
    PNG either way, so ``frames.jsonl`` is the one ``generate`` writes."""
    if not raw:
        return pp.write_image(out.dir, out.rel, i, img)
    from datasets_spec.io import save_raw_image

    name = f"{i:06d}.png"
    save_raw_image(out.dir / "rgb" / name, img)
    return {"image": f"{out.rel}/rgb/{name}"}


class _Job:
    """What every frame of one job needs: camera, truth, outputs, pass store, timers."""

    def __init__(self, job: plan.JobRecord):
        self.job = job
        self.K = np.asarray(job.camera.K, float)
        self.T_wd = np.asarray(job.gt.T_world_dock, float)
        self.markers = [m.model_dump(mode="json") for m in job.gt.markers]  # plain data for compose
        self.outputs = [_Output(o) for o in job.outputs]
        self.store = PassStore.from_job(job)
        self.distortion = _shared_distortion(job)
        self.unkept = set(job.raw_images)  # dockbench run: images not kept are never PNG-encoded
        self.share = FrameShare()
        self.clock = StageTimer()  # CPU and wall per stage (render, compose, write) for `bench suite`

    def sequences(self, fr: dict, passes: dict, rec: dict, pass_paths: dict) -> None:
        """Step 4 of the module docstring for every output sequence of the frame."""
        job, clock = self.job, self.clock
        for out in self.outputs:
            st = out.state
            with clock("compose"):
                img, occluded = condition_image(
                    passes,
                    st,
                    self.K,
                    fr,
                    self.markers,
                    job.fidelity,
                    T_world_dock=self.T_wd,
                    T_cam_dock=rec["T_cam_dock"],
                    share=self.share,
                )
                r = (
                    rec
                    if occluded is None
                    else pp.with_visibility(rec, self.markers, self.K, passes["index"], occluded)
                )
                if st.auto_exposure is not None:
                    r = {**r, "exposure_s": st.exposure_s}
            with clock("write"):
                paths = {**_write_image(out, fr["index"], img, fr["index"] in self.unkept), **pass_paths}
                out.frames.write(json.dumps({**r, **paths}) + "\n")
            st.advance()

    def frame(self, renderer: rd.Renderer, frame: FramePlan, geo, times: dict) -> None:
        """Render, compose and write one planned frame; per-frame seconds appended to ``times``."""
        job, clock, K = self.job, self.clock, self.K
        fr = frame.plain()
        t1 = time.perf_counter()
        with clock("render"):
            raw = renderer.render(frame, None if geo is None else geo.field.positions)
        t2 = time.perf_counter()
        with clock("compose"):
            passes = clean_passes(raw, K, job.render.ambient_radiance)
        t3 = time.perf_counter()
        with clock("write"):
            pass_paths = (
                self.store.write(fr["index"], pp.output_passes(passes, K, self.distortion)) if self.store else {}
            )
        with clock("compose"):
            rec = pp.frame_record(fr, self.T_wd, self.markers, K, job.camera.width, job.camera.height, passes["index"])
            self.share.begin(passes)  # sequences that are one condition under two names: one image
        self.sequences(fr, passes, rec, pass_paths)
        if geo is not None and geo not in [o.state for o in self.outputs]:
            geo.advance()
        times["render"].append(t2 - t1)
        times["depth_to_range"].append(t3 - t2)
        times["post_write"].append(time.perf_counter() - t3)


def run(job: plan.JobRecord, cache: dict | None = None) -> dict:
    """Render the job; returns timing figures (s) per stage.

    ``cache`` (a persistent worker's dict) keeps the built scene for the next job."""
    rd.load()
    t0 = time.perf_counter()
    renderer = rd.build(job.scene, job.camera.model_dump(), job.render, cache)
    loop = _Job(job)
    geo = _geometry_particles(job, renderer, [o.state for o in loop.outputs])
    # "render" includes reading the EXR passes back (the ROI path: the background and one render per box);
    # "depth_to_range" turns the planar depth pass into range along each ray
    times = {"scene_build": time.perf_counter() - t0, "render": [], "depth_to_range": [], "post_write": []}
    try:
        for fr in job.frames:
            loop.frame(renderer, fr, geo, times)
        times.update(loop.clock.totals())
    finally:
        renderer.close()
    return times


def run_file(job_file: str, cache: dict | None = None) -> None:
    """Run the job in ``job_file``; C-level stdout (Blender's render log) goes to the job's
    ``log``, its stage timings to its ``timing_out``."""
    job = plan.JobRecord.model_validate_json(Path(job_file).read_text())  # parsed once, typed from here on
    workerio.quiet_stdout(job.log or os.devnull)
    times = run(job, cache)
    if job.timing_out:
        Path(job.timing_out).write_text(json.dumps(times))


def main(argv: list[str]) -> int:
    run_file(argv[1])
    return 0


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
        workerio.log_to(req.get("log") or os.devnull)
        try:
            run_file(req["job"], cache)
        except Exception as e:  # noqa: BLE001 - reported to the parent, then this worker exits
            traceback.print_exc()
            reply({"ok": False, "error": f"{type(e).__name__}: {e}"})
            return 1
        reply({"ok": True, "rss_mb": round(workerio.rss_mb(), 1)})
    return 0


def serve_main() -> int:
    """``python -m blendgen.pipeline.executor --serve``: job requests on stdin, replies on
    the original stdout (JSON lines); Blender's output goes to each job's log."""
    return serve(sys.stdin, workerio.reply_channel())
