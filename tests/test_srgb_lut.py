"""The sRGB lookup equals the arithmetic encoder (it replaces it in SensorModel.apply)."""

import numpy as np

from blendgen.physics.camera import sensor, srgb_lut


def test_one_step_per_bucket():
    assert srgb_lut.check(sensor.srgb_encode) == 0


def test_lookup_equals_arithmetic_at_every_step_and_random_values():
    _, step = srgb_lut.tables(sensor.srgb_encode)
    s = step[np.isfinite(step)]
    bits = s.view(np.uint32)  # steps inside buckets, and every bucket's edges
    edges = np.arange(step.size, dtype=np.uint32) << np.uint32(srgb_lut.SHIFT)
    near = np.concatenate([bits - 1, bits, bits + 1, edges, edges[1:] - 1]).view(np.float32)
    near = near[near <= 1]
    rnd = np.random.default_rng(0).random(1_000_000, dtype=np.float32)
    y = np.concatenate([near, rnd, np.float32([0.0, -0.0, 1.0, 1e-30, 0.0031308])])
    np.testing.assert_array_equal(srgb_lut.encode_uint8(y, sensor.srgb_encode), sensor.to_uint8(y))


def test_sensor_apply_uses_same_codes_as_to_uint8():
    x = np.random.default_rng(1).random((48, 64, 3), dtype=np.float32) * 1.5
    cam = sensor.SensorModel()
    y = np.minimum(np.fmax(x * np.float32(cam.responsivity_e_per_s * cam.exposure_s * cam.K / 255), 0), 1)
    np.testing.assert_array_equal(cam.apply(x), sensor.to_uint8(y))
