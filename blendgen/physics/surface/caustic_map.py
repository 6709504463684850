"""Caustics by the forward ray map: every surface point's sunlight carried to its receiver.

The refracted sun ray that crosses the surface at ``xi`` is deflected by ``D grad eta(xi)``
(:func:`blendgen.physics.surface.optics.sun_deflection`, Snell's law to first order in the slope),
so after a beam path ``L`` it lands ``L D grad eta`` from its straight path (Schenck 1957;
Zaneveld, Boss & Barnard 2001). In the surface-crossing coordinates of the receivers (each
receiver point moved up its own sun beam to the mean surface) the landing point is
``xi + L(xi) D grad eta(xi)``, to first order whatever the receiver's orientation: a floor,
a wall and the dock differ only in their map of beam paths ``L``. Beyond the first focus
this map folds and several surface points light one receiver point; the irradiance is the
sum over all of them. So the surface is carried forward as a mesh
(:mod:`blendgen.physics.surface.caustic_mesh`), each cell's sunlight added where it lands:
all preimages counted, energy conserved by construction (mean 1 over a flat-surface value of 1).

Then two blurs:

- the sun's disc, uniform of radius ``R = L theta_sun / n``: on the sharp map a disc mean
  around each bin with the bin's own path (``caustic_mesh.disc_blur``); in the scattered map's
  Fourier product its transfer function ``2 J1(k R) / (k R)`` (:func:`sun_transfer`);
- light scattered on the way down (small-angle theory, Wells 1973, "Theory of small angle
  scattering", AGARD LS-61): the beam keeps ``M_k = exp(-b [L - (1 - e^{-a k L}) / (a k)])``
  of a pattern of wavenumber k, ``a = (1 - g) / sqrt(g)`` the width of the small-angle
  Henyey-Greenstein kernel. The unscattered share ``e^{-bL}`` keeps the sharp map; the rest
  is the map blurred over ``~a L`` (:func:`scattered_transfer`), made on bins of ``~a L / 4``.

Judge: ``dockbench bench caustics`` (a Cycles photon map: sun rays refracted by the same
glass surface and histogrammed on the floor). Units: metres, beam paths along the refracted
sun; arrays (ny, nx) are bins of a :class:`Patch`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from blendgen.physics.surface import caustic_mesh as cm
from blendgen.physics.surface import optics as sf

SLOPE_SIGMAS = 5.0  # reach of a deflection: this many rms slopes (capped by the sum of all)
FINEST_BIN_M = 0.01  # bins of a frame's maps: the sample's footprint, rounded up to 1 cm x 2^l
COARSEST_BIN_M = 0.32  # a footprint wider than this averages the network out (cells 0.4-1 m)
#: Source vertices: ``SOURCE_PER_BIN`` per bin side, more (up to ``MAX_PER_BIN``) where a bin
#: is wider than ``1 / MESH_PER_WAVELENGTH`` of the shortest wave; waves shorter than
#: ``MESH_PER_WAVELENGTH / 3`` mesh cells are left out of the mesh (their focusing is finer
#: than the bin, and after the path they shift the light by ``L |D grad eta|``, a few cm).
#: Against 8 per bin side (1 cm bins, 2 m/s waves, sun 18 deg off the zenith), the rms
#: difference of a map is 0.8 / 2.1 / 1.7 / 1.3 % of its contrast at 0.3 / 1 / 3 / 6 m with 1
#: per side, 0.4 / 0.8 / 0.5 / 0.4 % with 2 (2.5-3x the time). A single folded wave
#: (tests/test_caustic_map.py) 3 focal lengths down, 0.25 m long: 2-3.5 % of its contrast
#: with a vertex every 1 cm (24 per wavelength), 13-19 % every 2 cm.
SOURCE_PER_BIN = 1
MAX_PER_BIN = 4
MESH_PER_WAVELENGTH = 24
#: The scattered part's own deposit (bins ``ratio`` x coarser, sized from its blur ``a L``:
#: a bin is a quarter to an eighth of it): this many vertices per bin side, so a vertex every
#: ``a L / 16`` to ``a L / 8``. Against the Cycles photon map (``bench caustics``, Jerlov IB and
#: 1C, floors 1-8 m) the contrast stays within 0.004 of the ~1 cm mesh's and the PSD error
#: is the same or lower; with 1 per side the contrast in 1C at 4 m falls 8 % further (to -22 %).
SCATTERED_PER_BIN = 2
BAND_START_M = 0.25  # frame groups: beam paths in octaves from here (the blurs' parameters)


@dataclass(frozen=True)
class Patch:
    """Bins of the surface-crossing coordinates: origin ``(x0, y0)`` (m, the first bin's
    corner), ``bin_m`` (m), ``shape`` (ny, nx)."""

    x0: float
    y0: float
    bin_m: float
    shape: tuple[int, int]

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Bin centres, x (nx,) and y (ny,) in metres."""
        ny, nx = self.shape
        return (self.x0 + (np.arange(nx) + 0.5) * self.bin_m, self.y0 + (np.arange(ny) + 0.5) * self.bin_m)

    def padded(self, pad: int) -> Patch:
        """The patch ``pad`` bins wider on every side."""
        return Patch(
            self.x0 - pad * self.bin_m,
            self.y0 - pad * self.bin_m,
            self.bin_m,
            (self.shape[0] + 2 * pad, self.shape[1] + 2 * pad),
        )


