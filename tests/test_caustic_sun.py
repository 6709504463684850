"""Reference caustics in datasets (docs/light.md): the sun as a far spot whose light texture is the
frame's photon map (``blender/caustic_sun.py``, ``physics/surface/caustic_beam.py``).

Oracles: a flat surface's photons give the pattern that undoes the spot's inverse square
(``((D + s) / D)^2 / T_Fresnel`` per bin when every photon is kept); the spot's projective
lookup is the binning's; a rendered frame is the plain-sun frame plus the sun's direct light
times ``M(P) - 1`` at every pixel's world point, with the plain sun's mean."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from blendgen.physics.surface import caustic_beam as cb
from blendgen.physics.surface import optics as sf
from blendgen.pipeline.plan import INDEX_POOL

SURFACE = {"centre_xy": [0.0, 0.0], "half_xy": [7.5, 2.5], "z": 1.0}


def _sun(zenith_deg: float, azimuth_deg: float):
    z, a = math.radians(zenith_deg), math.radians(azimuth_deg)
    air = np.array([math.sin(z) * math.cos(a), math.sin(z) * math.sin(a), -math.cos(z)])
    return air, sf.refracted_sun(air)


def _flat_photons(grid: cb.Grid, air, t, pitch: float, rng) -> np.ndarray:
    """Photons of a jittered orthographic sun camera (pitch m) refracted by a flat surface at
    the grid's z and landing on the floor 6 m below it (every photon kept)."""
    e1, e2 = cb.beam_axes(air)
    half = 12.0
    n = int(2 * half / pitch)
    u = (np.arange(n)[:, None] + rng.random((n, n))) * pitch - half
    v = (np.arange(n)[None, :] + rng.random((n, n))) * pitch - half
    start = grid.c + u.ravel()[:, None] * e1 + v.ravel()[:, None] * e2  # rays across the air beam
    xi = start - ((start[:, 2] - grid.c[2]) / air[2])[:, None] * air  # on the surface plane
    return xi + (6.0 / -t[2]) * t  # 6 m below it


@pytest.mark.heavy  # ~11 CPU s each: 400 photons per bin over a 6 x 6 m grid
@pytest.mark.parametrize("zenith_deg, azimuth_deg", [(0.0, 0.0), (41.8, 0.0), (60.0, 150.0)])
def test_flat_surface_gives_the_flat_pattern(zenith_deg, azimuth_deg):
    air, t = _sun(zenith_deg, azimuth_deg)
    grid = cb.grid_for({**SURFACE, "half_xy": [3.0, 3.0]}, t, 0.1)
    pitch = cb.photon_pitch(grid.bin_m, 400.0, 1, air, t)
    P = _flat_photons(grid, air, t, pitch, np.random.default_rng(1))
    M = cb.pattern(grid, P, pitch, 1, air)
    inner = M[5:-5, 5:-5]
    s_floor = 6.0 / -t[2]  # the floor's distance along the beam
    expect = ((cb.D_SPOT + s_floor) / cb.D_SPOT) ** 2 / cb.transmittance(air)
    assert inner.mean() == pytest.approx(expect, rel=3e-3)
    assert inner.std() / inner.mean() < 0.08  # jitter only, no structure


def test_projective_coordinates_are_the_spot_rays_lookup():
    """A point's (p, q) is ``D n_x / -n_z`` of the spot's ray to it in the frame (e1, e2, -t)
    (the light texture's lookup in ``caustic_sun.gobo_spot``), and ``lookup`` returns ``M``
    at bin centres."""
    air, t = _sun(35.0, -70.0)
    grid = cb.grid_for(SURFACE, t, 0.05)
    rng = np.random.default_rng(3)
    P = grid.c + rng.uniform(-5, 5, (50, 3)) * [1, 1, 0] - rng.uniform(1, 9, (50, 1)) * [0, 0, 1]
    pq, _ = grid.coords(P)
    S = grid.c - cb.D_SPOT * grid.t
    d = P - S
    n = np.stack([d @ grid.e1, d @ grid.e2, d @ -grid.t], axis=1)
    np.testing.assert_allclose(pq, cb.D_SPOT * n[:, :2] / -n[:, 2:3], atol=1e-9)
    M = rng.random(grid.shape).astype(np.float32)
    i, j = 17, 31
    centre = grid.lo + (np.array([j, i]) + 0.5) * grid.bin_m  # (p, q) of bin (row i, col j)
    k = cb.D_SPOT / (cb.D_SPOT + 2.0)  # a point 2 m beyond c along the beam
    Pc = grid.c + 2.0 * grid.t + (centre[0] / k) * grid.e1 + (centre[1] / k) * grid.e2
    assert cb.lookup(grid, M, Pc[None])[0] == pytest.approx(M[i, j], abs=1e-5)
    assert cb.lookup(grid, M, (grid.c + 100.0 * grid.e1)[None])[0] == 1.0  # outside: plain sun


