"""Compiled per-pixel passes of the sensor model (numba): the same float32 operations, in the
same order, as the numpy chain they replace in :meth:`blendgen.physics.camera.sensor.SensorModel.apply`
(so the 8-bit images are identical), in one pass over the pixels instead of about ten.

:func:`charge` is the mean charge of an exposure; :func:`shot_read_signal` turns it and a
frame of standard normal draws (drawn by numpy's Generator beforehand, so the random stream is
unchanged) into the signal as a fraction of full scale. numba, like
:mod:`blendgen.physics.surface.kernels` (render extra; compiled once per machine).
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba as nb
except ImportError as exc:  # pragma: no cover - the render extra installs it
    raise ImportError("the sensor kernels need numba: pip install 'dockbench[render]'") from exc


@nb.njit(cache=True, nogil=True)
def _charge(x, scale, out):
    zero = np.float32(0.0)
    for i in range(x.size):
        v = x[i] * scale
        out[i] = v if v > zero else zero  # NaN and negatives -> 0, as np.fmax(v, 0)


def charge(linear: np.ndarray, e_per_unit: np.float32) -> np.ndarray:
    """Mean collected charge (H, W, 3) float32 electrons: ``max(linear * e_per_unit, 0)``
    (``linear`` float32 radiance; NaN -> 0). A new C-contiguous array."""
    x = np.ascontiguousarray(linear, np.float32)
    out = np.empty_like(x)
    _charge(x.ravel(), np.float32(e_per_unit), out.ravel())
    return out


@nb.njit(cache=True, nogil=True)
def _shot_read(mu, e, dark, cap, r2, well, scale):
    zero, one = np.float32(0.0), np.float32(1.0)
    for i in range(mu.size):
        m = mu[i] + dark
        m = m if m < cap else cap  # np.minimum(mu, 4 full wells)
        lam = m if m > zero else zero  # np.fmax(., 0)
        sd = np.float32(math.sqrt(lam + r2))  # float32 sqrt (double then round: exact)
        v = e[i] * sd
        v = v + lam
        v = v if v < well else well  # saturates at the full well
        v = v if v > zero else zero
        y = v * scale
        e[i] = y if y < one else one


def shot_read_signal(
    mu: np.ndarray, normals: np.ndarray, dark_e: np.float32, read_noise_e: float, full_well_e: float, scale: np.float32
) -> np.ndarray:
    """Signal (same shape as ``mu``, float32, in [0, 1], written into ``normals``): the charge
    ``mu`` (electrons, >= 0) plus ``dark_e``, capped at 4 full wells, with shot and read noise as
    one Normal of the same mean and variance (``normals``: standard normal draws of ``mu``'s
    shape, C-contiguous float32), saturated at ``full_well_e``, times ``scale`` (full scale per
    electron) and clipped at 1. Only for sensors whose read noise hides the photon count's skew
    (:func:`blendgen.physics.camera.sensor._exact_poisson` draws nothing exactly)."""
    m = np.ascontiguousarray(mu, np.float32)
    r2 = np.float32(read_noise_e) ** 2
    _shot_read(
        m.ravel(),
        normals.ravel(),
        np.float32(dark_e),
        np.float32(4 * full_well_e),
        np.float32(r2),
        np.float32(full_well_e),
        np.float32(scale),
    )
    return normals
