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
        except (OSError, RuntimeError) as e:  # a full disk here or in a worker: one line; else re-raised
            from datasets_spec.outdir import disk_full_message

            text = disk_full_message(e, kwargs.get("out"))
            if text is None:
                raise
            click.echo(f"error: {text}", err=True)
            sys.exit(USER_ERROR)
        except KeyboardInterrupt:
            hint = (
                "finished sequences (and their evaluations) are kept; re-run the same command to resume"
                if fn.__name__ in ("generate", "run")
                else "stopped by Ctrl-C (SIGINT)"
            )
            click.echo(f"\ninterrupted: {hint}", err=True)
            sys.exit(130)

    return wrapper


def _writes_out(command: str):
    """``-o`` of a command that writes into it as it goes follows :mod:`datasets_spec.outdir`'s rule
    (new, empty or this command's own folder, never a dataset; else ``--overwrite``) and its
    lock, checked before any work. Adds ``--overwrite``."""

    def deco(fn):
        @functools.wraps(fn)
        def wrapper(*args, overwrite_out: bool = False, **kwargs):
            from datasets_spec import outdir

            out = kwargs.get("out")
            if out is None:
                return fn(*args, **kwargs)
            with outdir.writing(out, command, overwrite_out):
                return fn(*args, **kwargs)

        return click.option(
            "--overwrite",
            "overwrite_out",
            is_flag=True,
            help="write into a non-empty -o that this command did not write",
        )(wrapper)

    return deco


class _Commands(click.Group):
    """A command group whose every subcommand gets the same user-error handling (exit 2)."""

    def invoke(self, ctx: click.Context):
        return _user_errors(super().invoke)(ctx)


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="dockbench")
def main():
    """Synthetic datasets and evaluation for vision-based AUV docking localization."""


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    default=None,
    type=click.Path(file_okay=False, path_type=Path),
    help="dataset directory (created; an interrupted run in it is resumed); required unless --show-config",
)
@click.option(
    "--workers", type=click.IntRange(1, 256), default=None, help="render processes at once (default: one per core)"
)
@click.option("--overwrite", is_flag=True, help="replace a dataset made from a different config")
@click.option(
    "--executor",
    type=click.Choice(["local", "ray"]),
    default="local",
    show_default=True,
    help="local process pool, or Ray tasks (pip install 'dockbench[ray]')",
)
@click.option(
    "--address",
    "ray_address",
    default=None,
    help="Ray cluster address (auto, host:6379, ray://host:10001); default: start a local Ray",
)
@click.option(
    "--show-config",
    is_flag=True,
    help="print the effective config (YAML: every mode-dependent default resolved) and exit; renders nothing",
)
@_user_errors
def generate(
    config: Path,
    out: Path | None,
    workers: int | None,
    overwrite: bool,
    executor: str,
    ray_address: str | None,
    show_config: bool,
):
    """Render the dataset described by CONFIG (a YAML file, or a bundled config's name: dockbench configs) into OUT."""
    from blendgen.config.models import load_experiment
    from blendgen.pipeline.generate import check_out_dir
    from blendgen.pipeline.generate import generate as run

    exp = load_experiment(config)
    if show_config:
        from blendgen.config.effective import as_yaml

        click.echo(as_yaml(exp), nl=False)
        return
    if out is None:
        raise click.UsageError("Missing option '-o' / '--out' (the dataset directory).")
    check_out_dir(exp, out, overwrite)
    manifest = run(exp, out, workers=workers, executor=executor, ray_address=ray_address)
    n = sum(s["n_frames"] for s in manifest["sequences"])
    click.echo(
        f"dataset {manifest['name']} {manifest['version']}: {len(manifest['sequences'])} sequences, "
        f"{n} frames -> {out} (content hash {manifest['content_hash'][:12]})"
    )


def _command_line(ctx: click.Context) -> list[str]:
    """The invocation as a canonical argv (every option spelled out, defaults included), so
    run.json can be replayed exactly even when the command was called from Python."""
    argv, positional = ["dockbench", *ctx.command_path.split()[1:]], []
    for param in ctx.command.params:
        value = ctx.params.get(param.name)
        if isinstance(param, click.Argument):
            positional.append(str(value))
            continue
        flag = max(param.opts, key=len)
        if getattr(param, "is_flag", False):
            argv += [flag] if value else []
        elif value is not None:
            argv += [x for v in (value if param.multiple else [value]) for x in (flag, str(v))]
    return argv + positional


@main.command()
@click.argument("dataset", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "-l",
    "--localizer",
    "localizers",
    multiple=True,
    required=True,
    help="built-in name, entry point, path/file.py:Class, module:attr or exec:COMMAND "
    "(any language, datasets_spec/LOCALIZER_PROTOCOL.md); repeatable",
)
@click.option(
    "-p",
    "--param",
    "params",
    multiple=True,
    help="key=value for every localizer's constructor, or NAME.key=value for one (repeatable)",
)
@click.option(
    "-o",
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="results folder (must be empty or absent unless --overwrite)",
)
@click.option("--overwrite", is_flag=True, help="replace a non-empty results folder")
@click.option(
    "--no-verify",
    is_flag=True,
    help="do not check the files read against the manifest's sha256 (recorded in run.json; "
    "the content hash is then recomputed from the bytes on disk)",
)
@click.option(
    "--frame-timeout",
    type=click.FloatRange(min=0.001),
    default=None,
    help="seconds per frame; slower frames fail with 'timeout'; turns on --isolate",
)
@click.option(
    "--isolate/--in-process",
    default=None,
    help="run each Python localizer in its own child process (memory-capped): a hang past "
    "--frame-timeout (default 30 s) is killed and a crash or os._exit costs one frame. "
    "Default: plugins (file.py:Class, module:attr, entry points) isolated, built-ins in process. "
    "Children get 4096 MiB of address space (env DOCKBENCH_MEMORY_LIMIT_MB, 0 = unlimited)",
)
@click.option(
    "--preprocess",
    default=None,
    metavar="STEPS",
    help="image preprocessing before every localizer, e.g. clahe,grayworld or median:k=5,clahe:clip=3 "
    "(denoise, bilateral, median, gaussian, clahe, stretch, gain, gamma, grayworld)",
)
@click.option(
    "--max-rel-error",
    "max_rel_dist",
    type=click.FloatRange(min=0.0, min_open=True),
    default=0.10,
    show_default=True,
    help="success: |d_est - d_true| <= this x d_true (or --min-tol)",
)
@click.option(
    "--min-tol",
    "min_tol_m",
    type=click.FloatRange(min=0.0, min_open=True),
    default=0.05,
    show_default=True,
    help="success: smallest distance/translation tolerance (m)",
)
@click.option(
    "--max-rel-trans",
    type=click.FloatRange(min=0.0, min_open=True),
    default=0.10,
    show_default=True,
    help="success with a pose: |t_est - t_true| <= this x d_true (or --min-tol)",
)
@click.option(
    "--max-rot-deg",
    type=click.FloatRange(min=0.0, min_open=True),
    default=10.0,
    show_default=True,
    help="success with a pose: rotation error <= this (deg)",
)
@click.option("--quiet", "-q", is_flag=True, help="print nothing but errors (no table, no progress bar)")
@click.option(
    "--json", "as_json", is_flag=True, help="print a machine-readable summary (JSON) on stdout instead of the tables"
)
@_user_errors
def evaluate(
    dataset: Path,
    localizers: tuple[str, ...],
    params: tuple[str, ...],
    out: Path,
    overwrite: bool,
    no_verify: bool,
    frame_timeout: float | None,
    isolate: bool | None,
    preprocess: str | None,
    max_rel_dist: float,
    min_tol_m: float,
    max_rel_trans: float,
    max_rot_deg: float,
    quiet: bool,
    as_json: bool,
):
    """Run localizers over DATASET; write tables, plots and per-frame estimates to OUT.

    A frame *succeeds* when the answer is within the error bounds (--max-rel-error,
    --min-tol and, for localizers that return a pose, --max-rel-trans / --max-rot-deg)
    and is no false positive; P_detect is the rate of any answer (the article's rate).
    (15 parameters: one per command-line option.)
    """
    from evalkit.metrics.core import SuccessCriteria
    from evalkit.metrics.extra import EvalSettings
    from evalkit.reports import results

    criteria = SuccessCriteria(max_rel_dist, min_tol_m, max_rel_trans, max_rot_deg)
    req = results.EvalRequest(
        dataset,
        list(localizers),
        out,
        list(params),
        isolate,
        frame_timeout,
        preprocess,
        verify=not no_verify,
        overwrite=overwrite,
        progress=not quiet,
        settings=EvalSettings(criteria=criteria),
        command=_command_line(click.get_current_context()),
    )
    if no_verify and not quiet:
        click.echo("warning: --no-verify: dataset files are read unchecked (recorded in run.json)", err=True)
    ds, paths, res = results.evaluate_dataset(req)
    if as_json:
        click.echo(results.json_summary(paths["run"]))
    elif not quiet:
        click.echo("\n" + paths["article_md"].read_text())
        click.echo(paths["range_bins_md"].read_text())
        click.echo(f"plots: {paths['plot_range_bins'].parent}" if "plot_range_bins" in paths else "")
        click.echo(f"per-frame estimates: {paths['estimates']}\nmetrics: {paths['metrics']}\nrun: {paths['run']}")
        click.echo(
            f"(success: {criteria.as_dict()}; only 0 <= d_true <= 10 m count; "
            f"e_rel excludes d_true < {ds.d_min_rel_m} m)"
        )


