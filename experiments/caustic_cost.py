"""CPU cost of the fast path's caustics on realistic frames, part by part (no Blender).

The frames: the article's docking approach in the 15 x 5 x 8 m pool (template ``pool_15x5x8``:
dock top 1 m deep near the +x wall, in-water sun at 60 deg elevation from -x, wind 1 m/s),
a 640x480 60 deg camera 1.2 m deep looking +x at 1, 2, 4, 6 and 10 m from the dock's face.
Its range pass is ray-cast analytically (pool box and dock body), its albedo a tiled grey, and
:func:`world_post.caustic_geometry` turns it into the caustic points of a real frame; each frame
is then shaded in the article's three waters (``clear``, ``mild``, ``moderate`` in physical
image formation), sharing the geometry as the frame loop does.

Reports CPU ms per frame (``time.process_time``: contention distorts it little) of: the
geometry (grouping points), the fine deposit (the numba ``caustic_mesh.deposit`` of each
group's sharp map), the coarse deposit (:func:`caustic_map._coarse_scattered`'s own), the
sun-disc blur, the FFT blur per water, the lookups, and the rest; minimum over ``--reps``.
``--save FILE`` writes every frame's factors (3 waters) to an .npz, ``--check FILE`` compares
with such a file (max relative difference). Run from the repository root::

    PYTHONPATH=. python experiments/caustic_cost.py --reps 3
"""

from __future__ import annotations

import argparse
import math
import time
from collections import defaultdict

import numpy as np

from blendgen.config.models import Water
from blendgen.physics.surface import caustic_map as cmap
from blendgen.physics.surface import caustic_mesh as cm
from blendgen.physics.surface import optics as sf
from blendgen.physics.water import optics
from blendgen.pipeline import world_post
from blendgen.pipeline.compose import _unit_rays
from blendgen.pipeline.plan import WorldPost, _sun_dir

W, H, HFOV_DEG = 640, 480, 60.0
POOL = (15.0, 5.0, 8.0)  # length (x), width (y), depth (z below 0)
DOCK_FACE_X, DOCK = 6.5, ((6.5, 7.5), (-0.5, 0.5), (-1.4, -1.0))
RANGES_M = (1.0, 2.0, 4.0, 6.0, 10.0)
WATERS = ("clear", "mild", "moderate")


def world() -> WorldPost:
    """The pool template's surface and sun (wind 1 m/s, sun 60 deg elevation, azimuth 180)."""
    return WorldPost(
        surface=True,
        caustics=True,
        wind_mps=1.0,
        wave_seed=2026,
        sky_radiance=0.2,
        ambient_radiance=0.05,
        sun_travel_dir=sf.sun_in_air(_sun_dir(60.0, 180.0)).tolist(),
        sun_irradiance=3.0,
        sun_lamp_w_m2=3.0,
    )


def frame(range_to_dock: float, lateral: float = 0.4):
    """(rgb, albedo, range, depth, rays, K, T) of the camera ``range_to_dock`` m from the dock."""
    f = W / 2 / math.tan(math.radians(HFOV_DEG / 2))
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    yaw = math.radians(4.0)
    fwd = np.array([math.cos(yaw), math.sin(yaw), -0.03])
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    T = np.eye(4)
    T[:3, :3] = np.stack([right, down, fwd], 1)  # OpenCV camera: x right, y down, z forward
    o = np.array([DOCK_FACE_X - range_to_dock, lateral, -1.2])
    T[:3, 3] = o
    rays = np.einsum("ijk,lk->ijl", _unit_rays(tuple(K.ravel()), W, H), T[:3, :3].astype(np.float32))
    d = rays.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        best = np.full((H, W), np.inf)
        for axis, planes in ((0, (-POOL[0] / 2, POOL[0] / 2)), (1, (-POOL[1] / 2, POOL[1] / 2)), (2, (-POOL[2],))):
            for p in planes:
                t = (p - o[axis]) / d[..., axis]
                best = np.where((t > 0) & (t < best), t, best)
        lo = np.stack([(DOCK[a][0] - o[a]) / d[..., a] for a in range(3)], -1)
        hi = np.stack([(DOCK[a][1] - o[a]) / d[..., a] for a in range(3)], -1)
        t0, t1 = np.minimum(lo, hi).max(-1), np.maximum(lo, hi).min(-1)
        best = np.where((t0 > 0) & (t0 <= t1) & (t0 < best), t0, best)
    p = o + best[..., None] * d
    best = np.where(p[..., 2] < 0.3, best, np.inf)  # above the rim: open sky
    depth = np.maximum(-p[..., 2], 0.0).astype(np.float32)
    tile = ((np.floor(p[..., 0] / 0.25) + np.floor(p[..., 1] / 0.25) + np.floor(p[..., 2] / 0.25)) % 2).astype(float)
    albedo = np.repeat((0.45 + 0.15 * np.nan_to_num(tile))[..., None], 3, -1).astype(np.float32) * [0.8, 1.0, 0.95]
    rgb = (albedo * (0.05 + 3.0 * 0.5 / math.pi)).astype(np.float32)
    return rgb, albedo.astype(np.float32), best.astype(np.float32), depth, rays, K, T


