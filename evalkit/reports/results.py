"""Results of one evaluation run on disk, tied to the dataset they were computed on.

A run directory (written by :func:`save_run`)::

    run.json           dataset name/version/content_hash, localizers, dockbench version,
                       timestamp, settings, per-condition metrics, runtime
    estimates.parquet  per-frame estimates (runner columns; CSV if parquet is unavailable)
    summary.csv        per trial (the article's P_succ, e_abs_mean, e_rel_mean)
    conditions.csv     per condition (the article's P_succ_mean, E_rel_mean)
    metrics.csv        per condition, everything (CIs, pose errors, FP rate, usable range, runtime)
    bins.csv           per condition and 1 m distance bin
    false_positives.csv, runtime.csv
    tables/article.md|tex, tables/metrics.md|tex
    plots/error_vs_distance.png, plots/success_vs_distance.png

Runs are comparable only when computed on the same dataset content:
:func:`compare_runs` refuses runs whose ``content_hash`` differ.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from evalkit.metrics import core as metrics

from evalkit.metrics import extra as metrics_extra

from evalkit.reports import tables

RUN_FORMAT = "dockbench-results"
RUN_FORMAT_VERSION = "1"
RUN_JSON = "run.json"


class ResultsError(Exception):
    """A results directory is missing/malformed, or runs are not comparable."""


def dockbench_version() -> str:
    """Installed dockbench version, or ``"unknown"``."""
    try:
        from importlib.metadata import version
        return version("dockbench")
    except Exception:  # noqa: BLE001 - not installed as a distribution
        return "unknown"


def _json_safe(value: Any) -> Any:
    """NaN/inf -> None, numpy scalars -> Python, recursively; unknown objects -> str."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        try:
            value = value.item()
        except (ValueError, TypeError):
            return str(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (str, int, bool)):
        return value
    return str(value)


def _records(df: pd.DataFrame) -> list[dict]:
    """DataFrame rows as JSON-safe dicts."""
    return [_json_safe(r) for r in df.to_dict(orient="records")]


def localizer_info(spec: Any) -> dict:
    """``{name, class, params}`` of a ``(name, localizer)`` pair (or a bare name).

    ``params`` are the localizer's public attributes of simple types (its
    constructor settings, by convention)."""
    if isinstance(spec, str):
        return {"name": spec, "class": None, "params": {}}
    name, obj = spec
    cls = type(obj)
    params = {k: v for k, v in vars(obj).items()
              if not k.startswith("_") and isinstance(v, (str, int, float, bool, type(None)))} \
        if hasattr(obj, "__dict__") else {}
    return {"name": str(name), "class": f"{cls.__module__}:{cls.__qualname__}",
            "params": _json_safe(params)}


def dataset_info(dataset) -> dict:
    """``{name, version, content_hash, spec_version, path}`` of a :class:`~evalkit.dataset.Dataset`."""
    m = dataset.manifest
    return {"name": m.get("name"), "version": m.get("version"), "content_hash": m.get("content_hash"),
            "spec_version": m.get("spec_version"), "path": str(Path(dataset.root).resolve())}


