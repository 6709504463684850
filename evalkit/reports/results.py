"""Results of one evaluation run on disk, tied to the dataset they were computed on.

A run directory (written by :func:`save_run`, atomically via
:func:`evalkit.reports.outdir.results_dir`)::

    run.json           command line, environment (versions, git commit), dataset identity
                       (content hash recomputed), localizers (spec, params as given, code
                       sha256), options, scoring settings, per-group metrics
    estimates.parquet  per-frame estimates, truth and scores (CSV if parquet is unavailable)
    summary.csv        per trial (P_succ, P_detect, errors)
    metrics.csv        per (localizer, trajectory, condition): CIs, pose errors, AR_dock, FP, usable range
    bins.csv, false_positives.csv, recall.csv, runtime.csv
    tables/article.md|tex, tables/metrics.md|tex, tables/range_bins.md
    plots/error_vs_distance.png, plots/success_vs_distance.png, plots/range_bins.png

summary.csv and metrics.csv hold no timings, so the same inputs give byte-identical
files; runtimes are in runtime.csv. Runs are comparable only when computed on the
same dataset content: :func:`compare_runs` refuses runs whose ``content_hash`` differ.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from evalkit.metrics import core as metrics
from evalkit.metrics import extra as metrics_extra
from evalkit.metrics.extra import EvalSettings
from evalkit.reports import tables

RUN_FORMAT = "dockbench-results"
RUN_FORMAT_VERSION = "2"
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


def dataset_info(dataset, content_hash: str | None = None) -> dict:
    """Identity of a :class:`~evalkit.dataset.Dataset` for run.json.

    ``content_hash`` is recomputed: from the manifest's verified ``files`` map, or
    (``dataset.verify`` false) from the bytes on disk; ``manifest_content_hash`` is the
    manifest's own value, ``verified`` whether every file read was checked."""
    from datasets_spec.io import content_hash as hash_files
    from evalkit.reports.provenance import disk_content_hash

    m = dataset.manifest
    files = m.get("files") or {}
    if content_hash is None and dataset.verify and not getattr(dataset, "streamed", False):  # every file
        from datasets_spec.io import DatasetError
        from evalkit.reports.provenance import first_changed_file

        bad = first_changed_file(Path(dataset.root), files)
        if bad is not None:
            raise DatasetError(
                f"{Path(dataset.root) / bad}: missing or sha256 differs from the manifest "
                "(dockbench verify lists every changed file); the run's content hash would "
                "not describe this dataset"
            )
    if content_hash is None:
        content_hash = hash_files(files) if dataset.verify else disk_content_hash(Path(dataset.root), files)
    return {
        "name": m.get("name"),
        "version": m.get("version"),
        "content_hash": content_hash,
        "manifest_content_hash": m.get("content_hash"),
        "verified": bool(dataset.verify),
        "spec_version": m.get("spec_version"),
        "path": str(Path(dataset.root).resolve()),
    }


@dataclass
class RunRecord:
    """Everything about a run that is not the per-frame estimates.

    ``dataset``: the :class:`~evalkit.dataset.Dataset` evaluated; ``localizers``: records
    from :func:`evalkit.reports.provenance.localizer_record` (or plain names);
    ``settings``: scoring; ``command``: the command line (argv) or None for API use;
    ``options``: evaluation options (isolate, frame_timeout_s, preprocess, verify);
    ``make_plots``: write the PNGs; ``environment``: versions (default: collected now)."""

    dataset: Any
    localizers: list = field(default_factory=list)
    settings: EvalSettings = field(default_factory=EvalSettings)
    command: list[str] | None = None
    options: dict = field(default_factory=dict)
    make_plots: bool = True
    environment: dict | None = None


def _localizer_entry(item: Any) -> dict:
    """A plain name, a ``(name, object)`` pair or a provenance record as a run.json entry."""
    if isinstance(item, dict):
        return item
    if isinstance(item, str):
        return {"name": item, "params": {}, "class": None, "code": []}
    name, obj = item
    cls = type(obj)
    return {"name": str(name), "params": {}, "class": f"{cls.__module__}:{cls.__qualname__}", "code": []}