@main.command("configs")
def list_configs():
    """List the bundled configs (usable by name: dockbench generate quickstart -o OUT)."""
    from blendgen.config.bundled import bundled_file, bundled_names, config_summary

    for name in bundled_names("configs"):
        click.echo(f"{name:18s} {config_summary(name)}")
    click.echo(f"(files in {bundled_file('configs', '')})")


@main.command("localizers")
def list_localizers():
    """List registered localizers (built-ins and entry points)."""
    from evalkit.registry import list_localizers as ls

    for name, target, doc in ls():
        click.echo(f"{name:12s} {target:45s} {doc}")


@main.command()
@click.argument("dataset", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--stream",
    "stream_json",
    type=click.Path(dir_okay=False, exists=True, path_type=Path),
    default=None,
    help="also check DATASET (a later generate of the config) against a run's stream.json: files by "
    "sha256, images and passes the run did not keep by their decoded pixels",
)
@_user_errors
def verify(dataset: Path, stream_json: Path | None):
    """Check every file of DATASET against the sha256 in its manifest."""
    from evalkit.dataset import DatasetError
    from evalkit.dataset import verify as check

    problems = check(dataset)
    if stream_json is not None and not problems:
        from evalkit.stream import check_against, load_stream_summary

        problems = check_against(load_stream_summary(stream_json), dataset)
    if problems:
        raise DatasetError(f"{dataset}: {len(problems)} problem(s):\n  " + "\n  ".join(problems))
    click.echo(f"{dataset}: ok")


@main.command("station-keeping")
@click.option("--flow", type=click.FloatRange(0.0, 2.0), default=0.5, show_default=True, help="flow speed (m/s)")
@click.option(
    "--duration",
    type=click.FloatRange(5.0, 3600.0),
    default=60.0,
    show_default=True,
    help="simulated seconds per row (steady values: mean of the last 10 s)",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="also write the table as CSV",
)
def station_keeping(flow: float, duration: float, out: Path | None):
    """The article's Table 5: steady thruster outputs while station keeping."""
    from blendgen.vehicle.docking import station_keeping_signs_ok, station_keeping_table
    from datasets_spec.outdir import check_file_out
    from evalkit.reports.tables import print_table

    check_file_out(out, "station-keeping")
    df = station_keeping_table(flow_speed=flow, duration_s=duration)
    print_table(df, floatfmt=".3f")
    unit = df.attrs.get("unit_N")
    click.echo(
        f"\nthrust per group: mean of its two thrusters, in N and in normalised units "
        f"(1 unit = {unit:.3f} N, so the benchmark vertical reads 6 as in the article)"
    )
    for k, ok in station_keeping_signs_ok(df).items():
        click.echo(f"  {'ok ' if ok else 'BAD'} {k}")
    if out:
        df.to_csv(out, index=False)


@main.command("authority")
@click.option(
    "--speed",
    "speeds",
    multiple=True,
    type=click.FloatRange(0.0, 5.0),
    help="flow speed (m/s), repeatable (default 0.5 and 1.0)",
)
@click.option(
    "--density", type=click.FloatRange(900.0, 1100.0), default=1025.0, show_default=True, help="water density (kg/m^3)"
)
@click.option("--experiment", default=None, help="also judge each condition of this paper experiment or config")
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="also write the station-keeping table as CSV",
)
def authority_cmd(speeds: tuple[float, ...], density: float, experiment: str | None, out: Path | None):
    """Can the thrusters hold station (and dock) against a steady current? Steady drag vs thrust limits."""
    import pandas as pd

    from blendgen.vehicle.authority import station_keeping_authority
    from evalkit.reports.tables import print_table

    exp_table = _experiment_authority(experiment) if experiment else None  # user errors first
    df = pd.DataFrame(station_keeping_authority(speeds or (0.5, 1.0), density))
    print_table(df, floatfmt=".3g")
    click.echo(
        "flow = direction the water pushes the vehicle (body axes); group thrust = mean of each pair "
        "(N, + forward/left/up); utilisation = largest thruster share / its forward or reverse limit; "
        "max_speed = largest holdable flow in that direction"
    )
    if exp_table is not None:
        click.echo(exp_table)
    if out:
        df.to_csv(out, index=False)


def _experiment_authority(experiment: str) -> str:
    """The docking authority of each condition of an experiment, as text."""
    import pandas as pd

    from blendgen.config.models import ConfigError
    from blendgen.tools.apps.closed_loop import capture_spec, condition_authority, load_bench_experiment
    from blendgen.vehicle.dynamics import VehicleParams

    exp = load_bench_experiment(experiment, None, ())
    traj = next((t for t in exp.trajectories if t.kind == "docking"), None)
    if traj is None:
        raise ConfigError(f"--experiment {experiment}: the config has no docking trajectory")
    capture = capture_spec(traj, exp.scene.dock.body_size_m, VehicleParams().diameter / 2)
    rows = []
    for c in exp.conditions:
        a = condition_authority(exp, c)
        rows.append(
            {
                "condition": c.label,
                "current_mps": str(list((c.fluid or exp.fluid).current_mps)),
                "heading_offset_deg": a["heading_offset_deg"],
                "utilisation": a["utilisation"],
                "max_current_mps": a["max_current_mps"],
                "verdict": a["verdict"],
            }
        )
    from evalkit.reports.tables import to_markdown

    return (
        f"\n{exp.name}: docking at {traj.final_speed_mps:g} m/s with |heading error| <= "
        f"{capture.max_heading_deg:g} deg (best crab angle within it)\n"
        + to_markdown(pd.DataFrame(rows), floatfmt=".3g")
    )


