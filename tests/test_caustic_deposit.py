"""The compiled deposit (``caustic_mesh.deposit``) against a reference kept here: the
block-at-a-time loop it replaced (every block carrying its own 9 x 9 vertices, each cell
spread as it is made).

Oracle: on the deposits of realistic maps -- the seeded pool waves, 1 cm to 8 cm bins with
1, 2 and 4 source vertices per bin side, a floor beyond the first focus (folded cells) and a
wall whose beam path changes across the patch, every bin wanted and only a scatter of them
(culled blocks) -- the two give the same map to 1e-5 relative (1/40 of an 8-bit step; the
deposit is built to sum the same terms in the same order, so it is in fact equal bit for bit
here). The inputs are checked to hold what they are meant to: folded cells and culled blocks."""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import pytest

from blendgen.physics.surface import caustic_map as cmap
from blendgen.physics.surface import caustic_mesh as cm
from blendgen.physics.surface import optics as sf

_ref_jit = nb.njit(nogil=True)
_ref_sum = nb.njit(nogil=True, fastmath={"reassoc", "contract"})


@_ref_sum
def _ref_row(cx, sx, cy, sy, ax, ay, xs, y, path_b, deflect, i0, i1, out_x, out_y):
    ny, nx = path_b.shape
    jj = min(max(int(math.floor(y)), 0), ny - 1)
    for i in range(i0, i1):
        gx = 0.0
        gy = 0.0
        for w in range(ax.size):
            c = cx[i, w] * cy[w] - sx[i, w] * sy[w]
            gx += ax[w] * c
            gy += ay[w] * c
        dx = deflect[0] * gx + deflect[1] * gy
        dy = deflect[2] * gx + deflect[3] * gy
        lb = path_b[jj, min(max(int(math.floor(xs[i])), 0), nx - 1)]
        for _ in range(2):
            lx, ly = xs[i] + lb * dx, y + lb * dy
            lb = path_b[min(max(int(math.floor(ly)), 0), ny - 1), min(max(int(math.floor(lx)), 0), nx - 1)]
        out_x[i - i0] = xs[i] + lb * dx
        out_y[i - i0] = y + lb * dy


@_ref_jit
def _ref_overlap(lo, hi, k):
    return max(0.0, min(hi, k + 1.0) - max(lo, k))


@_ref_jit
def _ref_cell(E, ax, ay, bx, by, cx, cy, dx, dy, e):
    ny, nx = E.shape
    area = 0.5 * (
        abs((bx - ax) * (cy - ay) - (cx - ax) * (by - ay)) + abs((cx - ax) * (dy - ay) - (dx - ax) * (cy - ay))
    )
    wx = max(ax, bx, cx, dx) - min(ax, bx, cx, dx)
    wy = max(ay, by, cy, dy) - min(ay, by, cy, dy)
    scale = math.sqrt(area / (wx * wy)) if wx * wy > 1e-12 else 0.0
    wx, wy = max(wx * scale, 1e-6), max(wy * scale, 1e-6)
    mx, my = 0.25 * (ax + bx + cx + dx), 0.25 * (ay + by + cy + dy)
    x0, x1, y0, y1 = mx - 0.5 * wx, mx + 0.5 * wx, my - 0.5 * wy, my + 0.5 * wy
    i0, i1 = max(int(math.floor(x0)), 0), min(int(math.floor(x1)), nx - 1)
    j0, j1 = max(int(math.floor(y0)), 0), min(int(math.floor(y1)), ny - 1)
    norm = e / (wx * wy)
    for j in range(j0, j1 + 1):
        fy = _ref_overlap(y0, y1, j)
        for i in range(i0, i1 + 1):
            E[j, i] += norm * fy * _ref_overlap(x0, x1, i)


