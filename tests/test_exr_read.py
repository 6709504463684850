"""The direct EXR reader (blendgen.blender.exr) gives the passes OpenImageIO gives, bit for
bit, and hands every EXR it does not understand back to OpenImageIO."""

import numpy as np
import pytest

oiio = pytest.importorskip("OpenImageIO")


def _write(path, px, compression="none", fmt="float"):
    spec = oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], fmt)
    spec.channelnames = tuple(f"Layer.Pass.{c}" for c in "XYZW"[: px.shape[2]])
    spec.attribute("compression", compression)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(px)
    out.close()


def test_single_part_float_scanlines_read_exactly(tmp_path):
    from blendgen.blender import exr

    rng = np.random.default_rng(0)
    px = rng.normal(size=(7, 5, 3)).astype(np.float32)
    px[0, 0, 0], px[1, 1, 1], px[2, 2, 2], px[3, 3, 0] = np.inf, np.nan, -0.0, 1e30
    _write(tmp_path / "a.exr", px)
    parts = exr.read_channels(str(tmp_path / "a.exr"))
    assert parts is not None and len(parts) == 1
    got = np.stack([parts[0][f"Layer.Pass.{c}"] for c in "XYZ"], axis=-1)
    assert got.tobytes() == px.tobytes()


@pytest.mark.parametrize("compression, fmt", [("zip", "float"), ("none", "half")])
def test_other_exrs_are_left_to_openimageio(tmp_path, compression, fmt):
    from blendgen.blender import exr

    _write(tmp_path / "b.exr", np.ones((4, 6, 1), np.float32), compression, fmt)
    assert exr.read_channels(str(tmp_path / "b.exr")) is None


def test_not_an_exr_is_left_to_openimageio(tmp_path):
    from blendgen.blender import exr

    (tmp_path / "c.exr").write_bytes(b"P6\n1 1\n255\n\0\0\0")
    assert exr.read_channels(str(tmp_path / "c.exr")) is None


@pytest.mark.blender
@pytest.mark.parametrize("border", [None, (0.25, 0.7, 0.1, 0.6)])
def test_rendered_passes_are_those_openimageio_reads(tmp_path, border):
    """A Cycles multilayer EXR as the worker writes it (every pass on; whole frame and an
    ROI crop): the direct reader is used and its passes equal OpenImageIO's bit for bit."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    cmd = [sys.executable, "-m", "blendgen.blender.testing.exr_oracle", str(tmp_path / "f.exr"), json.dumps(border)]
    r = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.strip().splitlines()
    assert "exr_threads 0" in lines  # written in the render thread, no OpenEXR pool
    same = lines[-1].split()
    assert same[0] == "same" and (same[1:] == ["48", "64"]) == (border is None)  # the crop is smaller
