"""Closed-loop visual docking benchmark: the localizer under test steers the vehicle.

For each condition of an experiment config and each trial (seeded random start, the same
starts as the open-loop datasets: :func:`blendgen.pipeline.plan.trial_seed`), the 6-DOF
vehicle (:mod:`blendgen.vehicle.closed_loop`) asks for a camera frame at its current pose
every 1/fps s. A warm Blender process (:mod:`blendgen.blender.serve`) renders the clean
passes with the dataset's own scene description and render settings; the condition's water,
depth light, small obstacles and sensor noise are applied by the dataset frame loop's own
stages (:func:`blendgen.pipeline.frameloop.clean_passes`, :func:`~blendgen.pipeline.frameloop.condition_image`); the
localizer (any registry spec,
with the same isolation options as ``dockbench evaluate``) returns its estimate, and
guidance steers on it. ``truth`` is the ground-truth-guidance baseline (nothing rendered).

Latency: the estimate of a frame reaches guidance ``camera.latency_s`` (config) plus the
localizer's compute time (``--compute-latency``: seconds, or ``measured`` = each frame's
measured time, which makes a run depend on machine load) after the frame's capture; the
filter treats it as a delayed measurement (:class:`blendgen.vehicle.closed_loop.DelayLine`).

Same images as datasets: each frame gets the dataset's ROI boxes
(:class:`blendgen.pipeline.plan.RenderRegions`), ambient term, particles lit by the LEDs and the
vehicle lamp, water and sensor stages, in the worker's order; a frame at the same pose and seed is
byte-identical to the dataset's (tests/test_closed_loop_render.py).

Not modelled here: reference (volumetric) fidelity, ``geometry: blender`` particles and sensor
motion blur (a dataset blurs by the planned next pose); the config is rejected for these three.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from blendgen import passfile
from blendgen.config.models import ConfigError, DockingTrajectory, Experiment
from blendgen.pipeline import compose, frameloop, groundtruth, plan, scene_check
from blendgen.vehicle import docking
from blendgen.vehicle import trajectories as tj
from blendgen.vehicle.closed_loop import Observation, TrialSetup, simulate_closed_loop
from blendgen.vehicle.contact import WaterSolid
from blendgen.vehicle.dynamics import VehicleParams
from blendgen.vehicle.visual_nav import CaptureSpec, FilterParams
from datasets_spec.io import png_params

TRUTH = "truth"


class RenderServerError(RuntimeError):
    """The warm render server failed; the message carries the tail of its log."""


class RenderClient:
    """A warm :mod:`blendgen.blender.serve` process: ``init`` once, ``render`` per pose."""

    def __init__(self, log_path: Path):
        self.log_path = Path(log_path)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "blendgen.blender.serve", str(self.log_path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        self.scratch = tempfile.mkdtemp(prefix="dockbench-cl-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)

    def _ask(self, req: dict) -> dict:
        try:
            self.proc.stdin.write(json.dumps(req) + "\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        except BrokenPipeError:
            line = ""
        if not line:
            tail = self.log_path.read_text(errors="replace").splitlines()[-20:] if self.log_path.exists() else []
            raise RenderServerError("render server died:\n" + "\n".join(tail))
        rep = json.loads(line)
        if not rep.get("ok"):
            raise RenderServerError(f"render server: {rep.get('error')}")
        return rep

    def init(self, scene: dict, camera: dict, render: dict) -> float:
        """Build the scene; returns the build time (s)."""
        return float(self._ask({"cmd": "init", "scene": scene, "camera": camera, "render": render})["scene_build_s"])

    def render(self, T_world_cam: np.ndarray, regions: dict | None = None) -> dict:
        """Clean passes (``rgb``, ``depth_z``, ``index``) at the camera pose (4x4, OpenCV); ``regions``
        the frame's ROI boxes (:meth:`blendgen.pipeline.plan.RenderRegions.boxes`; None: whole frame)."""
        out = os.path.join(self.scratch, "frame.passes")
        regions = regions or {}
        roi, rois = regions.get("roi"), regions.get("rois")
        self._ask(
            {
                "cmd": "render",
                "T_world_cam": np.asarray(T_world_cam).tolist(),
                "roi": None if roi is None else [int(v) for v in roi],
                "rois": None if rois is None else [[int(v) for v in b] for b in rois],
                "out": out,
            }
        )
        return passfile.read_passes(out)  # views of the server's file, copied only where written

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write('{"cmd": "quit"}\n')
                self.proc.stdin.close()
                self.proc.wait(10)
            except (BrokenPipeError, subprocess.TimeoutExpired, OSError):
                self.proc.kill()
                self.proc.wait()
        for f in Path(self.scratch).glob("*"):
            f.unlink()
        os.rmdir(self.scratch)


