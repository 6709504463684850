"""``dockbench bench suite``: the article's suite (or part of it) at N trials, measured.

Runs exactly what ``dockbench reproduce`` runs (generate the experiments together,
then evaluate led, qr and hybrid) and reports, per stage, CPU seconds and wall
seconds:

- ``render``  Cycles and reading its passes back (in the render workers);
- ``compose`` planar depth -> range, ground truth, water/particles/sensor per sequence;
- ``write``   PNGs (image per sequence, range and index once per render) and frames.jsonl;
- ``generate other`` what generation costs beyond the three (bpy import, scene build,
  manifest hashing): the workers' and the parent's CPU minus the three stages;
- ``evaluate`` localizers, metrics, tables and plots.

``compose`` is split into its terms where the frame loop times them
(:func:`blendgen.pipeline.stagetimer.term`: ``compose.passes``, ``compose.particles``,
``compose.water``, ``compose.caustics``, ``compose.surface``, ``compose.led_light``,
``compose.lamp``, ``compose.sensor``, ``compose.truth``; ``compose.other`` is the rest), and
``evaluate`` per localizer (``evaluate.<name>``: the wall time the evaluator records per call,
summed over the frames, times the CPU / wall of the one-thread process that evaluated the
sequence: an estimate of the calls' CPU that removes the waiting on a shared machine; the
hybrid's includes the LED and QR calls it shares with them, so these overlap).

``--mode physical|article|both`` overrides the experiments' ``image_formation`` the way
``dockbench reproduce --mode`` does (:func:`blendgen.tools.apps.reproduce.experiment`); with
``both`` the two suites run one after the other and are printed side by side with their
100-trial estimates on 2 cores (the machine the article's suite targets).

``--images none|sample:N`` measures the streaming path instead (``dockbench run``:
each sequence evaluated by a pool of processes as soon as it is rendered, only the
sampled images kept): ``evaluate`` is then the evaluation workers' CPU plus the
parent's metrics, ``total`` wall is the one run's wall (stages overlap).

plus the peak RSS of the whole process tree (sampled from /proc every 0.2 s), the disk
the run left (hard links counted once, like ``du``; also without the camera images),
and a linear extrapolation to 100 trials. Stage CPU comes from the workers' own timers
(``time.process_time``: all threads of a worker). A benchmark, never a test: nothing
is asserted. On a shared machine wall times include waiting for other users' work;
CPU seconds do not.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

STAGES = ("render", "compose", "write")
MODES = ("physical", "article")
#: The 100-trial estimate is quoted on this many idle cores: the 2-core machine the suite's cost
#: targets are set on (README, "Cost of the whole suite").
REFERENCE_CORES = 2


# -- measuring -------------------------------------------------------------------
class TreeRSS:
    """Peak of the summed resident memory (MB) of this process and all its descendants."""

    def __init__(self, period_s: float = 0.2):
        self.period_s, self.peak_mb = period_s, 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="rss-sampler")

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def _loop(self):
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, tree_rss_mb(os.getpid()))
            self._stop.wait(self.period_s)


def tree_rss_mb(root_pid: int) -> float:
    """Summed VmRSS (MB) of ``root_pid`` and its descendants, read from /proc."""
    parent, rss = {}, {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/status") as f:
                fields = dict(line.split(":", 1) for line in f if ":" in line)
        except OSError:
            continue
        parent[int(d)] = int(fields.get("PPid", "0").strip())
        rss[int(d)] = int(fields.get("VmRSS", "0 kB").split()[0]) if "VmRSS" in fields else 0
    tree, frontier = {root_pid}, [root_pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent.items() if pp == p and c not in tree]
        tree.update(kids)
        frontier.extend(kids)
    return sum(rss.get(p, 0) for p in tree) / 1024.0


def cpu_s(who: int) -> float:
    """User + system CPU seconds of ``resource.RUSAGE_SELF`` or ``RUSAGE_CHILDREN`` (waited-for)."""
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def both_cpu_s() -> float:
    return cpu_s(resource.RUSAGE_SELF) + cpu_s(resource.RUSAGE_CHILDREN)


def disk_mb(root: Path) -> dict[str, float]:
    """Allocated MB under ``root`` (each inode once, like ``du``): ``total``, ``images``
    (camera PNGs under ``sequences/*/rgb``), ``passes`` (``renders/``), ``without_images``."""
    seen, out = set(), {"total": 0.0, "images": 0.0, "passes": 0.0}
    for dirpath, _, files in os.walk(root):
        parts = Path(dirpath).relative_to(root).parts
        for f in files:
            st = os.lstat(os.path.join(dirpath, f))
            if st.st_ino in seen:
                continue
            seen.add(st.st_ino)
            mb = st.st_blocks * 512 / 1e6
            out["total"] += mb
            if "rgb" in parts and "sequences" in parts:
                out["images"] += mb
            elif "renders" in parts:
                out["passes"] += mb
    out["without_images"] = out["total"] - out["images"]
    return out


def stage_totals(dataset_dirs: list[Path]) -> dict[str, float]:
    """Summed ``cpu_<stage>_s`` / ``wall_<stage>_s`` of every worker timing file (the
    render workers of a shared job write into the first dataset's ``.work/timing``)."""
    tot: dict[str, float] = {}
    for d in dataset_dirs:
        for p in (Path(d) / ".work" / "timing").glob("*.json"):
            t = json.loads(p.read_text())
            for k, v in t.items():
                if k.startswith(("cpu_", "wall_")):
                    tot[k] = tot.get(k, 0.0) + float(v)
    return tot


# -- one run -----------------------------------------------------------------------
@dataclass
class SuiteRun:
    """Figures of one measured run (seconds, MB)."""

    label: str
    trials: int
    width: int
    height: int
    particles: str
    experiments: str
    renders: int = 0
    frames_rendered: int = 0
    sequences: int = 0
    frames_written: int = 0
    cpu: dict = field(default_factory=dict)
    wall: dict = field(default_factory=dict)
    peak_rss_mb: float = 0.0
    disk: dict = field(default_factory=dict)
    path: str = "generate+evaluate"  # or "run --images POLICY" (evaluated while rendering)
    mode: str = ""  # image formation forced by --mode ("": the configs' own)
    terms: dict = field(default_factory=dict)  # CPU s of the stages' terms, "compose.water": s
    localizers: dict = field(default_factory=dict)  # name -> {"s": summed per-call s, "frames": n}


@dataclass(frozen=True)
class Overrides:
    """Changes to the paper configs for one measured run (None = as configured).

    ``size`` (width, height) px; ``particles``: the occlusion experiment keeps one
    condition with this many small obstacles; ``max_distance_m``: only frames within this
    distance of the dock are rendered; ``samples``: Cycles samples in the dock's region."""

    size: tuple[int, int] | None = None
    particles: int | None = None
    max_distance_m: float | None = None
    samples: int | None = None

    def tag(self) -> str:
        parts = [f"{self.size[0]}x{self.size[1]}"] if self.size else []
        parts += [f"p{self.particles}"] if self.particles is not None else []
        parts += [f"within{self.max_distance_m:g}m"] if self.max_distance_m else []
        parts += [f"s{self.samples}"] if self.samples else []
        return "-".join(parts)


def configure(names: tuple[str, ...], trials: int, ov: Overrides = Overrides(), mode: str | None = None):
    """The paper experiments with ``trials``, the overrides ``ov`` and image formation ``mode``
    (None: the configs' own), as ``dockbench reproduce --mode`` builds them."""
    from blendgen.tools.apps.reproduce import experiment

    exps = []
    for n in names:
        e = experiment(n, trials, mode)
        if ov.max_distance_m is not None:
            e.render.max_distance_m = ov.max_distance_m
        if ov.samples is not None:
            e.render.samples = ov.samples
        if ov.size is not None:
            e.camera.width, e.camera.height = ov.size
        if ov.particles is not None and n == "occlusion":
            c = e.conditions[0].model_copy(deep=True)
            c.label = f"n{ov.particles}"
            c.occlusion.n_total = ov.particles
            e.conditions = [c]
        e.name += f"-{ov.tag()}" if ov.tag() else ""
        exps.append(e)
    return exps


def run_suite(
    exps: list, out: Path, label: str, workers: int | None, evaluate: bool = True, images: str = "all"
) -> SuiteRun:
    """Generate ``exps`` together into ``out/<name>/dataset``, evaluate each, measure.
    ``images`` other than ``all``: the streaming path of ``dockbench run`` instead."""
    from blendgen.pipeline.generate import generate_many
    from blendgen.tools.apps.reproduce import evaluate as run_eval

    if out.exists():
        shutil.rmtree(out)
    dsets = [out / e.name / "dataset" for e in exps]
    c = exps[0].camera
    occ = [f"{cnd.occlusion.n_total:g}" for e in exps for cnd in e.conditions if cnd.occlusion]
    run = SuiteRun(
        label,
        exps[0].trials,
        c.width,
        c.height,
        "/".join(occ) or "-",
        ",".join(e.name.split("-")[0].removeprefix("paper_") for e in exps),
    )
    if images != "all" and evaluate:
        return _stream_suite(exps, out, run, workers, images)
    with TreeRSS() as rss:
        c0, w0 = both_cpu_s(), time.perf_counter()
        mans = generate_many([(e, d) for e, d in zip(exps, dsets)], workers=workers, progress=False)
        run.cpu["generate"], run.wall["generate"] = both_cpu_s() - c0, time.perf_counter() - w0
        c1, w1 = both_cpu_s(), time.perf_counter()
        if evaluate:
            for e, d in zip(exps, dsets):
                run_eval(d, out / e.name / "results")
        run.cpu["evaluate"], run.wall["evaluate"] = both_cpu_s() - c1, time.perf_counter() - w1
    run.peak_rss_mb = rss.peak_mb
    _fill_counts(run, mans, dsets, out)
    return run


def _stream_suite(exps: list, out: Path, run: SuiteRun, workers: int | None, images: str) -> SuiteRun:
    """``run_suite`` through ``dockbench run`` (evaluation while rendering, ``images`` kept).
    ``evaluate`` CPU is the evaluation workers' own (``.stream/*/*.cost.json``) plus the
    parent's metrics/tables; its wall, the summed wall of the evaluation workers."""
    from blendgen.tools.apps.reproduce import LOCALIZERS
    from blendgen.tools.apps.streamrun import RunRequest, stream_run

    run.path = f"run --images {images}"
    bases = [out / e.name for e in exps]
    with TreeRSS() as rss:
        c0, w0 = both_cpu_s(), time.perf_counter()
        res = stream_run(
            list(zip(exps, bases)), RunRequest(list(LOCALIZERS), images=images, workers=workers, progress=False)
        )
        cpu, wall = both_cpu_s() - c0, time.perf_counter() - w0
    run.peak_rss_mb = rss.peak_mb
    costs = [json.loads(p.read_text()) for b in bases for p in (b / ".stream").glob("*/*.cost.json")]
    finish = [r["finish_cpu_s"] for r in res]
    run.cpu["evaluate"] = sum(c["cpu_s"] for c in costs) + sum(finish)
    run.wall["evaluate"] = sum(c["wall_s"] for c in costs)
    run.cpu["generate"], run.wall["generate"] = cpu - run.cpu["evaluate"], wall
    _fill_counts(run, [r["manifest"] for r in res], [b / "dataset" for b in bases], out)
    run.wall["total"] = wall
    return run


