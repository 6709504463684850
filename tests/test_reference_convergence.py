"""The reference fidelity's default volume bounces have converged.

The veil of the physical ``mild`` water (sun overhead, horizontal view at 2 m depth, black
target 40 m away: the backscatter oracle of test_reference_optics.py) rendered by the project's own scene builder and
water module at the ``render.volume_bounces`` default and at twice it: the mean radiance agrees
within 1 % per channel, while single scattering (0 bounces) is far from it (the test can fail:
the veil grows 4-5x with multiple scattering in G and B)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from blendgen.config.models import Render

pytestmark = pytest.mark.blender

#: physical ``mild`` (Jerlov II, article beta 0.2 split): the water of ``optics.light_field_veil``'s measurement
MILD = {
    "sigma_a": [0.176, 0.04, 0.08],
    "sigma_s": [0.024, 0.16, 0.12],
    "phase": "hg",
    "g": 0.9,
    "ff_ior": 1.1,
    "ff_backscatter": 0.0183,
    "box_min": [-5.0, -60.0, -60.0],
    "box_max": [60.0, 60.0, 0.0],
}


def veil(tmp_path, bounces: int, samples: int = 32, size: int = 8) -> np.ndarray:
    spec = {
        "water": MILD,
        "camera": {"z": -2.0, "clip_start": 0.001},
        "target": {"kind": "black", "x": 40.0},
        "sun": {"direction": [0, 0, -1], "strength": 3.0},
        "render": {"width": size, "height": size, "samples": samples, "volume_bounces": bounces, "seed": 1},
    }
    p = tmp_path / f"veil{bounces}.json"
    p.write_text(json.dumps(spec))
    res = subprocess.run(
        [sys.executable, "-m", "blendgen.blender.oracle_scenes", str(p)], capture_output=True, text=True, timeout=600
    )
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["volume_bounces"] == bounces
    return np.asarray(out["mean"], float)


def test_reference_default_volume_bounces_have_converged(tmp_path):
    n = Render().volume_bounces
    assert n >= 32, f"render.volume_bounces defaults to {n}: the reference would not be converged"
    v_n, v_2n, v_0 = veil(tmp_path, n), veil(tmp_path, 2 * n), veil(tmp_path, 0)
    np.testing.assert_allclose(v_n, v_2n, rtol=0.01)  # converged: 32 vs 64 within 1 %
    assert np.all(v_2n[1:] > 2.0 * v_0[1:])  # and single scattering is not
