"""Analytic oracles of the Cycles medium (docs/water.md) through the project's own water module (reference fidelity).

Each scene is built by ``blendgen.blender.oracle_scenes`` (scene builder + water
box of ``blendgen.blender.water``) and rendered in a subprocess (the test process
never imports bpy). Images are tiny (8x8 to 32x32 px) and each render takes < 2 s.
Type I Jerlov E(10 m)/E0 is asserted on the coefficients in tests/test_optics.py
(the 0-bounce medium attenuates the sun with c, not Kd: see docs/water.md).
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from blendgen.physics.water import optics

pytestmark = pytest.mark.blender

CLIP = 0.001
BOX = {"box_min": [-5.0, -60.0, -60.0], "box_max": [60.0, 60.0, 0.0]}


def oracle(tmp_path, spec: dict) -> dict:
    p = tmp_path / f"spec{len(list(tmp_path.iterdir()))}.json"
    p.write_text(json.dumps(spec))
    res = subprocess.run(
        [sys.executable, "-m", "blendgen.blender.oracle_scenes", str(p)], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def water(sigma_a, sigma_s, **kw) -> dict:
    return {
        "sigma_a": list(sigma_a),
        "sigma_s": list(sigma_s),
        "phase": "hg",
        "g": 0.0,
        "ff_ior": 1.1,
        "ff_backscatter": 0.0183,
        **BOX,
        **kw,
    }


def transmission_scene(w: dict, d: float, samples: int = 4) -> dict:
    return {
        "water": w,
        "camera": {"z": -10.0, "clip_start": CLIP},
        "target": {"kind": "emitter", "x": d, "radiance": 1.0},
        "render": {"width": 8, "height": 8, "samples": samples},
    }


def backscatter_scene(w: dict, samples: int, size: int) -> dict:
    """Oracle 4 (single-scatter backscatter): horizontal view at 2 m depth, sun straight down (E = 3),
    black target at 8 m, 0 volume bounces."""
    return {
        "water": w,
        "camera": {"z": -2.0, "clip_start": CLIP},
        "target": {"kind": "black", "x": 8.0},
        "sun": {"direction": [0, 0, -1], "strength": 3.0},
        "render": {"width": size, "height": size, "samples": samples, "volume_bounces": 0},
    }


def test_coefficients_mapping(tmp_path):
    """sigma_a, sigma_s, phase and its parameters land in the Volume Coefficients node."""
    w = water([0.35, 0.07, 0.03], [0.2, 0.25, 0.3], g=0.8)
    out = oracle(tmp_path, transmission_scene(w, 2.0, samples=1))
    c = out["coefficients"]
    assert np.allclose(c["sigma_a"], w["sigma_a"], atol=1e-7)
    assert np.allclose(c["sigma_s"], w["sigma_s"], atol=1e-7)
    assert c["emission"] == [0.0, 0.0, 0.0] and c["phase"] == "hg" and c["g"] == pytest.approx(0.8)
    assert c["linked_to"] == ["Volume"] and out["volume_bounces"] == 0  # single scattering
    ff = oracle(
        tmp_path,
        transmission_scene(water([0.1] * 3, [0.2] * 3, phase="ff", ff_ior=1.15, ff_backscatter=0.01), 2.0, samples=1),
    )["coefficients"]
    assert ff["phase"] == "ff" and ff["ff_ior"] == pytest.approx(1.15) and ff["ff_backscatter"] == pytest.approx(0.01)


def test_beer_lambert_absorption_only(tmp_path):
    """Oracle 1 (absorption, with the Coefficients node): sigma_a (.4, .25, .1), d = 2 m."""
    sa = np.array([0.4, 0.25, 0.1])
    out = oracle(tmp_path, transmission_scene(water(sa, [0, 0, 0]), 2.0))
    expect = np.exp(-sa * (2.0 - CLIP))
    assert np.allclose(expect, [0.4495, 0.6067, 0.8188], atol=1e-3)
    assert np.allclose(out["mean"], expect, rtol=0.01)


def test_beer_lambert_absorbing_and_scattering(tmp_path):
    """Oracle 3 (transmission): exp(-(sigma_a + sigma_s) d) when the emitter is hidden from scatter rays."""
    sa, ss = np.array([0.35, 0.07, 0.03]), np.array([0.2, 0.3, 0.4])
    out = oracle(tmp_path, transmission_scene(water(sa, ss, g=0.9), 3.0, samples=16))
    expect = np.exp(-(sa + ss) * (3.0 - CLIP))
    assert np.allclose(out["mean"], expect, rtol=0.01), (out["mean"], expect)


@pytest.mark.parametrize(
    "g,size,published", [(0.0, 16, (0.0286, 0.0912, 0.1103)), (0.9, 32, (0.00223, 0.00711, 0.00860))]
)
def test_single_scatter_backscatter(tmp_path, g, size, published):
    """Oracle 4 at 64 spp over 16x16 / 32x32 px (Cycles 5 samples homogeneous media
    with low variance: the pixel spread is ~1%); matches optics.single_scatter_backscatter."""
    sa, ss = [0.35, 0.07, 0.03], [0.2, 0.2, 0.2]
    out = oracle(tmp_path, backscatter_scene(water(sa, ss, g=g), samples=64, size=size))
    expect = optics.single_scatter_backscatter(sa, ss, g, 3.0, 2.0, 8.0 - CLIP)
    assert np.allclose(expect, published, rtol=0.01)
    assert np.allclose(out["mean"], expect, rtol=0.02), (out["mean"], expect)


def test_single_scatter_fournier_forand(tmp_path):
    """The Fournier-Forand phase of the medium is optics.ff_phase (Mobley 2002 form)."""
    sa, ss = [0.35, 0.07, 0.03], [0.2, 0.2, 0.2]
    w = water(sa, ss, phase="ff", ff_ior=1.1, ff_backscatter=0.0183)
    out = oracle(tmp_path, backscatter_scene(w, samples=64, size=16))
    expect = optics.single_scatter_backscatter(
        sa, ss, 0.0, 3.0, 2.0, 8.0 - CLIP, phase_fn=lambda t: float(optics.ff_phase(t, 1.1, 0.0183))
    )
    assert np.allclose(out["mean"], expect, rtol=0.02), (out["mean"], expect)


def test_sun_through_surface_box_is_attenuated_by_c(tmp_path):
    """Sunlight reaches depth through the box's top face (a World volume would give 0):
    single-scatter radiance scales as exp(-c H) between depths 1 m and 3 m."""
    sa, ss = [0.3, 0.1, 0.05], [0.1, 0.1, 0.1]
    vals = []
    for z in (-1.0, -3.0):
        spec = backscatter_scene(water(sa, ss), samples=32, size=16)
        spec["camera"]["z"] = z
        vals.append(np.array(oracle(tmp_path, spec)["mean"]))
    c = np.add(sa, ss)
    assert np.all(vals[0] > 0)
    assert np.allclose(vals[1] / vals[0], np.exp(-c * 2.0), rtol=0.02)


@pytest.mark.slow
@pytest.mark.parametrize("g", [0.0, 0.9])
def test_single_scatter_backscatter_1024spp(tmp_path, g):
    """Oracle 4 as published: 1024 spp, within 2%."""
    sa, ss = [0.35, 0.07, 0.03], [0.2, 0.2, 0.2]
    out = oracle(tmp_path, backscatter_scene(water(sa, ss, g=g), samples=1024, size=16))
    expect = optics.single_scatter_backscatter(sa, ss, g, 3.0, 2.0, 8.0 - CLIP)
    assert np.allclose(out["mean"], expect, rtol=0.02)