@dataclass
class Bench:
    """One experiment prepared for closed-loop trials: scene, camera, markers, docking spec."""

    exp: Experiment
    K: np.ndarray
    markers: list
    scene: dict
    T_world_dock: np.ndarray
    T_body_cam: np.ndarray
    traj: DockingTrajectory
    capture: CaptureSpec
    compute_latency: float | str = 0.0  # localizer time added to camera.latency_s (s or "measured")
    water: WaterSolid | None = None  # the pool's walls and floor or the seabed: scene_check.water_solid

    @classmethod
    def prepare(cls, exp: Experiment, assets: Path) -> Bench:
        """Check what the closed loop supports; write marker textures into ``assets``."""
        from blendgen.pipeline.generate import write_textures

        if exp.render.fidelity != "fast":
            raise ConfigError(
                f"{exp.name}: render.fidelity: closed-loop docking renders fast fidelity only "
                f"(got {exp.render.fidelity!r})"
            )
        for c in exp.conditions:
            occ = c.occlusion or exp.occlusion
            if occ is not None and occ.geometry == "blender":
                raise ConfigError(
                    f"{exp.name}: conditions[{c.label}].occlusion.geometry: closed-loop docking supports 'image' only"
                )
        if exp.camera.sensor.motion_blur:
            raise ConfigError(
                f"{exp.name}: camera.sensor.motion_blur: closed-loop docking renders no motion blur "
                "(a dataset blurs by the planned next pose, which a closed loop does not know yet); "
                "set it to false"
            )
        traj = next((t for t in exp.trajectories if t.kind == "docking"), DockingTrajectory())
        scene_check.check_scene(exp)  # the dock and the start box inside the water
        markers = plan.manifest_markers(exp)
        scene = plan.scene_description(exp, markers, write_textures(exp, assets))
        hull_r = VehicleParams().diameter / 2
        return cls(
            exp,
            plan.camera_K(exp),
            markers,
            scene,
            tj.T_world_dock_from_spec(exp.scene.dock),
            tj.T_body_cam_from_spec(exp.camera.T_body_cam),
            traj,
            capture_spec(traj, exp.scene.dock.body_size_m, hull_r),
            water=scene_check.water_solid(exp),
        )

    def camera_job(self) -> dict:
        c = self.exp.camera
        return {"width": c.width, "height": c.height, "hfov_rad": math.radians(c.hfov_deg), "K": self.K.tolist()}

    def localizer_camera(self, seq: str) -> dict:
        """The ``reset`` dict a dataset would give (evalkit.runner.camera_for_localizers)."""
        c = self.exp.camera
        return {
            "width": c.width,
            "height": c.height,
            "K": self.K.copy(),
            "fps": c.fps,
            "dist": None if c.distortion is None else np.asarray(c.distortion, float),
            "markers": self.markers,
            "sequence": seq,
        }

    def setup(self, cond, trial: int) -> TrialSetup:
        """The trial's start (same draw as the open-loop docking trajectory) and fluid."""
        seed = plan.trial_seed(self.exp, trial)
        st = self.traj.start
        start = docking.random_start(
            np.random.default_rng(seed),
            {
                "range_m": tuple(st.range_m),
                "lateral_m": st.lateral_m,
                "vertical_m": st.vertical_m,
                "heading_error_deg": st.heading_error_deg,
            },
        )
        fluid = cond.fluid or self.exp.fluid
        return TrialSetup(
            self.T_world_dock,
            start,
            self.T_body_cam,
            self.capture,
            current_world=tuple(fluid.current_mps),
            density=fluid.density_kg_m3,
            fps=self.exp.camera.fps,
            max_time_s=self.traj.max_time_s,
            seed=seed,
            guidance=docking.LosGuidance(
                cruise_speed=self.traj.cruise_speed_mps, final_speed=self.traj.final_speed_mps
            ),
            filter=FilterParams(),
            latency_s=self.exp.camera.latency_s,
            compute_latency=self.compute_latency,
            dock_size_m=tuple(self.exp.scene.dock.body_size_m),
            water=self.water,
        )

    def condition_authority(self, cond) -> dict:
        """:func:`condition_authority` of this bench's experiment (computed once per condition)."""
        cache = self.__dict__.setdefault("_authority", {})
        if cond.label not in cache:
            cache[cond.label] = condition_authority(self.exp, cond)
        return cache[cond.label]


def condition_authority(exp: Experiment, cond) -> dict:
    """Can the vehicle dock against this condition's mean current at all
    (:func:`blendgen.vehicle.authority.docking_authority` at the docking trajectory's final approach
    speed within the capture heading limit)? Adds ``max_current_mps``: the largest current in the
    same direction that it can (NaN in still water) and a one-line ``verdict``."""
    from blendgen.vehicle import authority

    traj = next((t for t in exp.trajectories if t.kind == "docking"), DockingTrajectory())
    capture = capture_spec(traj, exp.scene.dock.body_size_m, VehicleParams().diameter / 2)
    a = -tj.T_world_dock_from_spec(exp.scene.dock)[:3, 2]
    a[2] = 0.0
    fluid = cond.fluid or exp.fluid
    cur = np.asarray(fluid.current_mps, float)
    args = (a / np.linalg.norm(a), traj.final_speed_mps, capture.max_heading_deg, fluid.density_kg_m3)
    res = authority.docking_authority(cur, *args)
    speed = float(np.linalg.norm(cur))
    res["max_current_mps"] = authority.max_docking_current(cur, *args) if speed > 0 else math.nan
    res["verdict"] = authority_verdict(res, speed)
    return res


