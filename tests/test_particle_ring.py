"""A defocused particle straddling a near/far background edge: every pixel of the final fast
image (particles, then the water model) must lie between the two layers' own underwater
radiances -- the background at its range and the particle at its range -- per channel
(``T L_bg + (1 - T) L_p``, T in [0, 1]). Composing the background at the particle's range
(the old merged-range composite) put a bright ring on the far side of the edge."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.config.models import Lens
from blendgen.geometry import intrinsics_from_hfov, make_T
from blendgen.physics.particles.field import ParticleField, project_particles
from blendgen.pipeline import compose, particle_light
from blendgen.tools.bench import particle_bench

W, H = 160, 120
R = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # camera looks along world +x
CAM = [0.5, 0.0, 2.0]


def _scene(mode: str, far: float = 12.0):
    st = particle_bench._state(1, "uniform", lamp=False)
    st.post = st.post.model_copy(
        update={"image_formation": mode, "lens": Lens(focal_length_mm=8.0, f_number=1.4, focus_m=5.0)}
    )
    st.water, st.water_opts = st.water, {**st.water_opts, "blur": False}
    # one 1 cm particle 0.5 m ahead, on the optical axis: centred on the image's middle column
    st.field = ParticleField(
        np.array([[CAM[0] + 0.5, 0.0, CAM[2]]], np.float32),
        np.array([0.01], np.float32),
        [0.0, -2.5, -5.0],
        [15.0, 2.5, 3.0],
    )
    K = intrinsics_from_hfov(W, H, math.radians(60.0))
    T = make_T(R, CAM)
    rng = np.full((H, W), 1.5, np.float32)  # near wall (left) | far wall (right)
    rng[:, W // 2 :] = far
    passes = {"rgb": np.full((H, W, 3), 0.8, np.float32), "range_m": rng, "index": np.zeros((H, W), np.int32)}
    return st, K, T, passes


def _final(passes, st, K, T):
    return compose.water_image(passes, st, K, T, [])


@pytest.mark.parametrize("mode,far", [("physical", 12.0), ("article", 12.0), ("physical", np.inf)])
def test_defocused_particle_over_depth_edge_stays_between_its_layers(mode, far):
    st, K, T, passes = _scene(mode, far)
    seen, occ = compose.add_particles(passes, st, K, T, t_s=0.0)
    out = _final(seen, st, K, T)
    L_bg = _final(passes, st, K, T)
    # the particle layer alone: its own radiance (from a fully covering copy) at its own range
    cov = seen["range_m"] < passes["range_m"]
    assert cov.any() and cov[:, : W // 2].any() and cov[:, W // 2 :].any(), "particle must straddle the edge"
    r_p = float(seen["range_m"][cov].min())
    p = project_particles(st.field, K, T, W, H)
    J_p = particle_light.shader(st.post, st.water, T)(p)[0]
    L_p = _final(
        {**passes, "rgb": np.broadcast_to(J_p, (H, W, 3)).copy(), "range_m": np.full((H, W), r_p, np.float32)}, st, K, T
    )
    lo, hi = np.minimum(L_bg, L_p), np.maximum(L_bg, L_p)
    tol = 1e-4 + 1e-3 * hi
    assert np.all(out[cov] >= lo[cov] - tol[cov]) and np.all(out[cov] <= hi[cov] + tol[cov]), (
        f"overshoot {np.max(out[cov] - hi[cov]):.4g}, undershoot {np.max(lo[cov] - out[cov]):.4g}"
    )
    assert np.array_equal(out[~cov], L_bg[~cov])


def test_without_water_after_the_composite_is_the_plain_blend():
    st, K, T, passes = _scene("physical")
    a, _ = compose.add_particles(passes, st, K, T, t_s=0.0, water_after=False)
    cov = a["range_m"] < passes["range_m"]
    assert cov.any() and np.all(a["rgb"][cov] <= 0.8 + 1e-6)


@pytest.mark.parametrize("mode", ["physical", "article"])
@pytest.mark.parametrize("lamp", [True, False])
def test_a_frame_without_a_particle_in_view_leaves_the_passes_as_they_are(mode, lamp):
    """Every particle behind the camera (it left the pool): no particle draws, the passes come
    back unchanged and the occluder mask is empty. The lamp's spread beam was read with an empty
    map, which cv2.remap rejects: such a frame stopped the render."""
    st = particle_bench._state(600, "power_law", lamp=lamp, formation=mode)
    K = intrinsics_from_hfov(W, H, math.radians(60.0))
    passes = {
        "rgb": np.full((H, W, 3), 0.1, np.float32),
        "range_m": np.full((H, W), 14.0, np.float32),
        "index": np.zeros((H, W), np.int32),
    }
    seen, occluded = compose.add_particles(passes, st, K, make_T(R, [20.0, 0.0, 2.0]), t_s=0.0)
    assert not occluded.any()
    assert np.array_equal(seen["rgb"], passes["rgb"]) and np.array_equal(seen["range_m"], passes["range_m"])
