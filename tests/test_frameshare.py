"""Sequences that are one condition under two seeds share one image per frame; anything that
draws random numbers (noise, particles) or carries state is composed on its own."""

from __future__ import annotations

import numpy as np

from blendgen.config.models import Sensor, Water
from blendgen.pipeline import compose
from blendgen.pipeline.frameshare import FrameShare, share_key
from blendgen.pipeline.plan import SequencePost

W, H = 32, 24
K = np.array([[30.0, 0, (W - 1) / 2], [0, 30.0, (H - 1) / 2], [0, 0, 1]])


def _state(seed: int, noise_std: float = 0.0, preset: str = "mild", noise: bool = False) -> compose.SequenceState:
    """Shot/read noise off unless asked: the camera's default (noise on in both modes) draws random
    numbers, and such sequences are composed on their own."""
    return compose.SequenceState.start(
        SequencePost(
            seed=seed,
            fps=10,
            image_formation="article",
            water=Water(preset=preset),
            light_depth_m=1.0,
            surface_z_m=0.0,
            irradiance_w_m2=3.0,
            noise_std=noise_std,
            sensor=Sensor(noise=noise),
        )
    )


def _passes() -> dict:
    rng = np.random.default_rng(3)
    p = {
        "rgb": rng.random((H, W, 3), dtype=np.float32),
        "depth_z": np.full((H, W), 2.0, np.float32),
        "index": np.zeros((H, W), np.uint8),
    }
    return compose.add_range(p, K)


def _image(share, st, passes):
    frame = {"T_world_cam": np.eye(4), "t": 0.0}
    return share.image(st, passes, lambda: compose.camera_image(passes, st, K, frame, [], "fast"))


def test_same_condition_other_seed_is_made_once_and_equal():
    share, passes = FrameShare(), _passes()
    share.begin(passes)
    a, b = _state(1), _state(2)
    ia, ib = _image(share, a, passes), _image(share, b, passes)
    assert share.hits == 1 and ia is not ib
    np.testing.assert_array_equal(
        ib, compose.camera_image(passes, _state(2), K, {"T_world_cam": np.eye(4)}, [], "fast")
    )


def test_other_water_noise_or_other_frame_not_shared():
    share, passes = FrameShare(), _passes()
    share.begin(passes)
    _image(share, _state(1), passes)
    _image(share, _state(1, preset="moderate"), passes)
    assert share_key(_state(1, noise_std=2.0)) is None
    assert share_key(_state(1, noise=True)) is None  # the default camera: shot/read noise
    _image(share, _state(1, noise_std=2.0), passes)
    _image(share, _state(1, noise_std=2.0), passes)
    _image(share, _state(2), dict(passes))  # not the frame's passes (e.g. particles composited)
    assert share.hits == 0
    share.begin(_passes())
    _image(share, _state(1), passes)  # stale passes after begin: composed again
    assert share.hits == 0
