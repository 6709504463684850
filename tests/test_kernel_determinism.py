"""Datasets keep their bytes whether the compiled particle (and caustic) kernels were just compiled
or loaded from numba's cache. With fast-math flags that let LLVM choose its own rounding (reassociation,
fused multiply-add, approximate sqrt/division), a kernel compiled in the same process as its
caller (and inlined into it) rounded differently from the cached one: a first run on a fresh
machine gave other low bits than every later run (up to 3e-5 linear, enough to flip 8-bit pixels
and break ``dockbench verify``)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.integration  # two fresh interpreters compile the kernels

SCRIPT = textwrap.dedent("""
    import hashlib, math
    import numpy as np
    from blendgen.geometry import intrinsics_from_hfov, make_T
    from blendgen.pipeline import compose
    from blendgen.tools.bench import particle_bench as pb
    K = intrinsics_from_hfov(160, 120, math.radians(60.0))
    R = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    h = hashlib.sha256()
    for dist in ("power_law", "uniform"):            # specks and anti-aliased ellipses, lamp, lens
        st = pb._state(20000, dist, True)
        rng = np.random.default_rng(5)
        passes = {"rgb": rng.uniform(0, 0.5, (120, 160, 3)).astype(np.float32),
                  "range_m": rng.uniform(1, 14, (120, 160)).astype(np.float32),
                  "index": np.zeros((120, 160), np.int32)}
        for i in range(3):                          # streaks from the previous pose, drift between
            seen, occ = compose.add_particles(passes, st, K, make_T(R, [0.5 + 0.1 * i, 0.0, 2.0]), t_s=0.1 * i)
            for a in (seen["rgb"], seen["range_m"], occ, st.field.positions):
                h.update(np.ascontiguousarray(a).tobytes())
            st.advance()
    from blendgen.physics.surface import caustic_map as cmap, optics as sf  # the caustics' compiled deposit
    waves, patch = sf.waves_for(7, 3.0), cmap.Patch(1.3, -0.7, 0.02, (120, 150))
    sun = sf.sun_deflection([0.4, 0.2, -0.9])
    for scattering in (0.0, 0.05):
        h.update(cmap.light_map(waves, patch, 3.0, 0.4, sun, scattering, 0.92).tobytes())
    print(h.hexdigest())
""")


def _digest(cache_dir) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_freshly_compiled_and_cached_kernels_give_the_same_bytes(tmp_path):
    compiled = _digest(tmp_path)  # empty cache: every kernel compiled in this process
    cached = _digest(tmp_path)  # the same kernels loaded from the cache
    assert len(compiled) == 64 and compiled == cached