def _fill_counts(run: SuiteRun, mans: list[dict], dsets: list[Path], out: Path) -> None:
    st = stage_totals(dsets)
    for s in STAGES:
        run.cpu[s] = st.get(f"cpu_{s}_s", float("nan"))
        run.wall[s] = st.get(f"wall_{s}_s", float("nan"))
    run.cpu["generate_other"] = run.cpu["generate"] - sum(run.cpu[s] for s in STAGES)
    run.terms = {k[4:-2]: v for k, v in st.items() if k.startswith("cpu_") and "." in k}
    run.localizers = localizer_seconds(out)
    jobs = {}
    for d in dsets:
        for jf in (d / ".work" / "jobs").glob("*.json"):
            jobs[jf.name] = len(json.loads(jf.read_text())["frames"])
    run.renders, run.frames_rendered = len(jobs), sum(jobs.values())
    run.sequences = sum(len(m["sequences"]) for m in mans)
    run.frames_written = sum(s["n_frames"] for m in mans for s in m["sequences"])
    run.disk = disk_mb(out)


def localizer_seconds(out: Path) -> dict[str, dict]:
    """Per localizer over every frame of the results under ``out``
    (``*/results/estimates.parquet``): ``wall_s``, the evaluator's per-call seconds summed;
    ``s``, the same scaled per sequence by its evaluation process's CPU / wall
    (``.stream/*/<sequence>.cost.json``, at most 1; 1 without it: the generate-then-evaluate
    path), i.e. the call's CPU if the process waited evenly; ``frames``."""
    import pandas as pd

    tot: dict[str, dict] = {}
    for p in sorted(Path(out).glob("*/results/estimates.parquet")):
        busy = _cpu_share(p.parent.parent / ".stream")
        df = pd.read_parquet(p, columns=["localizer", "sequence", "ms"])
        for (name, seq), ms in df.groupby(["localizer", "sequence"])["ms"]:
            t = tot.setdefault(str(name), {"s": 0.0, "wall_s": 0.0, "frames": 0})
            t["wall_s"] += float(ms.sum()) / 1e3
            t["s"] += float(ms.sum()) / 1e3 * busy.get(str(seq), 1.0)
            t["frames"] += int(ms.size)
    return tot


