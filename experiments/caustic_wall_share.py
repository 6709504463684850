"""What a caustic map of the dock's wall, shared by every trial, would cost (no Blender).

The frames are those of ``experiments/caustic_cost.py`` (the article's approach in the 15 x 5 x 8 m
pool, 1-10 m from the dock, three waters). For each frame this prints the CPU of its caustics as
the frame loop makes them now (geometry and three waters), the share of its sunlit pixels on the
dock's wall (the pool's +x wall, a fixed plane) and the bin levels they read. Then it makes, at one
frame time, the map of the whole visible wall (``--depth`` m down, the pool's width) at each level
that holds 1 % or more of the frames' wall pixels, as a frame would if it saw all of it at that
level (the same grouping, deposit and blurs: :class:`caustic_map.FrameCaustics` on a grid of wall
points whose footprint reads that level), and prints its CPU. Every trial of an experiment meets
the same waves at the same frame times, so one such map per frame time and surface height could
serve all of them; it prints the number of trials beyond which making it pays, and how far the
factors a frame's wall pixels would read from such maps are from the frame's own. The estimate
leaves out reading them: a tile cache built on it read ~250,000 wall points per water in 38-80
CPU ms a frame against 75-117 for the frame's own maps, so it was not taken
(``docs/evidence/physical_suite_cost.md``). Run from the repository root::

    PYTHONPATH=. python experiments/caustic_wall_share.py
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import numpy as np

from blendgen.config.models import Water
from blendgen.physics.surface import caustic_map as cmap
from blendgen.physics.surface import optics as sf
from blendgen.physics.water import optics
from blendgen.pipeline import world_post

sys.path.insert(0, str(Path(__file__).resolve().parent))
cc = importlib.import_module("caustic_cost")  # the frames, waters and sun of the caustics harness


def sunlit(frame, wp) -> tuple[np.ndarray, ...]:
    """(sunlit (H, W) bool, on the dock's wall (H, W) bool, footprint (H, W) m, hit points
    (H, W, 3) m) of a harness frame, as ``world_post.caustic_geometry`` selects them."""
    rgb, albedo, rng, depth, rays, K, T = frame
    sun = sf.refracted_sun(wp.sun_travel_dir)
    n = world_post.facing_normals(rays, rng)
    cos_i = -(n @ sun.astype(np.float32))
    hit = np.isfinite(rng) & (depth > 0) & (cos_i > 0.02)
    p = T[:3, 3] + rays * rng[..., None]
    on_wall = np.abs(p[..., 0] - cc.POOL[0] / 2) < 0.01
    return hit, on_wall, world_post.footprint_m(rays, rng, n, 1.0 / float(K[0, 0]), sun, cos_i), p


def wall_pixels(frame, wp) -> tuple[np.ndarray, np.ndarray, int]:
    """(on the wall (m,) bool, bin level (m,)) of a frame's sunlit pixels, and their number."""
    hit, on_wall, foot, _ = sunlit(frame, wp)
    return on_wall[hit], cmap._levels(foot[hit]), int(hit.sum())


def wall_map_cpu(wp, waters, level: int, depth_m: float, t: float) -> tuple[float, int]:
    """CPU s to make the whole wall's map at ``level`` in every water, and its number of points."""
    x, y, path, foot = wall_points(level, depth_m, wp)
    c0 = time.process_time()
    fc = cmap.FrameCaustics(
        world_post.waves_of(wp.wave_seed, wp.wind_mps), x, y, path, foot, t, sf.sun_deflection(wp.sun_travel_dir)
    )
    for w in waters.values():
        fc.factor(float(np.mean(w.sigma_s)), float(w.g))
    return time.process_time() - c0, x.size


def wall_points(level: int, depth_m: float, wp) -> tuple[np.ndarray, ...]:
    """(x, y, path, footprint) (n,) of a grid of the dock's wall at ``level``'s bin: surface
    crossings, beam paths and a footprint that reads that level."""
    sun = sf.refracted_sun(wp.sun_travel_dir)
    b = cmap.FINEST_BIN_M * 2**level
    y, z = np.meshgrid(np.arange(-cc.POOL[1] / 2, cc.POOL[1] / 2, b) + b / 2, np.arange(-depth_m, 0.0, b) + b / 2)
    h = -z.ravel()
    back = -sun[:2] / -sun[2]
    return cc.POOL[0] / 2 + h * back[0], y.ravel() + h * back[1], h / -sun[2], np.full(h.size, 0.75 * b)