def reach_m(waves: sf.WaveField, path_m: float, deflect: np.ndarray) -> float:
    """Farthest (m) a ray can land from its straight path at beam path ``path_m``:
    ``L ||D|| min(5 rms slope, sum of the waves' slope amplitudes)``."""
    slope_amp = waves.amp * np.hypot(waves.k[:, 0], waves.k[:, 1])
    s = min(SLOPE_SIGMAS * math.sqrt(float((slope_amp**2).sum() / 2)), float(slope_amp.sum()))
    return float(path_m) * _spectral_norm(deflect) * s


def _spectral_norm(D) -> float:
    """Largest singular value of the 2 x 2 deflection matrix ``D`` (its 2-norm), kept per
    matrix: a frame's every deposit asks for the same one."""
    return _spectral_norm_of(tuple(np.asarray(D, np.float64).ravel().tolist()))


@functools.lru_cache(maxsize=64)
def _spectral_norm_of(entries: tuple[float, ...]) -> float:
    return float(np.linalg.norm(np.array(entries).reshape(2, 2), 2))


def sun_transfer(k: np.ndarray, path_m, n: float = sf.N_WATER) -> np.ndarray:
    """Transfer function of the sun's disc (uniform, radius ``R = L theta_sun / n``) at
    wavenumbers k (rad/m): ``2 J1(k R) / (k R)``."""
    from scipy.special import j1

    kr = k * path_m * sf.SUN_RADIUS_RAD / n
    return np.where(kr > 1e-6, 2 * j1(kr) / np.where(kr > 1e-6, kr, 1.0), 1.0)


def scattered_transfer(k: np.ndarray, path_m: float, scattering: float, g: float) -> np.ndarray:
    """Transfer function of the scattered part of the beam at wavenumbers k (rad/m): the whole
    beam's ``M_k`` (module docstring) less its unscattered share ``e^{-bL}``, over
    ``1 - e^{-bL}``. 1 at k = 0; 0 but the mean for ``g <= 0`` (no forward peak, no pattern)."""
    if g <= 0:
        return (k == 0).astype(float)
    a = _kernel_width(g)
    ak = np.maximum(a * k, 1e-12)
    whole = np.exp(-scattering * (path_m - (-np.expm1(-ak * path_m)) / ak))
    unscattered = math.exp(-scattering * path_m)
    return (whole - unscattered) / (1.0 - unscattered)


def _kernel_width(g: float) -> float:
    """Width ``a = (1 - g) / sqrt(g)`` (rad) of the small-angle HG kernel."""
    g = min(max(g, 1e-3), 0.9999)
    return (1.0 - g) / math.sqrt(g)


