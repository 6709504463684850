"""``dockbench bench io``: CPU cost of the per-frame file I/O a streaming run can skip, and of
the render EXR read (README, "Cost of the whole suite").

* camera image (640x480x3 uint8): PNG encode + write (generate, ``--images all``) and read +
  sha256 + decode (the evaluator) vs raw ``.npy`` write and read + pixel sha256 (frames a
  ``dockbench run`` does not keep); range pass: uint16 PNG encode vs pixel sha256;
* render passes: :func:`blendgen.blender.render.read_passes` (numpy views over the EXR)
  vs :func:`~blendgen.blender.render.read_passes_oiio` (OpenImageIO), and whether they
  give the same bytes, on EXRs Cycles writes as the worker does (every pass; three passes;
  half resolution, as the ROI path's background).

CPU time (``time.process_time``), median of ``repeat`` runs; a shared machine inflates it.
"""

from __future__ import annotations

import hashlib
import tempfile
import time
from pathlib import Path

import numpy as np


def _cpu_ms(fn, n: int, repeat: int) -> float:
    fn()
    runs = []
    for _ in range(repeat):
        c0 = time.process_time()
        fn()
        runs.append(time.process_time() - c0)
    return 1e3 * float(np.median(runs)) / n


def camera_images(dataset: Path | None, n: int = 40) -> list[np.ndarray]:
    """Up to ``n`` camera images (H,W,3) uint8 RGB of ``dataset``, else ``n`` synthetic
    640x480 frames (a vertical gradient plus Gaussian noise of sigma 2 DN)."""
    import cv2

    if dataset is not None:
        paths = sorted(Path(dataset).glob("sequences/*/rgb/*.png"))[:n]
        if paths:
            return [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in paths]
    rng = np.random.default_rng(0)
    ramp = np.linspace(20, 120, 480)[:, None, None] * np.array([0.3, 0.8, 0.7])
    return [np.clip(ramp + rng.normal(0, 2, (480, 640, 3)), 0, 255).astype(np.uint8) for _ in range(n)]


def image_io_table(images: list[np.ndarray], repeat: int = 5) -> list[tuple[str, float]]:
    """(what, CPU ms per frame) of writing and reading ``images`` each way."""
    import cv2

    from datasets_spec import io as dsio

    cv2.setNumThreads(1)
    n = len(images)
    with tempfile.TemporaryDirectory(prefix="dockbench-io-") as d:
        paths = [Path(d) / f"{i:06d}.png" for i in range(n)]

        def png_read():
            for p in paths:
                data = p.read_bytes()
                hashlib.sha256(data).hexdigest()
                cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)

        def raw_read():
            for p in paths:
                dsio.pixel_sha256(dsio.load_raw_image(dsio.raw_image_path(p), *images[0].shape[:2]))

        h, w = images[0].shape[:2]
        rng = np.random.default_rng(1)
        ranges = [np.full((h, w), 3.0, np.float32) + rng.normal(0, 0.01, (h, w)).astype(np.float32) for _ in range(n)]
        rows = [
            ("camera image: PNG encode + write", lambda: [dsio.save_image(p, im) for p, im in zip(paths, images)]),
            ("camera image: read + sha256 + PNG decode", png_read),
            ("camera image: raw .npy write", lambda: [dsio.save_raw_image(p, im) for p, im in zip(paths, images)]),
            ("camera image: raw read + pixel sha256", raw_read),
            ("range pass: uint16 PNG encode + write", lambda: [dsio.save_range(p, r) for p, r in zip(paths, ranges)]),
            (
                "range pass: pixel sha256 (not kept)",
                lambda: [dsio.pixel_sha256(dsio.range_to_units(r)) for r in ranges],
            ),
        ]
        return [(name, _cpu_ms(fn, n, repeat)) for name, fn in rows]


def exr_table(exrs: list[Path], repeat: int = 20) -> list[tuple[str, float, float, bool]]:
    """(EXR, OpenImageIO CPU ms, direct CPU ms, same bytes) per read of each EXR."""
    from blendgen.blender import render

    out = []
    for p in exrs:
        a, b = render.read_passes(str(p)), render.read_passes_oiio(str(p))
        same = sorted(a) == sorted(b) and all(
            a[k].dtype == b[k].dtype and a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes() for k in a
        )
        out.append(
            (
                f"{p.name} ({', '.join(sorted(a))})",
                _cpu_ms(lambda: render.read_passes_oiio(str(p)), 1, repeat),
                _cpu_ms(lambda: render.read_passes(str(p)), 1, repeat),
                same,
            )
        )
    return out


def run_io_bench(dataset: Path | None) -> None:
    """Print both tables (EXRs rendered here with Cycles, 1 spp, a monkey in an empty scene)."""
    from blendgen.blender import render

    images = camera_images(dataset)
    src = f"{len(images)} frames of {dataset}" if dataset else f"{len(images)} synthetic 640x480 frames"
    print(f"per-frame file I/O, {src} (CPU ms per frame, median of 5)")
    for name, ms in image_io_table(images):
        print(f"  {name:44s} {ms:7.2f}")
    with tempfile.TemporaryDirectory(prefix="dockbench-exr-") as d:
        exrs = []
        for w, h, every in ((640, 480, True), (640, 480, False), (320, 240, False)):
            p = Path(d) / f"{w}x{h}-{'5' if every else '3'}pass.exr"
            render.scratch_exr(str(p), w, h, every)
            exrs.append(p)
        print("render EXR read (CPU ms per read, median of 20): OpenImageIO -> direct, same bytes")
        for name, t_oiio, t_direct, same in exr_table(exrs):
            print(f"  {name:56s} {t_oiio:6.2f} -> {t_direct:6.2f}  {'yes' if same else 'NO'}")
