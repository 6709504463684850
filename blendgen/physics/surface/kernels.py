"""Compiled per-pixel loops for the surfaces the camera sees (numba): their normals and where
a reflected ray meets them.

:func:`reflect` marches rays (the surface's total internal reflection) through the camera's
range pass (screen-space reflection). :func:`normals` replaces a chain of ~12 numpy passes
over the (h, w, 3) interleaved grid (differences, cross product, norm, orientation, masking:
~15 ms on a 640x480 frame) with one pass (~2 ms); ``surface_light.surface_normals`` states
the law and calls it. numba, like
:mod:`blendgen.physics.particles.kernels` (render extra; compiled once per machine).
"""

from __future__ import annotations

import math

try:
    import numba as nb
except ImportError as exc:  # pragma: no cover - the render extra installs it
    raise ImportError("the surface kernels need numba: pip install 'dockbench[render]'") from exc


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


@nb.njit(cache=True, nogil=True)
def _pixel(c0, c1, c2, K, range_m):
    """The pixel (flat index; -1 outside the image or behind the camera) a camera-frame point
    (m) projects to, and its squared range from the camera less the squared range pass there
    (> 0: the point is behind the surface the camera sees at that pixel)."""
    h, w = range_m.shape
    if c2 < 1e-3:
        return -1, 0.0
    iz = 1.0 / c2
    u = (K[0, 0] * c0 + K[0, 1] * c1) * iz + K[0, 2]
    v = K[1, 1] * c1 * iz + K[1, 2]
    if not (-0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5):
        return -1, 0.0
    iu, iv = int(u + 0.5), int(v + 0.5)
    rb = range_m[iv, iu]
    return iv * w + iu, (c0 * c0 + c1 * c1 + c2 * c2) - rb * rb


@nb.njit(cache=True, nogil=True)
def reflect(P, E, C, Rt, K, range_m, max_s, pix, dist):
    """Screen-space ray march: for each ray from ``P`` (n, 3) along unit ``E`` (n, 3) (world,
    m), the first surface of the camera's image it meets: ``pix`` (n,) its flat pixel index (-1:
    the ray leaves the image, passes behind the camera, goes beyond every surface of the range
    pass or beyond ``max_s``) and ``dist`` (n,) the distance along the ray (m). The camera at
    ``C`` (3,), ``Rt`` (3, 3) camera from world, ``K`` (3, 3), ``range_m`` (h, w) its range pass
    (inf: nothing). A ray meets the surface of a pixel where it passes behind it; steps of
    5 cm + 5 % of the distance, the crossing refined by bisection, and kept only when the ray
    is behind by less than a step (else it passed behind an object, as behind the dock, and
    marches on)."""
    far = 0.0  # no surface is farther from the camera than this
    for v in range(range_m.shape[0]):
        for u in range(range_m.shape[1]):
            if range_m[v, u] < math.inf:
                far = max(far, range_m[v, u])
    far2 = (far + 0.5) ** 2
    for i in range(P.shape[0]):
        pix[i], dist[i] = -1, 0.0
        d0, d1, d2 = P[i, 0] - C[0], P[i, 1] - C[1], P[i, 2] - C[2]
        a0 = Rt[0, 0] * d0 + Rt[0, 1] * d1 + Rt[0, 2] * d2  # start, camera frame
        a1 = Rt[1, 0] * d0 + Rt[1, 1] * d1 + Rt[1, 2] * d2
        a2 = Rt[2, 0] * d0 + Rt[2, 1] * d1 + Rt[2, 2] * d2
        e0 = Rt[0, 0] * E[i, 0] + Rt[0, 1] * E[i, 1] + Rt[0, 2] * E[i, 2]  # direction, camera frame
        e1 = Rt[1, 0] * E[i, 0] + Rt[1, 1] * E[i, 1] + Rt[1, 2] * E[i, 2]
        e2 = Rt[2, 0] * E[i, 0] + Rt[2, 1] * E[i, 1] + Rt[2, 2] * E[i, 2]
        ae = a0 * e0 + a1 * e1 + a2 * e2  # d|c|^2/ds = 2 (ae + s): the range grows once s > -ae
        lo, s = 0.0, 0.02
        while s < max_s:
            c0, c1, c2 = a0 + s * e0, a1 + s * e1, a2 + s * e2
            p, behind = _pixel(c0, c1, c2, K, range_m)
            if p < 0 or (c0 * c0 + c1 * c1 + c2 * c2 > far2 and ae + s > 0):
                break  # left the image, or going away beyond every surface
            if behind > 0:
                x, y = lo, s
                for _ in range(8):
                    m = 0.5 * (x + y)
                    pm, bm = _pixel(a0 + m * e0, a1 + m * e1, a2 + m * e2, K, range_m)
                    if pm >= 0 and bm > 0:
                        y = m
                    else:
                        x = m
                c0, c1, c2 = a0 + y * e0, a1 + y * e1, a2 + y * e2
                pb, bb = _pixel(c0, c1, c2, K, range_m)
                r = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                if pb >= 0 and r - math.sqrt(max(r * r - bb, 0.0)) < 0.05 + 0.05 * y + (s - lo):
                    pix[i], dist[i] = pb, y
                    break
            lo = s
            s += 0.05 + 0.05 * s
