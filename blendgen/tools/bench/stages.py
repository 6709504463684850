"""``dockbench bench``: where the time goes at 640x480, per stage and per localizer.

Renders the quickstart approach (``frames`` frames, 12 m -> 1 m) once per sample
count and image-formation mode (``--mode``: ``physical``: ambient pass, per-surface
depth light, sensor noise; ``article``: none of them; ``both``) with one worker using
every core, reports the median ms/frame of each stage and the CPU ms per frame of each
stage and compose term (:func:`blendgen.pipeline.stagetimer.term`) from the worker's own
timers, modes side by side, and the cost of each image-formation term on one 640x480
frame, then runs each built-in localizer on one core over each mode's frames and reports
frames/s. A benchmark, not a test: nothing is asserted; the numbers are printed and
written to CSV files under ``OUT``.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import click
import numpy as np
import pandas as pd

from blendgen.config.bundled import bundled_file
from blendgen.config.models import load_experiment
from blendgen.pipeline.generate import generate, timing_summary

LOCALIZERS = ("led", "qr", "aruco", "hybrid", "qr_track")
# (label, QrLocalizer params): single-frame decoders, then zxing with the ROI of the previous
# frame's code resampled 2x (what "qr" does in a sequence).
QR_DETECTORS = (
    ("zxing", {"detector": "zxing", "roi": False}),
    ("aruco", {"detector": "aruco", "roi": False}),
    ("classic", {"detector": "classic", "roi": False}),
    ("zxing+roi2x", {"detector": "zxing"}),
)
RANGE_BINS_M = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, float("inf")))


def bench_experiment(frames: int, samples: int, mode: str = "physical"):
    """Quickstart config reduced to one linear approach with ``frames`` frames."""
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    exp.image_formation = mode
    traj = exp.trajectories[0]
    traj.speed_mps = (traj.start_range_m - traj.end_range_m) * exp.camera.fps / (frames - 1)
    exp.trajectories = [traj]
    exp.render.samples = samples
    exp.name = f"bench-{mode}-s{samples}"
    return exp


def render_stages(out: Path, frames: int, samples: int, mode: str = "physical", progress: bool = False) -> dict:
    """Generate the bench dataset (``progress``: generate's frame counter on stderr); median
    ms/frame per stage and the wall time per frame."""
    if out.exists():
        shutil.rmtree(out)
    exp = bench_experiment(frames, samples, mode)
    t0 = time.perf_counter()
    man = generate(exp, out, workers=1, progress=progress)
    wall = time.perf_counter() - t0
    st = timing_summary(out)
    n = sum(s["n_frames"] for s in man["sequences"])
    return {
        "mode": mode,
        "samples": samples,
        "frames": n,
        "scene_build_ms": 1e3 * st["scene_build"],
        "render_read_ms": 1e3 * st["render"],
        "depth_to_range_ms": 1e3 * st["depth_to_range"],
        "post_write_ms": 1e3 * st["post_write"],
        "render+write_ms": 1e3 * (st["render"] + st["depth_to_range"] + st["post_write"]),
        "wall_ms_per_frame": 1e3 * wall / n,
    }


def stage_cpu_table(dirs: dict[str, Path]) -> pd.DataFrame:
    """CPU ms per frame of each frame-loop stage and term (``compose.water``, ...; the worker's
    own :class:`~blendgen.pipeline.stagetimer.StageTimer`), one column per bench dataset
    (``dirs``: label -> rendered bench dataset); the ratio physical / article when both ran."""
    from blendgen.tools.bench.suitebench import STAGES, stage_totals

    cols = {}
    for label, d in dirs.items():
        st = stage_totals([d])
        n = sum(len(json.loads(p.read_text())["frames"]) for p in (d / ".work" / "jobs").glob("*.json"))
        cpu = {k[4:-2]: 1e3 * v / max(n, 1) for k, v in st.items() if k.startswith("cpu_")}
        for s in STAGES:
            terms = [v for k, v in cpu.items() if k.startswith(f"{s}.")]
            if terms and s in cpu:
                cpu[f"{s}.other"] = cpu[s] - sum(terms)
        cols[f"{label} CPU ms/frame"] = cpu
    order = sorted(
        {k for c in cols.values() for k in c},
        key=lambda k: (STAGES.index(k.split(".")[0]) if k.split(".")[0] in STAGES else 9, k),
    )
    df = pd.DataFrame({"stage": order, **{c: [v.get(k, np.nan) for k in order] for c, v in cols.items()}})
    phys = [c for c in cols if c.startswith("physical")]
    art = [c for c in cols if c.startswith("article")]
    if phys and art:
        df["physical / article"] = df[phys[0]] / df[art[0]]
    return df


def _median_ms(fn, repeats: int = 15, clock=time.perf_counter) -> float:
    """Median time (ms) of fn over ``repeats`` calls by ``clock``: wall (perf_counter) or CPU
    of all this process's threads (process_time: less inflated when other processes share
    the cores)."""
    ts = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        ts.append(clock() - t0)
    return 1e3 * float(np.median(ts))


# fmt: off
def term_costs(dataset: Path) -> pd.DataFrame:
    """Median ms of each image-formation term on one frame of a rendered bench dataset
    (its range and index passes, its image as the clean render, albedo 0.5). A term that
    is switched off is not called: its cost is 0 by construction."""
    from blendgen.config.models import Sensor, Water
    from blendgen.physics.camera import sensor
    from blendgen.physics.water import optics
    from blendgen.pipeline import compose
    from blendgen.pipeline.plan import SequencePost, WorldPost
    from datasets_spec.io import load_index, load_range
    from evalkit.dataset import Dataset
    ds = Dataset.open(dataset)
    frames = list(ds.iter_frames(ds.sequences[0]["id"]))
    f = frames[len(frames) // 2]
    K = np.asarray(ds.manifest["camera"]["K"], float)
    rgb = sensor.srgb_decode(ds.load_image(f)).astype(np.float32)
    passes = {"rgb": rgb, "albedo": np.full_like(rgb, 0.5),
              "range_m": np.asarray(load_range(ds.frame_file(f, "depth")), np.float32),   # 1.1 PNG or 1.0 NPZ
              "index": load_index(ds.frame_file(f, "object_index"))}
    frame = {"T_world_cam": f["T_world_cam"]}
    markers = ds.markers
    T_wd = np.asarray(ds.manifest["dock"]["T_world_dock"], float)

    def state(mode, world=None, lamps=(), **sens):
        return compose.SequenceState.start(SequencePost(
            seed=0, fps=10, image_formation=mode, water=Water(preset="mild"), light_depth_m=1.0, surface_z_m=0.0,
            irradiance_w_m2=3.2, sensor=Sensor(**sens), world=world, lamps=list(lamps),
            lamp_forward_kept=0.85 if lamps else None))
    phys, art = state("physical", noise=False), state("article")
    surf, caus = (state("physical", WorldPost(surface=s, caustics=not s, wind_mps=1.0, wave_seed=0, sky_radiance=0.21,
                                              ambient_radiance=0.34, sun_travel_dir=[0.0, -0.5, -0.866]),
                        noise=False) for s in (True, False))
    compose.water_image(passes, caus, K, frame["T_world_cam"], markers, t=0.3)   # per-sequence caustic table
    from blendgen.config.models import Lamp
    from blendgen.physics.light import lamp_shadow, lamp_water
    from blendgen.tools.bench.lamp_bench import DEMO_LAMP
    lamp = state("physical", lamps=[Lamp(**DEMO_LAMP)], noise=False)
    noshadow = compose.SequenceState.start(lamp.post.model_copy(update={"lamp_shadows": False}))
    lit = {**passes, "normal": np.broadcast_to(np.float32([0, 0, 1]), rgb.shape).copy()}
    noisy, bloom = state("physical", noise=True), state("physical", noise=False, bloom_fraction=0.05)
    dist = [-0.2, 0.05, 0.0, 0.0, 0.0]
    rows = [
        ("ambient (albedo x L)", lambda: compose.add_ambient(dict(passes), 0.34)),
        ("surface depth map", lambda: compose.surface_depth(passes["range_m"], K, frame["T_world_cam"], 0.0)),
        ("water physical (incl. depth map)",
         lambda: compose.water_image(passes, phys, K, frame["T_world_cam"], markers)),
        ("water article", lambda: compose.water_image(passes, art, K, frame["T_world_cam"], markers)),
        ("water physical + surface (Snell's window)",
         lambda: compose.water_image(passes, surf, K, frame["T_world_cam"], markers, t=0.3)),
        ("water physical + caustics",
         lambda: compose.water_image(passes, caus, K, frame["T_world_cam"], markers, t=0.3)),
        ("water physical + vehicle lamp", lambda: compose.water_image(lit, lamp, K, frame["T_world_cam"], markers)),
        ("  vehicle lamp (surfaces + veil)", lambda: compose.lamp_image(lit, lamp.lamp, K, frame["T_world_cam"])),
        ("  of which backscatter veil", lambda: lamp_water.backscatter(lamp.lamp, K, passes["range_m"])),
        ("  of which lamp shadows (screen-space test)", lambda: lamp_shadow.visibility(
            lamp.lamp.lights[0].position_m, K, compose._unit_rays(tuple(K.ravel()), rgb.shape[1], rgb.shape[0]),
            passes["range_m"])),
        ("  vehicle lamp without shadows", lambda: compose.lamp_image(lit, noshadow.lamp, K, frame["T_world_cam"])),
        ("  of which LED glow", lambda: optics.add_emitter_glow(
            rgb, compose.emissive_mask(passes["index"], markers), passes["range_m"], phys.water, float(K[0, 0]))),
        ("8-bit sRGB encode only (before: to_uint8)", lambda: sensor.to_uint8(rgb)),
        ("sensor, no noise", lambda: phys.camera.apply(rgb, phys.rng)),
        ("sensor, shot + read noise", lambda: noisy.camera.apply(rgb, noisy.rng)),
        ("sensor, blooming", lambda: bloom.camera.apply(rgb * 20, bloom.rng)),
        ("LEDs light nearby surfaces (physical)", lambda: compose.led_light(
            passes, phys, K, frame["T_world_cam"], markers, T_wd)),
        ("  LEDs light: no LED array (off)",
         lambda: compose.led_light(passes, phys, K, frame["T_world_cam"], [], T_wd)),
        ("auto-exposure metering (99.9 percentile)", lambda: sensor.AutoExposure().next_exposure(
            rgb, 0.004, phys.camera, 0.1)),
        ("motion blur 5 px", lambda: sensor.motion_blur(rgb, (5.0, 1.0))),
        ("distortion RGB + index + range", lambda: (sensor.distort_image(rgb, K, dist),
                                                    compose.output_passes(passes, K, dist))),
    ]
    return pd.DataFrame([{"term": name, "ms_per_frame": _median_ms(fn),
                          "cpu_ms_per_frame": _median_ms(fn, clock=time.process_time)}
                         for name, fn in rows])
# fmt: on


def localizer_speed(dataset: Path) -> pd.DataFrame:
    """Frames/s of each built-in localizer on one core over a rendered dataset (a ``mode``
    column: the dataset's image formation, from its manifest)."""
    import cv2

    from evalkit import registry, runner
    from evalkit.dataset import Dataset

    cv2.setNumThreads(1)
    ds = Dataset.open(dataset)
    mode = ds.manifest.get("config", {}).get("image_formation", "?")
    rows = []
    for name in LOCALIZERS:
        df = runner.evaluate(ds, [(name, registry.resolve(name, {}))], progress=False)
        ms = df["ms"].to_numpy()
        rows.append(
            {
                "mode": mode,
                "localizer": name,
                "frames": len(ms),
                "median_ms": float(np.median(ms)),
                "p95_ms": float(np.percentile(ms, 95)),
                "frames_per_s": 1e3 / float(np.mean(ms)),
                "P_succ_in_view": float(df.loc[df["in_view"], "success"].mean()),
            }
        )
    return pd.DataFrame(rows)


def load_sequences(dataset: Path) -> tuple:
    """(Dataset, camera dict for reset, [(sequence id, [(frame dict, RGB image)])]) with
    every image decoded once up front, so that timings hold only the localizer."""
    from evalkit import runner
    from evalkit.dataset import Dataset

    ds = Dataset.open(dataset)
    seqs = [(s["id"], [(f, ds.load_image(f)) for f in ds.iter_frames(s["id"])]) for s in ds.sequences]
    return ds, runner.camera_for_localizers(ds), seqs


def time_localizer(loc, camera: dict, seqs) -> pd.DataFrame:
    """Run ``loc`` over the sequences in order (reset per sequence, so ROI/tracking state
    is realistic); per frame: d_true, in-view flags, estimate, CPU ms (this thread) and wall ms."""
    rows = []
    for seq_id, frames in seqs:
        loc.reset({**camera, "sequence": seq_id})
        for frame, img in frames:
            c0, w0 = time.thread_time(), time.perf_counter()
            est = loc.localize(img)
            cpu, wall = 1e3 * (time.thread_time() - c0), 1e3 * (time.perf_counter() - w0)
            markers = frame.get("markers") or {}
            rows.append(
                {
                    "sequence": seq_id,
                    "d_true": frame.get("d_true"),
                    "cpu_ms": cpu,
                    "wall_ms": wall,
                    "in_view": any(bool(m.get("in_fov")) for m in markers.values()),
                    "in_fov": {k: bool(m.get("in_fov")) for k, m in markers.items()},
                    "success": isinstance(est, dict),
                    "marker": est.get("marker_id") if est else None,
                    "d_est": float(est["distance"]) if est else np.nan,
                }
            )
    return pd.DataFrame(rows)


def localizer_cpu_table(dataset: Path, names=LOCALIZERS) -> pd.DataFrame:
    """CPU ms per frame (one thread) of each localizer, default parameters, frames in order."""
    import cv2

    from evalkit import registry

    cv2.setNumThreads(1)
    _, camera, seqs = load_sequences(dataset)
    rows = []
    for name in names:
        loc = registry.resolve(name, {})
        df = time_localizer(loc, camera, seqs)
        cpu = df["cpu_ms"].to_numpy()
        rows.append(
            {
                "localizer": name,
                "frames": len(df),
                "cpu_ms_median": float(np.median(cpu)),
                "cpu_ms_mean": float(cpu.mean()),
                "cpu_ms_p95": float(np.percentile(cpu, 95)),
                "wall_ms_median": float(df["wall_ms"].median()),
                "P_succ_in_view": float(df.loc[df["in_view"], "success"].mean()),
                "estimates_by_marker": " ".join(f"{k}:{v}" for k, v in df["marker"].value_counts().items()),
                "near_range_m": getattr(loc, "near_range_m", np.nan),
            }
        )  # the hybrid's QR range
    return pd.DataFrame(rows)


def qr_decode_table(dataset: Path, detectors=QR_DETECTORS, marker_id: str | None = None) -> pd.DataFrame:
    """Per QR detector, over the frames with the QR marker in the field of view: successes
    (payload decoded and pose solved) per d_true bin, the farthest success and its
    px/module (f * module_size_m / d_true), CPU ms median (one thread)."""
    import cv2

    from evalkit.localizers.qr import QrLocalizer

    cv2.setNumThreads(1)
    ds, camera, seqs = load_sequences(dataset)
    qr = next(m for m in ds.markers if (m["id"] == marker_id if marker_id else m["kind"] == "qr"))
    module_m = qr.get("module_size_m") or qr["size_m"] / (qr.get("modules") or 21)
    K = np.asarray(camera["K"], float).reshape(3, 3)
    rows = []
    for det, params in detectors:
        df = time_localizer(QrLocalizer(marker_id=qr["id"], **params), camera, seqs)
        df = df[[bool(f.get(qr["id"])) for f in df["in_fov"]]]
        row = {"detector": det, "frames_in_view": len(df)}
        for lo, hi in RANGE_BINS_M:
            b = df[(df["d_true"] >= lo) & (df["d_true"] < hi)]
            row[f"{lo:g}-{hi:g} m"] = f"{int(b['success'].sum())}/{len(b)}"
        far = df.loc[df["success"], "d_true"].max() if df["success"].any() else np.nan
        row["farthest_m"] = far
        row["px_per_module_at_farthest"] = K[0, 0] * module_m / far if far == far else np.nan
        row["cpu_ms_median"] = float(df["cpu_ms"].median())
        rows.append(row)
    return pd.DataFrame(rows)


def led_centroid_table(dataset: Path) -> pd.DataFrame:
    """LED blob centroid error (px) against the true projected LED centres, per centroid
    mode (intensity-weighted vs saturated core) and d_true bin: each true LED in the image
    is matched to the nearest candidate blob (within 5 px)."""
    import cv2

    from evalkit.localizers.led import LedLocalizer

    ds, camera, seqs = load_sequences(dataset)
    led = next(m for m in ds.markers if m["kind"] == "led_array")
    K = np.asarray(camera["K"], float).reshape(3, 3)
    dist = camera.get("dist")
    dist = None if dist is None else np.asarray(dist, float)
    kp = np.asarray(led["keypoints"], float).reshape(-1, 1, 3)
    errs = {"weighted": [], "core": []}
    for mode in errs:
        loc = LedLocalizer(centroid=mode)
        loc.reset(camera)
        for _, frames in seqs:
            for frame, img in frames:
                T = np.asarray(frame["T_cam_dock"], float)
                uv = cv2.projectPoints(kp, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, dist)[0].reshape(-1, 2)
                blobs = loc.candidates(np.ascontiguousarray(img))
                if blobs is None:
                    continue
                for p in uv:
                    e = np.linalg.norm(blobs[0] - p, axis=1).min()
                    if e < 5.0:
                        errs[mode].append((frame["d_true"], e))
    rows = []
    for lo, hi in RANGE_BINS_M + ((0.0, float("inf")),):
        row = {"d_true": f"{lo:g}-{hi:g} m"}
        for mode, vals in errs.items():
            e = np.array([x for d, x in vals if lo <= d < hi])
            row[f"{mode}_n"] = len(e)
            row[f"{mode}_median_px"] = float(np.median(e)) if len(e) else np.nan
            row[f"{mode}_p95_px"] = float(np.percentile(e, 95)) if len(e) else np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def run_localizer_bench(dataset: Path, out: Path) -> None:
    """Print and write OUT/bench_localizer_cpu.csv and OUT/bench_qr_decoders.csv."""
    from evalkit.reports.tables import print_table

    out.mkdir(parents=True, exist_ok=True)
    cpu = localizer_cpu_table(dataset)
    click.echo("localizers, CPU ms per frame on one thread (cv2.setNumThreads(1), images decoded beforehand):")
    print_table(cpu, floatfmt=".2f")
    cpu.to_csv(out / "bench_localizer_cpu.csv", index=False)
    from evalkit.dataset import Dataset

    kinds = {m.get("kind") for m in Dataset.open(dataset).markers}
    for kind, table in (("qr", "QR decoders"), ("led_array", "LED centroids")):
        if kind not in kinds:
            click.echo(f"\n(no {kind} marker in {dataset}: no {table} table)")
    if "qr" not in kinds:
        return
    qr = qr_decode_table(dataset)
    click.echo("\nQR detectors on the frames with the QR in view (success = payload decoded + pose):")
    print_table(qr, floatfmt=".2f")
    qr.to_csv(out / "bench_qr_decoders.csv", index=False)
    if "led_array" not in kinds:
        return
    led = led_centroid_table(dataset)
    click.echo("\nLED centroid error vs the true projected LED centres (px):")
    print_table(led, floatfmt=".3f")
    led.to_csv(out / "bench_led_centroids.csv", index=False)


def run_bench(
    out: Path, frames: int, samples: tuple[int, ...], modes: tuple[str, ...] = ("physical", "article")
) -> None:
    """Run and print the tables for each image-formation mode in ``modes``; write them to
    OUT/bench_render.csv, OUT/bench_terms.csv and OUT/bench_localizers.csv."""
    from evalkit.reports.tables import print_table

    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for mode in modes:
        for s in samples:
            click.echo(f"rendering {frames} frames at 640x480, {s} spp, {mode} mode ...", err=True)
            rows.append(render_stages(out / f"{mode}-s{s}", frames, s, mode, progress=True))
    render_df = pd.DataFrame(rows)
    click.echo("\nrender stages (median ms/frame; scene_build once per sequence):")
    print_table(render_df, floatfmt=".1f")
    render_df.to_csv(out / "bench_render.csv", index=False)
    cpu_df = stage_cpu_table({m: out / f"{m}-s{max(samples)}" for m in modes})
    click.echo(f"\nCPU ms per rendered frame per stage and term at {max(samples)} spp (the worker's own timers):")
    print_table(cpu_df, floatfmt=".2f")
    cpu_df.to_csv(out / "bench_stage_cpu.csv", index=False)
    terms = term_costs(out / f"{modes[0]}-s{max(samples)}")
    click.echo("\nimage-formation terms on one 640x480 frame (median ms; a term switched off is not called):")
    print_table(terms, floatfmt=".2f")
    terms.to_csv(out / "bench_terms.csv", index=False)
    loc_df = pd.concat([localizer_speed(out / f"{mode}-s{max(samples)}") for mode in modes], ignore_index=True)
    click.echo(f"\nlocalizers on one core (cv2.setNumThreads(1)), on the {' and '.join(modes)} frames:")
    print_table(loc_df, floatfmt=".2f")
    loc_df.to_csv(out / "bench_localizers.csv", index=False)