@main.command("docking-paths")
@click.option(
    "--current",
    "currents",
    multiple=True,
    type=click.FloatRange(0.0, 2.0),
    help="lateral current (m/s), repeatable (default 0, 0.5, 1.0)",
)
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=1, show_default=True)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="PNG to write: the top view of one docking trial per current",
)
def docking_paths_cmd(currents: tuple[float, ...], seed: int, out: Path):
    """Plot one docking trial per lateral current (same start), judged by `dock`'s capture geometry."""
    import numpy as np

    from blendgen.tools.apps.dynamics_report import docking_paths, plot_docking_paths
    from datasets_spec.outdir import check_file_out

    check_file_out(out, "docking-paths")
    runs = docking_paths(currents or (0.0, 0.5, 1.0), seed=seed)
    for r in runs:
        hit = f", {r['contact_part']} hit at {r['impact_speed_mps']:.2f} m/s" if r["outcome"] == "collision" else ""
        crossing = (
            f"crossing lateral {r['cross_lateral_m']:+.2f} m, heading {r['cross_heading_deg']:+.1f} deg"
            if np.isfinite(r["cross_lateral_m"])
            else "no entry-plane crossing"
        )
        click.echo(
            f"current {r['current_mps']:.2f} m/s: {r['outcome']}{hit} after {r['t'][-1]:.1f} s ({crossing}), "
            f"authority: {r['authority']}, heading std {np.std(r['heading_error_deg']):.2f} deg, "
            f"{r['ms_per_sim_s']:.2f} ms CPU per simulated s"
        )
    click.echo(f"plot: {plot_docking_paths(runs, out)}")


@main.group(cls=_Commands)
def bench():
    """Benchmarks (print and write CSV under -o; nothing is asserted)."""


def _bench_mode(fn):
    """``--mode physical|article|both`` (default both), given to the command as ``modes``: a
    tuple of image formations; it overrides the experiments' ``image_formation``."""

    @functools.wraps(fn)
    def inner(*args, mode: str, **kwargs):
        return fn(*args, modes=("physical", "article") if mode == "both" else (mode,), **kwargs)

    return click.option(
        "--mode",
        type=click.Choice(["physical", "article", "both"]),
        default="both",
        show_default=True,
        help="image formation of the measured runs (overrides the configs'); both: side by side",
    )(inner)


@bench.command("stages")
@_writes_out("bench")
@click.option("--frames", type=click.IntRange(5, 10000), default=40, help="frames to render per setting")
@click.option(
    "--samples",
    "samples",
    multiple=True,
    type=click.IntRange(1, 4096),
    help="Cycles samples to time (repeatable; default 1 and 4)",
)
@_bench_mode
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory to write bench_render.csv, bench_stage_cpu.csv, bench_terms.csv and bench_localizers.csv "
    "into (and the renders)",
)
@_user_errors
def bench_stages(frames: int, samples: tuple[int, ...], modes: tuple[str, ...], out: Path):
    """Time each stage at 640x480 (scene build, render + EXR read, depth to range, post+write; CPU per stage and
    term) and localizer frames/s, per image-formation mode."""
    from blendgen.tools.bench.stages import run_bench

    run_bench(out, frames, samples or (1, 4), modes)


def _size_options(fn):
    """Image size and reference settings shared by `bench fidelity` and `calibrate-water`."""
    fn = click.option(
        "--frames",
        type=click.IntRange(2, 50),
        default=4,
        show_default=True,
        help="frames of the approach, evenly spaced from 10 m to 1 m",
    )(fn)
    fn = click.option(
        "--ref-samples",
        type=click.IntRange(1, 65536),
        default=64,
        show_default=True,
        help="reference spp (the medium is single-scatter and low-noise)",
    )(fn)
    return _wh_size("320x240")(fn)


def _wh_size(default: str):
    """``--size WxH`` (16..8192 px each), given to the command as ``width=``, ``height=``."""

    def deco(fn):
        @functools.wraps(fn)
        def inner(*args, size, **kwargs):
            return fn(*args, width=size[0], height=size[1], **kwargs)

        return click.option(
            "--size",
            callback=lambda c, p, v: _suite_size(c, p, v),
            default=default,
            show_default=True,
            metavar="WxH",
            help="image size, e.g. 320x240",
        )(inner)

    return deco


@bench.command("io")
@click.option(
    "--dataset",
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    default=None,
    help="time its camera images (default: synthetic 640x480 frames)",
)
@_user_errors
def bench_io(dataset: Path | None):
    """CPU per frame of PNG vs raw camera images and passes (what `run` skips for frames not kept), and of the
    render EXR read (direct vs OpenImageIO, same bytes)."""
    from blendgen.tools.bench.iobench import run_io_bench

    run_io_bench(dataset)


@bench.command("fidelity")
@_writes_out("bench")
@_size_options
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for veil.csv, fidelity.csv, fidelity_pareto.png and the fast and reference renders",
)
@click.option(
    "--volume-bounces",
    type=click.IntRange(0, 128),
    default=32,
    show_default=True,
    help="multiple scattering of the reference medium (32 converge the veil)",
)
@click.option("--veil-only", is_flag=True, help="only the veil residual table (no renders)")
@click.option(
    "--caustics", is_flag=True, help="caustics on in both fidelities (the reference's from a photon map per frame)"
)
def bench_fidelity(
    width: int,
    height: int,
    ref_samples: int,
    frames: int,
    out: Path,
    volume_bounces: int,
    veil_only: bool,
    caustics: bool,
):
    """Time vs image error vs localization change of fast water settings against the reference.

    First the physical veil: the fast model vs the stored multiple-scattering Cycles references
    of `calibrate-veil` per preset, depth, view elevation and channel (OUT/veil.csv). Then renders
    the held-in set (clear/mild/moderate/jerlov_1C, 10 m -> 1 m) once as a Cycles medium with
    VOLUME_BOUNCES and once per fast setting; writes OUT/fidelity.csv and OUT/fidelity_pareto.png."""
    from blendgen.tools.bench.fidelity import run_bench, veil_residual_table
    from evalkit.reports.tables import print_table

    out.mkdir(parents=True, exist_ok=True)
    vt = veil_residual_table()
    vt.to_csv(out / "veil.csv", index=False)
    wide = vt.pivot_table(index=["preset", "depth_m", "elev_deg"], columns="ch", values="rel_err", sort=False)
    print_table(wide.reset_index(), floatfmt=".3f")
    ok = vt[vt["reference"] > 1e-4]
    click.echo(
        f"\nveil fast/reference - 1 over {len(ok)} points x channels with reference > 1e-4: max |.| "
        f"{ok['rel_err'].abs().max():.3f}, median |.| {ok['rel_err'].abs().median():.3f} "
        f"(isotropic-equivalent estimate before: median |.| {ok['rel_err_isotropic'].abs().median():.2f}, "
        f"max {ok['rel_err_isotropic'].abs().max():.1f}); {out / 'veil.csv'}\n"
    )
    if veil_only:
        return
    df = run_bench(
        out,
        width,
        height,
        frames,
        ref_samples,
        echo=lambda m: click.echo(m, err=True),
        volume_bounces=volume_bounces,
        caustics=caustics,
    )
    cols = [
        "setting",
        "condition",
        "width",
        "ms_per_frame",
        "psnr_db",
        "mae",
        "dP_succ_led",
        "de_rel_led",
        "dP_succ_qr",
        "de_rel_qr",
    ]
    print_table(df[cols], floatfmt=".3g")
    click.echo(
        f"\n{out / 'fidelity.csv'}\n{out / 'fidelity_pareto.png'}\n(ms are medians on shared cores: noisy; "
        "errors in linear RGB over the marker region; d* = fast - reference)"
    )