def save_run(estimates_df: pd.DataFrame, out_dir: str | Path, dataset, localizer_specs: Iterable[Any],
             extra: dict | None = None, truth: pd.DataFrame | None = None, n_boot: int = 2000,
             level: float = 0.95, seed: int = 0, bin_m: float = 1.0, usable_threshold: float = 0.9,
             make_plots: bool = True) -> dict[str, Path]:
    """Compute every metric of ``estimates_df`` (from :func:`evalkit.runner.evaluate`) and write
    the run directory ``out_dir`` (see the module docstring). Returns the written paths.

    ``dataset`` is the :class:`~evalkit.dataset.Dataset` evaluated (its manifest's
    name/version/content_hash go into ``run.json``; its frames give the truth
    unless ``truth`` from :func:`evalkit.metrics.truth.frame_truth_table` is passed).
    ``localizer_specs``: the ``(name, localizer)`` pairs (or names) that were run.
    ``extra``: free JSON-able dict stored under ``run.json["extra"]`` (e.g. CLI params).
    Bootstrap: ``n_boot`` resamples of the trials, ``level`` CI, ``seed``.
    """
    from evalkit import runner
    from evalkit.metrics.truth import frame_truth_table

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    d_max = float(estimates_df.attrs.get("d_max_m", metrics.D_MAX_M))
    d_min_rel = float(estimates_df.attrs.get("d_min_rel_m", dataset.d_min_rel_m))
    if truth is None:
        seqs = sorted(set(estimates_df["sequence"].astype(str))) if len(estimates_df) else []
        truth = frame_truth_table(dataset, seqs)
    res = metrics_extra.compute_all(estimates_df, truth, d_max=d_max, d_min_rel=d_min_rel,
                                    bin_m=bin_m, usable_threshold=usable_threshold,
                                    n_boot=n_boot, level=level, seed=seed)
    paths = dict(runner.write_results(estimates_df, out, d_max=d_max, d_min_rel=d_min_rel))
    for key, name in (("metrics", "metrics.csv"), ("bins", "bins.csv"), ("fp", "false_positives.csv"),
                      ("runtime", "runtime.csv")):
        paths[key] = tables.write_csv(res[key], out / name)
    tdir = out / "tables"
    tdir.mkdir(exist_ok=True)
    ds_label = f"{dataset.manifest.get('name')} {dataset.manifest.get('version')}"
    caption = (f"Average positioning error (E_rel) and successful docking location rate (P_succ) "
               f"per condition, {ds_label}; 95% bootstrap CI over trials in brackets.")
    paths["article_md"] = _write(tdir / "article.md", tables.article_markdown(res["metrics"]))
    paths["article_tex"] = _write(tdir / "article.tex",
                                  tables.article_latex(res["metrics"], caption=caption,
                                                       label="tab:dockbench-article"))
    paths["metrics_md"] = _write(tdir / "metrics.md", tables.to_markdown(res["metrics"]))
    paths["metrics_tex"] = _write(tdir / "metrics.tex", tables.to_latex(res["metrics"]))
    if make_plots:
        from evalkit.reports import plots
        pdir = out / "plots"
        paths["plot_error"] = plots.plot_error_vs_distance(
            estimates_df, pdir / "error_vs_distance.png", d_max=d_max, d_min_rel=d_min_rel,
            title=f"error vs distance, one trial per condition ({ds_label})")
        paths["plot_success"] = plots.plot_success_vs_distance(
            res["bins"], pdir / "success_vs_distance.png", threshold=usable_threshold,
            title=f"P_succ per {bin_m:g} m bin ({ds_label})")
    run = {
        "format": RUN_FORMAT, "format_version": RUN_FORMAT_VERSION,
        "dataset": dataset_info(dataset),
        "localizers": [localizer_info(s) for s in localizer_specs],
        "dockbench_version": dockbench_version(),
        "timestamp": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "settings": {"d_max_m": d_max, "d_min_rel_m": d_min_rel, "bin_m": bin_m,
                     "usable_threshold": usable_threshold,
                     "bootstrap": {"n_boot": n_boot, "level": level, "seed": seed}},
        "n_frames": int(len(estimates_df)),
        "metrics": _records(res["metrics"]),
        "runtime": _records(res["runtime"]),
        "files": {k: p.relative_to(out).as_posix() for k, p in paths.items()},
        "extra": _json_safe(extra or {}),
    }
    paths["run"] = _write(out / RUN_JSON, json.dumps(run, indent=1) + "\n")
    return paths


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


@dataclass
class Run:
    """A loaded run directory."""

    path: Path
    run: dict
    metrics: pd.DataFrame
    conditions: pd.DataFrame | None = None
    summary: pd.DataFrame | None = None
    bins: pd.DataFrame | None = None
    _estimates: pd.DataFrame | None = field(default=None, repr=False)

    @property
    def dataset(self) -> dict:
        return self.run.get("dataset") or {}

    @property
    def content_hash(self) -> str | None:
        return self.dataset.get("content_hash")

    @property
    def label(self) -> str:
        """Short name of the run: its directory name."""
        return self.path.name

    @property
    def estimates(self) -> pd.DataFrame:
        """Per-frame estimates (read on first use)."""
        if self._estimates is None:
            p = self.path / "estimates.parquet"
            self._estimates = pd.read_parquet(p) if p.is_file() else pd.read_csv(self.path / "estimates.csv")
        return self._estimates


