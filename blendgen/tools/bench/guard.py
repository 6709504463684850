"""``dockbench bench check``: the suite's CPU per stage against a recorded baseline.

The baseline (``blendgen/data/bench_baseline.json``, package data beside
``water_calibration.json`` so that an installed dockbench can check itself) holds, per
image-formation mode, the CPU seconds of every stage of ``dockbench bench suite``
(:func:`blendgen.tools.bench.suitebench.stage_figures`) with what they were measured on:
the command, the git commit, the machine (cores, CPU model, load average) and the
measurement (experiments, trials, image size, ``--images``, modes, frames).

``bench check`` reruns that measurement and prints per stage the old and new seconds,
their ratio and a flag where the stage moved by more than the tolerance (20 %, the
threshold the suite's cost is watched at) in either direction; stages new or gone since
the baseline are named. Stages that stay below a floor (0.5 CPU s in both runs) are not
flagged: at that size one scheduler tick is several per cent. ``--record`` writes the new
figures as the baseline. A benchmark, never a test: nothing is asserted, the exit code
is 0 whatever moved; tests check :func:`compare` on synthetic numbers only.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
from dataclasses import asdict, dataclass
from pathlib import Path

BASELINE = Path(__file__).resolve().parents[2] / "data" / "bench_baseline.json"
TOLERANCE = 0.2  # relative move that is flagged (either direction)
FLOOR_S = 0.5  # CPU s under which, in both runs, a stage is not flagged
MAX_BASELINE_BYTES = 1 << 20
VERSION = 1


@dataclass(frozen=True)
class Measurement:
    """What the suite measures: experiments run together, trials, image size (w, h),
    ``--images`` policy and image-formation modes."""

    experiments: tuple[str, ...] = ("turbidity",)
    trials: int = 1
    size: tuple[int, int] = (640, 480)
    images: str = "none"
    modes: tuple[str, ...] = ("physical", "article")

    @classmethod
    def from_json(cls, d: dict) -> Measurement:
        return cls(
            tuple(d["experiments"]), int(d["trials"]), tuple(int(v) for v in d["size"]), d["images"], tuple(d["modes"])
        )

    def options(self) -> str:
        """The ``bench suite`` options of this measurement."""
        exps = " ".join(f"-e {e}" for e in self.experiments)
        mode = "both" if set(self.modes) == {"physical", "article"} else self.modes[0]
        w, h = self.size
        return f"--trials {self.trials} {exps} --size {w}x{h} --images {self.images} --mode {mode}"


# -- comparing ---------------------------------------------------------------------
def compare(old: dict[str, float], new: dict[str, float], tolerance: float = TOLERANCE, floor_s: float = FLOOR_S):
    """Rows stage, old_s, new_s, ratio (new / old), flag: ``slower`` / ``faster`` where the
    stage moved by more than ``tolerance`` (a fraction) either way and is at least
    ``floor_s`` in one of the runs; ``new stage`` / ``missing`` where it is in one run only;
    else empty. Stages in the baseline's order, new ones after them."""
    import pandas as pd

    rows = []
    for stage in list(old) + [s for s in new if s not in old]:
        o, n = old.get(stage), new.get(stage)
        ratio = n / o if o and n is not None else float("nan")
        if o is None:
            flag = "new stage"
        elif n is None:
            flag = "missing"
        elif max(abs(o), abs(n)) < floor_s:
            flag = ""
        elif not o or abs(ratio - 1.0) > tolerance:
            flag = "slower" if n > o else "faster"
        else:
            flag = ""
        rows.append({"stage": stage, "old_s": o, "new_s": n, "ratio": ratio, "flag": flag})
    return pd.DataFrame(rows, columns=["stage", "old_s", "new_s", "ratio", "flag"])


def flat_figures(runs: dict[str, dict]) -> dict[str, float]:
    """``{"<mode> <stage>": CPU s}`` of a baseline's (or a fresh record's) ``runs``."""
    return {f"{m} {s}": v for m, r in runs.items() for s, v in r["cpu_s"].items()}


# -- the baseline file -------------------------------------------------------------------
def machine() -> dict:
    """Cores, CPU model (``/proc/cpuinfo``'s model name; else the platform's), platform,
    Python, and the 1-minute load average when the measurement started."""
    model = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), model)
    except OSError:
        pass
    return {
        "cores": os.cpu_count(),
        "cpu_model": model,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "load_average_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
    }


def record(runs: dict, meas: Measurement, host: dict) -> dict:
    """The baseline document of suite ``runs`` (mode -> SuiteRun) measured as ``meas`` (the
    command that reproduces it names no path of this machine: ``-o OUT``)."""
    from blendgen.tools.bench.suitebench import REFERENCE_CORES, extrapolate, stage_figures
    from evalkit.reports.provenance import git_state

    git = git_state() or {}
    return {
        "version": VERSION,
        "what": "dockbench bench suite: CPU seconds per stage and image-formation mode (blendgen/tools/bench/guard.py)",
        "command": f"dockbench bench check -o OUT --record {meas.options()}",
        "commit": git.get("commit"),
        "dirty": git.get("dirty"),
        "recorded_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": host,
        "measurement": {**asdict(meas), "size": list(meas.size)},
        "runs": {
            m: {
                "renders": r.renders,
                "frames_rendered": r.frames_rendered,
                "sequences": r.sequences,
                "frames_written": r.frames_written,
                f"h_per_100_trials_on_{REFERENCE_CORES}_cores": extrapolate(r, cores=REFERENCE_CORES)[
                    "cpu_bound_wall_h"
                ],
                "cpu_s": {k: round(v, 3) for k, v in stage_figures(r).items()},
            }
            for m, r in runs.items()
        },
    }