@bench.command("render-settings")
@_writes_out("bench")
@click.argument("base", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("variant", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("-l", "--localizer", "names", multiple=True, default=("led", "qr", "aruco"), show_default=True)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory to write the image and localization delta tables into",
)
def bench_render_settings(base: Path, variant: Path, names: tuple[str, ...], out: Path):
    """Image and localization deltas of two datasets made from one config with different
    `render` settings (same seed: same camera paths and noise), e.g. per-marker ROIs vs one
    dock box: marker-region DN/PSNR and off-marker DN by range, P_succ and E_rel per localizer."""
    from blendgen.tools.bench.render_settings import run

    run(base, variant, out, echo=click.echo, names=names)


@bench.command("pnp")
@_writes_out("bench")
@click.option(
    "--trials",
    type=click.IntRange(5, 100000),
    default=60,
    show_default=True,
    help="random poses per (target, Z, angle, noise) cell",
)
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=0, show_default=True)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory to write pnp.csv and pnp.png into",
)
def bench_pnp(trials: int, seed: int, out: Path):
    """Stress the planar PnP solvers: error vs distance/angle/noise against the Z^2 law,
    wrong IPPE-branch picks (naive vs disambiguated), NaN and behind-camera solutions."""
    import time

    from evalkit.pnp_bench import format_report, plot, run_sweep

    t0 = time.perf_counter()
    df = run_sweep(n_trials=trials, seed=seed)
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / "pnp.csv", index=False)
    plot(df, out / "pnp.png")
    click.echo(format_report(df))
    click.echo(f"\n{len(df)} cells in {time.perf_counter() - t0:.1f} s -> {out / 'pnp.csv'}, {out / 'pnp.png'}")


@bench.command("particles")
@click.option(
    "-n",
    "--count",
    "counts",
    type=click.IntRange(0, 20_000_000),
    multiple=True,
    help="particles in the 600 m^3 pool (repeatable; default 600, 6000, 60000)",
)
@click.option(
    "--size",
    callback=lambda c, p, v: _suite_size(c, p, v),
    default="640x480",
    show_default=True,
    metavar="WxH",
    help="image size, e.g. 320x240",
)
@click.option("--frames", type=click.IntRange(1, 1000), default=10, show_default=True)
@click.option(
    "--fidelity",
    "fidelity_out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="instead: fast particles vs real spheres in the render (Blender), datasets under this dir "
    "(-n: the particle counts, default 6000 and 60000; --frames: frames of the approach)",
)
def bench_particles(counts: tuple[int, ...], size: tuple[int, int], frames: int, fidelity_out: Path | None):
    """Fast-path cost of small obstacles per frame (add_particles: cull, light, blur, draw), CPU and wall ms;
    or, with --fidelity, fast vs reference particles (coverage, IoU, contrast, visible fractions,
    LED and QR localization: P_succ and E_rel deltas)."""
    import os

    if fidelity_out is not None:
        import pandas as pd

        from blendgen.tools.bench.particle_fidelity import COUNTS, compare
        from evalkit.reports.tables import print_table

        rows, loc = compare(fidelity_out, *size, counts=counts or COUNTS, frames=frames)
        df = pd.DataFrame(rows)
        print_table(df, floatfmt=".3g")
        click.echo("\nmean per condition:")
        print_table(df.drop(columns="frame").groupby("condition").mean().reset_index(), floatfmt=".3g")
        click.echo("\nlocalization, fast vs reference (P_succ, E_rel = e_rel_mean of detected frames):")
        print_table(loc, floatfmt=".3g")
        return
    from blendgen.tools.bench.particle_bench import format_row, run

    click.echo(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (wall times are upper bounds)")
    for n in counts or (600, 6000, 60000):
        for dist, lamp, formation in (
            ("power_law", True, "physical"),
            ("uniform", True, "physical"),
            ("uniform", False, "article"),
        ):  # the last: paper_occlusion.yaml
            click.echo(format_row(run(n, size[0], size[1], frames, dist, lamp, formation)))


@bench.command("glow")
@_writes_out("bench")
@click.option("--samples", type=click.IntRange(1, 65536), default=64, show_default=True)
@click.option("--size", type=click.IntRange(16, 1024), default=96, show_default=True)
@click.option(
    "--volume-bounces",
    type=click.IntRange(0, 1024),
    default=0,
    show_default=True,
    help="0: single-scatter model vs single-scatter Cycles; > 0: the widening multiple-scatter "
    "kernel vs Cycles with that many volume bounces",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for glow.csv and the Cycles medium renders",
)
def bench_glow(samples: int, size: int, volume_bounces: int, out: Path):
    """Emitter glow: fast PSF vs the Cycles medium (HG g 0.9), mild/moderate x 2/5/8 m: energy and radius."""
    from blendgen.tools.bench.fidelity import glow_comparison
    from evalkit.reports.tables import print_table

    df = glow_comparison(out, size=size, samples=samples, volume_bounces=volume_bounces)
    print_table(df, floatfmt=".4g")
    df.to_csv(out / "glow.csv", index=False)
    click.echo(
        f"\n{out / 'glow.csv'} (green channel; EE relative to the unscattered irradiance; "
        f"max |ratio - 1| = {(df['ratio'] - 1).abs().max():.3f})"
    )


@bench.command("caustics")
@_writes_out("bench")
@click.option(
    "--depth",
    "depths",
    multiple=True,
    type=click.FloatRange(0.1, 30.0),
    help="floor depth in m (repeatable; default 1, 2, 4, 8)",
)
@click.option(
    "--water",
    "waters",
    multiple=True,
    type=click.Choice(["I", "IA", "IB", "II", "III", "1C", "3C", "5C"]),
    help="Jerlov type, green channel, grey medium (repeatable; default IB and 1C)",
)
@click.option(
    "--size",
    type=click.IntRange(128, 4096),
    default=1024,
    show_default=True,
    help="sun rays per render side (photons = size^2 x renders)",
)
@click.option(
    "--renders",
    type=click.IntRange(1, 64),
    default=4,
    show_default=True,
    help="sun directions over its disc, one Cycles render each",
)
@click.option(
    "--sun-zenith",
    type=click.FloatRange(0.0, 70.0),
    default=0.0,
    show_default=True,
    help="the sun's zenith angle in air (deg), heading +x",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for caustics.csv and the cached photon-map reference renders",
)
@_user_errors
def bench_caustics(
    depths: tuple[float, ...], waters: tuple[str, ...], size: int, renders: int, sun_zenith: float, out: Path
):
    """Fast caustics vs the Cycles photon-map reference on a 2 x 2 m floor under the seeded
    waves (2 m/s): contrast std E / mean E, mean irradiance over the sun's, pattern correlation.
    Reference maps are cached in OUT (one niced Blender job at a time)."""
    import pandas as pd

    from blendgen.tools.bench import caustic_bench as cb

    rows = cb.run(
        out,
        depths or cb.DEPTHS_M,
        waters or ("IB", "1C"),
        size,
        renders,
        echo=lambda m: click.echo(m, err=True),
        sun_zenith_deg=sun_zenith,
    )
    click.echo(cb.format_rows(rows))
    click.echo(
        "C: contrast (ref: shot noise 'noise' removed); E: mean irradiance / sun's above the surface (fast: "
        "cos(zenith) exp(-Kd h); beam: cos(zenith) exp(-c h slant)); corr* = corr / the ref's signal share"
    )
    pd.DataFrame(rows).to_csv(out / "caustics.csv", index=False)
    click.echo(str(out / "caustics.csv"))


@bench.command("lamp")
@_writes_out("bench")
@click.option(
    "--samples",
    type=click.IntRange(1, 65536),
    default=256,
    show_default=True,
    help="Cycles samples of the veil renders (the card renders use the same)",
)
@click.option(
    "--bounces",
    type=click.IntRange(1, 1024),
    default=32,
    show_default=True,
    help="volume bounces of the multiple-scattering reference",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for lamp_card.csv, lamp_shadow.csv, lamp_veil.csv and renders/",
)
def bench_lamp(samples: int, bounces: int, out: Path):
    """Vehicle lamp: grey card vs inverse square x attenuation, and the backscatter veil, fast vs Cycles."""
    from blendgen.tools.bench import lamp_bench
    from blendgen.tools.bench.lamp_bench import card_table, shadow_table, veil_table
    from evalkit.reports.tables import print_table

    out.mkdir(parents=True, exist_ok=True)
    lamp_bench.ON_RENDER = lambda m: click.echo(f"bench lamp: {m} ...", err=True)
    card = card_table(out / "renders", samples=samples)
    click.echo("grey card (albedo 0.5) centre radiance, green, lamp 0.3 m off the camera; card - black card:")
    print_table(card, floatfmt=".4g")
    shadow = shadow_table(out / "renders", samples=min(samples, 64))
    click.echo(
        "\nlamp shadows (320x240, a 5 cm slab at 1 m and a 5 cm post at 1.8 m before a wall at 3 m, lamp 0.2 m "
        "right and 0.3 m below the camera; 0 volume bounces, F = 0; green): shadowed wall area IoU (fast vs "
        "Cycles vs the segment-box geometry) and mean radiance of the shadow's core over the lit ring around it:"
    )
    print_table(shadow, floatfmt=".4g")
    shadow.to_csv(out / "lamp_shadow.csv", index=False)
    veil = veil_table(out / "renders", bounces=(0, bounces), samples=samples)
    click.echo(
        "\nbackscatter veil, no surface (green; F = 0 vs the 0-bounce reference, "
        "F = lamp_forward_kept and the beam spread vs the multi-bounce one; block errors over 8x6 blocks; "
        "mean ratio outside / inside the single-scatter cone):"
    )
    print_table(veil, floatfmt=".4g")
    card.to_csv(out / "lamp_card.csv", index=False)
    veil.to_csv(out / "lamp_veil.csv", index=False)
    click.echo(
        f"\nmax |card/law - 1|: reference {(card['ref/law'] - 1).abs().max():.4f}, "
        f"fast {(card['fast/law'] - 1).abs().max():.4f}; veil mean ratio fast/reference "
        f"{veil['ratio'].min():.3f}..{veil['ratio'].max():.3f} -> {out}"
    )


@main.command("calibrate-water")
@_writes_out("bench")
@_size_options
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="work directory for the renders; water_calibration.json too unless --data names another",
)
@click.option(
    "--data",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="calibration file to write (default: OUT/water_calibration.json; never the installed "
    "package's unless named here)",
)
def calibrate_water(width: int, height: int, ref_samples: int, frames: int, out: Path, data: Path | None):
    """Fit the fast model's B_inf and depth light to reference renders; write the calibration file."""
    from blendgen.tools.bench.fidelity import run_calibration
    from blendgen.tools.calibration.veil import check_data_file

    data = data or out / "water_calibration.json"
    check_data_file(data)
    d = run_calibration(out, data, width, height, frames, ref_samples, echo=lambda m: click.echo(m, err=True))
    for name, e in d["presets"].items():
        r = e["residual"]
        click.echo(
            f"{name:10s} B_inf={e['B_inf']} Kd={e['Kd']}  MAE uncalibrated {r['uncalibrated']['mae']:.4f}"
            f" -> calibrated {r['calibrated']['mae']:.4f} (rel {r['calibrated']['rel_mae']:.1%})"
        )
    click.echo(f"wrote {data}")


