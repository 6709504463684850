"""Diagnostic for docs/LAMP.md: how much of Cycles' multiply scattered lamp veil is the second
order, and what the fast beam spread adds, outside and inside the single-scatter cone.

Scene of ``dockbench bench lamp``'s veil table (no surface, 96x72, DEMO_LAMP), green channel.
Monte Carlo of the veil's orders 1 and 2 along pixel rays (t and s exponential with rate c,
the second scattering direction drawn from the Henyey-Greenstein phase function), 6 random
pixels per 8x6 block, 10^6 paths each; compared with Cycles 0-bounce (order 1) and
32-bounce - 0-bounce (orders >= 2) renders, and with fast(F) - fast(F = 0).

    python experiments/lamp_order2_mc.py [mild|moderate] [RENDER_CACHE]   (~1 min; renders cached)
"""

import sys
from pathlib import Path

import cv2
import numpy as np

from blendgen.physics.light.sources import lamp_lights
from blendgen.physics.water import optics
from blendgen.tools.bench import lamp_bench as lb

NAME = sys.argv[1] if len(sys.argv) > 1 else "moderate"
WORK = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("out/bench_lamp/renders")
G, BLOCKS, PIXELS, PATHS = 1, (8, 6), 6, 1_000_000
w = optics.get_preset(NAME)
b, c, g = float(w.sigma_s[G]), float(w.c[G]), float(w.g)
spec0 = lb.scene_spec(w, [lb.DEMO_LAMP], None, (96, 72), 256, 0)
spec32 = lb.scene_spec(w, [lb.DEMO_LAMP], None, (96, 72), 256, 32)
ref0, ref32 = lb.reference(spec0, WORK)[..., G], lb.reference(spec32, WORK)[..., G]
fast0, fast = lb.fast(spec32, w, 0.0)[..., G], lb.fast(spec32, w)[..., G]
K, rays = lb.camera(spec32)
light = lamp_lights([lb._ns(lb.DEMO_LAMP)])[0]
pos, axis, I0 = np.asarray(light.position_m), np.asarray(light.axis), float(light.intensity_w_sr[G])
rng = np.random.default_rng(0)


def hg(cos):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos) ** 1.5)


def hg_sample(n, mean_dir):
    u = rng.random(n)
    cos = (1 + g * g - ((1 - g * g) / (1 - g + 2 * g * u)) ** 2) / (2 * g)
    phi = 2 * np.pi * rng.random(n)
    sin = np.sqrt(np.clip(1 - cos * cos, 0, None))
    t1 = np.cross(mean_dir, [1.0, 0, 0] if abs(mean_dir[0]) < 0.9 else [0, 1.0, 0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(mean_dir, t1)
    return cos[:, None] * mean_dir + sin[:, None] * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)


def lamp_irradiance(y):
    v = y - pos
    d = np.maximum(np.linalg.norm(v, axis=1), 0.05)
    v /= d[:, None]
    return I0 * light.profile(v @ axis) * np.exp(-c * d) / d**2, v


def order1(ray):
    x = rng.exponential(1 / c, PATHS)[:, None] * ray
    E, v = lamp_irradiance(x)
    return float(np.mean(b / c * hg(-(v @ ray)) * E))


def order2(ray):
    x = rng.exponential(1 / c, PATHS)[:, None] * ray
    w_in = hg_sample(PATHS, -ray)  # direction of travel at x, drawn from p(theta_2)
    E, v = lamp_irradiance(x - rng.exponential(1 / c, PATHS)[:, None] * w_in)
    return float(np.mean((b / c) ** 2 * hg(np.sum(v * w_in, axis=1)) * E))


def block_mc(order):
    h, wd = ref0.shape
    bw, bh = wd // BLOCKS[0], h // BLOCKS[1]
    out = np.zeros(BLOCKS[::-1])
    for j in range(BLOCKS[1]):
        for i in range(BLOCKS[0]):
            out[j, i] = np.mean(
                [order(rays[j * bh + rng.integers(bh), i * bw + rng.integers(bw)]) for _ in range(PIXELS)]
            )
    return out


def blocks(a):
    return cv2.resize(np.ascontiguousarray(a), BLOCKS, interpolation=cv2.INTER_AREA)


m1, m2 = block_mc(order1), block_mc(order2)
higher, added = blocks(ref32) - blocks(ref0), blocks(fast) - blocks(fast0)
out = blocks(fast0) < 0.05 * blocks(fast0).mean()
print(f"{NAME}: check, Cycles 0-bounce / MC order 1 (frame mean): {blocks(ref0).mean() / m1.mean():.3f}")
for label, sel in (("outside the single-scatter cone", out), ("whole frame", np.ones_like(out))):
    print(
        f"{label} ({int(sel.sum())} blocks): Cycles orders >= 2 {higher[sel].mean():.3g}, MC order 2 "
        f"{m2[sel].mean():.3g} ({m2[sel].mean() / higher[sel].mean():.0%}), fast spread adds "
        f"{added[sel].mean():.3g} ({added[sel].mean() / higher[sel].mean():.0%})"
    )
