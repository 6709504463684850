"""``dockbench reproduce NAME``: the article's experiments, one command each.

For ``turbidity``, ``depth``, ``current`` and ``occlusion`` (configs/paper_NAME.yaml):
generate the dataset (resumable), evaluate the LED, QR and hybrid localizers, and
report the article-shaped table (condition, average positioning error = E_rel_mean,
success rate = P_succ_mean, with bootstrap 95% CIs over trials), the error-vs-distance
plot of one representative trial per condition, and the breakdown by marker with the
usable range of each (largest 1 m bin with P_succ >= 0.9). Trends are reported as they
come out. ``all`` generates the four together, rendering each camera path once for
every experiment that shares it (turbidity, depth, occlusion and the zero-current
condition share their trajectories), then evaluates each (``dockbench calibrate``
covers section 6).
"""
from __future__ import annotations

import time
from pathlib import Path

import click
import pandas as pd

from blendgen.config.models import load_experiment
from blendgen.config.bundled import bundled_file

EXPERIMENTS = ("turbidity", "depth", "current", "occlusion")
LOCALIZERS = ("led", "qr", "hybrid")


def experiment(name: str, trials: int | None):
    """The paper config, optionally with fewer trials (the dataset name records it)."""
    exp = load_experiment(bundled_file("configs", f"paper_{name}.yaml"))
    if trials is not None:
        exp.trials = trials
        exp.name = f"{exp.name}-{trials}trials"
    return exp


def evaluate(dataset_dir: Path, out: Path, localizers=LOCALIZERS, workers: int | None = None) -> dict:
    """Run the localizers over the dataset (one process per core, split by sequence) and
    save the full run record."""
    from evalkit.parallel import evaluate_dataset
    return evaluate_dataset(dataset_dir, localizers, out, workers=workers)[1]


def report(name: str, paths: dict) -> str:
    """Article table, per-marker usable range and where the plots are."""
    m = pd.read_csv(paths["metrics"]) if "metrics" in paths else pd.read_csv(Path(paths["summary"]).parent / "metrics.csv")
    lines = [f"## {name}", "", Path(paths["article_md"]).read_text().strip(), "",
             "breakdown by localizer (marker): usable range = largest 1 m bin with P_succ >= 0.9", ""]
    for _, r in m.iterrows():
        rng = "-" if pd.isna(r["max_range_m"]) else f"{r['max_range_m']:.0f} m"
        lines.append(f"- {r['localizer']:7s} {r['condition']:12s} P_succ {100 * r['P_succ_mean']:5.1f}%  "
                     f"E_rel {100 * r['E_rel_mean']:.2f}%  usable range {rng}  "
                     f"{r['ms_median']:.1f} ms/frame")
    plots = Path(paths["article_md"]).parent.parent / "plots"
    lines += ["", f"plots: {plots / 'error_vs_distance.png'}, {plots / 'success_vs_distance.png'}"]
    return "\n".join(lines)


def reproduce(names: tuple[str, ...], out_root: Path, trials: int | None, workers: int | None,
              overwrite: bool = False) -> list[str]:
    """Generate the experiments' datasets together (each shared camera path is rendered
    once for all of them), then evaluate and report each; returns the Markdown reports."""
    from blendgen.pipeline.generate import check_out_dir, generate_many
    exps = [experiment(n, trials) for n in names]
    bases = [Path(out_root) / e.name for e in exps]
    for e, b in zip(exps, bases):
        check_out_dir(e, b / "dataset", overwrite=overwrite)
    t0 = time.perf_counter()
    generate_many([(e, b / "dataset") for e, b in zip(exps, bases)], workers=workers)
    t1 = time.perf_counter()
    reports = []
    for e, b in zip(exps, bases):
        t2 = time.perf_counter()
        paths = evaluate(b / "dataset", b / "results")
        text = report(e.name, paths) + (f"\n\ntimes: generate (all {len(exps)} together) {t1 - t0:.0f} s, "
                                         f"evaluate {time.perf_counter() - t2:.0f} s\n")
        (b / "report.md").write_text(text)
        reports.append(text)
    return reports


@click.command("reproduce")
@click.argument("name", type=click.Choice(EXPERIMENTS + ("all",)))
@click.option("--trials", type=click.IntRange(1, 100000), default=None,
              help="trials per condition (default: the config's 100)")
@click.option("-o", "--out", "out", type=click.Path(file_okay=False, path_type=Path),
              default=Path("out/reproduce"), show_default=True)
@click.option("--workers", type=click.IntRange(1, 256), default=None)
@click.option("--overwrite", is_flag=True, help="replace a dataset made from an older version of the config")
def reproduce_cmd(name: str, trials: int | None, out: Path, workers: int | None, overwrite: bool):
    """Run one of the article's experiments (or all): generate, evaluate, report."""
    for text in reproduce(EXPERIMENTS if name == "all" else (name,), out, trials, workers, overwrite):
        click.echo(text)