def authority_verdict(res: dict, speed: float) -> str:
    """``within (margin N%)`` or ``beyond the vehicle's authority (...)`` for a docking_authority dict."""
    if res["holds"]:
        return f"within (margin {100 * res['margin']:.0f}%)"
    lim = res.get("max_current_mps", math.nan)
    return (
        f"beyond the vehicle's authority ({res['limiting']} thrusters at {res['utilisation']:.2f}x their "
        f"limit; max {lim:.2f} m/s, current {speed:.2f} m/s)"
    )


def capture_spec(traj: DockingTrajectory, body_size_m, hull_radius_m: float) -> CaptureSpec:
    """The trajectory's ``capture`` limits on the dock face; the radius defaults from the face."""
    lim = traj.capture
    kw = {"max_heading_deg": lim.max_heading_deg, "max_lateral_speed_mps": lim.max_lateral_speed_mps}
    if lim.radius_m is not None:
        kw["capture_radius_m"] = lim.radius_m
    return CaptureSpec.from_dock(body_size_m, hull_radius_m, **kw)


class VisionCamera:
    """The observer of one trial: render at the true pose, compose the condition's image,
    run the localizer; per-frame facts go to the trial log."""

    def __init__(
        self, bench: Bench, client: RenderClient, localizer, executor, post: dict, image_dir: Path | None = None
    ):
        self.b, self.client, self.loc, self.executor, self.post = bench, client, localizer, executor, post
        self.state = compose.SequenceState.start(post)
        self.ambient = plan.ambient_radiance(bench.exp)  # the same ambient term datasets get
        self.regions = plan.RenderRegions.of(bench.exp) if bench.exp.render.roi else None
        self.by_file = callable(getattr(localizer, "localize_file", None))
        self.image_dir = image_dir
        if image_dir is not None or self.by_file:
            self.image_dir = image_dir or Path(client.scratch)
            self.image_dir.mkdir(parents=True, exist_ok=True)

    def _image(self, k: int, t: float, T_wc: np.ndarray) -> tuple[np.ndarray, dict, dict]:
        """Frame ``k`` at ``t`` s: the dataset's stages in the dataset's order (pipeline/frameloop.py): the
        same ROI boxes, ambient term, particles lit by the LEDs and the lamp, water and sensor; so a
        frame at the same pose and seed is the dataset's frame, byte for byte."""
        b, c = self.b, self.b.exp.camera
        regions = None if self.regions is None else self.regions.boxes(T_wc, b.T_world_dock)
        t0 = time.perf_counter()
        passes = frameloop.clean_passes(self.client.render(T_wc, regions), b.K, self.ambient)
        t1 = time.perf_counter()
        gt = groundtruth.frame_truth(T_wc, b.T_world_dock, b.markers, b.K, c.width, c.height)
        img, _ = frameloop.condition_image(
            passes,
            self.state,
            b.K,
            {"T_world_cam": T_wc, "t": t},
            b.markers,
            "fast",
            T_world_dock=b.T_world_dock,
            T_cam_dock=gt["T_cam_dock"],
        )
        self.state.advance()
        times = {"render_ms": 1e3 * (t1 - t0), "compose_ms": 1e3 * (time.perf_counter() - t1)}
        return img, gt, times

    def __call__(self, k: int, t: float, T_wc: np.ndarray) -> Observation:
        from evalkit.runner import validate_estimate

        img, gt, times = self._image(k, t, T_wc)
        path = None
        if self.image_dir is not None:
            path = self.image_dir / f"{k:06d}.png"
            cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), png_params())
        res = (
            self.executor.call(self.loc, "localize_file", str(path.resolve()), k)
            if self.by_file
            else self.executor.call(self.loc, "localize", img)
        )
        est, reason = (None, res.error) if res.error else validate_estimate(res.value)
        in_fov = [k for k, m in gt["markers"].items() if m["in_fov"]]
        T_est = None if est is None or est.get("T_cam_dock") is None else np.asarray(est["T_cam_dock"], float)
        info = {
            "d_true": float(gt["d_true"]),
            "in_view": bool(in_fov),
            "markers_in_fov": ",".join(in_fov),
            "detected": est is not None,
            "d_est": est["distance"] if est else math.nan,
            "marker_id": est.get("marker_id") if est else None,
            "T_cam_dock_est": None if T_est is None else T_est.ravel().tolist(),
            "T_cam_dock": np.asarray(gt["T_cam_dock"], float).ravel().tolist(),
            "fail_reason": reason,
            "ms": res.ms,
            **times,
        }
        return Observation(est, info)