def _cpu_share(stream: Path) -> dict[str, float]:
    """Sequence id -> CPU / wall (at most 1) of the process that evaluated it."""
    out = {}
    for c in stream.glob("*/*.cost.json"):
        d = json.loads(c.read_text())
        if d.get("wall_s"):
            out[c.name.removesuffix(".cost.json")] = min(1.0, float(d["cpu_s"]) / float(d["wall_s"]))
    return out


# -- reporting -----------------------------------------------------------------------
def stage_table(run: SuiteRun):
    """Rows stage, CPU s, wall s (wall of render/compose/write: summed over workers)."""
    import pandas as pd

    rows = [
        {"stage": s, "cpu_s": run.cpu.get(s), "wall_s": run.wall.get(s, float("nan"))}
        for s in (*STAGES, "generate_other", "generate", "evaluate")
    ]
    rows.append(
        {
            "stage": "total",
            "cpu_s": run.cpu["generate"] + run.cpu["evaluate"],
            "wall_s": run.wall.get("total", run.wall["generate"] + run.wall["evaluate"]),
        }
    )
    return pd.DataFrame(rows)


def stage_figures(run: SuiteRun) -> dict[str, float]:
    """CPU seconds per stage in print order: each frame-loop stage then its terms (and
    ``<stage>.other``, the stage minus its terms), ``generate_other``, ``evaluate`` then
    ``evaluate.<localizer>`` (the evaluator's per-call seconds, module docstring), ``total``."""
    cpu, out = run.cpu, {}
    for s in STAGES:
        out[s] = cpu[s]
        terms = {k: v for k, v in run.terms.items() if k.startswith(f"{s}.")}
        out.update(sorted(terms.items()))
        if terms:
            out[f"{s}.other"] = cpu[s] - sum(terms.values())
    out["generate_other"] = cpu["generate_other"]
    out["evaluate"] = cpu["evaluate"]
    out.update({f"evaluate.{n}": v["s"] for n, v in sorted(run.localizers.items())})
    out["total"] = cpu["generate"] + cpu["evaluate"]
    return out


