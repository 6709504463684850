"""Reports of the vehicle model: the article's Table 5 and docking paths under current."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from blendgen.vehicle import docking
from blendgen.vehicle import trajectories as tj


def docking_paths(currents=(0.0, 0.5, 1.0), seed: int = 1, start: dict | None = None) -> list[dict]:
    """One ground-truth-guidance docking trial per lateral current (m/s, across the dock axis) from the
    same start, run and judged exactly as ``dockbench dock`` runs its ``truth`` baseline
    (:func:`blendgen.vehicle.closed_loop.simulate_closed_loop`: the trial ends when the nose crosses the
    dock's entry plane and the capture geometry names the outcome: docked, misaligned, collision,
    out_of_capture; never range alone), with the default dock, camera mount and capture limits, in
    the default pool (its walls and floor solid to the hull: :func:`blendgen.pipeline.scene_check.water_solid`).

    Returns per current: ``p_dock`` (N,3) body-origin path in the dock frame (x lateral, y vertical,
    z range), heading error (deg), ``t`` (s), ``outcome`` (the capture verdict), the crossing's lateral
    offset (m) and heading (deg), impact speed (m/s) and part hit (collisions: the hull against the
    dock's collision geometry, :mod:`blendgen.vehicle.contact`), the docking ``authority`` verdict of
    that current (:func:`blendgen.vehicle.authority.docking_authority`) and CPU ms per simulated second."""
    from blendgen.config.models import Camera, DockingTrajectory, Experiment
    from blendgen.pipeline.scene_check import water_solid
    from blendgen.tools.apps.closed_loop import authority_verdict, capture_spec
    from blendgen.vehicle import authority
    from blendgen.vehicle.closed_loop import TrialSetup, simulate_closed_loop
    from blendgen.vehicle.dynamics import VehicleParams

    traj = DockingTrajectory()
    exp = Experiment(name="docking_paths", trajectories=[traj])  # the default scene: pool and dock
    dock, water = exp.scene.dock, water_solid(exp)
    T_wd = tj.T_world_dock_from_spec(dock)
    T_bc = tj.T_body_cam_from_spec(Camera.model_fields["T_body_cam"].default)
    capture = capture_spec(traj, dock.body_size_m, VehicleParams().diameter / 2)
    lateral = T_wd[:3, 0]  # dock +x is horizontal and across the approach axis
    approach = -T_wd[:3, 2]
    start = start or {"range_m": 10.0, "lateral_m": 1.0, "vertical_m": 0.2, "heading_error_deg": 10.0}
    out = []
    for c in currents:
        t0 = time.process_time()
        setup = TrialSetup(
            T_wd,
            start,
            T_bc,
            capture,
            current_world=tuple(c * lateral),
            seed=seed,
            max_time_s=traj.max_time_s,
            guidance=docking.LosGuidance(traj.cruise_speed_mps, traj.final_speed_mps),
            dock_size_m=tuple(dock.body_size_m),
            water=water,
        )
        run = simulate_closed_loop(setup)
        cpu = time.process_time() - t0
        f = run["frames"]
        auth = authority.docking_authority(c * lateral, approach, traj.final_speed_mps, capture.max_heading_deg)
        if c > 0:
            auth["max_current_mps"] = authority.max_docking_current(
                lateral, approach, traj.final_speed_mps, capture.max_heading_deg
            )
        out.append(
            {
                "current_mps": c,
                "t": np.array([r["t"] for r in f]),
                "p_dock": np.array([[r["lateral_m"], r["vertical_m"], r["range_m"]] for r in f]),
                "heading_error_deg": np.array([r["heading_err_deg"] for r in f]),
                "outcome": run["outcome"],
                "cross_lateral_m": run["cross_lateral_m"],
                "cross_heading_deg": run["cross_heading_deg"],
                "impact_speed_mps": run["impact_speed_mps"],
                "contact_part": run["contact_part"],
                "authority": authority_verdict(auth, c),
                "ms_per_sim_s": 1e3 * cpu / max(float(run["t_end"]), 1e-9),
            }
        )
    return out


def plot_docking_paths(runs: list[dict], path: Path) -> Path:
    """Top view (lateral vs range) and heading error vs time, one line per current."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for r in runs:
        lab = f"{r['current_mps']:g} m/s lateral: {r['outcome']}"
        a.plot(r["p_dock"][:, 2], r["p_dock"][:, 0], label=lab)
        b.plot(r["t"], r["heading_error_deg"], label=lab)
    a.invert_xaxis()
    a.set(xlabel="range to dock face (m)", ylabel="lateral offset (m)", title="docking path (top view)")
    b.set(xlabel="time (s)", ylabel="heading error (deg)", title="heading")
    a.grid(alpha=0.3), b.grid(alpha=0.3), a.legend(fontsize=8), b.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
