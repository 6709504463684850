"""``dockbench`` command line: generate datasets (Blender), evaluate localizers (no Blender).

User errors (bad config, bad dataset, unknown localizer, bad option) print one clear
message per problem and exit with code 2, never a traceback.
"""
from __future__ import annotations

import functools
import sys
from pathlib import Path

import click

USER_ERROR = 2


def _user_errors(fn):
    """Turn the project's user-error exceptions into a message and exit code 2."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from blendgen.config.models import ConfigError
        from evalkit.dataset import DatasetError
        from evalkit.registry import RegistryError
        try:
            return fn(*args, **kwargs)
        except (ConfigError, DatasetError, RegistryError, FileExistsError) as e:
            click.echo(f"error: {e}", err=True)
            sys.exit(USER_ERROR)
        except KeyboardInterrupt:
            click.echo("\ninterrupted: finished sequences are kept; re-run the same command to resume",
                       err=True)
            sys.exit(130)
    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="dockbench")
def main():
    """Synthetic datasets and evaluation for vision-based AUV docking localization."""


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="dataset directory (created; an interrupted run in it is resumed)")
@click.option("--workers", type=click.IntRange(1, 256), default=None,
              help="render processes at once (default: one per core)")
@click.option("--overwrite", is_flag=True, help="replace a dataset made from a different config")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local process pool, or Ray tasks (pip install 'dockbench[ray]')")
@click.option("--address", "ray_address", default=None,
              help="Ray cluster address (auto, host:6379, ray://host:10001); default: start a local Ray")
@_user_errors
def generate(config: Path, out: Path, workers: int | None, overwrite: bool, executor: str,
             ray_address: str | None):
    """Render the dataset described by CONFIG (YAML) into OUT."""
    from blendgen.pipeline.generate import generate as run, check_out_dir
    from blendgen.config.models import load_experiment
    exp = load_experiment(config)
    check_out_dir(exp, out, overwrite)
    manifest = run(exp, out, workers=workers, executor=executor, ray_address=ray_address)
    n = sum(s["n_frames"] for s in manifest["sequences"])
    click.echo(f"dataset {manifest['name']} {manifest['version']}: {len(manifest['sequences'])} sequences, "
               f"{n} frames -> {out} (content hash {manifest['content_hash'][:12]})")


@main.command()
@click.argument("dataset", type=click.Path(file_okay=False, path_type=Path))
@click.option("-l", "--localizer", "localizers", multiple=True, required=True,
              help="built-in name, entry point, path/file.py:Class, module:attr or exec:COMMAND "
                   "(any language, datasets_spec/LOCALIZER_PROTOCOL.md); repeatable")
@click.option("-p", "--param", "params", multiple=True,
              help="key=value for every localizer's constructor, or NAME.key=value for one (repeatable)")
@click.option("-o", "--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--frame-timeout", type=click.FloatRange(min=0.001), default=None,
              help="seconds per frame; slower frames fail with 'timeout'; turns on --isolate")
@click.option("--isolate", is_flag=True,
              help="run each Python localizer in its own child process: a hang past --frame-timeout "
                   "(default 60 s) is killed and a crash costs one frame")
@click.option("--preprocess", default=None, metavar="STEPS",
              help="image preprocessing before every localizer, e.g. clahe,grayworld or median:k=5,clahe:clip=3 "
                   "(denoise, bilateral, median, gaussian, clahe, stretch, gain, gamma, grayworld)")
@_user_errors
def evaluate(dataset: Path, localizers: tuple[str, ...], params: tuple[str, ...], out: Path,
             frame_timeout: float | None, isolate: bool, preprocess: str | None):
    """Run localizers over DATASET; write tables, plots and per-frame estimates to OUT."""
    import pandas as pd
    from evalkit.reports import results
    from evalkit.reports import tables
    ds, paths = results.evaluate_dataset(dataset, localizers, out, params, isolate, frame_timeout, preprocess)
    tables.print_table(pd.read_csv(paths["summary"]))
    click.echo("\n" + paths["article_md"].read_text())
    click.echo(f"per-frame estimates: {paths['estimates']}\nsummary: {paths['summary']}\nrun: {out / 'run.json'}")
    click.echo(f"(e_rel excludes frames with d_true < {ds.d_min_rel_m} m; only 0 <= d_true <= 10 m count)")


@main.command("localizers")
def list_localizers():
    """List registered localizers (built-ins and entry points)."""
    from evalkit.registry import list_localizers as ls
    for name, target, doc in ls():
        click.echo(f"{name:12s} {target:45s} {doc}")


@main.command()
@click.argument("dataset", type=click.Path(file_okay=False, path_type=Path))
@_user_errors
def verify(dataset: Path):
    """Check every file of DATASET against the sha256 in its manifest."""
    from evalkit.dataset import DatasetError, verify as check
    problems = check(dataset)
    if problems:
        raise DatasetError(f"{dataset}: {len(problems)} problem(s):\n  " + "\n  ".join(problems))
    click.echo(f"{dataset}: ok")


@main.command("station-keeping")
@click.option("--flow", type=click.FloatRange(0.0, 2.0), default=0.5, show_default=True, help="flow speed (m/s)")
@click.option("--duration", type=click.FloatRange(5.0, 3600.0), default=60.0, show_default=True,
              help="simulated seconds per row (steady values: mean of the last 10 s)")
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="also write the table as CSV")
def station_keeping(flow: float, duration: float, out: Path | None):
    """The article's Table 5: steady thruster outputs while station keeping."""
    from blendgen.vehicle.docking import station_keeping_signs_ok, station_keeping_table
    from evalkit.reports.tables import print_table
    df = station_keeping_table(flow_speed=flow, duration_s=duration)
    print_table(df, floatfmt=".3f")
    unit = df.attrs.get("unit_N")
    click.echo(f"\nthrust per group: mean of its two thrusters, in N and in normalised units "
               f"(1 unit = {unit:.3f} N, so the benchmark vertical reads 6 as in the article)")
    for k, ok in station_keeping_signs_ok(df).items():
        click.echo(f"  {'ok ' if ok else 'BAD'} {k}")
    if out:
        df.to_csv(out, index=False)


