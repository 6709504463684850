"""Evidence sheet for the lamp's beam spread (docs/LAMP.md): rows mild / moderate water; columns
Cycles (32 volume bounces, 256 spp), fast with the sharp beam (the model before), fast with the
spread beam (physics/light/beam_spread.py). No surface: the image is the lamp's veil. Green channel,
sRGB-like gamma, each row scaled by the reference's 99th percentile.

    python experiments/lamp_beam_spread.py OUT.jpg [WORK_DIR]"""

import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np

from blendgen.physics.light import lamp_water
from blendgen.physics.light.sources import lamp_lights
from blendgen.physics.water import optics
from blendgen.tools.bench import lamp_bench as lb


def row(name: str, work: Path) -> np.ndarray:
    w = optics.get_preset(name)
    spec = lb.scene_spec(w, [lb.DEMO_LAMP], None, (96, 72), 256, 32)
    ref = lb.reference(spec, work)[..., 1]
    K, rays = lb.camera(spec)
    passes = lb.scene_passes(spec, rays)[:3]
    spread = lamp_water.LampWater.build(lamp_lights([lb._ns(d) for d in spec["lamps"]]), w)
    imgs = [ref] + [
        lamp_water.lamp_radiance(m, K, rays, *passes)[..., 1]
        for m in (dataclasses.replace(spread, spread=False), spread)
    ]
    top = np.percentile(ref, 99)
    tiles = [
        cv2.resize(
            (np.clip(i / top, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8), (288, 216), interpolation=cv2.INTER_NEAREST
        )
        for i in imgs
    ]
    return np.hstack([np.pad(t, 2) for t in tiles])


if __name__ == "__main__":
    work = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("out/bench_lamp")
    sheet = np.vstack([row(n, work) for n in ("mild", "moderate")])
    cv2.imwrite(sys.argv[1], sheet, [cv2.IMWRITE_JPEG_QUALITY, 90])