def side_by_side(runs: dict[str, SuiteRun]):
    """Rows stage; a CPU-seconds column per mode (``runs``: mode -> run), the ratio of
    physical to article when both ran, and the 100-trial estimate on
    :data:`REFERENCE_CORES` idle cores as the last row."""
    import pandas as pd

    figs = {m: stage_figures(r) for m, r in runs.items()}
    stages = list(dict.fromkeys(k for f in figs.values() for k in f))
    df = pd.DataFrame(
        {"stage": stages, **{f"{m} CPU s": [f.get(k, float("nan")) for k in stages] for m, f in figs.items()}}
    )
    est = {f"{m} CPU s": extrapolate(r, cores=REFERENCE_CORES)["cpu_bound_wall_h"] for m, r in runs.items()}
    df = pd.concat([df, pd.DataFrame([{"stage": f"100 trials: h on {REFERENCE_CORES} idle cores", **est}])])
    if {"physical", "article"} <= set(runs):
        df["physical / article"] = df["physical CPU s"] / df["article CPU s"]
    return df.reset_index(drop=True)


def extrapolate(run: SuiteRun, trials: int = 100, cores: int | None = None) -> dict:
    """Linear in trials (every docking trial has its own camera paths): measured x trials/N.
    ``cpu_bound_wall_h``: the CPU spread over ``cores`` with nothing else running."""
    k = trials / run.trials
    cores = cores or os.cpu_count() or 1
    cpu = (run.cpu["generate"] + run.cpu["evaluate"]) * k
    return {
        "trials": trials,
        "cpu_h": cpu / 3600,
        "cpu_bound_wall_h": cpu / cores / 3600,
        "cores": cores,
        "measured_wall_scaled_h": run.wall.get("total", run.wall["generate"] + run.wall["evaluate"]) * k / 3600,
        "disk_gb": run.disk["total"] * k / 1e3,
        "disk_without_images_gb": run.disk["without_images"] * k / 1e3,
        "peak_rss_mb": run.peak_rss_mb,
    }