def _write_tables(res: dict, out: Path, label: str, sequences: list[dict] | None = None) -> dict[str, Path]:
    """CSV and Markdown/LaTeX tables of ``res`` (from :func:`compute_all`) into ``out``;
    ``sequences``: the manifest's (how each camera path ended, for the article table's note)."""
    paths = {
        "summary": out / "summary.csv",
        "metrics": out / "metrics.csv",
        "bins": out / "bins.csv",
        "fp": out / "false_positives.csv",
        "recall": out / "recall.csv",
        "runtime": out / "runtime.csv",
    }
    for key, df in (
        ("summary", res["trials"]),
        ("metrics", res["metrics"]),
        ("bins", res["bins"]),
        ("fp", res["fp"]),
        ("recall", res["recall"]),
        ("runtime", res["runtime"]),
    ):
        tables.write_csv(df, paths[key])
    tdir = out / "tables"
    tdir.mkdir(exist_ok=True)
    caption = (
        f"Successful localization rate (P_succ, error within the success thresholds), "
        f"answer rate (P_detect) and average relative distance error (E_rel) per trajectory "
        f"and condition, {label}; 95% bootstrap CI over the M trials in brackets."
    )
    paths["article_md"] = _write(tdir / "article.md", tables.article_markdown(res["metrics"], sequences=sequences))
    paths["article_tex"] = _write(
        tdir / "article.tex", tables.article_latex(res["metrics"], caption=caption, label="tab:dockbench-article")
    )
    paths["metrics_md"] = _write(tdir / "metrics.md", tables.to_markdown(res["metrics"]))
    paths["range_bins_md"] = _write(tdir / "range_bins.md", tables.range_bins_markdown(res["bins"]))
    paths["metrics_tex"] = _write(tdir / "metrics.tex", tables.to_latex(res["metrics"]))
    return paths


def _write_plots(res: dict, out: Path, settings: EvalSettings, label: str) -> dict[str, Path]:
    """The PNGs of a run."""
    from evalkit.reports import plots

    pdir = out / "plots"
    return {
        "plot_error": plots.plot_error_vs_distance(
            res["frames"],
            pdir / "error_vs_distance.png",
            trials=res["trials"],
            d_max=settings.d_max_m,
            title=f"error vs distance, one representative trial ({label})",
        ),
        "plot_success": plots.plot_success_vs_distance(
            res["bins"],
            pdir / "success_vs_distance.png",
            threshold=settings.usable_threshold,
            title=f"P_succ per {settings.bin_m:g} m bin ({label})",
        ),
        "plot_range_bins": plots.plot_range_bins(
            res["bins"],
            pdir / "range_bins.png",
            threshold=settings.usable_threshold,
            title=f"success and error per {settings.bin_m:g} m range bin ({label})",
        ),
    }


