"""Compiled per-pixel loop for the surfaces the camera sees (numba): their normals.

:func:`normals` replaces a chain of ~12 numpy passes over the (h, w, 3) interleaved grid
(differences, cross product, norm, orientation, masking: ~15 ms on a 640x480 frame) with one
pass (~2 ms); ``surface_light.surface_normals`` states the law and calls it. numba, like
:mod:`blendgen.physics.particle_kernels` (render extra; compiled once per machine).
"""
from __future__ import annotations

import math

try:
    import numba as nb
except ImportError as exc:                      # pragma: no cover - the render extra installs it
    raise ImportError("surface normals need numba: pip install 'dockbench[render]'") from exc


@nb.njit(cache=True, nogil=True)
def _neighbours(k: int, n: int) -> tuple[int, int]:
    """The two samples a difference at index k of n takes: central inside, one-sided at the border."""
    if k == 0:
        return 0, 1
    if k == n - 1:
        return n - 2, n - 1
    return k - 1, k + 1


@nb.njit(cache=True, nogil=True)
def normals(P, out):
    """Fill ``out`` (h, w, 3) with the unit normals of the grid of points ``P`` (h, w, 3),
    h, w >= 2: ``du x dv`` (du along a row, dv down a column; central differences, one-sided at
    the border) divided by its length and turned toward the origin (``n . P <= 0``); 0 where
    the length is 0 or not finite (a nan neighbour: nothing hit)."""
    h, w = P.shape[0], P.shape[1]
    for j in range(h):
        j0, j1 = _neighbours(j, h)
        for i in range(w):
            i0, i1 = _neighbours(i, w)
            ux, uy, uz = P[j, i1, 0] - P[j, i0, 0], P[j, i1, 1] - P[j, i0, 1], P[j, i1, 2] - P[j, i0, 2]
            vx, vy, vz = P[j1, i, 0] - P[j0, i, 0], P[j1, i, 1] - P[j0, i, 1], P[j1, i, 2] - P[j0, i, 2]
            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if not (norm > 0.0 and norm < math.inf):
                out[j, i, 0] = out[j, i, 1] = out[j, i, 2] = 0.0
                continue
            s = (-1.0 if nx * P[j, i, 0] + ny * P[j, i, 1] + nz * P[j, i, 2] > 0.0 else 1.0) / norm
            out[j, i, 0], out[j, i, 1], out[j, i, 2] = nx * s, ny * s, nz * s