@main.command("docking-paths")
@click.option("--current", "currents", multiple=True, type=click.FloatRange(0.0, 2.0),
              help="lateral current (m/s), repeatable (default 0, 0.5, 1.0)")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=1, show_default=True)
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path),
              default=Path("out/docking_paths.png"), show_default=True)
def docking_paths_cmd(currents: tuple[float, ...], seed: int, out: Path):
    """Plot one docking trial per lateral current (same start) and time the dynamics."""
    import numpy as np
    from blendgen.tools.dynamics_report import docking_paths, plot_docking_paths
    runs = docking_paths(currents or (0.0, 0.5, 1.0), seed=seed)
    for r in runs:
        click.echo(f"current {r['current_mps']:.2f} m/s: {r['stop_reason']} after {r['t'][-1]:.1f} s, "
                   f"heading std {np.std(r['heading_error_deg']):.2f} deg, "
                   f"final lateral {r['p_dock'][-1, 0]:+.2f} m, {r['ms_per_sim_s']:.2f} ms CPU per simulated s")
    click.echo(f"plot: {plot_docking_paths(runs, out)}")


@main.group(invoke_without_command=True)
@click.pass_context
def bench(ctx: click.Context):
    """Benchmarks (print and write CSV; nothing is asserted). Without a subcommand: stages."""
    if ctx.invoked_subcommand is None:
        ctx.invoke(bench_stages)


@bench.command("stages")
@click.option("--frames", type=click.IntRange(5, 10000), default=40, help="frames to render per setting")
@click.option("--samples", "samples", multiple=True, type=click.IntRange(1, 4096),
              help="Cycles samples to time (repeatable; default 1 and 4)")
@click.option("-o", "--out", "out", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/bench"), show_default=True)
@_user_errors
def bench_stages(frames: int, samples: tuple[int, ...], out: Path):
    """Time each stage at 640x480 (scene build, render + EXR read, depth to range, post+write) and localizer frames/s."""
    from blendgen.tools.bench import run_bench
    run_bench(out, frames, samples or (1, 4))


def _register() -> None:
    """Commands defined next to their code (imports inside them stay lazy)."""
    from evalkit.reports.bop import export_bop_cmd
    from evalkit.reports.leaderboard import leaderboard_cmd
    from blendgen.tools.fidelity import calibrate_water_cmd, fidelity_cmd
    from blendgen.tools.preview import preview_cmd
    from blendgen.tools.reproduce import reproduce_cmd
    main.add_command(leaderboard_cmd)
    reproduce_cmd.callback = _user_errors(reproduce_cmd.callback)
    main.add_command(reproduce_cmd)
    main.add_command(export_bop_cmd)
    main.add_command(calibrate_water_cmd)
    main.add_command(preview_cmd)
    bench.add_command(fidelity_cmd, "fidelity")
    from blendgen.tools import suitebench
    suite_cmd = suitebench.make_command()
    suite_cmd.callback = _user_errors(suite_cmd.callback)
    bench.add_command(suite_cmd, "suite")
    from blendgen.tools.calibration import calibrate_cmd
    calibrate_cmd.callback = _user_errors(calibrate_cmd.callback)
    main.add_command(calibrate_cmd)
    from evalkit.pnp_bench import pnp_cmd
    bench.add_command(pnp_cmd, "pnp")


_register()

if __name__ == "__main__":
    main()