@main.command("calibrate-veil")
@_writes_out("calibrate")
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="work directory for the render specs; water_calibration.json too unless --data names another",
)
@click.option(
    "--data",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="calibration file to update (default: OUT/water_calibration.json, seeded from the "
    "package's; the installed package's file only when named here)",
)
@click.option("--preset", "presets", multiple=True, help="presets to measure (repeatable; default all)")
def calibrate_veil(out: Path, data: Path | None, presets: tuple[str, ...]):
    """Fit the physical veil model (kappa, K_v per channel, eta) to Cycles references with 64 volume
    bounces at depths 1/3/6 m and views -30/0/+30 deg; ~6 renders of ~10 s per preset."""
    from blendgen.tools.calibration import veil as vc

    data = data or out / "water_calibration.json"
    vc.check_data_file(data)  # before any render
    d = vc.run(out, data, presets or vc.PRESETS, echo=lambda m: click.echo(m, err=True))
    for name, e in d["presets"].items():
        click.echo(
            f"{name:10s} kappa={e['kappa']} K_v={e['K_v']} eta={e['eta']} "
            f"max |fast/ref - 1| {e['max_abs_rel_residual']:.3f}"
        )
    click.echo(f"wrote {data}")


@main.command("preview")
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="PNG to write: the contact sheet",
)
@_wh_size("320x240")
@click.option("--samples", type=click.IntRange(1, 65536), default=4, show_default=True)
@click.option("--fidelity", type=click.Choice(["fast", "reference"]), default="fast", show_default=True)
@click.option(
    "--mode", type=click.Choice(["physical", "article"]), default="physical", show_default=True, help="image formation"
)
def preview(out: Path, width: int, height: int, samples: int, fidelity: str, mode: str):
    """Contact sheet: clear/mild/moderate x depth 0/1/5 m, camera 8/5/2 m from the dock."""
    from blendgen.tools.apps.preview import make_preview
    from datasets_spec.outdir import check_file_out

    check_file_out(out, "preview")
    click.echo(f"wrote {make_preview(out, width, height, samples, fidelity, mode=mode)}")


@main.command("reproduce")
@click.argument("name", type=click.Choice(("turbidity", "depth", "current", "occlusion", "turbidity_ladder", "all")))
@click.option(
    "--trials",
    type=click.IntRange(1, 100000),
    default=None,
    help="trials per condition (default: the config's, 100; turbidity_ladder 50)",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory to write each experiment's dataset, results and report.md into",
)
@click.option("--workers", type=click.IntRange(1, 256), default=None)
@click.option("--overwrite", is_flag=True, help="replace a dataset made from an older version of the config")
@click.option(
    "--mode",
    type=click.Choice(["physical", "article"]),
    default=None,
    help="image formation (default: the paper configs' own)",
)
@click.option(
    "--images",
    default="all",
    show_default=True,
    callback=lambda c, p, v: _images_policy(v),
    help="camera images kept on disk: all, none or sample:N (N per sequence); evaluation "
    "runs while rendering either way",
)
def reproduce(
    name: str, trials: int | None, out: Path, workers: int | None, overwrite: bool, mode: str | None, images: str
):
    """Run one of the article's experiments (or all of them), or the physical turbidity ladder over
    Jerlov I ... 9C (turbidity_ladder): generate, evaluate, report."""
    from blendgen.tools.apps.reproduce import EXPERIMENTS
    from blendgen.tools.apps.reproduce import reproduce as run

    for text in run(EXPERIMENTS if name == "all" else (name,), out, trials, workers, overwrite, mode, images):
        click.echo(text)


def _images_policy(value: str) -> str:
    """``--images`` checked (none, all, sample:N): a bad value is a usage error (exit 2)."""
    from evalkit.stream import ImagesPolicyError, parse_images

    try:
        parse_images(value)
    except ImagesPolicyError as e:
        raise click.BadParameter(str(e)) from None
    return value.strip().lower()


