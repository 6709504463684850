"""Latency sweep with a perfect localizer (true T_cam_dock every frame, no rendering): docking rate and
|lateral offset| at the entry plane vs camera latency; starts drawn like paper_turbidity's (seed 2026)."""

import sys

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "tests"))
import numpy as np
from test_closed_loop import oracle, setup

from blendgen.config.models import load_experiment
from blendgen.pipeline.plan import trial_seed
from blendgen.vehicle import docking
from blendgen.vehicle.closed_loop import simulate_closed_loop

exp = load_experiment(
    str(__import__("pathlib").Path(__file__).resolve().parents[1] / "configs" / "paper_turbidity.yaml")
)
N = 10
starts = []
for i in range(N):
    s = trial_seed(exp, i)
    st = docking.random_start(
        np.random.default_rng(s), {"range_m": (6.0, 12.0), "lateral_m": 1.5, "vertical_m": 0.5, "heading_error_deg": 15}
    )
    starts.append((s, st))
print("current_mps latency_s docked/10 mean|cross_lat|_m est_lat_rms_m outcomes")
for cur in (0.0, 0.5):
    for lat in (0.0, 0.1, 0.2, 0.5, 1.0):
        ok, cl, rms, outs = 0, [], [], {}
        for s, st in starts:
            r = simulate_closed_loop(setup(start=st, seed=s, latency_s=lat, current_world=(0.0, cur, 0.0)), oracle())
            ok += r["outcome"] == "docked"
            outs[r["outcome"]] = outs.get(r["outcome"], 0) + 1
            if np.isfinite(r["cross_lateral_m"]):
                cl.append(abs(r["cross_lateral_m"]))
            e = np.array([f["est_lateral_m"] - f["lateral_m"] for f in r["frames"]])
            rms.append(np.sqrt(np.nanmean(e**2)))
        print(f"{cur:4.1f} {lat:4.1f} {ok:2d}/{N} {np.mean(cl):.3f} {np.mean(rms):.3f} {outs}")