# ------------------------------------------------------------------ running trials ----
TRIAL_COLUMNS = [
    "localizer",
    "condition",
    "trial",
    "seed",
    "outcome",
    "docked",
    "t_end_s",
    "time_to_dock_s",
    "cross_lateral_m",
    "cross_vertical_m",
    "cross_heading_deg",
    "cross_lateral_speed_mps",
    "final_lateral_m",
    "final_vertical_m",
    "final_range_m",
    "final_heading_deg",
    "start_range_m",
    "start_lateral_m",
    "start_heading_deg",
    "n_frames",
    "wall_s",
    "impact_speed_mps",
    "contact_part",
    "reacquisitions",
    "lost_after_s",
    "authority",
]


@dataclass
class LocalizerSpec:
    """How to build the localizer under test (the ``dockbench evaluate`` options)."""

    name: str
    params: dict
    isolate: bool | None = None  # None: evalkit's default (plugins isolated, built-ins not)
    frame_timeout_s: float | None = None
    preprocess: str | None = None

    def build(self):
        from evalkit import assemble

        return assemble.build(
            self.name, self.params, isolate=self.isolate, timeout_s=self.frame_timeout_s, preprocess=self.preprocess
        )


def run_trial(bench: Bench, cond, trial: int, name: str, observer_factory=None) -> tuple[dict, list[dict]]:
    """One closed-loop trial; ``observer_factory(setup) -> Observer`` (None = ground truth).
    Returns the trial row (:data:`TRIAL_COLUMNS`) and its per-frame rows."""
    setup = bench.setup(cond, trial)
    t0 = time.perf_counter()
    res = simulate_closed_loop(setup, None if observer_factory is None else observer_factory(setup))
    st = setup.start
    row = {
        "localizer": name,
        "condition": cond.label,
        "trial": trial,
        "seed": setup.seed,
        "docked": res["outcome"] == "docked",
        "t_end_s": res["t_end"],
        "n_frames": len(res["frames"]),
        "start_range_m": st["range_m"],
        "start_lateral_m": st["lateral_m"],
        "start_heading_deg": st["heading_error_deg"],
        "wall_s": time.perf_counter() - t0,
        "authority": "within" if bench.condition_authority(cond)["holds"] else "beyond",
        **{k: res[k] for k in TRIAL_COLUMNS if k in res},
    }
    frames = [{"localizer": name, "condition": cond.label, "trial": trial, **f} for f in res["frames"]]
    return row, frames


def _vision_factory(
    bench: Bench, client: RenderClient, localizer, executor, cond, trial: int, name: str, image_root: Path | None
):
    """Observer factory of one trial: reset the localizer as for a dataset sequence."""
    seq = f"{name}-{cond.label}-t{trial:03d}"

    def make(setup: TrialSetup):
        res = executor.call(localizer, "reset", bench.localizer_camera(seq))
        if res.error:
            raise ConfigError(f"localizer {name!r} failed in reset: {res.error}")
        post = plan.condition_post(bench.exp, cond, setup.seed)
        img_dir = None if image_root is None else image_root / seq
        return VisionCamera(bench, client, localizer, executor, post, img_dir)

    return make


def run_suite(
    bench: Bench,
    localizers: list[LocalizerSpec],
    trials: int,
    out: Path,
    images: bool = False,
    threads: int = 0,
    baseline: bool = True,
    progress=print,
) -> tuple[list[dict], list[dict]]:
    """Every (trial, condition, localizer), trial-major so that an interrupted run has the same
    number of trials in every cell; ``truth`` first when ``baseline``. The tables are
    rewritten after every trial (``OUT/trials.parquet``, ``OUT/frames.parquet``). Returns trial
    and frame rows; the render server starts only when a localizer needs frames."""
    from evalkit.runner import InProcessExecutor

    executor = InProcessExecutor()
    names = ([TRUTH] if baseline else []) + [s.name for s in localizers]
    locs = {s.name: s.build() for s in localizers}
    client = start_client(bench, out / "render_server.log", threads) if locs else None
    rows, frames = [], []
    try:
        for trial in range(trials):
            for cond in bench.exp.conditions:
                for name in names:
                    loc = locs.get(name)
                    fac = (
                        None
                        if loc is None
                        else _vision_factory(
                            bench, client, loc, executor, cond, trial, name, out / "images" if images else None
                        )
                    )
                    row, fr = run_trial(bench, cond, trial, name, fac)
                    rows.append(row)
                    frames.extend(fr)
                    write_tables(rows, frames, out)
                    extra = (f", re-acquired {row['reacquisitions']}x" if row.get("reacquisitions") else "") + (
                        f", {row['contact_part']} hit at {row['impact_speed_mps']:.2f} m/s"
                        if row["outcome"] == "collision"
                        else ""
                    )
                    progress(
                        f"{cond.label:14s} {name:10s} trial {trial:3d}: {row['outcome']:15s} "
                        f"{row['t_end_s']:5.1f} s sim, {row['wall_s']:6.1f} s wall{extra}"
                    )
    finally:
        if client is not None:
            client.close()
        for loc in locs.values():
            getattr(loc, "close", lambda: None)()
    return rows, frames