@main.command("run")
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-l",
    "--localizer",
    "localizers",
    multiple=True,
    required=True,
    help="localizer spec as for evaluate (repeatable); led, qr and hybrid together run LED and QR once per frame",
)
@click.option("-p", "--param", "params", multiple=True, help="key=value or NAME.key=value (as for evaluate)")
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="run folder: dataset/, results/, stream.json; an interrupted run in it is resumed",
)
@click.option(
    "--images",
    default="sample:5",
    show_default=True,
    callback=lambda c, p, v: _images_policy(v),
    help="camera images kept: all, none or sample:N (N evenly spaced per sequence)",
)
@click.option(
    "--workers",
    type=click.IntRange(1, 256),
    default=None,
    help="render processes at once (default: one per core); evaluation: one process per core",
)
@click.option("--preprocess", default=None, metavar="STEPS", help="image preprocessing (as for evaluate)")
@click.option("--overwrite", is_flag=True, help="start over when OUT holds a run of another config or other localizers")
@click.option("--quiet", "-q", is_flag=True, help="print nothing but errors")
@_user_errors
def run(
    config: Path,
    localizers: tuple[str, ...],
    params: tuple[str, ...],
    out: Path,
    images: str,
    workers: int | None,
    preprocess: str | None,
    overwrite: bool,
    quiet: bool,
):
    """Generate CONFIG and evaluate localizers on it in one pass, keeping a sample of the images.

    Writes OUT/results (as evaluate), OUT/dataset (the kept files) and OUT/stream.json (the
    sha256 of every image: a dataset generated later from CONFIG must match it).
    """
    from blendgen.config.models import load_experiment
    from blendgen.pipeline.generate import check_out_dir
    from blendgen.tools.apps.streamrun import RunRequest, stream_run
    from datasets_spec import outdir
    from evalkit import assemble, registry

    exp = load_experiment(config)
    kw = registry.parse_params(list(params))
    for n in localizers:  # bad specs and params before anything renders
        assemble.build(n, registry.params_for(n, kw, list(localizers)), preprocess=preprocess)
    outdir.check(out, "run", overwrite)  # new, empty or an earlier run's folder; never a dataset
    check_out_dir(exp, out / "dataset", overwrite)
    req = RunRequest(
        list(localizers),
        list(params),
        images,
        workers,
        preprocess=preprocess,
        progress=not quiet,
        command=_command_line(click.get_current_context()),
        overwrite=overwrite,
    )
    with outdir.writing(out, "run", overwrite):
        r = stream_run([(exp, out)], req)[0]
    if not quiet:
        click.echo("\n" + r["paths"]["article_md"].read_text())
        st = r["stream"]
        click.echo(
            f"results: {out / 'results'}\ndataset content hash {st['content_hash'][:12]} "
            f"({st['n_files']} files; {st['n_kept']} kept in {out / 'dataset'}, --images {images})"
        )


@main.command("calibrate")
@_writes_out("calibrate")
@click.option(
    "--config",
    "config",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="calibration config (YAML; default: the bundled configs/calibration.yaml)",
)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="output directory (rendered frames, calibration.csv, calibration_trials.csv)",
)
@click.option(
    "--size",
    callback=lambda c, p, v: _suite_size(c, p, v),
    default=None,
    metavar="WxH",
    help="one resolution instead of the config's list, e.g. 320x240",
)
@click.option(
    "--trials", type=click.IntRange(1, 100), default=None, help="trials per resolution (default: the config's)"
)
def calibrate(config: Path | None, out: Path, size: tuple[int, int] | None, trials: int | None):
    """Render chessboards and check Zhang's calibration against the true K."""
    import time

    from blendgen.tools.calibration import camera as cal

    cfg = cal.with_overrides(cal.load_config(config or cal.DEFAULT_CONFIG), size, trials)
    t0 = time.perf_counter()
    try:
        results = cal.run_calibration(cfg, out)
    except RuntimeError as e:  # a failed render or an unreachable pose constraint
        click.echo(f"error: {e}", err=True)
        sys.exit(1)
    rows = cal.summarize(results)
    summary, per_trial = cal.write_csv(results, rows, out)
    click.echo(
        f"Zhang calibration vs ground-truth K: relative error %, mean over {cfg.trials} trials "
        f"({cfg.poses_per_trial} poses each, {cfg.samples} spp, hfov {cfg.hfov_deg:g} deg, "
        f"{'no distortion' if cfg.fix_distortion else 'k1 k2 p1 p2 k3 estimated'})"
    )
    click.echo(cal.format_table(rows))
    click.echo(f"wall time {time.perf_counter() - t0:.0f} s; {summary}, {per_trial}")


@bench.command("localizers")
@_writes_out("bench")
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory to write bench_localizer_cpu.csv, bench_qr_decoders.csv and bench_led_centroids.csv into",
)
def bench_localizers(dataset: Path, out: Path) -> None:
    """CPU ms per 640x480 frame of each built-in localizer and QR decode rate by range, on DATASET."""
    from blendgen.tools.bench.stages import run_localizer_bench

    run_localizer_bench(dataset, out)


@main.command("leaderboard")
@click.argument("results_dirs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="HTML file to write",
)
@click.option("--title", default="dockbench leaderboard", show_default=True)
@click.option(
    "--screenshot",
    "shot",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="also render the page to this PNG (needs chromium)",
)
def leaderboard(results_dirs: tuple[Path, ...], out: Path, title: str, shot: Path | None):
    """Rank localizers per dataset and condition from RESULTS_DIRS (of `dockbench evaluate`, and
    `dockbench dock` outputs: their closed_loop.json, datasets_spec/CLOSED_LOOP.md) into one static
    HTML page."""
    import subprocess

    from datasets_spec.outdir import check_file_out
    from evalkit.reports.leaderboard import build_leaderboard, screenshot
    from evalkit.reports.results import ResultsError

    check_file_out(out, "leaderboard")
    check_file_out(shot, "leaderboard")
    try:
        path = build_leaderboard(results_dirs, out, title)
    except ResultsError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"leaderboard: {path}")
    if shot is not None:
        try:
            click.echo(f"screenshot: {screenshot(path, shot)}")
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            click.echo(f"error: screenshot: {exc}", err=True)
            sys.exit(2)


@main.command("export-bop")
@click.argument("dataset", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "-o",
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="BOP dataset directory to write",
)
@click.option("--split", default="test", show_default=True, help="BOP split folder name")
@click.option(
    "--copy/--symlink",
    "copy_images",
    default=True,
    show_default=True,
    help="copy the RGB images, or link them by relative symlinks (move the export and the dataset together)",
)
@click.option(
    "--depth-scale",
    type=click.FloatRange(min=0.0, min_open=True),
    default=1.0,
    show_default=True,
    help="mm per depth PNG unit (1.0: up to 65.5 m; 0.1: up to 6.5 m)",
)
@click.option("--no-masks", is_flag=True, help="do not write mask_visib PNGs")
@click.option(
    "--undistort",
    is_flag=True,
    help="camera with lens distortion: remap images, depth and masks "
    "to the pinhole camera of the same K (else refused)",
)
@click.option(
    "--pixels",
    type=click.Choice(["opencv", "toolkit"]),
    default="opencv",
    show_default=True,
    help="silhouette pixel convention: the renderer's (OpenCV pixel centres) or the BOP toolkit's "
    "OpenGL renderers' (half a pixel off; scene_gt_info then equals its calc_gt_info.py)",
)
@click.option(
    "--results",
    "results_dirs",
    multiple=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="a results folder of `dockbench evaluate` on DATASET (repeatable): write each pose "
    "localizer's estimates as OUT/results/METHOD_dockbench-SPLIT.csv and print its BOP19 AR",
)
@click.option("--overwrite", is_flag=True, help="replace a non-empty OUT")
def export_bop(
    dataset: Path,
    out: Path,
    split: str,
    copy_images: bool,
    depth_scale: float,
    no_masks: bool,
    undistort: bool,
    pixels: str,
    results_dirs: tuple[Path, ...],
    overwrite: bool,
):
    """Export DATASET in the BOP format (scene_camera/scene_gt/scene_gt_info, rgb, depth) to OUT,
    written whole or not at all, after the checks of `dockbench verify`; with --results also BOP
    results files and their scores (docs/bop.md)."""
    import json

    from datasets_spec.outdir import results_dir
    from evalkit.dataset import DatasetError, verify_before_reading
    from evalkit.reports.bop import export_bop as run

    runs = _bop_runs(dataset, results_dirs) if results_dirs else []
    try:
        verify_before_reading(dataset)
        with results_dir(out, overwrite, "export-bop") as tmp:
            s = run(
                dataset,
                tmp,
                split=split,
                copy_images=copy_images,
                depth_scale=depth_scale,
                masks=not no_masks,
                undistort=undistort,
                pixels=pixels,
                progress=True,
            )
            if results_dirs:
                _bop_results(dataset, tmp, runs, out)
    except DatasetError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
    click.echo(f"BOP export: {s['scenes']} scenes, {s['images']} images, {s['objects']} objects -> {out}")
    info = json.loads((out / "dockbench_scenes.json").read_text())["visib_fract"]
    if info["from_object_index"]:
        click.echo(
            f"note: {info['from_object_index']} visib_fract values from the object-index pass "
            "(no depth pass for the toolkit's depth test)",
            err=True,
        )
    if info["copied_from_dataset"]:
        click.echo(
            f"note: {info['copied_from_dataset']} visib_fract values copied from the dataset's "
            "visible_fraction (no object-index pass to compute them from)",
            err=True,
        )
    if s["depth_clipped_px"]:
        click.echo(
            f"note: {s['depth_clipped_px']} depth pixels beyond {65535 * depth_scale / 1000:.1f} m "
            f"written as 0 (use a larger --depth-scale)",
            err=True,
        )