def accuracy(frame, wp, waters, depth_m: float, t: float) -> str:
    """How far the factors a frame's wall pixels read from maps of the whole wall (their own
    points grouped with the wall's grid at their levels) are from the frame's own factors."""
    hit, on_wall, foot, p = sunlit(frame, wp)
    wall = hit & on_wall
    foot, h = foot[wall], frame[3][wall].astype(np.float64)  # footprints and depths of the wall pixels
    sun = sf.refracted_sun(wp.sun_travel_dir)
    back = -sun[:2] / -sun[2]
    own = (cc.POOL[0] / 2 + h * back[0], p[..., 1][wall] + h * back[1], h / -sun[2], foot)
    grids = [wall_points(int(v), depth_m, wp) for v in np.unique(cmap._levels(foot)) if v >= 0]
    pts = [np.concatenate(c) for c in zip(own, *grids)]
    waves, D = world_post.waves_of(wp.wave_seed, wp.wind_mps), sf.sun_deflection(wp.sun_travel_dir)
    alone, shared = cmap.FrameCaustics(waves, *own, t, D), cmap.FrameCaustics(waves, *pts, t, D)
    out = []
    for name, w in waters.items():
        a = alone.factor(float(np.mean(w.sigma_s)), float(w.g))
        d = np.abs(shared.factor(float(np.mean(w.sigma_s)), float(w.g))[: a.size] - a)
        out.append(f"{name} mean {d.mean():.4f} p99 {np.quantile(d, 0.99):.3f} max {d.max():.2f} (std {a.std():.2f})")
    return "; ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--depth", type=float, default=6.0, help="how far down the wall the map reaches (m)")
    args = ap.parse_args()
    wp = cc.world()
    waters = {n: optics.fast_water(Water(preset=n), "physical", 3.0)[0] for n in cc.WATERS}
    frames = [cc.frame(r) for r in cc.RANGES_M]
    cc.run(frames[:1], waters)  # compile / warm the caches
    levels: set[int] = set()
    per_frame = []
    for r, fr in zip(cc.RANGES_M, frames):
        c0 = time.process_time()
        cc.run([fr], waters)
        cpu = time.process_time() - c0
        wall, lev, n = wall_pixels(fr, wp)
        hist = {int(v): round(float(np.mean(lev[wall] == v)), 3) for v in np.unique(lev[wall])}
        levels |= {v for v, share in hist.items() if v >= 0 and share >= 0.01}  # rarer: left per frame
        per_frame.append(cpu * wall.mean())
        print(f"{r:4.1f} m: caustics {1e3 * cpu:6.1f} CPU ms, {n} sunlit px, {wall.mean():.2f} on the wall")
        print(f"        share of its wall pixels per level (-1: coarser than the coarsest, no pattern): {hist}")
    total = 0.0
    for level in sorted(levels):
        cpu, m = wall_map_cpu(wp, waters, level, args.depth, 0.4)
        total += cpu
        print(f"wall map, level {level} ({100 * cmap.FINEST_BIN_M * 2**level:g} cm, {m} bins): {1e3 * cpu:.0f} CPU ms")
    share = float(np.mean(per_frame))
    print(
        f"per frame time: the whole wall {1e3 * total:.0f} CPU ms (levels {sorted(levels)}) against "
        f"{1e3 * share:.0f} ms of a frame's caustics on the wall: pays beyond {total / share:.1f} trials"
    )
    print("|whole-wall map - frame's own map| at the frame's wall pixels (factor, 1 = flat sunlight):")
    for r, fr in zip(cc.RANGES_M, frames):
        print(f"{r:4.1f} m: {accuracy(fr, wp, waters, args.depth, 0.4)}")


if __name__ == "__main__":
    main()
