"""Reports of the vehicle model: the article's Table 5 and docking paths under current."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from blendgen.vehicle import docking

from blendgen.vehicle import trajectories as tj
from blendgen.config.models import Dock


def docking_paths(currents=(0.0, 0.5, 1.0), seed: int = 1, start: dict | None = None) -> list[dict]:
    """One docking trial per lateral current (m/s, across the dock axis) from the same start.

    Returns per current: ``p_dock`` (N,3) path in the dock frame, heading error (deg),
    stop reason (``reached`` = the stop range, whatever the lateral offset), the verdict by
    geometry at the last frame (:func:`geometric_verdict`), and CPU ms per simulated second."""
    T_wd = tj.T_world_dock_from_spec(Dock())
    lateral = T_wd[:3, 0]  # dock +x is horizontal and across the approach axis
    start = start or {"range_m": 10.0, "lateral_m": 1.0, "vertical_m": 0.2, "heading_error_deg": 10.0}
    out = []
    for c in currents:
        t0 = time.process_time()
        run = docking.simulate_docking_trial(T_wd, start, current_world=tuple(c * lateral), seed=seed)
        cpu = time.process_time() - t0
        out.append({"current_mps": c, "p_dock": run["p_dock"], "heading_error_deg": run["heading_error_deg"],
                    "t": run["t"], "stop_reason": run["stop_reason"], "verdict": geometric_verdict(run),
                    "ms_per_sim_s": 1e3 * cpu / max(float(run["t"][-1]), 1e-9)})
    return out


def geometric_verdict(run: dict) -> str:
    """Docking outcome of an open-loop trial judged at its last frame as if that were the entry
    plane (:func:`blendgen.vehicle.visual_nav.crossing_outcome`, default capture spec of the 1 m
    dock): the body's lateral/vertical offset, heading error and lateral speed (last two frames)."""
    from blendgen.vehicle.dynamics import VehicleParams
    from blendgen.vehicle.visual_nav import CaptureSpec, crossing_outcome
    if run["stop_reason"] != "reached":
        return run["stop_reason"]
    spec = CaptureSpec.from_dock(Dock().body_size_m, VehicleParams().diameter / 2)
    p = run["p_dock"]
    v_lat = float((p[-1, 0] - p[-2, 0]) / (run["t"][-1] - run["t"][-2])) if len(p) > 1 else 0.0
    return crossing_outcome(spec, p[-1], float(run["heading_error_deg"][-1]), v_lat)


def plot_docking_paths(runs: list[dict], path: Path) -> Path:
    """Top view (lateral vs range) and heading error vs time, one line per current."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for r in runs:
        lab = f"{r['current_mps']:g} m/s lateral ({r['stop_reason']}, by geometry: {r['verdict']})"
        a.plot(r["p_dock"][:, 2], r["p_dock"][:, 0], label=lab)
        b.plot(r["t"], r["heading_error_deg"], label=lab)
    a.invert_xaxis()
    a.set(xlabel="range to dock face (m)", ylabel="lateral offset (m)", title="docking path (top view)")
    b.set(xlabel="time (s)", ylabel="heading error (deg)", title="heading")
    a.grid(alpha=.3), b.grid(alpha=.3), a.legend(fontsize=8), b.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