def _bop_runs(dataset: Path, results_dirs: tuple[Path, ...]) -> list:
    """The estimates of each results folder, checked to be of DATASET (before anything is written)."""
    from evalkit.dataset import Dataset, DatasetError
    from evalkit.reports.results import ResultsError, load_run

    ds = Dataset.open(dataset)
    out = []
    for rdir in results_dirs:
        try:
            run = load_run(rdir)
            est = run.estimates
        except (ResultsError, OSError) as exc:
            raise DatasetError(f"{rdir}: not a results folder of `dockbench evaluate` ({exc})") from None
        if run.content_hash not in (None, ds.manifest.get("content_hash")):
            raise DatasetError(
                f"{rdir}: evaluated another dataset (content hash {run.content_hash[:12]}, "
                f"{dataset} has {str(ds.manifest.get('content_hash'))[:12]})"
            )
        out.append(est)
    return out


def _bop_results(dataset: Path, out: Path, runs: list, final_out: Path) -> None:
    """Results CSVs of every pose localizer in ``runs`` (estimates tables) in the export being
    written at ``out`` (renamed to ``final_out`` once whole) and a table: the BOP19 AR (per
    marker, VSD + MSSD + MSPD) next to dockbench's AR_dock (the dock as one object)."""
    import pandas as pd

    from evalkit.dataset import Dataset
    from evalkit.reports.bop_results import pooled_dock_ar, write_results
    from evalkit.reports.bop_score import bop19_scores
    from evalkit.reports.tables import print_table

    ds = Dataset.open(dataset)
    rows = []
    for est in runs:
        dock_ar = pooled_dock_ar(est, ds.markers, ds.camera)
        for name, path in write_results(est, ds.markers, out, out / "results").items():
            rows.append(
                {
                    "localizer": name,
                    **bop19_scores(out, path, progress=True),
                    "AR_dock": dock_ar.get(name),
                    "file": str(final_out / path.relative_to(out)),
                }
            )
    if rows:
        print_table(pd.DataFrame(rows), floatfmt=".3f")
    click.echo(
        "AR_BOP19: per marker object, (AR_VSD + AR_MSSD + AR_MSPD) / 3 over test_targets_bop19 (the BOP "
        "toolkit's definition); AR_dock: the dock as one object, MSSD + MSPD only (dockbench's own)"
    )


@main.command("dock")
@click.argument("experiment")
@click.option(
    "-l",
    "--localizer",
    "localizers",
    multiple=True,
    default=("led", "aruco", "hybrid"),
    show_default=True,
    help="localizer spec as for `dockbench evaluate` (repeatable); `none`: only the ground-truth baseline "
    "(no rendering)",
)
@click.option("-p", "--param", "params", multiple=True, help="key=value or NAME.key=value for localizers")
@click.option(
    "--trials",
    type=click.IntRange(1, 100000),
    default=10,
    show_default=True,
    help="seeded trials per condition and localizer",
)
@click.option("--condition", "conditions", multiple=True, help="only these condition labels (repeatable)")
@click.option("--size", default=None, metavar="WxH", help="override the camera resolution, e.g. 320x240")
@click.option("--images", is_flag=True, help="keep every camera image (OUT/images/<trial>/)")
@click.option("--no-baseline", is_flag=True, help="skip the ground-truth-guidance baseline")
@click.option("--threads", type=click.IntRange(0, 256), default=0, help="Cycles threads (0: all cores)")
@click.option("--isolate", is_flag=True, help="run built-in localizers in a child process too (plugins always are)")
@click.option("--frame-timeout", type=click.FloatRange(min=0.001), default=None, help="s per frame")
@click.option("--preprocess", default=None, metavar="STEPS", help="image preprocessing (see evaluate)")
@click.option(
    "--compute-latency",
    default="0",
    show_default=True,
    metavar="S|measured",
    help="localizer compute time added to camera.latency_s before guidance sees an estimate: "
    "seconds (0..10), or 'measured' (each frame's measured time; depends on machine load)",
)
@click.option("--report-only", is_flag=True, help="only summarise and plot the tables already in OUT")
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="output directory: trials.parquet, frames.parquet, summary.csv/.md, paths.png, closed_loop.json "
    "(--report-only: the directory read)",
)
@click.option("--overwrite", is_flag=True, help="write into a non-empty OUT that dock did not write")
def dock(
    experiment,
    localizers,
    params,
    trials,
    conditions,
    size,
    images,
    no_baseline,
    threads,
    isolate,
    frame_timeout,
    preprocess,
    compute_latency,
    report_only,
    out,
    overwrite,
):
    """Closed-loop docking: each localizer steers the vehicle from seeded starts.

    EXPERIMENT is turbidity, depth, current, occlusion (the paper configs) or a config file.
    Writes trials.parquet, frames.parquet, summary.csv/.md and paths.png (top view)."""
    from blendgen.config.models import ConfigError
    from blendgen.pipeline.executor import require_render_stack
    from blendgen.tools.apps.closed_loop import _specs, load_bench_experiment, parse_compute_latency, run_dock
    from evalkit.reports.tables import print_table

    exp = load_bench_experiment(experiment, size, conditions)
    compute_latency = parse_compute_latency(compute_latency)
    specs = _specs(localizers, params, isolate, frame_timeout, preprocess)
    if not specs and no_baseline and not report_only:
        raise ConfigError("-l none with --no-baseline: nothing to run (drop one of them)")
    if specs and not report_only:
        require_render_stack()
        for s in specs:  # user errors before the first trial
            loc = s.build()
            getattr(loc, "close", lambda: None)()
    from datasets_spec import outdir

    with outdir.writing(out, "dock", overwrite):  # the -o rule and lock of every writing command
        paths = run_dock(
            exp,
            specs,
            trials,
            out,
            images,
            threads,
            not no_baseline,
            progress=lambda m: click.echo(m, err=True),
            report_only=report_only,
            compute_latency=compute_latency,
        )
    import pandas as pd

    print_table(pd.read_csv(paths["summary"]), floatfmt=".3g")
    click.echo("\n".join(f"{k}: {v}" for k, v in paths.items()))