def save_run(estimates_df: pd.DataFrame, out_dir: str | Path, record: RunRecord) -> tuple[dict[str, Path], dict]:
    """Compute every metric of ``estimates_df`` (from :func:`evalkit.runner.evaluate`) and
    write the run directory ``out_dir`` (see the module docstring; the caller provides an
    empty folder, normally from :func:`~evalkit.reports.outdir.results_dir`).

    Returns ``(paths, tables)``: the written files and :func:`compute_all`'s tables."""
    from evalkit.metrics.recall import DockModel
    from evalkit.reports import provenance

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ds, settings = record.dataset, record.settings
    cam = ds.camera
    model = DockModel.from_markers(ds.markers, cam["K"], cam["width"])
    res = metrics_extra.compute_all(estimates_df, settings, model)
    label = f"{ds.manifest.get('name')} {ds.manifest.get('version')}"
    paths = {"estimates": _write_estimates(res["frames"], out / "estimates.parquet")}
    paths.update(_write_tables(res, out, label, ds.manifest.get("sequences")))
    if record.make_plots:
        paths.update(_write_plots(res, out, settings, label))
    run = {
        "format": RUN_FORMAT,
        "format_version": RUN_FORMAT_VERSION,
        "command": record.command,
        "dataset": dataset_info(ds),
        "localizers": [_localizer_entry(s) for s in record.localizers],
        "options": record.options,
        "settings": settings.as_dict(),
        "dock_model": None
        if model is None
        else {
            "n_vertices": int(len(model.points)),
            "diameter_m": model.diameter_m,
            "mssd_thresholds_m": model.mssd_thresholds().tolist(),
            "mspd_thresholds_px": model.mspd_thresholds().tolist(),
        },
        "dockbench_version": dockbench_version(),
        "environment": record.environment or provenance.environment(),
        "timestamp": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "n_frames": int(len(estimates_df)),
        "metrics": _records(res["metrics"]),
        "files": {k: p.relative_to(out).as_posix() for k, p in paths.items()},
    }
    paths["run"] = _write(out / RUN_JSON, json.dumps(_json_safe(run), indent=1) + "\n")
    return paths, res


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _write_estimates(df: pd.DataFrame, path: Path) -> Path:
    """Write ``path`` (parquet); if no parquet engine imports, write CSV beside it and warn.

    Returns the path actually written, so a long run never loses its results
    to a broken optional dependency.
    """
    try:
        df.to_parquet(path, index=False)
        return path
    except ImportError as exc:
        csv_path = path.with_suffix(".csv")
        print(
            f"warning: cannot write {path.name} ({_parquet_problem(exc)}); wrote {csv_path.name} instead",
            file=sys.stderr,
        )
        df.to_csv(csv_path, index=False, lineterminator="\n")
        return csv_path


def _parquet_problem(exc: ImportError) -> str:
    """Short reason why parquet is unavailable (pyarrow's own import error if any)."""
    try:
        import pyarrow  # noqa: F401
    except ImportError as pa_exc:
        return f"pyarrow: {pa_exc}"
    return str(exc).strip().splitlines()[0]


@dataclass
class Run:
    """A loaded run directory."""

    path: Path
    run: dict
    metrics: pd.DataFrame
    runtime: pd.DataFrame | None = None
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


@dataclass
class EvalRequest:
    """One ``dockbench evaluate``: what to run on what, and where the results go.

    ``localizers``: ``-l`` specs; ``params``: ``-p`` items (``key=value``); ``isolate`` /
    ``frame_timeout_s`` / ``preprocess``: see :func:`evalkit.assemble.build`;
    ``verify``: check every file read against the manifest; ``overwrite``: replace a
    non-empty ``out_dir``; ``command``: argv recorded in run.json."""

    dataset_dir: Path
    localizers: list[str]
    out_dir: Path
    params: list[str] = field(default_factory=list)
    isolate: bool | None = None  # None: plugins isolated, built-ins in process
    frame_timeout_s: float | None = None
    preprocess: str | None = None
    verify: bool = True
    overwrite: bool = False
    progress: bool = True
    settings: EvalSettings = field(default_factory=EvalSettings)
    command: list[str] | None = None
    workers: int | None = 1  # evaluation processes (split by sequence); None: one per core