def scaling_row(run: SuiteRun) -> dict:
    per_trial_cpu = (run.cpu["generate"] + run.cpu["evaluate"]) / run.trials
    return {
        "label": run.label,
        "experiments": run.experiments,
        "trials": run.trials,
        "size": f"{run.width}x{run.height}",
        "particles": run.particles,
        "renders": run.renders,
        "frames_rendered": run.frames_rendered,
        "frames_written": run.frames_written,
        "render_cpu_s": run.cpu["render"],
        "compose_cpu_s": run.cpu["compose"],
        "write_cpu_s": run.cpu["write"],
        "evaluate_cpu_s": run.cpu["evaluate"],
        "cpu_s_per_trial": per_trial_cpu,
        "wall_s": run.wall.get("total", run.wall["generate"] + run.wall["evaluate"]),
        "path": run.path,
        "peak_rss_mb": run.peak_rss_mb,
        "disk_mb": run.disk["total"],
        "disk_mb_without_images": run.disk["without_images"],
    }


def save(run: SuiteRun, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "bench_suite.jsonl", "a") as f:
        f.write(json.dumps(asdict(run)) + "\n")


SCALING = (  # (label, experiments, trials, size, particles): one factor at a time
    ("base", ("turbidity",), 1, None, None),
    ("trials 3", ("turbidity",), 3, None, None),
    ("1280x720", ("turbidity",), 1, (1280, 720), None),
    ("particles 0", ("occlusion",), 1, None, 0),
    ("particles 6000", ("occlusion",), 1, None, 6000),
    ("particles 60000", ("occlusion",), 1, None, 60000),
)


def print_run(run: SuiteRun) -> None:
    import click

    from evalkit.reports.tables import print_table

    click.echo(
        f"\n{run.label} ({run.path}): {run.experiments}, {run.trials} trial(s), {run.width}x{run.height}: "
        f"{run.renders} renders / {run.frames_rendered} rendered frames -> {run.sequences} sequences / "
        f"{run.frames_written} written frames"
    )
    print_table(stage_table(run), floatfmt=".1f")
    d = run.disk
    click.echo(
        f"peak RSS of the process tree {run.peak_rss_mb:.0f} MB; disk {d['total']:.1f} MB "
        f"(camera images {d['images']:.1f}, shared range/index passes {d['passes']:.1f}, "
        f"without images {d['without_images']:.1f})"
    )
    x = extrapolate(run)
    click.echo(
        f"extrapolated to {x['trials']} trials (linear in trials; machine shared, so wall is an upper "
        f"bound): {x['cpu_h']:.2f} CPU-h = {x['cpu_bound_wall_h']:.2f} h on {x['cores']} idle cores; "
        f"measured wall x {x['trials']}/{run.trials} = {x['measured_wall_scaled_h']:.2f} h; disk "
        f"{x['disk_gb']:.1f} GB ({x['disk_without_images_gb']:.1f} GB without images); "
        f"peak RSS {x['peak_rss_mb']:.0f} MB (bounded in trials: a render worker is replaced "
        f"above executor.RECYCLE_MB)"
    )