def _planned(tmp_path, **scene):
    from blendgen.config.models import Experiment
    from blendgen.pipeline.generate import _Target, manifest_base

    exp = Experiment.model_validate(
        {
            "name": "caustic-plan",
            "image_formation": "physical",
            "render": {"fidelity": "reference"},
            "scene": {"template": "pool_15x5x8", **scene},
            "trajectories": [
                {"kind": "linear", "id": "a", "start_range_m": 4.0, "end_range_m": 3.0, "speed_mps": 10.0}
            ],
        }
    )
    tg = _Target.prepare(exp, tmp_path / f"ds{len(list(tmp_path.iterdir()))}")
    return tg.jobs[0].scene, manifest_base(exp, tg.K, tg.markers, tg.scene, tg.jobs)


def test_reference_jobs_carry_the_photon_budget_only_when_caustics_are_drawn(tmp_path):
    """Reference jobs with caustics carry the photon budget (the pool's spot in pools only: an
    open-water seabed is beyond a photon budget) and the manifest records it, valid under its
    schema; with caustics off or no sun, neither."""
    import jsonschema

    from blendgen.pipeline import plan
    from datasets_spec.validate import load_schema

    for kind in ("pool", "open_water"):
        scene, manifest = _planned(tmp_path, kind=kind)
        assert scene["water_surface"]["caustics"] == {**plan.REFERENCE_CAUSTICS, "pool_spot": kind == "pool"}
        assert manifest["reference_caustics"]["pool_spot"] == (kind == "pool")
        jsonschema.validate(
            manifest["reference_caustics"], load_schema("manifest.schema.json")["properties"]["reference_caustics"]
        )
    for other in ({"world": {"caustics": False}}, {"sun_strength": 0.0}):
        scene, manifest = _planned(tmp_path, **other)
        assert "caustics" not in (scene.get("water_surface") or {}) and "reference_caustics" not in manifest


def _check_spec(tmp_path, kind: str = "pool") -> dict:
    """One frame of a reference job: the template pool (or open water, seabed 3.2 m deep), dock
    at 2 m, camera 1.55 m from the dock face looking at it and the end wall (seabed) behind,
    waves of 2 m/s, clear water, 96 x 72 px."""
    from blendgen.config.models import Experiment
    from blendgen.pipeline import plan
    from blendgen.pipeline.generate import _Target

    exp = Experiment.model_validate(
        {
            "name": "caustic-check",
            "image_formation": "physical",
            "seed": 4,
            "scene": {
                "template": "pool_15x5x8",
                "kind": kind,
                "world": {"wind_mps": 2.0, "seabed_depth_m": 3.2},
                "sky_fraction": 0.0,
            },
            "camera": {"width": 96, "height": 72, "hfov_deg": 70, "fps": 10, "T_body_cam": {"xyz": [0.65, 0, 0]}},
            "render": {"fidelity": "reference", "reference_samples": 64},
            "water": {"preset": "clear"},
            "trajectories": [{"kind": "linear", "id": "a", "start_range_m": 2.2, "end_range_m": 1.7, "speed_mps": 5.0}],
            "conditions": [{"label": "c", "dock_water_depth_m": 2.0}],
        }
    )
    tg = _Target.prepare(exp, tmp_path / "ds")
    job = tg.jobs[0]
    assert job.scene["water_surface"]["caustics"] == {**plan.REFERENCE_CAUSTICS, "pool_spot": kind == "pool"}
    c = exp.camera
    return {
        "scene": job.scene,
        "render": plan.render_settings(exp, 2),
        "camera": {"width": c.width, "height": c.height, "hfov_rad": math.radians(c.hfov_deg), "K": tg.K.tolist()},
        "frame": {
            "T_world_cam": np.asarray(job.frames[0]["T_world_cam"]).tolist(),
            "t": job.frames[0]["t"],
            "index": 0,
        },
    }, tg.K