def evaluate_dataset(dataset_dir: str | Path, localizers: Iterable[str], out_dir: str | Path,
                     params: Iterable[str] = (), isolate: bool | None = None, frame_timeout_s: float | None = None,
                     preprocess: str | None = None, progress: bool = True) -> tuple[Any, dict[str, Path]]:
    """Open a dataset, build the localizers (``-l`` specs with ``-p`` params), run them
    and save the run record; returns ``(dataset, paths)``. What ``dockbench evaluate``
    and ``dockbench reproduce`` both do."""
    from evalkit import assemble, registry, runner
    from evalkit.dataset import Dataset
    ds = Dataset.open(dataset_dir)
    names, params = list(localizers), list(params)
    kw = registry.parse_params(params)
    specs = [(n, assemble.build(n, registry.params_for(n, kw, names), isolate=isolate,
                                timeout_s=frame_timeout_s, preprocess=preprocess)) for n in names]
    df = runner.evaluate(ds, specs, frame_timeout_s=frame_timeout_s, progress=progress)
    extra = {"localizers": names, "params": params, "frame_timeout_s": frame_timeout_s}
    return ds, save_run(df, out_dir, ds, specs, extra=extra)


def _read_csv(path: Path) -> pd.DataFrame | None:
    return pd.read_csv(path) if path.is_file() else None


def load_run(path: str | Path) -> Run:
    """Load a directory written by :func:`save_run`; :class:`ResultsError` if it is not one."""
    root = Path(path)
    rj = root / RUN_JSON
    if not rj.is_file():
        raise ResultsError(f"{root}: not a dockbench results directory (no {RUN_JSON}; "
                           f"write one with `dockbench evaluate`)")
    try:
        run = json.loads(rj.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ResultsError(f"{rj}: invalid JSON: {exc}") from None
    if not isinstance(run, dict) or run.get("format") != RUN_FORMAT:
        raise ResultsError(f"{rj}: \"format\" is not {RUN_FORMAT!r}")
    m = _read_csv(root / "metrics.csv")
    if m is None:
        m = pd.DataFrame(run.get("metrics") or [], columns=metrics_extra.METRIC_COLUMNS)
    for col in ("localizer", "condition"):
        m[col] = m[col].astype(str)
    return Run(root, run, m, _read_csv(root / "conditions.csv"), _read_csv(root / "summary.csv"),
               _read_csv(root / "bins.csv"))


def _describe(run: Run) -> str:
    d = run.dataset
    h = d.get("content_hash") or "?"
    return f"{run.path}: dataset {d.get('name')!r} {d.get('version')} (content_hash {h[:12]})"


def compare_runs(runs: Iterable[Run | str | Path]) -> pd.DataFrame:
    """Per-condition metrics of several runs side by side (columns ``run, dataset, version,
    content_hash, label`` + :data:`~evalkit.metrics.extra.METRIC_COLUMNS`).

    ``label`` is the localizer name, with ``" [run]"`` appended when several runs
    contain the same name. Raises :class:`ResultsError` if the runs were not all
    computed on the same dataset content (``content_hash``), or a run has none.
    """
    loaded = [r if isinstance(r, Run) else load_run(r) for r in runs]
    if not loaded:
        raise ResultsError("no runs to compare")
    missing = [r for r in loaded if not r.content_hash]
    if missing:
        raise ResultsError("cannot compare: run(s) without a dataset content_hash: "
                           + ", ".join(str(r.path) for r in missing))
    hashes = {r.content_hash for r in loaded}
    if len(hashes) > 1:
        raise ResultsError("cannot compare runs computed on different datasets "
                           "(content_hash differs; results are comparable only on the same data):\n  "
                           + "\n  ".join(_describe(r) for r in loaded))
    labels = [r.label for r in loaded]
    if len(set(labels)) < len(labels):
        labels = [str(r.path) for r in loaded]
    frames = []
    for r, run_label in zip(loaded, labels):
        m = r.metrics.copy()
        m.insert(0, "run", run_label)
        m.insert(1, "dataset", r.dataset.get("name"))
        m.insert(2, "version", r.dataset.get("version"))
        m.insert(3, "content_hash", r.content_hash)
        frames.append(m)
    out = pd.concat(frames, ignore_index=True)
    dup = out.groupby("localizer")["run"].transform("nunique") > 1
    out.insert(4, "label", out["localizer"].where(~dup, out["localizer"] + " [" + out["run"] + "]"))
    return out
