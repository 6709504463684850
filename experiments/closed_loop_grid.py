"""Join the ``dockbench dock`` runs of one experiment into one table and check the pool's walls.

A grid of closed-loop trials is run as several ``dock`` commands (conditions and localizers
split across processes). This script concatenates their ``trials.parquet`` and
``frames.parquet`` into OUT (refusing duplicate (localizer, condition, trial) rows), so that
``dockbench dock EXPERIMENT --report-only -o OUT`` writes the joint summary and path plot.

It also writes ``OUT/wall_check.csv``: each trial's smallest hull clearance to the pool's walls
and floor (:func:`blendgen.vehicle.water_clearance.trial_water_clearance`, exact from the logged
camera offset), and ``wall_touch_before_end``: the hull touched a wall before the trial's
recorded end. Runs made before the walls were solid to the hull record such a trial by where it
went on; with solid walls it ends at that touch as a ``collision`` (``pool_wall``).

    python experiments/closed_loop_grid.py EXPERIMENT OUT RUN_DIR [RUN_DIR ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from blendgen.pipeline.scene_check import water_solid
from blendgen.tools.apps.closed_loop import load_bench_experiment
from blendgen.vehicle.contact import Hull
from blendgen.vehicle.dynamics import VehicleParams
from blendgen.vehicle.water_clearance import axis_from_camera, frame_clearance, trial_water_clearance

KEYS = ["localizer", "condition", "trial"]


def join_runs(runs: list[Path], out: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Concatenated (trials, frames) of ``runs``, written to ``out``; duplicate trials are an error."""
    tables = {}
    for name in ("trials", "frames"):
        parts = [pd.read_parquet(r / f"{name}.parquet") for r in runs]
        tables[name] = pd.concat(parts, ignore_index=True)
    dup = tables["trials"].duplicated(KEYS, keep=False)
    if dup.any():
        raise SystemExit(f"duplicate trials in the runs: {tables['trials'].loc[dup, KEYS].to_dict('records')[:5]}")
    out.mkdir(parents=True, exist_ok=True)
    for name, df in tables.items():
        df.to_parquet(out / f"{name}.parquet", index=False)
    return tables["trials"], tables["frames"]


def wall_check(experiment: str, trials: pd.DataFrame, frames: pd.DataFrame) -> pd.DataFrame:
    """Per trial: smallest wall clearance (m) with its face and time (s), the first frame's time
    (s) at which the hull touched a solid face (NaN: never), and whether that was before the
    trial's recorded end (``t_end_s``)."""
    exp = load_bench_experiment(experiment, None, ())
    cam_x, water = float(exp.camera.T_body_cam.xyz[0]), water_solid(exp)
    p = VehicleParams()
    hull = Hull.from_vehicle(p.length, p.diameter)
    clear, _ = frame_clearance(
        frames[["x_world", "y_world", "z_world"]].to_numpy(float), axis_from_camera(frames, cam_x), water, hull
    )
    first = frames.loc[clear <= 0].groupby(KEYS)["t"].min().rename("first_touch_s").reset_index()
    closest = trial_water_clearance(frames, water, hull, cam_forward_m=cam_x)
    df = trials[[*KEYS, "outcome", "t_end_s"]].merge(closest, on=KEYS, how="left").merge(first, on=KEYS, how="left")
    df["wall_touch_before_end"] = df["first_touch_s"] < df["t_end_s"] - 1e-9
    return df


def main(argv: list[str]) -> int:
    if len(argv) < 3:
        print(__doc__.strip().splitlines()[-1].strip(), file=sys.stderr)
        return 2
    experiment, out, runs = argv[0], Path(argv[1]), [Path(a) for a in argv[2:]]
    trials, frames = join_runs(runs, out)
    check = wall_check(experiment, trials, frames)
    check.to_csv(out / "wall_check.csv", index=False)
    touched = check[check["wall_touch_before_end"]]
    print(f"{experiment}: {len(trials)} trials from {len(runs)} runs -> {out}")
    print(f"wall touches before the recorded end: {len(touched)}")
    if len(touched):
        print(touched[[*KEYS, "outcome", "t_end_s", "first_touch_s", "part", "min_clearance_m"]].to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