def _slack_bins(waves: sf.WaveField, path_m: float, bin_m: float, D: np.ndarray) -> float:
    """How far (bins) a source vertex can land from the box of its block's corners: 1 plus the
    bilinear interpolation error of the displacement ``L D grad eta`` over a block of side
    ``s = BLOCK / 2`` bins, ``s^2 / 4 max|second derivative|``, the third derivatives of eta
    bounded by ``sum a |k|^3``."""
    third = float((waves.amp * np.hypot(waves.k[:, 0], waves.k[:, 1]) ** 3).sum())
    side_m = cm.BLOCK / 2 * bin_m
    return 1.0 + side_m**2 / 4 * path_m * _spectral_norm(D) * third / bin_m


def _deposit(
    waves: sf.WaveField,
    grid: Patch,
    path_m: np.ndarray,
    t: float,
    D: np.ndarray,
    traced: np.ndarray | None,
    per_bin: int | None = None,
) -> np.ndarray:
    """Sunlight per bin (ny, nx) over its flat-surface value on ``grid``, before any blur:
    a source mesh of ``per_bin`` vertices per bin side (None: as ``SOURCE_PER_BIN`` and
    ``MAX_PER_BIN`` say; the waves it cannot resolve left out) over the grid plus the reach of
    a deflection, carried by ``path_m`` (ny, nx) (m, defined at every bin). ``traced`` (bool):
    the bins to get right (None: all); the others hold the flat surface's 1."""
    b, L = grid.bin_m, float(path_m.max())
    reach = int(math.ceil(reach_m(waves, L, D) / b)) + 1
    wavelength = 2 * math.pi / np.hypot(waves.k[:, 0], waves.k[:, 1])
    if per_bin is None:
        per_bin = min(
            max(SOURCE_PER_BIN, math.ceil(b * MESH_PER_WAVELENGTH / float(wavelength.min()) - 1e-9)), MAX_PER_BIN
        )
    step = 1.0 / per_bin
    keep = wavelength >= MESH_PER_WAVELENGTH / 3 * b * step
    if not keep.any():
        return np.ones(grid.shape, np.float32)
    if not keep.all():
        waves = sf.WaveField(waves.amp[keep], waves.k[keep], waves.omega[keep], waves.phase[keep])
    xs = -reach + step * np.arange(per_bin * (grid.shape[1] + 2 * reach) + 1)  # bin units
    ys = -reach + step * np.arange(per_bin * (grid.shape[0] + 2 * reach) + 1)
    cx, sx = _trig_table(grid.x0 + b * xs[0], b * step, xs.size, waves.k[:, 0], 0.0)
    cy, sy = _trig_table(grid.y0 + b * ys[0], b * step, ys.size, waves.k[:, 1], waves.phase - t * waves.omega)
    sat = _summed_area(np.ones(grid.shape, bool) if traced is None else traced)
    E = cm.deposit(
        cx,
        sx,
        cy,
        sy,
        waves.amp * waves.k[:, 0],
        waves.amp * waves.k[:, 1],
        xs,
        ys,
        np.ascontiguousarray(path_m / b, np.float64),
        np.ascontiguousarray(D, np.float64).ravel(),
        sat,
        step * step,
        _slack_bins(waves, L, b, D),
    )
    if traced is not None:
        E[~traced] = 1.0  # the flat surface's light, for the blurs' tails
    return E


def _summed_area(mask: np.ndarray) -> np.ndarray:
    """Summed-area table (ny + 1, nx + 1) int64 of a bool (ny, nx): the count of True bins
    above and left of each corner (OpenCV's integral, a zero first row and column)."""
    import cv2

    return cv2.integral(np.ascontiguousarray(mask).view(np.uint8)).astype(np.int64)


