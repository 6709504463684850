"""``dockbench bench``: where the time goes at 640x480, per stage and per localizer.

Renders the quickstart approach (``frames`` frames, 12 m -> 0.5 m) once per sample
count with one worker using every core, reports the median ms/frame of each
stage from the worker's own timers, then runs each built-in localizer on one
core over the frames and reports frames/s. A benchmark, not a test: nothing is
asserted; the numbers are printed and written to ``OUT/bench.csv``.
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

import click
import numpy as np
import pandas as pd

from blendgen.pipeline.generate import generate, timing_summary
from blendgen.config.models import load_experiment
from blendgen.config.bundled import bundled_file

LOCALIZERS = ("led", "qr", "aruco")


def bench_experiment(frames: int, samples: int):
    """Quickstart config reduced to one linear approach with ``frames`` frames."""
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    traj = exp.trajectories[0]
    traj.speed_mps = (traj.start_range_m - traj.end_range_m) * exp.camera.fps / (frames - 1)
    exp.trajectories = [traj]
    exp.render.samples = samples
    exp.name = f"bench-s{samples}"
    return exp


def render_stages(out: Path, frames: int, samples: int) -> dict:
    """Generate the bench dataset; median ms/frame per stage and the wall time per frame."""
    if out.exists():
        shutil.rmtree(out)
    exp = bench_experiment(frames, samples)
    t0 = time.perf_counter()
    man = generate(exp, out, workers=1, progress=False)
    wall = time.perf_counter() - t0
    st = timing_summary(out)
    n = sum(s["n_frames"] for s in man["sequences"])
    return {"samples": samples, "frames": n, "scene_build_ms": 1e3 * st["scene_build"],
            "render_read_ms": 1e3 * st["render"], "depth_to_range_ms": 1e3 * st["depth_to_range"],
            "post_write_ms": 1e3 * st["post_write"],
            "render+write_ms": 1e3 * (st["render"] + st["depth_to_range"] + st["post_write"]),
            "wall_ms_per_frame": 1e3 * wall / n}


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
    for s in samples:
        click.echo(f"rendering {frames} frames at 640x480, {s} spp ...", err=True)
        rows.append(render_stages(out / f"s{s}", frames, s))
    render_df = pd.DataFrame(rows)
    click.echo("\nrender stages (median ms/frame; scene_build once per sequence):")
    print_table(render_df, floatfmt=".1f")
    render_df.to_csv(out / "bench_render.csv", index=False)
    loc_df = localizer_speed(out / f"s{max(samples)}")
    click.echo("\nlocalizers on one core (cv2.setNumThreads(1)):")
    print_table(loc_df, floatfmt=".2f")
    loc_df.to_csv(out / "bench_localizers.csv", index=False)