def evaluate_dataset(req: EvalRequest) -> tuple[Any, dict[str, Path], dict]:
    """Lock the results folder, open (and verify) the dataset, build the localizers, run
    them and save the run record atomically; returns ``(dataset, paths, tables)``. What
    ``dockbench evaluate`` and ``dockbench reproduce`` both do."""
    from dataclasses import replace

    from evalkit import assemble, registry, runner
    from evalkit.dataset import Dataset
    from evalkit.reports.outdir import results_dir
    from evalkit.reports.provenance import localizer_record

    out = Path(req.out_dir)
    ds = Dataset.open(req.dataset_dir, verify=req.verify)  # dataset errors before anything is written
    for seq in ds.sequences:  # ground truth checked before any localizer runs (images: as read)
        ds.check_file(ds.frames_path(seq["id"]))
    with results_dir(out, req.overwrite) as tmp:
        names = list(req.localizers)
        kw = registry.parse_params(list(req.params))
        given = {n: registry.params_for(n, kw, names) for n in names}
        specs = [
            (
                n,
                assemble.build(
                    n, given[n], isolate=req.isolate, timeout_s=req.frame_timeout_s, preprocess=req.preprocess
                ),
            )
            for n in names
        ]
        records = [localizer_record(n, given[n], obj) for n, obj in specs]
        if req.workers == 1:
            df = runner.evaluate(ds, specs, frame_timeout_s=req.frame_timeout_s, progress=req.progress)
        else:  # the same per-frame table from one process per core (evalkit.parallel)
            from evalkit.parallel import evaluate_frames

            df = evaluate_frames(
                req.dataset_dir,
                names,
                list(req.params),
                req.workers,
                req.isolate,
                req.frame_timeout_s,
                req.preprocess,
                verify=req.verify,
            )
        settings = replace(req.settings, d_min_rel_m=ds.d_min_rel_m)
        options = {
            "params": list(req.params),
            "isolate": req.isolate,
            "frame_timeout_s": req.frame_timeout_s,
            "preprocess": req.preprocess,
            "verify": req.verify,
            "overwrite": req.overwrite,
        }
        record = RunRecord(ds, records, settings, req.command, options)
        paths, res = save_run(df, tmp, record)
    return ds, {k: out / p.relative_to(tmp) for k, p in paths.items()}, res


def json_summary(run_json: Path) -> str:
    """The machine-readable summary ``evaluate --json`` prints: results folder, dataset,
    settings and the per-group metrics from run.json (no timings, no timestamp)."""
    run = json.loads(Path(run_json).read_text(encoding="utf-8"))
    keep = {
        "results": str(Path(run_json).parent),
        "dataset": run["dataset"],
        "settings": run["settings"],
        "localizers": [{"name": loc["name"], "params": loc.get("params")} for loc in run["localizers"]],
        "metrics": run["metrics"],
    }
    return json.dumps(keep, indent=1, sort_keys=True)