@_ref_jit
def _ref_deposit(cx, sx, cy, sy, ax, ay, xs, ys, path_b, deflect, wanted, cell_area, slack):
    """The block-at-a-time deposit: (map, blocks skipped, blocks, folded cells traced)."""
    E = np.zeros((wanted.shape[0] - 1, wanted.shape[1] - 1), np.float32)
    B = cm.BLOCK
    nbx, nby = (xs.size - 2) // B + 1, (ys.size - 2) // B + 1
    ci = np.minimum(np.arange(nbx + 1) * B, xs.size - 1)
    cj = np.minimum(np.arange(nby + 1) * B, ys.size - 1)
    ccx, csx, cxs = cx[ci], sx[ci], xs[ci]
    QX, QY = np.empty((nby + 1, nbx + 1)), np.empty((nby + 1, nbx + 1))
    for j in range(nby + 1):
        _ref_row(ccx, csx, cy[cj[j]], sy[cj[j]], ax, ay, cxs, ys[cj[j]], path_b, deflect, 0, nbx + 1, QX[j], QY[j])
    PX, PY = np.empty((B + 1, B + 1)), np.empty((B + 1, B + 1))
    skipped, folded = 0, 0
    for bj in range(nby):
        for bi in range(nbx):
            if not cm._block_wanted(QX, QY, bj, bi, slack, wanted):
                skipped += 1
                continue
            i0, i1 = bi * B, min((bi + 1) * B, xs.size - 1) + 1
            j0, j1 = bj * B, min((bj + 1) * B, ys.size - 1) + 1
            for j in range(j0, j1):
                _ref_row(cx, sx, cy[j], sy[j], ax, ay, xs, ys[j], path_b, deflect, i0, i1, PX[j - j0], PY[j - j0])
            for j in range(j1 - j0 - 1):
                for i in range(i1 - i0 - 1):
                    ux, uy = PX[j, i + 1] - PX[j, i], PY[j, i + 1] - PY[j, i]
                    vx, vy = PX[j + 1, i] - PX[j, i], PY[j + 1, i] - PY[j, i]
                    folded += ux * vy - uy * vx < 0  # the cell landed turned over: past a focus
                    _ref_cell(
                        E,
                        PX[j, i],
                        PY[j, i],
                        PX[j, i + 1],
                        PY[j, i + 1],
                        PX[j + 1, i + 1],
                        PY[j + 1, i + 1],
                        PX[j + 1, i],
                        PY[j + 1, i],
                        cell_area,
                    )
    return E, skipped, nbx * nby, folded


def _deposits(bin_m: float, per_bin: int, wall: bool, sparse: bool, depth_m: float):
    """(new, reference (map, skipped, blocks, folded)) of one ``caustic_map._deposit``: the
    pool waves (2 m/s wind), a sun 30 deg off the zenith, 96 x 80 bins, beam path ``depth_m``
    (a wall: rising by 2 m across the patch), every bin traced or a sparse scatter of them."""
    waves = sf.waves_for(2026, 2.0)  # 24 waves, the shortest 0.26 m
    grid = cmap.Patch(0.37, -1.21, bin_m, (80, 96))
    D = np.asarray(sf.sun_deflection([0.5, 0.0, -math.sqrt(0.75)]), np.float64).reshape(2, 2)
    path = np.full(grid.shape, depth_m)
    if wall:
        path = path + np.linspace(0.0, 2.0, grid.shape[1])[None, :]
    traced = None
    if sparse:
        rng = np.random.default_rng(4)
        marks = np.zeros(grid.shape, bool)
        marks[rng.integers(0, 80, 12), rng.integers(0, 96, 12)] = True
        marks[30:40, 60:75] = True
        traced = cmap._dilate(marks, 3)
    got: dict = {}
    real = cm.deposit

    def both(*a):
        got["ref"] = _ref_deposit(*a)
        got["new"] = real(*a)
        return got["new"].copy()  # _deposit writes the untraced bins' 1 into what it gets

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cm, "deposit", both)
        cmap._deposit(waves, grid, path, 0.7, D, traced, per_bin)
    return got["new"], got["ref"]


@pytest.mark.parametrize(
    "bin_m, per_bin",
    [(0.01, 1), (0.02, 2), (0.04, 4), (0.08, 4)],
)
@pytest.mark.parametrize("wall", [False, True])
@pytest.mark.parametrize("sparse", [False, True])
def test_deposit_equals_the_block_at_a_time_reference(bin_m, per_bin, wall, sparse):
    depth = 6.0 if bin_m <= 0.02 else 9.0  # beyond the first focus of the shortest waves
    new, (ref, skipped, blocks, folded) = _deposits(bin_m, per_bin, wall, sparse, depth)
    assert folded > 0  # folded cells were traced
    assert skipped > 0 or bin_m >= 0.08  # culled blocks (beyond the reach; and far from the sparse bins)
    assert np.std(ref) > 0.1  # a real pattern
    np.testing.assert_allclose(new, ref, rtol=1e-5, atol=1e-6)
