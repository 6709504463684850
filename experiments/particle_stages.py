"""Per-stage CPU of the fast particle path on `bench particles`' scene (docs/particles.md, Speed):
wraps the stages of compose.add_particles (projection with the blur, shading, and the fused splat,
background transfer and compositing with the mask and merged range) in timers and prints their
medians over 30 frames, after one warm-up; the rest of the total is Python around them.

    python experiments/particle_stages.py [power_law|uniform|paper] [N]

``paper``: the paper config's row of ``bench particles`` (uniform 5-20 mm, the article's image
formation, no lamp)."""

import collections
import sys
import time

import numpy as np

from blendgen.physics.particles import field as P
from blendgen.physics.particles import splat as ps
from blendgen.pipeline import compose
from blendgen.pipeline import particle_light as pl
from blendgen.tools.bench import particle_bench as pb

TIMES = collections.defaultdict(list)


def timed(fn, label):
    def call(*a, **k):
        t = time.process_time()
        out = fn(*a, **k)
        TIMES[label].append(time.process_time() - t)
        return out

    return call


def timed_factory(factory, label):
    """Time the callables that the particle_light factories return, not the factories."""
    return lambda *a, **k: timed(factory(*a, **k), label)


def main(config: str = "power_law", n: int = 60000) -> None:
    P.project_particles = timed(P.project_particles, "projection + blur")
    ps.over = timed(ps.over, "splat + transfer + compositing (fused)")
    compose._particle_background = timed(compose._particle_background, "background setup")
    compose.add_particles = timed(compose.add_particles, "total add_particles")
    for name, label in (("shader", "shading"),):
        setattr(pl, name, timed_factory(getattr(pl, name), label))
    paper = config == "paper"
    r = pb.run(
        n,
        frames=30,
        size_dist="uniform" if paper else config,
        lamp=not paper,
        formation="article" if paper else "physical",
    )
    print(pb.format_row(r))
    for label, t in TIMES.items():
        print(f"  {label:40s} {np.median(t[1:]) * 1e3:6.2f} ms CPU")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "power_law", int(sys.argv[2]) if len(sys.argv) > 2 else 60000)