def _read_csv(path: Path) -> pd.DataFrame | None:
    """A results CSV (None: absent); an unreadable one is a :class:`ResultsError`."""
    if not path.is_file():
        return None
    try:
        return pd.read_csv(path)
    except (ValueError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        raise ResultsError(f"{path}: unreadable CSV ({type(exc).__name__}: {str(exc)[:100]})") from None


def load_run(path: str | Path) -> Run:
    """Load a directory written by :func:`save_run`; :class:`ResultsError` if it is not one."""
    root = Path(path)
    rj = root / RUN_JSON
    if not rj.is_file():
        raise ResultsError(
            f"{root}: not a dockbench results directory (no {RUN_JSON}; write one with `dockbench evaluate`)"
        )
    try:
        run = json.loads(rj.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as exc:
        raise ResultsError(f"{rj}: invalid JSON: {type(exc).__name__}: {str(exc)[:120]}") from None
    if not isinstance(run, dict) or run.get("format") != RUN_FORMAT:
        raise ResultsError(f'{rj}: "format" is not {RUN_FORMAT!r}')
    if str(run.get("format_version")) != RUN_FORMAT_VERSION:
        raise ResultsError(
            f"{rj}: results format {run.get('format_version')!r}, this dockbench reads "
            f"{RUN_FORMAT_VERSION!r} (format 1 counted any answer as a success); "
            "re-run dockbench evaluate"
        )
    m = _read_csv(root / "metrics.csv")
    if m is None:
        m = pd.DataFrame(run.get("metrics") or [], columns=metrics_extra.METRIC_COLUMNS)
    for col in metrics.GROUP:
        m[col] = m[col].fillna("").astype(str) if col in m.columns else ""
    runtime = _read_csv(root / "runtime.csv")
    _check_numbers(root, run, m, runtime)
    return Run(root, run, m, runtime, _read_csv(root / "summary.csv"), _read_csv(root / "bins.csv"))


def _check_numbers(root: Path, run: dict, m: pd.DataFrame, runtime: pd.DataFrame | None) -> None:
    """Every number the leaderboard shows or ranks within what evaluate can produce
    (:mod:`evalkit.reports.numbers`); else :class:`ResultsError` naming file, row and column."""
    from evalkit.reports.numbers import NumberError, check_metric_rows

    settings = run.get("settings")
    if not isinstance(settings, dict):
        settings = {}
    d_min = settings.get("d_min_rel_m")
    d_min = d_min if isinstance(d_min, (int, float)) and not isinstance(d_min, bool) else None
    try:
        shown = root / "metrics.csv" if (root / "metrics.csv").is_file() else root / RUN_JSON
        check_metric_rows(shown, m.to_dict("records"), d_min)
        if isinstance(run.get("metrics"), list) and all(isinstance(r, dict) for r in run["metrics"]):
            check_metric_rows(root / RUN_JSON, run["metrics"], d_min)
        if runtime is not None:
            check_metric_rows(root / "runtime.csv", runtime.to_dict("records"))
    except NumberError as exc:
        raise ResultsError(str(exc)) from None


def _describe(run: Run) -> str:
    d = run.dataset
    h = d.get("content_hash") or "?"
    return f"{run.path}: dataset {d.get('name')!r} {d.get('version')} (content_hash {h[:12]})"


def compare_runs(runs: Iterable[Run | str | Path]) -> pd.DataFrame:
    """Per-group metrics of several runs side by side (columns ``run, dataset, version,
    content_hash, label`` + :data:`~evalkit.metrics.extra.METRIC_COLUMNS` + ``ms_median, ms_p95``
    from runtime.csv).

    ``label`` is the localizer name, with ``" [run]"`` appended when several runs
    contain the same name. Raises :class:`ResultsError` if the runs were not all
    computed on the same dataset content (``content_hash``), or a run has none.
    """
    loaded = [r if isinstance(r, Run) else load_run(r) for r in runs]
    if not loaded:
        raise ResultsError("no runs to compare")
    missing = [r for r in loaded if not r.content_hash]
    if missing:
        raise ResultsError(
            "cannot compare: run(s) without a dataset content_hash: " + ", ".join(str(r.path) for r in missing)
        )
    hashes = {r.content_hash for r in loaded}
    if len(hashes) > 1:
        raise ResultsError(
            "cannot compare runs computed on different datasets "
            "(content_hash differs; results are comparable only on the same data):\n  "
            + "\n  ".join(_describe(r) for r in loaded)
        )
    labels = [r.label for r in loaded]
    if len(set(labels)) < len(labels):
        labels = [f"{r.path.parent.name}/{r.path.name}" for r in loaded]
    if len(set(labels)) < len(labels):
        labels = [str(r.path) for r in loaded]
    frames = []
    for r, run_label in zip(loaded, labels):
        m = r.metrics.copy()
        rt = r.runtime
        if rt is not None and set(metrics.GROUP) <= set(rt.columns):
            rt = rt.assign(**{c: rt[c].fillna("").astype(str) for c in metrics.GROUP})
            m = m.merge(rt[metrics.GROUP + ["ms_median", "ms_p95"]], on=metrics.GROUP, how="left")
        m.insert(0, "run", run_label)
        m.insert(1, "dataset", r.dataset.get("name"))
        m.insert(2, "version", r.dataset.get("version"))
        m.insert(3, "content_hash", r.content_hash)
        frames.append(m)
    out = pd.concat(frames, ignore_index=True)
    dup = out.groupby("localizer")["run"].transform("nunique") > 1
    out.insert(4, "label", out["localizer"].where(~dup, out["localizer"] + " [" + out["run"] + "]"))
    return out
