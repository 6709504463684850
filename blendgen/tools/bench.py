"""``dockbench bench``: where the time goes at 640x480, per stage and per localizer.

Renders the quickstart approach (``frames`` frames, 12 m -> 1 m) once per sample
count and image-formation mode (``physical``: ambient pass, per-surface depth light,
sensor noise; ``article``: none of them) with one worker using every core, reports
the median ms/frame of each stage from the worker's own timers and the cost of each
image-formation term on one 640x480 frame, then runs each built-in localizer on one
core over the frames and reports frames/s. A benchmark, not a test: nothing is
asserted; the numbers are printed and written to ``OUT/bench.csv``.
"""
from __future__ import annotations

from blendgen.config.bundled import bundled_file

import shutil
import time
from pathlib import Path

import click
import numpy as np
import pandas as pd

from blendgen.pipeline.generate import generate, timing_summary
from blendgen.config.models import load_experiment

LOCALIZERS = ("led", "qr", "aruco")


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


def render_stages(out: Path, frames: int, samples: int, mode: str = "physical") -> dict:
    """Generate the bench dataset; median ms/frame per stage and the wall time per frame."""
    if out.exists():
        shutil.rmtree(out)
    exp = bench_experiment(frames, samples, mode)
    t0 = time.perf_counter()
    man = generate(exp, out, workers=1, progress=False)
    wall = time.perf_counter() - t0
    st = timing_summary(out)
    n = sum(s["n_frames"] for s in man["sequences"])
    return {"mode": mode, "samples": samples, "frames": n, "scene_build_ms": 1e3 * st["scene_build"],
            "render_read_ms": 1e3 * st["render"], "depth_to_range_ms": 1e3 * st["depth_to_range"],
            "post_write_ms": 1e3 * st["post_write"],
            "render+write_ms": 1e3 * (st["render"] + st["depth_to_range"] + st["post_write"]),
            "wall_ms_per_frame": 1e3 * wall / n}


def _median_ms(fn, repeats: int = 15) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def term_costs(dataset: Path) -> pd.DataFrame:
    """Median ms of each image-formation term on one frame of a rendered bench dataset
    (its range and index passes, its image as the clean render, albedo 0.5). A term that
    is switched off is not called: its cost is 0 by construction."""
    import cv2
    from blendgen.config.models import Sensor, Water
    from blendgen.physics import optics, sensor
    from blendgen.pipeline import compose
    from blendgen.pipeline.plan import SequencePost
    from evalkit.dataset import Dataset
    ds = Dataset.open(dataset)
    frames = list(ds.iter_frames(ds.sequences[0]["id"]))
    f = frames[len(frames) // 2]
    K = np.asarray(ds.manifest["camera"]["K"], float)
    rgb = sensor.srgb_decode(ds.load_image(f)).astype(np.float32)
    passes = {"rgb": rgb, "albedo": np.full_like(rgb, 0.5),
              "range_m": np.load(ds.root / f["depth"])["range_m"].astype(np.float32),
              "index": cv2.imread(str(ds.root / f["object_index"]), cv2.IMREAD_UNCHANGED)}
    frame = {"T_world_cam": f["T_world_cam"]}
    markers = ds.markers

    def state(mode, **sens):
        return compose.SequenceState.start(SequencePost(
            seed=0, fps=10, image_formation=mode, water=Water(preset="mild"), light_depth_m=1.0, surface_z_m=0.0,
            irradiance_w_m2=3.2, sensor=Sensor(**sens)))
    phys, art = state("physical", noise=False), state("article")
    noisy, bloom = state("physical", noise=True), state("physical", noise=False, bloom_fraction=0.05)
    dist = [-0.2, 0.05, 0.0, 0.0, 0.0]
    rows = [
        ("ambient (albedo x L)", lambda: compose.add_ambient(dict(passes), 0.34)),
        ("surface depth map", lambda: compose.surface_depth(passes["range_m"], K, frame["T_world_cam"], 0.0)),
        ("water physical (incl. depth map)", lambda: compose.water_image(passes, phys, K, frame["T_world_cam"], markers)),
        ("water article", lambda: compose.water_image(passes, art, K, frame["T_world_cam"], markers)),
        ("  of which LED glow", lambda: optics.add_emitter_glow(
            rgb, compose.emissive_mask(passes["index"], markers), passes["range_m"], phys.water, float(K[0, 0]))),
        ("8-bit sRGB encode only (before: to_uint8)", lambda: sensor.to_uint8(rgb)),
        ("sensor, no noise", lambda: phys.camera.apply(rgb, phys.rng)),
        ("sensor, shot + read noise", lambda: noisy.camera.apply(rgb, noisy.rng)),
        ("sensor, blooming", lambda: bloom.camera.apply(rgb * 20, bloom.rng)),
        ("motion blur 5 px", lambda: sensor.motion_blur(rgb, (5.0, 1.0))),
        ("distortion RGB + index + range", lambda: (sensor.distort_image(rgb, K, dist),
                                                    compose.output_passes(passes, K, dist))),
    ]
    return pd.DataFrame([{"term": name, "ms_per_frame": _median_ms(fn)} for name, fn in rows])


def localizer_speed(dataset: Path) -> pd.DataFrame:
    """Frames/s of each built-in localizer on one core over a rendered dataset."""
    import cv2
    from evalkit import registry, runner
    from evalkit.dataset import Dataset
    cv2.setNumThreads(1)
    ds = Dataset.open(dataset)
    rows = []
    for name in LOCALIZERS:
        df = runner.evaluate(ds, [(name, registry.resolve(name, {}))], progress=False)
        ms = df["ms"].to_numpy()
        rows.append({"localizer": name, "frames": len(ms), "median_ms": float(np.median(ms)),
                     "p95_ms": float(np.percentile(ms, 95)), "frames_per_s": 1e3 / float(np.mean(ms)),
                     "P_succ_in_view": float(df.loc[df["in_view"], "success"].mean())})
    return pd.DataFrame(rows)


def run_bench(out: Path, frames: int, samples: tuple[int, ...]) -> None:
    """Run and print both tables; write them to OUT/bench_render.csv and OUT/bench_localizers.csv."""
    from evalkit.reports.tables import print_table
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for mode in ("physical", "article"):
        for s in samples:
            click.echo(f"rendering {frames} frames at 640x480, {s} spp, {mode} mode ...", err=True)
            rows.append(render_stages(out / f"{mode}-s{s}", frames, s, mode))
    render_df = pd.DataFrame(rows)
    click.echo("\nrender stages (median ms/frame; scene_build once per sequence):")
    print_table(render_df, floatfmt=".1f")
    render_df.to_csv(out / "bench_render.csv", index=False)
    terms = term_costs(out / f"physical-s{max(samples)}")
    click.echo("\nimage-formation terms on one 640x480 frame (median ms; a term switched off is not called):")
    print_table(terms, floatfmt=".2f")
    terms.to_csv(out / "bench_terms.csv", index=False)
    loc_df = localizer_speed(out / f"physical-s{max(samples)}")
    click.echo("\nlocalizers on one core (cv2.setNumThreads(1)):")
    print_table(loc_df, floatfmt=".2f")
    loc_df.to_csv(out / "bench_localizers.csv", index=False)