@bench.command("closed-loop")
@_writes_out("bench")
@click.option("--experiment", default="turbidity", show_default=True, help="paper experiment or config file")
@click.option("-l", "--localizer", default="led", show_default=True)
@click.option("--trials", type=click.IntRange(1, 1000), default=2, show_default=True)
@click.option("--size", default=None, metavar="WxH", help="override the resolution (default: the config's)")
@click.option(
    "--open-loop-frames",
    type=click.IntRange(0, 10000),
    default=30,
    show_default=True,
    help="frames of the open-loop stage bench to compare with (0: skip)",
)
@click.option("--threads", type=click.IntRange(0, 256), default=0, help="Cycles threads (0: all cores)")
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for bench_closed_loop.csv, the trials' renders and open_loop/",
)
def bench_closed_loop(experiment, localizer, trials, size, open_loop_frames, threads, out):
    """Seconds per closed-loop trial (fast fidelity) vs the open-loop cost per frame."""
    import os

    import pandas as pd

    from blendgen.pipeline.executor import require_render_stack
    from blendgen.tools.apps.closed_loop import closed_loop_cost, cpu_seconds, load_bench_experiment
    from evalkit.reports.tables import print_table

    require_render_stack()
    exp = load_bench_experiment(experiment, size, ())
    row = closed_loop_cost(exp, localizer, trials, out, threads)
    click.echo("\nclosed loop (one warm Blender process, render -> compose -> localize -> guide):")
    print_table(pd.DataFrame([row]), floatfmt=".1f")
    pd.DataFrame([row]).to_csv(out / "bench_closed_loop.csv", index=False)
    if open_loop_frames:
        from blendgen.tools.bench.stages import render_stages

        c0 = cpu_seconds()
        ol = render_stages(out / "open_loop", open_loop_frames, exp.render.samples)
        ol_cpu = 1e3 * (cpu_seconds() - c0) / ol["frames"]
        click.echo(
            f"\nopen loop (dockbench generate, quickstart approach, 640x480, {exp.render.samples} spp): "
            f"{ol['wall_ms_per_frame']:.1f} ms/frame wall incl. process start and scene build, "
            f"{ol['render+write_ms']:.1f} ms/frame render+post+write, {ol_cpu:.1f} CPU ms/frame "
            f"(load average {os.getloadavg()[0]:.1f})"
        )
        click.echo(
            f"closed loop: {row['ms_per_frame']:.1f} ms/frame wall, {row['cpu_ms_per_frame']:.1f} CPU ms/frame "
            f"-> {row['s_per_trial']:.1f} s per trial of {row['frames'] / row['trials']:.0f} frames"
        )


def _suite_size(ctx, param, value):
    """``--size WxH`` -> (width, height) px, each 16..8192."""
    if value is None:
        return None
    try:
        w, h = (int(v) for v in value.lower().split("x"))
    except ValueError:
        w = h = 0
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise click.BadParameter(f"{value!r}: expected WIDTHxHEIGHT, each 16..8192, e.g. 1280x720")
    return w, h


@bench.command("suite")
@_writes_out("bench")
@click.option("--trials", type=click.IntRange(1, 100000), default=1, show_default=True)
@click.option(
    "-e",
    "--experiment",
    "names",
    multiple=True,
    type=click.Choice(("turbidity", "depth", "current", "occlusion")),
    help="experiments to run together (repeatable; default all four)",
)
@click.option("--size", callback=_suite_size, default=None, help="override the camera, e.g. 1280x720")
@click.option(
    "--particles",
    type=click.IntRange(0, 10_000_000),
    default=None,
    help="occlusion experiment: one condition with this many small obstacles",
)
@click.option("--workers", type=click.IntRange(1, 256), default=None)
@click.option(
    "--scaling",
    is_flag=True,
    help="run the scaling table instead (trials 1/3, 640x480 vs "
    "1280x720 on turbidity; particles 0/6000/60000 on occlusion; 1 trial each)",
)
@click.option("--no-evaluate", is_flag=True, help="generate only")
@click.option("--table", is_flag=True, help="only print the table of the runs recorded in OUT")
@click.option(
    "--max-distance",
    "max_distance_m",
    type=click.FloatRange(0.5, 100.0),
    default=None,
    help="render only the frames within this distance (m) of the dock (a cheaper, "
    "close-range-heavy workload for scaling runs)",
)
@click.option(
    "--samples",
    type=click.IntRange(1, 4096),
    default=None,
    help="Cycles samples in the dock's region (default: the configs' 4)",
)
@click.option(
    "--images",
    default="all",
    show_default=True,
    callback=lambda c, p, v: _images_policy(v),
    help="all: generate then evaluate (datasets kept); none or sample:N: the streaming path of "
    "`dockbench run` (evaluated while rendering, N images per sequence kept)",
)
@_bench_mode
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for bench_suite.jsonl (appended), bench_suite.csv, bench_scaling.csv and the suite's "
    "datasets and results; with --table: the directory read",
)
def bench_suite(
    trials, names, size, particles, workers, scaling, no_evaluate, table, max_distance_m, samples, images, modes, out
):
    """Generate and evaluate the article's suite at N trials per image-formation mode; CPU/wall per stage, RSS,
    disk, 100-trial estimate, modes side by side."""
    from blendgen.tools.apps.reproduce import EXPERIMENTS
    from blendgen.tools.bench.suitebench import Overrides, print_recorded
    from blendgen.tools.bench.suitebench import bench_suite as run

    if table:
        return print_recorded(out)
    run(
        trials,
        names or EXPERIMENTS,
        Overrides(size, particles, max_distance_m, samples),
        out,
        workers,
        scaling,
        not no_evaluate,
        images,
        modes,
    )


@bench.command("check")
@_writes_out("bench")
@click.option(
    "--baseline",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="baseline to compare with (default: the package's blendgen/data/bench_baseline.json); with --record "
    "the file rewritten (default: OUT/bench_baseline.json, never the package's unless named here)",
)
@click.option(
    "--tolerance",
    type=click.FloatRange(0.01, 10.0),
    default=0.2,
    show_default=True,
    help="flag a stage whose CPU moved by more than this fraction, either way",
)
@click.option(
    "--floor",
    "floor_s",
    type=click.FloatRange(0.0, 1e6),
    default=0.5,
    show_default=True,
    help="CPU s under which (in both runs) a stage is not flagged",
)
@click.option("--record", is_flag=True, help="write the new figures as the baseline")
@click.option("--trials", type=click.IntRange(1, 100000), default=None, help="with --record: trials (default 1)")
@click.option(
    "-e",
    "--experiment",
    "names",
    multiple=True,
    type=click.Choice(("turbidity", "depth", "current", "occlusion")),
    help="with --record: experiments (repeatable; default turbidity)",
)
@click.option("--size", callback=_suite_size, default=None, help="with --record: image size (default 640x480)")
@click.option(
    "--images",
    default=None,
    callback=lambda c, p, v: None if v is None else _images_policy(v),
    help="with --record: all, none or sample:N as for bench suite (default none)",
)
@click.option(
    "--mode",
    type=click.Choice(["physical", "article", "both"]),
    default=None,
    help="with --record: image formation (default both)",
)
@click.option("--workers", type=click.IntRange(1, 256), default=None)
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="directory for the suite's runs, bench_suite.jsonl and bench_check.csv",
)
@_user_errors
def bench_check(baseline, tolerance, floor_s, record, trials, names, size, images, mode, workers, out):
    """Rerun the baseline's `bench suite` measurement; print per stage old and new CPU s, their ratio and a flag
    where a stage moved by more than --tolerance (a benchmark: exit code 0 whatever moved)."""
    from blendgen.tools.bench import guard

    given = {"trials": trials, "experiments": names or None, "size": size, "images": images, "mode": mode}
    meas = None
    if any(v is not None for v in given.values()):
        d = guard.Measurement()
        modes = d.modes if mode in (None, "both") else (mode,)
        meas = guard.Measurement(
            tuple(names) or d.experiments, trials or d.trials, size or d.size, images or d.images, modes
        )
    guard.run_check(guard.CheckRequest(out, baseline, tolerance, floor_s, record, meas, workers))


if __name__ == "__main__":
    main()