def _trig_table(start_m: float, spacing_m: float, n: int, k: np.ndarray, phase) -> tuple[np.ndarray, np.ndarray]:
    """``cos`` and ``sin`` (n, waves) of ``k (start + spacing j) + phase`` for j < n (positions
    in m, ``k`` (waves,) rad/m, ``phase`` rad, a number or (waves,)), by angle addition: exact
    at every ``~sqrt(n)``-th position and at the offsets within such a step, the rest
    ``cos(a + b) = cos a cos b - sin a sin b`` (a few ulp from the direct values, ~2 sqrt(n)
    transcendentals per wave instead of 2n)."""
    step = max(1, int(math.isqrt(max(n - 1, 0))) + 1)
    coarse = np.multiply.outer(start_m + spacing_m * step * np.arange(-(-n // step)), k) + phase
    fine = np.multiply.outer(spacing_m * np.arange(step), k)
    ca, sa, cb, sb = np.cos(coarse)[:, None], np.sin(coarse)[:, None], np.cos(fine), np.sin(fine)
    shape = (-1, k.size)
    cos = (ca * cb - sa * sb).reshape(shape)[:n]
    sin = (sa * cb + ca * sb).reshape(shape)[:n]
    return cos, sin


def _mark(shape: tuple[int, int], j: np.ndarray, i: np.ndarray, offsets) -> np.ndarray:
    """(ny, nx) bool: the bins (j + dj, i + di) for every offset pair, clamped to the grid.
    The bins (j, i) (each (m,) int) lie in the grid and ``offsets`` is a run of consecutive
    integers holding 0, so this is the bins (j, i) dilated by the offsets' box."""
    import cv2

    out = np.zeros(shape, np.uint8)
    out.ravel()[j * shape[1] + i] = 1
    side, last = len(offsets), max(offsets)
    return cv2.dilate(out, np.ones((side, side), np.uint8), anchor=(last, last)).view(bool)


def _dilate(mask: np.ndarray, pad: int) -> np.ndarray:
    import cv2

    return cv2.dilate(np.ascontiguousarray(mask).view(np.uint8), np.ones((2 * pad + 1, 2 * pad + 1), np.uint8)).view(
        bool
    )


def _pad(a: np.ndarray, pad: int, edge: bool = False) -> np.ndarray:
    """``a`` (ny, nx) (float or bool) ``pad`` bins wider on every side: the new bins copies of
    the nearest edge bin (``edge``) or 0 (False); as ``np.pad``, by OpenCV's copyMakeBorder."""
    import cv2

    src = np.ascontiguousarray(a)
    flag = a.dtype == np.bool_
    border = cv2.BORDER_REPLICATE if edge else cv2.BORDER_CONSTANT
    out = cv2.copyMakeBorder(src.view(np.uint8) if flag else src, pad, pad, pad, pad, border, value=0)
    return out.view(bool) if flag else out


def _scattered(E: np.ndarray, grid: Patch, path_m: np.ndarray, scattering: float, g: float, n: float) -> np.ndarray:
    """The deposit blurred by the scattered light's transfer function (and the sun's disc)
    at the least and largest path of the grid, blended per bin linearly in log path. The
    transfer functions depend on |k| alone: made on the rows of ky >= 0 (a row of -ky is
    the same numbers) and copied to the others."""
    ny = grid.shape[0]
    half = ny // 2 + 1
    ky = np.fft.fftfreq(ny, grid.bin_m)[:half]
    k = 2 * np.pi * np.hypot(*np.meshgrid(np.fft.rfftfreq(grid.shape[1], grid.bin_m), ky))
    rows = np.r_[0:half, (ny - 1) // 2 : 0 : -1]  # row of each frequency row's |ky| in k
    spectrum = np.fft.rfft2(E)
    lo, hi = max(float(path_m.min()), 1e-3), max(float(path_m.max()), 1e-3)
    maps = [
        np.fft.irfft2(spectrum * sun_transfer(k, L, n)[rows] * scattered_transfer(k, L, scattering, g)[rows], s=E.shape)
        for L in ((lo,) if hi < 1.01 * lo else (lo, hi))
    ]
    if len(maps) == 1:
        return maps[0]
    w = np.clip(np.log(np.maximum(path_m, lo) / lo) / math.log(hi / lo), 0.0, 1.0)
    return maps[0] + w * (maps[1] - maps[0])


def light_map(
    waves: sf.WaveField,
    patch: Patch,
    path_m,
    t: float,
    deflect=None,
    scattering: float = 0.0,
    g: float = 0.9,
    n: float = sf.N_WATER,
    wanted: np.ndarray | None = None,
) -> np.ndarray:
    """Sun irradiance over its flat-surface value (ny, nx) on ``patch``, time ``t`` (module
    docstring). ``path_m``: the beam path (m) to the receiver under each bin, a number or
    (ny, nx); ``deflect``: :func:`surface.sun_deflection` (None: the zenith); ``scattering``
    (1/m) and HG ``g`` of the water; ``wanted`` (ny, nx) bool: the bins that will be read
    (None: all; other bins are not valid, the light that lands far from every wanted bin is
    not traced). Each map is made with a margin as wide as its blur, so the patch's edges
    see the light that lands from outside it."""
    X, Y = np.meshgrid(*patch.centres())
    L = np.broadcast_to(np.asarray(path_m, np.float64), patch.shape)
    return _light_at(waves, patch, L, t, deflect, scattering, g, n, wanted, X.ravel(), Y.ravel(), L.ravel()).reshape(
        patch.shape
    )


def _light_at(
    waves: sf.WaveField,
    patch: Patch,
    L: np.ndarray,
    t: float,
    deflect,
    scattering: float,
    g: float,
    n: float,
    wanted: np.ndarray | None,
    x: np.ndarray,
    y: np.ndarray,
    path_m: np.ndarray,
    memo: dict | None = None,
) -> np.ndarray:
    """:func:`light_map` (bins' beam paths ``L`` (ny, nx)) read at points (x, y, path) (m,):
    ``e^{-b L} sharp + (1 - e^{-b L}) scattered``, each map read bilinearly. ``memo``: a dict
    kept for the same points, patch and waves (:class:`FrameCaustics`): the sharp reading and
    the deposit are made once for every water (they do not depend on it)."""
    D = np.asarray(sf.sun_deflection(None, n) if deflect is None else deflect, np.float64).reshape(2, 2)
    b = patch.bin_m
    memo = {} if memo is None else memo
    if "paths" not in memo:  # the least and largest path of the bins read
        sel = L if wanted is None else L[wanted]
        memo["paths"] = float(sel.min()), float(sel.max())
    lo, hi = memo["paths"]
    theta = sf.SUN_RADIUS_RAD / n
    pad = int(math.ceil(3 * hi * theta / b)) + 2
    a, turbid = _kernel_width(g), math.exp(-scattering * lo) < 0.999
    ratio = 2 ** max(0, int(math.floor(math.log2(max(a * lo / 4, b) / b)))) if turbid else 1
    if turbid and ratio == 1:  # the scattered blur is a few bins: one deposit serves both
        pad = max(pad, int(math.ceil(2 * a * hi / b)) + 2)
    if "sharp" not in memo:  # the sun-disc blurred map read at the points: the same at any pad >= its own
        memo["deposit"] = grid, Lg, E, look = _padded_deposit(waves, patch, L, t, D, wanted, pad)
        sharp = cm.disc_blur(E, (Lg * theta / b).astype(np.float64), np.ones(E.shape, bool) if look is None else look)
        memo["sharp"] = lookup(sharp, grid, x, y)
    out = memo["sharp"]
    if not turbid:
        return out
    if "path32" not in memo:
        memo["path32"] = np.asarray(path_m, np.float32)
    beam = np.exp(-scattering * memo["path32"])
    lit = beam * out  # the unscattered share of the sharp map
    rest = np.subtract(1.0, beam, out=beam)
    longest = 0.5 * float(np.hypot(waves.k[:, 0], waves.k[:, 1]).min())  # rad/m: twice the longest wave
    if float(scattered_transfer(np.array([longest]), lo, scattering, g)[0]) < 0.01:
        return np.add(lit, rest, out=lit)  # the scattered light keeps < 1 % of any pattern: its mean
    if ratio == 1:
        grid, Lg, E = _deposit_padded_by(memo, "deposit", waves, patch, L, t, D, wanted, pad)
        wide, wide_grid = _scattered(E, grid, Lg, scattering, g, n), grid
    else:
        wide, wide_grid = _coarse_scattered(waves, patch, L, wanted, ratio, t, D, scattering, g, n, memo)
    wide_at = lookup(wide, wide_grid, x, y)
    wide_at *= rest
    return np.add(lit, wide_at, out=lit)


def _deposit_padded_by(
    memo: dict, key, waves, patch: Patch, L: np.ndarray, t: float, D, marks, pad: int, per_bin: int | None = None
) -> tuple[Patch, np.ndarray, np.ndarray]:
    """(grid, beam paths, deposit) of :func:`_padded_deposit` at ``pad``, cut from the widest
    one made so far (``memo[key]``; its bins traced only by the wider margin reset to the flat
    1, as a deposit at ``pad`` leaves them) or made and kept when there is none as wide.
    ``per_bin``: mesh vertices per bin side, as :func:`_deposit`'s (kept with the deposit)."""
    if key in memo:
        grid, Lg, E, _ = memo[key]
        cut = (grid.shape[0] - patch.shape[0]) // 2 - pad
        if cut == 0:
            return grid, Lg, E
        if cut > 0:
            inner = (slice(cut, E.shape[0] - cut), slice(cut, E.shape[1] - cut))
            E = E[inner].copy()
            if marks is not None:
                E[~_dilate(_pad(marks, pad), pad)] = 1.0
            return patch.padded(pad), Lg[inner], E
    memo[key] = grid, Lg, E, _ = _padded_deposit(waves, patch, L, t, D, marks, pad, per_bin)
    return grid, Lg, E


def _padded_deposit(
    waves: sf.WaveField, patch: Patch, L: np.ndarray, t: float, D, marks, pad: int, per_bin: int | None = None
) -> tuple:
    """:func:`_deposit` on ``patch`` padded by ``pad`` bins, traced within ``pad`` of the
    ``marks`` bins (None: everywhere): (grid, its beam paths (edge values in the margin), the
    deposit, the padded ``marks`` or None). ``per_bin`` as :func:`_deposit`'s."""
    grid = patch.padded(pad)
    Lg = _pad(L, pad, edge=True)
    look = None if marks is None else _pad(marks, pad)
    return grid, Lg, _deposit(waves, grid, Lg, t, D, None if look is None else _dilate(look, pad), per_bin), look


def _coarse_scattered(
    waves,
    patch: Patch,
    L: np.ndarray,
    wanted,
    ratio: int,
    t: float,
    D,
    scattering: float,
    g: float,
    n: float,
    memo: dict | None = None,
) -> tuple[np.ndarray, Patch]:
    """The scattered part of :func:`light_map` made on bins ``ratio`` times coarser (a deposit
    of its own, :data:`SCATTERED_PER_BIN` mesh vertices per bin side, blurred over ``~a L``)
    and its grid; ``memo`` as :func:`_light_at`'s (the
    deposit kept per ``ratio``, cut to a narrower margin for a water of wider ``g``)."""
    coarse = Patch(
        patch.x0, patch.y0, patch.bin_m * ratio, (-(-patch.shape[0] // ratio) + 1, -(-patch.shape[1] // ratio) + 1)
    )
    cpad = int(math.ceil(2 * _kernel_width(g) * float(L.max()) / coarse.bin_m)) + 2
    jj = np.clip(np.arange(coarse.shape[0]) * ratio + ratio // 2, 0, patch.shape[0] - 1)
    ii = np.clip(np.arange(coarse.shape[1]) * ratio + ratio // 2, 0, patch.shape[1] - 1)
    memo = {} if memo is None else memo
    if ("marks", ratio) not in memo:
        memo["marks", ratio] = None if wanted is None else _coarse_marks(wanted, ratio, coarse.shape)
    marks = memo["marks", ratio]
    grid, Lg, E = _deposit_padded_by(
        memo, ("coarse", ratio), waves, coarse, L[np.ix_(jj, ii)], t, D, marks, cpad, SCATTERED_PER_BIN
    )
    return _scattered(E, grid, Lg, scattering, g, n), grid


def _coarse_marks(wanted: np.ndarray, ratio: int, shape: tuple[int, int]) -> np.ndarray:
    """(ny', nx') bool on bins ``ratio`` times coarser (``shape`` holding every one): the coarse
    bins of the ``wanted`` (ny, nx) bins and their 8 neighbours."""
    ny, nx = wanted.shape
    fine = np.zeros((-(-ny // ratio) * ratio, -(-nx // ratio) * ratio), bool)
    fine[:ny, :nx] = wanted
    j, i = np.nonzero(fine.reshape(fine.shape[0] // ratio, ratio, -1, ratio).any((1, 3)))
    return _mark(shape, j, i, (-1, 0, 1))


def lookup(M: np.ndarray, patch: Patch, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear value (m,) float32 of the map (ny, nx) at points (x, y) (m,), clamped to its
    edge bins (OpenCV's remap: the points are laid out in rows of 1024)."""
    import cv2

    m = np.size(x)
    rows = -(-m // 1024)
    fx, fy = np.zeros(rows * 1024, np.float32), np.zeros(rows * 1024, np.float32)
    fx[:m] = (np.asarray(x, np.float64) - patch.x0) / patch.bin_m - 0.5
    fy[:m] = (np.asarray(y, np.float64) - patch.y0) / patch.bin_m - 0.5
    out = cv2.remap(
        np.ascontiguousarray(M, np.float32),
        fx.reshape(rows, 1024),
        fy.reshape(rows, 1024),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.ravel()[:m]


def _levels(footprint_m: np.ndarray) -> np.ndarray:
    """Level l of each footprint (m,): bins of ``FINEST_BIN_M 2^l`` at least as wide as the
    footprint (1-2 times it: a pixel averages the pattern over its footprint, as a render's
    pixel filter does); -1 beyond ``COARSEST_BIN_M`` (the pattern averages to 1 there)."""
    f = np.maximum(np.nan_to_num(np.asarray(footprint_m, np.float64), nan=np.inf), FINEST_BIN_M)
    ok = f <= COARSEST_BIN_M
    return np.where(ok, np.ceil(np.log2(np.where(ok, f, 1.0) / FINEST_BIN_M) - 1e-9), -1).astype(np.int64)


def _group_patch(x: np.ndarray, y: np.ndarray, L: np.ndarray, b: float) -> tuple[Patch, np.ndarray, np.ndarray]:
    """The patch around points (x, y) (m,) with bins of ``b``, the bins bilinear reads at them
    (bool), and the beam path of every bin: the mean of its points', nearest elsewhere."""
    x0, y0 = math.floor(x.min() / b) * b - b, math.floor(y.min() / b) * b - b
    patch = Patch(x0, y0, b, (int(math.ceil((y.max() - y0) / b)) + 2, int(math.ceil((x.max() - x0) / b)) + 2))
    fi, fj = (x - x0) / b - 0.5, (y - y0) / b - 0.5
    wanted = _mark(patch.shape, np.floor(fj).astype(np.int64), np.floor(fi).astype(np.int64), (0, 1))
    own_j = np.clip(np.rint(fj), 0, patch.shape[0] - 1).astype(np.int64)
    own_i = np.clip(np.rint(fi), 0, patch.shape[1] - 1).astype(np.int64)
    return patch, wanted, _fill_nearest(own_j, own_i, L, patch.shape)


def _fill_nearest(
    j: np.ndarray, i: np.ndarray, values: np.ndarray, shape: tuple[int, int], block: int = 8
) -> np.ndarray:
    """(ny, nx) mean of ``values`` (m,) over the points in each bin (their bins ``j, i`` (m,));
    in a bin without any, the mean of the nearest block (``block`` x ``block`` bins) that has
    some (a Euclidean transform on the blocks)."""
    from scipy import ndimage

    ny, nx = shape
    by, bx = -(-ny // block), -(-nx // block)
    own = j * nx + i
    count = np.bincount(own, minlength=ny * nx).reshape(shape)
    total = np.bincount(own, values, minlength=ny * nx).reshape(shape)
    bins_block = (np.arange(ny)[:, None] // block * bx + np.arange(nx) // block).ravel()
    bc = np.zeros((by * block, bx * block), np.int64)
    bc[:ny, :nx] = count
    bc = bc.reshape(by, block, bx, block).sum((1, 3))
    bt = np.bincount(bins_block[own], values, minlength=by * bx).reshape(by, bx)
    if bc.all():
        coarse = bt / bc
    else:
        near = ndimage.distance_transform_edt(bc == 0, return_distances=False, return_indices=True)
        coarse = (bt / np.maximum(bc, 1))[near[0], near[1]]
    filled = np.repeat(np.repeat(coarse, block, 0), block, 1)[:ny, :nx]
    return np.where(count > 0, total / np.maximum(count, 1), filled)


class FrameCaustics:
    """:func:`frame_factor`'s points grouped once, ``factor(scattering, g)`` per water. A
    group's deposit and sharp (sun-disc blurred) map do not depend on the water, so a frame
    seen through several waters (the conditions of one render) makes them once; only the
    scattered part is made per water."""

    def __init__(self, waves: sf.WaveField, x, y, path_m, footprint_m, t: float, deflect=None, n: float = sf.N_WATER):
        self.waves, self.t, self.deflect, self.n = waves, t, deflect, n
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        L = np.maximum(np.asarray(path_m, np.float64), 0.0)
        level = _levels(footprint_m)
        band = np.floor(np.log2(np.maximum(L, BAND_START_M) / BAND_START_M)).astype(np.int64)
        key = np.where(level >= 0, band * 16 + level, -1).astype(np.int16)
        self.size = x.size
        self.groups: list[tuple] = []
        if not np.any(key >= 0):
            return
        order = np.argsort(key, kind="stable")  # 16-bit keys: a radix sort, O(m)
        starts = np.searchsorted(key[order], np.arange(-1, int(key.max()) + 2))
        for group in range(int(key.max()) + 1):
            sel = order[starts[group + 1] : starts[group + 2]]
            if sel.size:
                xs, ys, Ls = x[sel], y[sel], L[sel]
                patch, wanted, path = _group_patch(xs, ys, Ls, FINEST_BIN_M * 2 ** (group % 16))
                self.groups.append((sel, patch, path, wanted, xs, ys, Ls, {}))

    def factor(self, scattering: float = 0.0, g: float = 0.9) -> np.ndarray:
        """Sun irradiance over its flat-surface value (m,) float32 in water of ``scattering``
        (1/m) and HG ``g`` (:func:`frame_factor`)."""
        out = np.ones(self.size, np.float32)
        for sel, patch, path, wanted, xs, ys, Ls, memo in self.groups:
            out[sel] = _light_at(
                self.waves, patch, path, self.t, self.deflect, scattering, g, self.n, wanted, xs, ys, Ls, memo
            )
        return out


def frame_factor(
    waves: sf.WaveField,
    x,
    y,
    path_m,
    footprint_m,
    t: float,
    deflect=None,
    scattering: float = 0.0,
    g: float = 0.9,
    n: float = sf.N_WATER,
) -> np.ndarray:
    """Sun irradiance over its flat-surface value (m,) at m receiver points: ``x, y`` (m,) where
    each point's beam crossed the surface, ``path_m`` (m,) its slant beam path, ``footprint_m``
    (m,) the width of surface a sample stands for (its map is binned that coarse: a pixel sees
    the mean over its footprint; 1 beyond ``COARSEST_BIN_M``). Points are grouped by bin level
    and by octave of beam path; each group is one :func:`light_map` over its bounding box
    with every bin's own beam path (:class:`FrameCaustics`, for one water)."""
    return FrameCaustics(waves, x, y, path_m, footprint_m, t, deflect, n).factor(scattering, g)