def _check(tmp_path, kind: str):
    """Run the check on one frame; returns (lit pool/seabed pixels, lit dock pixels, predicted
    change, rendered change, plain) over the hit pixels (module docstring's prediction)."""
    spec, K = _check_spec(tmp_path, kind)
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / "check.npz"
    subprocess.run(
        [sys.executable, "-m", "blendgen.blender.testing.caustic_sun_check", str(tmp_path / "spec.json"), str(out)],
        check=True,
        timeout=600,
    )
    r = np.load(out)
    names = [k for k in ("pool", "dock") if f"{k}_M" in r]
    assert names == (["pool", "dock"] if kind == "pool" else ["dock"])
    grids = {
        k: cb.Grid(
            r[f"{k}_c"],
            r[f"{k}_t"],
            r[f"{k}_e1"],
            r[f"{k}_e2"],
            r[f"{k}_lo"],
            float(r[f"{k}_bin_m"]),
            r[f"{k}_M"].shape,
        )
        for k in names
    }
    z = r["depth_z"]
    h, w = z.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    hit = np.isfinite(z)
    P_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(z)], -1)[hit] * z[hit, None]
    T = np.asarray(spec["frame"]["T_world_cam"])
    P = P_cam @ T[:3, :3].T + T[:3, 3]
    direct = (r["plain"] - r["nosun"])[hit].mean(axis=1)
    lit = direct > 0.25 * np.percentile(direct, 90)
    pool = r["index"][hit] == INDEX_POOL  # pool or seabed; the rest: dock, frame, markers
    m_pool = cb.lookup(grids["pool"], r["pool_M"], P) if "pool" in grids else np.ones(len(P))
    m = np.where(pool, m_pool, cb.lookup(grids["dock"], r["dock_M"], P))
    got = (r["caustic"] - r["plain"])[hit].mean(axis=1)
    return lit & pool, lit & ~pool, direct * (m - 1.0), got, r["plain"][hit].mean(axis=1)


def _agrees(sel, pred, got, plain):
    """The pattern where predicted (correlation), as strong (slope) and as bright (mean)."""
    assert sel.mean() > 0.2  # the spot fills part of the frame
    assert np.corrcoef(pred[sel], got[sel])[0, 1] > 0.8
    assert 0.8 < (pred[sel] @ got[sel]) / (pred[sel] @ pred[sel]) < 1.1
    mean = plain[sel].mean()
    assert (mean + got[sel].mean()) / mean == pytest.approx((mean + pred[sel].mean()) / mean, abs=0.03)


@pytest.mark.blender
def test_reference_caustic_spots_put_their_photon_maps_on_pool_and_dock(tmp_path):
    """Rendered = plain + (plain - no sun) (M(P) - 1) at each pixel's world point P, M from
    the pool's spot on pool pixels and from the dock's finer spot on the dock's: the pattern
    sits where the photons landed (correlation > 0.8 on each, which fails if a lookup is
    mirrored or shifted by a cell, or a spot lights the other's receivers), with the predicted
    strength (the regression slope; pixels average the map over their footprint, so a little
    below 1) and mean (within 3 %: the spots' power, their inverse square, the light linking).
    Measured: correlation 0.997 (pool) and 0.953 (dock), slope 0.97 / 0.91, mean ratio
    1.071 / 0.743 against 1.071 / 0.733 predicted (this frame's cells on the dock are dark)."""
    pool, dock, pred, got, plain = _check(tmp_path, "pool")
    _agrees(pool, pred, got, plain)
    _agrees(dock, pred, got, plain)


@pytest.mark.blender
def test_open_water_reference_caustics_light_the_dock_and_leave_the_seabed_plain(tmp_path):
    """Open water: the dock's spot draws its map on the dock, and the seabed keeps the plain
    sun (rendered change within 3 % of its radiance: the sun lamp still lights it). Measured:
    dock correlation 0.981, slope 0.84, mean ratio 0.850 against 0.835; seabed change 0.0000."""
    seabed, dock, pred, got, plain = _check(tmp_path, "open_water")
    _agrees(dock, pred, got, plain)
    assert seabed.mean() > 0.1
    assert abs(got[seabed].mean()) < 0.03 * plain[seabed].mean()
