"""``dockbench reproduce NAME``: the article's experiments, one command each.

For ``turbidity``, ``depth``, ``current`` and ``occlusion`` (configs/paper_NAME.yaml):
generate the dataset (resumable), evaluate the LED, QR and hybrid localizers, and
report the article-shaped table (condition, average positioning error = E_rel_mean,
success rate = P_succ_mean, with bootstrap 95% CIs over trials, and beside the pooled
error the range-matched one over the 1 m bins every condition answers in), success and
error per 1 m range bin for every condition (table and ``plots/range_bins.png``: one
figure per experiment, conditions as lines), the error-vs-distance
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

import pandas as pd
from pydantic import ValidationError

from blendgen.config.bundled import bundled_file
from blendgen.config.models import ConfigError, format_validation_error, load_experiment

EXPERIMENTS = ("turbidity", "depth", "current", "occlusion")
LOCALIZERS = ("led", "qr", "hybrid")
#: Experiments beyond the article's (not in ``all``): name -> (bundled config, localizers).
#: ``turbidity_ladder``: the physical turbidity experiment over Jerlov I ... 9C (docs/waters.md).
EXTRA = {"turbidity_ladder": ("turbidity_ladder.yaml", ("led", "qr", "aruco", "hybrid"))}
NAMES = EXPERIMENTS + tuple(EXTRA)


def config_file(name: str) -> str:
    """The bundled config of an experiment name."""
    return EXTRA[name][0] if name in EXTRA else f"paper_{name}.yaml"


def localizers_of(names) -> list[str]:
    """Every localizer the experiments ``names`` evaluate (the article's three, plus extras)."""
    out = list(LOCALIZERS)
    for n in names:
        out += [loc for loc in (EXTRA[n][1] if n in EXTRA else ()) if loc not in out]
    return out


def experiment(name: str, trials: int | None, mode: str | None = None):
    """The paper config, optionally with fewer trials or another image formation (the
    dataset name records both). In physical mode the dock sits at the deepest condition's
    depth, so every depth condition lowers the surface inside the pool's walls
    (``scene_check.check_surfaces``)."""
    path = bundled_file("configs", config_file(name))
    exp = load_experiment(path)
    raw = exp.model_dump()
    if trials is not None:  # re-validated: the trials and frame limits apply here too
        raw.update(trials=trials, name=f"{raw['name']}-{trials}trials")
    if mode is not None and mode != exp.image_formation:
        raw.update(image_formation=mode, name=f"{raw['name']}-{mode}")
    if raw["image_formation"] == "physical":  # the dock at the deepest condition: the surface
        depths = [c["dock_water_depth_m"] for c in raw["conditions"] if c.get("dock_water_depth_m") is not None]
        raw["scene"]["dock"]["water_depth_m"] = max([raw["scene"]["dock"]["water_depth_m"], *depths])
    try:
        exp = type(exp).model_validate(raw)
    except ValidationError as e:
        raise ConfigError(format_validation_error(Path(f"{path} with --trials {trials}"), e)) from None
    return exp


def evaluate(dataset_dir: Path, out: Path, localizers=LOCALIZERS, workers: int | None = None) -> dict:
    """Run the localizers over the dataset (one process per core, split by sequence) and
    save the full run record."""
    from evalkit.reports.results import EvalRequest, evaluate_dataset

    req = EvalRequest(dataset_dir, list(localizers), out, overwrite=True, workers=workers)
    return evaluate_dataset(req)[1]


def report(name: str, paths: dict, exp=None) -> str:
    """Article table, per-marker usable range and where the plots are; for the turbidity
    ladder (``exp`` given) also the usable range per water beside its prediction."""
    m = pd.read_csv(paths["metrics"], keep_default_na=False, na_values=[""])
    group = ["localizer", "trajectory", "condition"]
    rt = pd.read_csv(paths["runtime"], keep_default_na=False, na_values=[""])
    m = m.merge(rt[group + ["ms_median"]], on=group, how="left")
    lines = [
        f"## {name}",
        "",
        Path(paths["article_md"]).read_text().strip(),
        "",
        "breakdown by localizer (marker): usable range = largest 1 m bin with P_succ >= 0.9",
        "",
    ]
    for _, r in m.iterrows():
        rng = "-" if pd.isna(r["max_range_m"]) else f"{r['max_range_m']:.0f} m"
        lines.append(
            f"- {r['localizer']:7s} {r['trajectory']}/{r['condition']:12s} "
            f"P_succ {100 * r['P_succ_mean']:5.1f}%  P_detect {100 * r['P_detect_mean']:5.1f}%  "
            f"E_rel {100 * r['E_rel_mean']:.2f}% (range-matched {_matched(r)})  usable range {rng}  "
            f"{r['ms_median']:.1f} ms/frame"
        )
    if exp is not None and exp.name.startswith("turbidity_ladder"):
        from blendgen.tools.apps.water_ladder import ladder_table

        lines += ["", "usable range per water: contrast-threshold prediction / measured", "", ladder_table(exp, m)]
    lines += ["", Path(paths["range_bins_md"]).read_text().strip()]
    plots = Path(paths["article_md"]).parent.parent / "plots"
    lines += [
        "",
        f"plots: {plots / 'range_bins.png'} (success and error per range bin, conditions as lines), "
        f"{plots / 'error_vs_distance.png'}, {plots / 'success_vs_distance.png'}",
    ]
    return "\n".join(lines)


def _matched(r) -> str:
    """``0.41% over 1-7 m``: a metrics row's range-matched error and its bins, or ``-``."""
    if pd.isna(r.get("E_rel_matched")) or pd.isna(r.get("matched_lo_m")):
        return "-"
    return f"{100 * r['E_rel_matched']:.2f}% over {r['matched_lo_m']:g}-{r['matched_hi_m']:g} m"


def reproduce(
    names: tuple[str, ...],
    out_root: Path,
    trials: int | None,
    workers: int | None,
    overwrite: bool = False,
    mode: str | None = None,
    images: str = "all",
) -> list[str]:
    """Generate the experiments' datasets together (each shared camera path is rendered
    once for all of them) and evaluate every sequence as soon as it is written
    (:mod:`blendgen.tools.apps.streamrun`; ``images``: which camera images stay on disk), then
    report each; returns the Markdown reports."""
    from blendgen.pipeline.generate import check_out_dir
    from blendgen.tools.apps.streamrun import RunRequest, stream_run

    exps = [experiment(n, trials, mode) for n in names]
    bases = [Path(out_root) / e.name for e in exps]
    for e, b in zip(exps, bases):
        check_out_dir(e, b / "dataset", overwrite=overwrite)
    t0 = time.perf_counter()
    runs = stream_run(
        list(zip(exps, bases)), RunRequest(localizers_of(names), images=images, workers=workers, overwrite=overwrite)
    )
    dt = time.perf_counter() - t0
    reports = []
    for e, b, r in zip(exps, bases, runs):
        text = report(e.name, r["paths"], e) + (
            f"\n\ntimes: generate + evaluate (all {len(exps)} together, evaluated while rendering) {dt:.0f} s\n"
        )
        (b / "report.md").write_text(text)
        reports.append(text)
    return reports