def load_baseline(path: Path) -> dict:
    """The baseline at ``path``, checked: a JSON object of at most 1 MiB with this module's
    keys; else :class:`~blendgen.config.models.ConfigError` (one line)."""
    from blendgen.config.models import ConfigError

    allowed = "a baseline written by `dockbench bench check --record`"
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--baseline {path}: no such file (expected {allowed})")
    if path.stat().st_size > MAX_BASELINE_BYTES:
        raise ConfigError(f"--baseline {path}: larger than 1 MiB (expected {allowed})")
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
        Measurement.from_json(data["measurement"])
        for r in data["runs"].values():
            assert all(isinstance(v, (int, float)) for v in r["cpu_s"].values())
    except (UnicodeDecodeError, ValueError, RecursionError, KeyError, TypeError, AttributeError, AssertionError):
        raise ConfigError(f"--baseline {path}: not {allowed} (JSON with measurement and runs.*.cpu_s)") from None
    return data


def check_record_target(path: Path) -> None:
    """``--record`` may write ``path``: absent in an existing folder, or a baseline file
    (:func:`load_baseline`); checked before anything is measured."""
    from blendgen.config.models import ConfigError

    path = Path(path)
    if path.exists():
        load_baseline(path)
    elif not path.parent.is_dir():
        raise ConfigError(f"--baseline {path}: folder {path.parent} does not exist")


def write_baseline(doc: dict, path: Path) -> None:
    """Write ``doc`` to ``path`` whole (a temporary file beside it, then renamed)."""
    tmp = Path(path).with_name(f".{Path(path).name}.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, path)


# -- the command ------------------------------------------------------------------------
@dataclass(frozen=True)
class CheckRequest:
    """``bench check``'s options: ``baseline`` read (None: the package's), ``record``: write the
    new figures (to ``baseline`` when named, else ``out/bench_baseline.json``), ``meas``: the
    measurement to record (None: the baseline's; only with ``record``)."""

    out: Path
    baseline: Path | None = None
    tolerance: float = TOLERANCE
    floor_s: float = FLOOR_S
    record: bool = False
    meas: Measurement | None = None
    workers: int | None = None


def _plan(req: CheckRequest) -> tuple[dict | None, Measurement, Path | None]:
    """(baseline or None, measurement, file to record or None), checked before any render."""
    from blendgen.config.models import ConfigError

    source = req.baseline or BASELINE
    if not req.record:
        if req.meas is not None:
            raise ConfigError(
                "bench check: --trials/-e/--size/--images/--mode apply with --record only; a check "
                f"reruns the measurement of its baseline ({source})"
            )
        base = load_baseline(source)
        return base, Measurement.from_json(base["measurement"]), None
    target = req.baseline or req.out / "bench_baseline.json"
    check_record_target(target)
    base = load_baseline(source) if Path(source).is_file() else None
    meas = req.meas or (Measurement.from_json(base["measurement"]) if base else Measurement())
    return base, meas, target


def run_check(req: CheckRequest) -> None:
    """Measure (the baseline's measurement, or ``req.meas``), print the modes side by side and
    the comparison against the baseline; write ``bench_check.csv``; with ``record`` the baseline."""
    import click

    from blendgen.tools.bench.suitebench import Overrides, measure_modes

    base, meas, target = _plan(req)
    host = machine()
    runs = measure_modes(
        meas.trials, meas.experiments, Overrides(size=meas.size), req.out, req.workers, True, meas.images, meas.modes
    )
    doc = record(runs, meas, host)
    _print_modes(runs, meas)
    if base is not None and Measurement.from_json(base["measurement"]) == meas:
        _report(base, doc, req)
    elif base is not None:
        click.echo(f"\nthe baseline measured {Measurement.from_json(base['measurement']).options()}: not compared")
    if target is not None:
        write_baseline(doc, target)
        click.echo(f"recorded the baseline {target} (commit {doc['commit']}, {meas.options()})")


def _print_modes(runs: dict, meas: Measurement) -> None:
    """The modes side by side, as ``bench suite`` prints them."""
    import click

    from blendgen.tools.bench.suitebench import side_by_side
    from evalkit.reports.tables import print_table

    click.echo(f"\nCPU seconds per stage ({meas.options()}):")
    print_table(side_by_side(runs), floatfmt=".2f")


def _report(base: dict, doc: dict, req: CheckRequest) -> None:
    """Print and write (``bench_check.csv``) the comparison of ``doc`` with ``base``."""
    import click

    from evalkit.reports.tables import print_table

    df = compare(flat_figures(base["runs"]), flat_figures(doc["runs"]), req.tolerance, req.floor_s)
    m = base["machine"]
    click.echo(
        f"\nagainst the baseline of {base['recorded_utc']} (commit {str(base['commit'])[:10]}, {m['cores']} cores "
        f"{m['cpu_model']}, load {m['load_average_1min']}; now load {doc['machine']['load_average_1min']}): CPU s"
    )
    print_table(df, floatfmt=".2f")
    df.to_csv(req.out / "bench_check.csv", index=False)
    for mode, r in doc["runs"].items():
        old = base["runs"].get(mode, {})
        if old and old.get("frames_rendered") != r["frames_rendered"]:
            click.echo(
                f"{mode}: {old.get('frames_rendered')} -> {r['frames_rendered']} rendered frames (the work changed)"
            )
    moved = df[df["flag"] != ""]
    pct = f"{100 * req.tolerance:g} %"
    if moved.empty:
        click.echo(f"no stage moved by more than {pct} (floor {req.floor_s:g} CPU s)")
    for _, r in moved.iterrows():
        what = r["flag"] if r["flag"] in ("new stage", "missing") else f"{r['flag']} x{r['ratio']:.2f}, more than {pct}"
        click.echo(f"MOVED {r['stage']}: {what}")
