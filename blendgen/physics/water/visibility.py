"""Where a dock marker stops being visible in a water: the contrast-threshold prediction.

Pure numpy. Horizontal line of sight through uniform water, per RGB channel (docs/waters.md
derives it). A target of inherent radiance ``L_t`` seen against a background of inherent
radiance ``L_b`` (both at range ``r``, the same depth) has the apparent radiances
``L(r) = L_0 exp(-c r) + L_inf (1 - exp(-c r))`` (Duntley 1963; Mobley 1994, sec. 1.9), so
its apparent contrast against that background is::

    C(r) = (L_t - L_b) exp(-c r) / (L_b exp(-c r) + L_inf (1 - exp(-c r)))

With the water itself as background (``L_b = L_inf``) this is Duntley's
``C(r) = C_0 exp(-c r)``. The target is visible while ``|C(r)| >= C_t``, the contrast
threshold (0.02: Duntley 1963's threshold of the eye for large targets, used for cameras in
the absence of a detector model). An LED (disc of radius ``rho``, radiance
``I / (pi rho^2)``) smaller than a pixel fills a fraction ``pi rho^2 f^2 / r^2`` of it
(``f`` the focal length in pixels): the rest of the pixel is the dock face behind it. A
square marker also needs its cells resolved: ``f s / r >= MIN_PX_PER_CELL`` for a cell of
side ``s``. Not modelled: the glow of forward-scattered light, sensor noise and saturation,
the veil's change along a slanted ray.
"""

from __future__ import annotations

import math

import numpy as np

#: Contrast threshold (Duntley 1963: 0.02, the eye's threshold for large targets in daylight).
CONTRAST_THRESHOLD = 0.02
#: Pixels per code cell a square-marker decoder needs (2: the sampling theorem's minimum).
MIN_PX_PER_CELL = 2.0
#: Ranges (m) on which the prediction is searched.
RANGE_GRID_M = np.arange(0.05, 60.0, 0.01)


def apparent_contrast(L_target, L_background, L_inf, c, range_m) -> np.ndarray:
    """Apparent contrast (..., 3) of a target against its own background at ``range_m`` (m).

    ``L_target``, ``L_background`` inherent radiances (3,) or (N, 3); ``L_inf`` the water's
    veiling radiance (3,) on the line of sight; ``c`` beam attenuation (3,), 1/m; ``range_m``
    scalar or (N,)."""
    t = np.exp(-np.asarray(c, float) * np.asarray(range_m, float)[..., None])
    Lb = np.asarray(L_background, float)
    den = Lb * t + np.asarray(L_inf, float) * (1.0 - t)
    num = (np.asarray(L_target, float) - Lb) * t
    return np.divide(num, den, out=np.full(np.broadcast(num, den).shape, np.inf), where=den > 0)


def visible_range_m(
    contrast: np.ndarray, ranges_m: np.ndarray = RANGE_GRID_M, threshold: float = CONTRAST_THRESHOLD
) -> float:
    """Largest range (m) up to which the best channel of ``contrast`` (N, 3) stays at or above
    ``threshold`` from the nearest range on; 0 when it is below at the nearest."""
    ok = np.abs(contrast).max(axis=-1) >= threshold
    if not ok[0]:
        return 0.0
    bad = np.flatnonzero(~ok)
    return float(ranges_m[-1] if bad.size == 0 else ranges_m[bad[0] - 1])


def led_range_m(
    intensity_rgb,
    radius_m: float,
    L_face,
    L_inf,
    c,
    f_px: float,
    ranges_m: np.ndarray = RANGE_GRID_M,
    threshold: float = CONTRAST_THRESHOLD,
) -> float:
    """Predicted range (m) at which one LED (on-axis intensity ``intensity_rgb`` (3,), W/sr,
    disc ``radius_m``) stops standing out from the dock face (radiance ``L_face`` (3,))."""
    L_led = np.asarray(intensity_rgb, float) / (math.pi * radius_m**2)
    cover = np.minimum(1.0, math.pi * radius_m**2 * f_px**2 / ranges_m**2)[:, None]
    L_pix = cover * L_led + (1.0 - cover) * np.asarray(L_face, float)
    return visible_range_m(apparent_contrast(L_pix, L_face, L_inf, c, ranges_m), ranges_m, threshold)


def square_marker_range_m(
    cell_m: float,
    L_white,
    L_black,
    L_inf,
    c,
    f_px: float,
    ranges_m: np.ndarray = RANGE_GRID_M,
    threshold: float = CONTRAST_THRESHOLD,
) -> dict:
    """Predicted range (m) of a printed code with cells of side ``cell_m``: where the white
    cells' contrast against the black ones falls below ``threshold`` (``contrast_m``), where a
    cell shrinks below :data:`MIN_PX_PER_CELL` pixels (``resolution_m``) and the smaller."""
    contrast = apparent_contrast(np.broadcast_to(L_white, (len(ranges_m), 3)), L_black, L_inf, c, ranges_m)
    r_c = visible_range_m(contrast, ranges_m, threshold)
    r_res = f_px * cell_m / MIN_PX_PER_CELL
    return {"contrast_m": r_c, "resolution_m": r_res, "range_m": min(r_c, r_res)}