def start_client(bench: Bench, log: Path, threads: int) -> RenderClient:
    """A warm render server with the dataset's scene and fast render settings."""
    client = RenderClient(log)
    try:
        client.init(bench.scene, bench.camera_job(), plan.render_settings(bench.exp, threads or os.cpu_count() or 1))
    except BaseException:
        client.close()
        raise
    return client


# ------------------------------------------------------------------ reporting ----------
SUMMARY_COLUMNS = [
    "localizer",
    "condition",
    "n_trials",
    "n_docked",
    "success_rate",
    "ci_low",
    "ci_high",
    "time_to_dock_median_s",
    "final_lateral_abs_mean_m",
    "final_heading_abs_mean_deg",
    "outcomes",
    "n_reacquired",
    "lost_after_s_median",
    "impact_speed_median_mps",
    "authority",
    "P_detect_mean",
    "P_succ_mean",
    "E_rel_mean",
]


def write_tables(rows: list[dict], frames: list[dict], out: Path) -> dict[str, Path]:
    """``trials.parquet`` (one row per trial, :data:`TRIAL_COLUMNS`) and ``frames.parquet``
    (trajectory + per-frame localization of the same run)."""
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    paths = {"trials": out / "trials.parquet", "frames": out / "frames.parquet"}
    pd.DataFrame(rows, columns=TRIAL_COLUMNS).to_parquet(paths["trials"], index=False)
    pd.DataFrame(frames).to_parquet(paths["frames"], index=False)
    return paths


