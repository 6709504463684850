"""Run: PYTHONPATH=. python experiments/particle_ring_before_after.py OUT.png

Ring evidence (docs/particles.md): a defocused 3 mm particle 0.25 m ahead straddling a near (1.5 m) / far (12 m) wall
edge."""

import math
import sys

import cv2
import numpy as np

from blendgen.config.models import Lens
from blendgen.geometry import intrinsics_from_hfov, make_T
from blendgen.physics.particles.field import ParticleField
from blendgen.pipeline import compose
from blendgen.tools.bench import particle_bench

W, H = 320, 240
R = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
CAM = [0.5, 0.0, 2.0]
st = particle_bench._state(1, "uniform", lamp=False)
st.post = st.post.model_copy(update={"lens": Lens(focal_length_mm=8.0, f_number=1.0, focus_m=5.0)})
st.water_opts = {**st.water_opts, "blur": False}
pos = np.array(
    [[CAM[0] + 0.25, 0.0, CAM[2]], [CAM[0] + 0.4, 0.02, CAM[2] + 0.03], [CAM[0] + 0.3, -0.01, CAM[2] - 0.04]],
    np.float32,
)
st.field = ParticleField(pos, np.array([0.003, 0.002, 0.004], np.float32), [0.0, -2.5, -5.0], [15.0, 2.5, 3.0])
K = intrinsics_from_hfov(W, H, math.radians(60.0))
T = make_T(R, CAM)
rng = np.full((H, W), 1.5, np.float32)
rng[:, W // 2 :] = 12.0
alb = np.full((H, W, 3), 0.8, np.float32)
passes = {"rgb": alb, "range_m": rng, "index": np.zeros((H, W), np.int32)}
imgs = []
for after in (False, True):
    import copy

    s2 = copy.copy(st)
    seen, occ = compose.add_particles(passes, s2, K, T, t_s=0.0, water_after=after)
    imgs.append(compose.water_image(seen, s2, K, T, []))
bg = compose.water_image(passes, st, K, T, [])


def tone(x):
    x = np.clip(x / np.percentile(bg, 99.5), 0, 1) ** (1 / 2.2)
    return (x * 255).astype(np.uint8)


y0, x0, s = H // 2 - 30, W // 2 - 40, 80
crops = [
    cv2.resize(tone(im)[y0 : y0 + 60, x0 : x0 + s], (s * 5, 60 * 5), interpolation=cv2.INTER_NEAREST) for im in imgs
]
# profile along the centre row
row = [im[H // 2, x0 : x0 + s, 1] for im in imgs] + [bg[H // 2, x0 : x0 + s, 1]]
ph = 200
plot = np.full((ph, s * 5, 3), 255, np.uint8)
lo, hi = min(r.min() for r in row), max(r.max() for r in row)
for r, col in zip(row, [(0, 0, 220), (0, 160, 0), (120, 120, 120)]):
    pts = np.stack([np.arange(s) * 5 + 2, ph - 10 - (r - lo) / (hi - lo) * (ph - 20)], 1).astype(np.int32)
    cv2.polylines(plot, [pts], False, col, 2)


def label(img, t):
    img = img.copy()
    cv2.putText(img, t, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 0), 1, cv2.LINE_AA)
    return img


top = np.hstack(
    [
        label(crops[0], "before: bg composited at particle range"),
        np.zeros((300, 6, 3), np.uint8),
        label(crops[1], "after: exact two-layer composite"),
    ]
)
cv2.putText(
    plot,
    "centre row, green channel: blue=before, green=after, grey=no particle",
    (6, 16),
    cv2.FONT_HERSHEY_SIMPLEX,
    0.45,
    (0, 0, 0),
    1,
    cv2.LINE_AA,
)
bottom = np.hstack([plot, np.full((ph, 6, 3), 255, np.uint8), np.full((ph, s * 5, 3), 255, np.uint8)])
sheet = np.vstack([top, bottom])
cv2.imwrite(sys.argv[1], cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
print(
    sheet.shape,
    "max over analytic envelope before/after:",
    [float(np.max(im - np.maximum(bg, im.min()))) for im in imgs],
)