def print_recorded(out: Path) -> None:
    """Print the scaling table of every run recorded in ``out/bench_suite.jsonl``."""
    import click
    import pandas as pd

    from evalkit.reports.tables import print_table

    path = out / "bench_suite.jsonl"
    if not path.is_file():
        raise click.UsageError(f"{path}: no recorded runs; run `dockbench bench suite -o {out}` first")
    runs = [SuiteRun(**json.loads(line)) for line in path.read_text().splitlines() if line.strip()]
    df = pd.DataFrame([scaling_row(r) for r in runs])
    click.echo(f"runs recorded in {path} (CPU seconds; wall on a shared machine):")
    print_table(df, floatfmt=".1f")
    df.to_csv(out / "bench_scaling.csv", index=False)


def run_scaling(ov: Overrides, out: Path, workers: int | None, evaluate: bool, images: str, modes) -> None:
    """The ``--scaling`` table: :data:`SCALING`, one factor at a time, in each of ``modes``
    (None: the configs' own image formation)."""
    import click
    import pandas as pd

    from evalkit.reports.tables import print_table

    rows = []
    for mode in modes:
        for label, exps, n, sz, p in SCALING:
            label = f"{label} {mode}" if mode else label
            click.echo(f"scaling run: {label} ...", err=True)
            row_ov = Overrides(sz, p, ov.max_distance_m, ov.samples)
            run = run_suite(
                configure(exps, n, row_ov, mode),
                out / "scaling" / label.replace(" ", "_"),
                label,
                workers,
                evaluate,
                images,
            )
            run.mode = mode or ""
            save(run, out)
            rows.append(scaling_row(run))
    df = pd.DataFrame(rows)
    click.echo(f"\nscaling (one factor at a time; CPU seconds; wall on a shared machine; {ov.tag() or '-'}):")
    print_table(df, floatfmt=".1f")
    df.to_csv(out / "bench_scaling.csv", index=False)


def measure_modes(
    trials: int,
    names: tuple[str, ...],
    ov: Overrides,
    out: Path,
    workers: int | None,
    evaluate: bool,
    images: str,
    modes,
) -> dict[str, SuiteRun]:
    """One suite run per image-formation mode into ``out/suite-<mode>`` (``modes``: names,
    or ``(None,)`` for the configs' own, into ``out/suite``); each saved and printed."""
    runs = {}
    for mode in modes:
        label = "-".join(
            [f"t{trials}", *names]
            + ([ov.tag()] if ov.tag() else [])
            + ([f"images-{images.replace(':', '')}"] if images != "all" else [])
            + ([mode] if mode else [])
        )
        sub = out / (f"suite-{mode}" if mode else "suite")
        run = run_suite(configure(names, trials, ov, mode), sub, label, workers, evaluate, images)
        run.mode = mode or ""
        save(run, out)
        print_run(run)
        runs[mode or "configured"] = run
    return runs


def bench_suite(
    trials: int,
    names: tuple[str, ...],
    ov: Overrides,
    out: Path,
    workers: int | None,
    scaling: bool,
    evaluate: bool,
    images: str = "all",
    modes: tuple = MODES,
) -> None:
    """The ``bench suite`` command body (see the module docstring); parameters are its options,
    ``modes`` the image formations to run (``(None,)``: the configs' own)."""
    import click

    from evalkit.reports.tables import print_table

    if scaling:
        return run_scaling(ov, out, workers, evaluate, images, modes)
    runs = measure_modes(trials, names, ov, out, workers, evaluate, images, modes)
    df = side_by_side(runs)
    click.echo(f"\nCPU seconds per stage, {' vs '.join(runs)} ({trials} trial(s); module docstring of suitebench):")
    print_table(df, floatfmt=".2f")
    df.to_csv(out / "bench_suite.csv", index=False)