class Timers:
    """CPU seconds per part, by wrapping the caustic modules' entry points."""

    def __init__(self):
        self.s: dict[str, float] = defaultdict(float)
        self.coarse = False
        self._saved: list = []

    def _wrap(self, mod, name, label):
        real = getattr(mod, name)

        def timed(*a, **k):
            t0 = time.process_time()
            try:
                return real(*a, **k)
            finally:
                self.s[label() if callable(label) else label] += time.process_time() - t0

        self._saved.append((mod, name, real))
        setattr(mod, name, timed)

    def __enter__(self):
        real_coarse = cmap._coarse_scattered

        def coarse(*a, **k):
            self.coarse = True
            try:
                return real_coarse(*a, **k)
            finally:
                self.coarse = False

        self._saved.append((cmap, "_coarse_scattered", real_coarse))
        cmap._coarse_scattered = coarse
        self._wrap(cm, "deposit", lambda: "coarse deposit" if self.coarse else "fine deposit")
        self._wrap(cm, "disc_blur", "disc blur")
        self._wrap(cmap, "_deposit", "deposit all")
        self._wrap(cmap, "_scattered", "FFT blur")
        self._wrap(cmap, "lookup", "lookups")
        return self

    def __exit__(self, *exc):
        for mod, name, real in reversed(self._saved):
            setattr(mod, name, real)


def run(frames, waters, t0: float = 0.3):
    """One pass over the frames: (CPU s per part, factors per frame and water)."""
    wp = world()
    timers = Timers()
    out = {}
    with timers:
        for n, (rgb, albedo, rng, depth, rays, K, T) in enumerate(frames):
            t = t0 + 0.1 * n
            c0 = time.process_time()
            geo = world_post.caustic_geometry(rgb, albedo, rng, depth, wp, rays, K, T, t)
            assert geo is not None  # the pool is sun-lit
            timers.s["geometry"] += time.process_time() - c0
            for name, w in waters.items():
                c0 = time.process_time()
                out[f"f{n}_{name}"] = geo.caustics.factor(float(np.mean(w.sigma_s)), float(w.g))
                timers.s["factor total"] += time.process_time() - c0
    return dict(timers.s), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--save")
    ap.add_argument("--check")
    args = ap.parse_args()
    frames = [frame(r) for r in RANGES_M]
    waters = {n: optics.fast_water(Water(preset=n), "physical", 3.0)[0] for n in WATERS}
    run(frames[:1], waters)  # compile / warm the caches
    best: dict[str, float] = {}
    for _ in range(args.reps):
        s, factors = run(frames, waters)
        best = {k: min(v, best.get(k, math.inf)) for k, v in s.items()}
    nf = len(frames)
    pts = [int(np.count_nonzero(np.isfinite(f[2]) & (f[3] > 0))) for f in frames]
    print(f"{nf} frames 640x480, {np.mean(pts):.0f} lit-candidate pixels/frame, waters {', '.join(WATERS)}")
    for n, w in waters.items():
        print(f"  {n}: scattering {float(np.mean(w.sigma_s)):.4f}/m g {float(w.g):.3f}")
    parts: tuple[str, ...] = ("fine deposit", "coarse deposit", "disc blur", "FFT blur", "lookups")
    caustics = best["geometry"] + best["factor total"]
    best["deposit tables"] = (
        best.get("deposit all", 0.0) - best.get("fine deposit", 0.0) - best.get("coarse deposit", 0.0)
    )
    parts += ("deposit tables",)
    named = sum(best.get(p, 0.0) for p in parts)
    print(f"CPU ms/frame (min of {args.reps}): caustics total {1e3 * caustics / nf:.1f}")
    for p in parts:
        per_water = "  (all waters)" if p == "FFT blur" else ""
        print(f"  {p:15s} {1e3 * best.get(p, 0.0) / nf:8.1f}{per_water}")
    print(f"  {'rest':15s} {1e3 * (caustics - named) / nf:8.1f}  (grouping, caustic_geometry, padding, blends)")
    if args.save:
        np.savez_compressed(args.save, **factors)
    if args.check:
        ref = np.load(args.check)
        worst = max(float(np.max(np.abs(factors[k] - ref[k]) / np.maximum(np.abs(ref[k]), 1e-6))) for k in ref.files)
        dev = max(float(np.std(ref[k])) for k in ref.files)
        print(f"check against {args.check}: max relative difference {worst:.2e} (largest factor std {dev:.3f})")


if __name__ == "__main__":
    main()