def wilson_ci(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a success proportion k/n (scipy's binomtest)."""
    from scipy.stats import binomtest

    if n == 0:
        return math.nan, math.nan
    ci = binomtest(int(k), int(n)).proportion_ci(level, method="wilson")
    return float(ci.low), float(ci.high)


def _localization(frames, d_min_rel: float):
    """Per (localizer, condition) per-frame localization of the run, scored by evalkit
    (:func:`evalkit.metrics.core.summarize`): ``P_detect_mean`` (any answer, the article's
    rate), ``P_succ_mean`` (a right answer) and ``E_rel_mean``, means over trials."""
    import pandas as pd

    from evalkit.metrics import core

    cols = ["localizer", "condition", "P_detect_mean", "P_succ_mean", "E_rel_mean"]
    if "detected" not in frames and "success" in frames:  # tables of the first version
        frames = frames.rename(columns={"success": "detected"})
    if frames.empty or "detected" not in frames:
        return pd.DataFrame(columns=cols)
    f = frames[frames["d_true"].notna()].copy()
    for c, v in (("T_cam_dock", None), ("T_cam_dock_est", None), ("markers_in_fov", ""), ("marker_id", None)):
        if c not in f:
            f[c] = v
    f["sequence"] = f["localizer"] + "-" + f["condition"] + "-t" + f["trial"].astype(str)
    f["trajectory"] = ""
    f["detected"] = f["detected"].astype(bool)
    _, cond = core.summarize(f, d_min_rel=d_min_rel)
    return cond[cols]


def _column(table, name: str):
    """``table[name]``, or NaN for every row when an older run's table lacks the column."""
    import pandas as pd

    return table[name] if name in table else pd.Series(math.nan, index=table.index)


def summary_table(trials, frames, d_min_rel: float = 0.2, authority: dict | None = None):
    """Per (localizer, condition): docking success rate with its Wilson 95% CI, median time to
    dock (docked trials), mean |final lateral| (m) and |final heading| (deg) at the last frame,
    outcome counts, trials that re-acquired a lost target, median seconds without a fix at a
    lost-target abort, median impact speed of collisions (m/s), the condition's docking authority
    (``authority``: label -> verdict text, :func:`condition_authority`; empty when not given) and
    the per-frame localization metrics of the same run. Trial tables of older runs (without the
    lost-target and contact columns) give NaN there."""
    import pandas as pd

    out = []
    for (loc, cond), g in trials.groupby(["localizer", "condition"], sort=False):
        k, n = int(g["docked"].sum()), len(g)
        lo, hi = wilson_ci(k, n)
        counts = g["outcome"].value_counts()
        out.append(
            {
                "localizer": loc,
                "condition": cond,
                "n_trials": n,
                "n_docked": k,
                "success_rate": k / n,
                "ci_low": lo,
                "ci_high": hi,
                "time_to_dock_median_s": g["time_to_dock_s"].median(),
                "final_lateral_abs_mean_m": g["final_lateral_m"].abs().mean(),
                "final_heading_abs_mean_deg": g["final_heading_deg"].abs().mean(),
                "outcomes": ", ".join(f"{o} {c}" for o, c in counts.items()),
                "n_reacquired": int((_column(g, "reacquisitions").fillna(0) > 0).sum()),
                "lost_after_s_median": _column(g, "lost_after_s").median(),
                "impact_speed_median_mps": _column(g, "impact_speed_mps").median(),
                "authority": (authority or {}).get(cond, ""),
            }
        )
    df = pd.DataFrame(out)
    df = df.merge(_localization(frames, d_min_rel), on=["localizer", "condition"], how="left")
    return df[SUMMARY_COLUMNS]


def _with_camera_xy(frames, T_world_dock: np.ndarray, cam_forward_m: float):
    """Frames with ``x_cam_world``/``y_cam_world``; tables without them (older runs) get the
    body origin moved ``cam_forward_m`` along the logged heading (level vehicle)."""
    if "x_cam_world" in frames and frames["x_cam_world"].notna().all():
        return frames
    z = T_world_dock[:3, 2]
    yaw = math.atan2(-z[1], -z[0]) + np.radians(frames["heading_err_deg"].to_numpy())
    return frames.assign(
        x_cam_world=frames["x_world"] + cam_forward_m * np.cos(yaw),
        y_cam_world=frames["y_world"] + cam_forward_m * np.sin(yaw),
    )


def _draw_dock(ax, T_world_dock: np.ndarray, capture: CaptureSpec, dock_size_m) -> None:
    """Top view of the dock's body (face width x depth, black) and the capture mouth (green)."""
    o, xd, zd = T_world_dock[:3, 3], T_world_dock[:3, 0], T_world_dock[:3, 2]
    hw, d = float(dock_size_m[0]) / 2, float(dock_size_m[2])
    box = np.array([o - xd * hw, o + xd * hw, o + xd * hw - zd * d, o - xd * hw - zd * d, o - xd * hw])
    ax.plot(box[:, 0], box[:, 1], color="k", lw=1.5)
    mouth = np.array([o - xd * capture.capture_radius_m, o + xd * capture.capture_radius_m])
    ax.plot(mouth[:, 0], mouth[:, 1], color="limegreen", lw=3)


def plot_paths(
    trials,
    frames,
    capture: CaptureSpec,
    T_world_dock: np.ndarray,
    path: Path,
    cam_forward_m: float = 0.65,
    pool_xy_m: tuple[float, float] | None = None,
    dock_size_m=(1.0, 1.0, 0.4),
) -> Path:
    """Top-down paths of the camera (= nose; world x, y) per condition, one colour per localizer;
    the dock's body (``dock_size_m`` w, h, depth, m) and its capture mouth drawn, and the pool walls
    (length, width centred on the origin) when given; last points: o docked, x any failure."""
    from evalkit.reports.plots import _pyplot

    plt = _pyplot()
    frames = _with_camera_xy(frames, T_world_dock, cam_forward_m)
    conds = list(dict.fromkeys(trials["condition"]))
    locs = list(dict.fromkeys(trials["localizer"]))
    colours = dict(zip(locs, plt.get_cmap("tab10").colors))
    ncols = min(3, len(conds))
    nrows = -(-len(conds) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(max(5.4 * ncols, 9.0), 4.2 * nrows), squeeze=False)
    for ax, cond in zip(axes.ravel(), conds):
        for (loc, trial), g in frames[frames["condition"] == cond].groupby(["localizer", "trial"], sort=False):
            ax.plot(
                g["x_cam_world"],
                g["y_cam_world"],
                color=colours[loc],
                lw=0.8,
                alpha=0.7,
                label=loc if trial == 0 else None,
            )
            end = trials[(trials["condition"] == cond) & (trials["localizer"] == loc) & (trials["trial"] == trial)]
            docked = bool(end["docked"].iloc[0]) if len(end) else False
            ax.plot(
                g["x_cam_world"].iloc[-1], g["y_cam_world"].iloc[-1], "o" if docked else "x", color=colours[loc], ms=4
            )
        _draw_dock(ax, T_world_dock, capture, dock_size_m)
        if pool_xy_m is not None:
            lx, ly = pool_xy_m[0] / 2, pool_xy_m[1] / 2
            ax.plot([-lx, lx, lx, -lx, -lx], [-ly, -ly, ly, ly, -ly], color="0.5", lw=1, ls="--")
        ax.set_title(cond)
        ax.set_xlabel("world x (m)")
        ax.set_ylabel("world y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in axes.ravel()[len(conds) :]:
        ax.set_visible(False)
    walls = ", dashed: pool walls (solid to the hull)" if pool_xy_m is not None else ""
    fig.suptitle(
        "closed-loop docking, camera/nose paths (top view): o docked, x failed\n"
        f"black: the dock's body (collision geometry), green: capture radius{walls}",
        fontsize=10,
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------ command ------------
EXPERIMENTS = ("turbidity", "depth", "current", "occlusion")


def load_bench_experiment(name_or_path: str, size: str | None, conditions: tuple[str, ...]) -> Experiment:
    """A paper experiment by name (configs/paper_NAME.yaml) or a config file; ``size`` "WxH"
    overrides the camera resolution; ``conditions`` keeps only these labels."""
    from blendgen.config.bundled import bundled_file
    from blendgen.config.models import load_experiment

    path = bundled_file("configs", f"paper_{name_or_path}.yaml") if name_or_path in EXPERIMENTS else Path(name_or_path)
    exp = load_experiment(path)
    if size:
        try:
            w, h = (int(v) for v in size.lower().split("x"))
            exp.camera = exp.camera.model_validate({**exp.camera.model_dump(), "width": w, "height": h})
        except ValueError as e:
            raise ConfigError(f"--size: expected WIDTHxHEIGHT with 16..8192 px each, got {size!r}") from e
    if conditions:
        known = [c.label for c in exp.conditions]
        bad = [c for c in conditions if c not in known]
        if bad:
            raise ConfigError(f"--condition: unknown {', '.join(bad)}; the config has {', '.join(known)}")
        exp.conditions = [c for c in exp.conditions if c.label in conditions]
    return exp


def report(summary, out: Path, exp: Experiment, capture: CaptureSpec) -> str:
    """Markdown report of a run (also written to ``OUT/summary.md``)."""
    from evalkit.reports.tables import to_markdown

    c = exp.camera
    lines = [
        f"## closed-loop docking: {exp.name} ({c.width}x{c.height} at {c.fps:g} Hz, fast fidelity)",
        "",
        (
            f"docked = the camera/nose crosses the dock face plane within {capture.capture_radius_m:.2f} m of its "
            f"centre, |heading error| <= {capture.max_heading_deg:g} deg, |lateral speed| <= "
            f"{capture.max_lateral_speed_mps:g} m/s; success rate with a Wilson 95% CI; 'truth' = ground-truth "
            "guidance (baseline); P_detect_mean / P_succ_mean / E_rel_mean: per-frame localization of the "
            "same run scored by evalkit (frames with 0 <= d_true <= 10 m); authority: can the thrusters hold "
            "the condition's mean current at the final approach speed within the heading limit at all "
            "(`dockbench authority`)"
        ),
        "",
    ]
    beyond = sorted({r["condition"] for _, r in summary.iterrows() if str(r.get("authority", "")).startswith("beyond")})
    if beyond:
        lines += [
            (
                f"**{', '.join(beyond)}: beyond the vehicle's authority** -- no guidance law docks there within "
                "the capture limits; its failures are not localization or guidance failures."
            ),
            "",
        ]
    lines += [to_markdown(summary, floatfmt=".3g")]
    text = "\n".join(lines) + "\n"
    (out / "summary.md").write_text(text)
    return text


RESULTS_FILE = "closed_loop.json"  # the leaderboard's interface (datasets_spec/CLOSED_LOOP.md)
RESULTS_FORMAT, RESULTS_FORMAT_VERSION = "dockbench-closed-loop", "1"


def _json_value(v):
    """NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(v, (np.integer, np.floating, np.bool_)):
        v = v.item()
    return None if isinstance(v, float) and not math.isfinite(v) else v


def write_results_file(
    summary, out: Path, exp: Experiment, capture: CaptureSpec, trials: int, compute_latency: float | str = 0.0
) -> Path:
    """``OUT/closed_loop.json``: the run's summary rows plus what they were measured under
    (experiment + config hash, camera, latency, capture geometry); format in
    datasets_spec/CLOSED_LOOP.md. ``truth`` rows carry ``"baseline": true``."""
    import datetime as dt
    import hashlib

    from evalkit.reports.results import dockbench_version

    cfg = exp.model_dump(mode="json")
    c = exp.camera
    rows = [
        {**{k: _json_value(v) for k, v in r.items()}, "baseline": r["localizer"] == TRUTH}
        for r in summary.to_dict("records")
    ]
    doc = {
        "format": RESULTS_FORMAT,
        "format_version": RESULTS_FORMAT_VERSION,
        "timestamp": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "dockbench_version": dockbench_version(),
        "experiment": {
            "name": exp.name,
            "version": exp.version,
            "config_hash": hashlib.sha256(json.dumps(cfg, sort_keys=True).encode()).hexdigest(),
        },
        "camera": {"width": c.width, "height": c.height, "fps": c.fps, "latency_s": c.latency_s},
        "compute_latency": compute_latency,
        "fidelity": exp.render.fidelity,
        "trials_requested": trials,
        "capture": {
            "capture_radius_m": capture.capture_radius_m,
            "max_heading_deg": capture.max_heading_deg,
            "max_lateral_speed_mps": capture.max_lateral_speed_mps,
            "frame_half_m": list(capture.frame_half_m),
            "entry_plane_m": capture.entry_plane_m,
        },
        "rows": rows,
    }
    path = out / RESULTS_FILE
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return path


def run_dock(
    exp: Experiment,
    specs: list[LocalizerSpec],
    trials: int,
    out: Path,
    images: bool = False,
    threads: int = 0,
    baseline: bool = True,
    progress=print,
    report_only: bool = False,
    compute_latency: float | str = 0.0,
) -> dict:
    """Run the suite (unless ``report_only``: the tables already in ``out``) and write the
    summary and the path plot into ``out``; returns paths. Nine parameters (a reason): they
    are the ``dockbench dock`` run options, passed through by name."""
    import pandas as pd

    bench = Bench.prepare(exp, out / "assets")
    bench.compute_latency = compute_latency
    if report_only:
        paths = {"trials": out / "trials.parquet", "frames": out / "frames.parquet"}
        if not paths["trials"].is_file():
            raise ConfigError(f"--report-only: no {paths['trials']} (run without it first)")
    else:
        rows, frames = run_suite(bench, specs, trials, out, images, threads, baseline, progress)
        paths = write_tables(rows, frames, out)
    tr, fr = pd.read_parquet(paths["trials"]), pd.read_parquet(paths["frames"])
    verdicts = {c.label: bench.condition_authority(c)["verdict"] for c in exp.conditions}
    summary = summary_table(tr, fr, exp.d_min_rel_m, verdicts)
    summary.to_csv(out / "summary.csv", index=False)
    paths["summary"] = out / "summary.csv"
    pool = exp.scene.pool if exp.scene.kind == "pool" else None
    paths["plot"] = plot_paths(
        tr,
        fr,
        bench.capture,
        bench.T_world_dock,
        out / "paths.png",
        float(bench.T_body_cam[0, 3]),
        None if pool is None else (pool.length_m, pool.width_m),
        exp.scene.dock.body_size_m,
    )
    paths["report"] = out / "summary.md"
    report(summary, out, exp, bench.capture)
    paths["results"] = write_results_file(summary, out, exp, bench.capture, trials, compute_latency)
    (out / "run.json").write_text(
        json.dumps(
            {
                "config": exp.model_dump(mode="json"),
                "trials": trials,
                "localizers": [s.__dict__ for s in specs],
                "baseline": baseline,
                "capture": bench.capture.__dict__,
                "latency": {"camera_latency_s": exp.camera.latency_s, "compute_latency": compute_latency},
            },
            indent=1,
            default=str,
        )
    )
    return paths


def parse_compute_latency(text: str) -> float | str:
    """``--compute-latency``: ``measured`` or seconds in [0, 10]; anything else is a ConfigError."""
    if str(text).strip().lower() == "measured":
        return "measured"
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not 0.0 <= v <= 10.0:
        raise ConfigError(f"--compute-latency: expected seconds in [0, 10] or 'measured', got {text!r}")
    return v


NO_LOCALIZER = "none"  # ``-l none``: only the ground-truth baseline


def _specs(localizers, params, isolate, frame_timeout, preprocess) -> list[LocalizerSpec]:
    from evalkit.registry import params_for, parse_params

    p = parse_params(params)
    names = list(localizers)
    if NO_LOCALIZER in names:  # the ground-truth baseline alone: no rendering
        if len(names) > 1:
            raise ConfigError(f"-l {NO_LOCALIZER}: runs the ground-truth baseline alone; give no other -l")
        return []
    if TRUTH in names:
        raise ConfigError(f"-l {TRUTH}: the ground-truth baseline is always run (omit it with --no-baseline)")
    return [
        LocalizerSpec(n, params_for(n, p, names), True if isolate else None, frame_timeout, preprocess) for n in names
    ]


# ------------------------------------------------------------------ cost ---------------
def cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and its finished children."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def closed_loop_cost(exp: Experiment, localizer: str, trials: int, out: Path, threads: int = 0) -> dict:
    """Seconds per closed-loop trial and ms per frame by stage (render incl. reading the passes,
    compose, localize, the rest = dynamics + filter + bookkeeping) over ``trials`` trials of
    the first condition; also CPU seconds per frame (this process + the render server), which
    a machine shared with other jobs inflates less than wall time."""
    import pandas as pd

    bench = Bench.prepare(exp, out / "assets")
    exp.conditions = exp.conditions[:1]
    t0, c0 = time.perf_counter(), cpu_seconds()
    rows, frames = run_suite(
        bench,
        [LocalizerSpec(localizer, {})],
        trials,
        out,
        baseline=False,
        threads=threads,
        progress=lambda m: print(m, file=sys.stderr),
    )
    wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    f, tr = pd.DataFrame(frames), pd.DataFrame(rows)
    n = len(f)
    per_frame = 1e3 * float(tr["wall_s"].sum()) / n
    stages = {
        s: float(f[c].mean())
        for s, c in (("render_ms", "render_ms"), ("compose_ms", "compose_ms"), ("localize_ms", "ms"))
    }
    return {
        "localizer": localizer,
        "size": f"{exp.camera.width}x{exp.camera.height}",
        "fps": exp.camera.fps,
        "trials": len(tr),
        "frames": n,
        "s_per_trial": float(tr["wall_s"].mean()),
        "sim_s_per_trial": float(tr["t_end_s"].mean()),
        "ms_per_frame": per_frame,
        **stages,
        "other_ms": per_frame - sum(stages.values()),
        "wall_s_incl_server_start": wall,
        "cpu_ms_per_frame": 1e3 * cpu / n,
        "load_avg_1min": os.getloadavg()[0],
        "outcomes": ", ".join(tr["outcome"]),
    }
