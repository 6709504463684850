"""Blob stage of the LED localizer: background and noise, thresholds, components, LED-likeness, colour.

An LED seen through water is a compact round spot, brighter than its *local* background
by many noise standard deviations, of a known colour once that background is taken away.
This module measures exactly those properties, and nothing else of the LED array:

* :func:`prepare`: the frame's brightness ``v = max(R, G, B)``, a local background of
  ``v`` and of each colour channel (median of a coarse grid of cells; see
  :func:`background`), and a robust noise estimate ``sigma`` (:func:`noise_sigma`);
* :func:`components`: 8-connected components of the pixels above a brightness level
  *and* ``k_sigma * sigma`` above their local background (the noise-aware absolute floor:
  a relative level that falls below a bright veil no longer merges the frame into one
  component), with per-blob area, box, excess mass and compactness (vectorised: one
  ``np.bincount`` over the bright pixels, no loop over blobs);
* :func:`measure`: centroid (core or weighted) and colour of one blob, the colour from
  its background-subtracted pixels (the blob and its halo above the noise floor), so a
  veil brighter than the threshold adds nothing to the colour and a white core with
  every channel clipped (colour lost) is left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

SQ3_2 = math.sqrt(3.0) / 2.0

#: Cells per image width of the background grid: 20 cells = 32 px at 640 px. The median
#: over 5 x 5 cells (160 px) ignores any LED of an array that is wholly in view (an LED
#: disc spans at most 2 r / s = 13 % of the array's width: 85 px when the array fills a
#: 640 px frame), so the background is the veil/scene around the LED, not the LED.
BG_CELLS_PER_WIDTH = 20
BG_MEDIAN_CELLS = 5

#: Detection floor in noise standard deviations: the 5 sigma convention of point-source
#: detection (one-sided Gaussian false-alarm rate 2.9e-7 per pixel, i.e. < 0.1 false
#: pixel per 640 x 480 frame).
K_SIGMA = 5.0
#: Noise floor (DN): the 8-bit quantisation step, so a noise-free synthetic frame still
#: needs a blob to stand out by a few DN.
MIN_SIGMA_DN = 1.0
#: Level of a clipped channel: a pixel with every channel clipped has lost its colour.
CLIP_DN = 255


@dataclass
class Frame:
    """Per-image quantities shared by every threshold level.

    rgb (H,W,3) uint8; v (H,W) uint8 brightness max(R,G,B); excess (H,W) uint8
    ``v - background`` (saturating); bg_rgb (h,w,3) uint8 the coarse per-channel background;
    cell (px) its cell size; sigma (DN) the noise standard deviation of ``v``; origin
    (x0, y0) px of these arrays in the camera image (a search window; (0, 0) for the whole
    image) and image_px the camera image's pixel count."""

    rgb: np.ndarray
    v: np.ndarray
    excess: np.ndarray
    bg_rgb: np.ndarray
    cell: int
    sigma: float
    origin: tuple[int, int] = (0, 0)
    image_px: int = 0

    @property
    def floor(self) -> float:
        """The absolute floor (DN above the local background): K_SIGMA x sigma."""
        return K_SIGMA * self.sigma

    def bg_at(self, u: float, w: float) -> np.ndarray:
        """Background colour (3,) float32 at pixel (u, w)."""
        r = min(self.bg_rgb.shape[0] - 1, max(0, int(w) // self.cell))
        c = min(self.bg_rgb.shape[1] - 1, max(0, int(u) // self.cell))
        return self.bg_rgb[r, c].astype(np.float32)


def background(img: np.ndarray, cell: int) -> np.ndarray:
    """Local background of ``img`` (H,W) or (H,W,C) uint8 on a grid of ``cell`` px cells:
    cell means, then the median over BG_MEDIAN_CELLS x BG_MEDIAN_CELLS cells. Returns the
    coarse grid (h,w[,C]) uint8."""
    h, w = img.shape[:2]
    gh, gw = max(1, round(h / cell)), max(1, round(w / cell))
    small = cv2.resize(img, (gw, gh), interpolation=cv2.INTER_AREA)
    if min(gh, gw) >= BG_MEDIAN_CELLS:
        small = cv2.medianBlur(small, BG_MEDIAN_CELLS)
    return small


def noise_sigma(v: np.ndarray) -> float:
    """Robust noise standard deviation (DN) of the brightness (H,W) uint8: the median
    absolute difference of diagonal neighbours, / (0.6745 sqrt 2) (the MAD of a Gaussian
    difference of two independent pixels), sampled on a 4-px lattice (2-px below 400 x 400
    px: ~19 000 pairs at 640x480); edges and LEDs are a small share of the pixels and do
    not move the median. At least MIN_SIGMA_DN."""
    step = 4 if v.size >= 160_000 else 2
    a = np.ascontiguousarray(v[0:-1:step, 0:-1:step])
    b = np.ascontiguousarray(v[1::step, 1::step][: a.shape[0], : a.shape[1]])
    if a.size == 0:
        return MIN_SIGMA_DN
    hist = np.bincount(cv2.absdiff(a, b).ravel(), minlength=256)
    cum = np.cumsum(hist)
    k = int(np.searchsorted(cum, 0.5 * a.size))  # the median's bin, interpolated within it
    below = float(cum[k - 1]) if k > 0 else 0.0
    med = max(0.0, k - 0.5 + (0.5 * a.size - below) / max(float(hist[k]), 1.0))
    return max(MIN_SIGMA_DN, med / (0.6745 * math.sqrt(2.0)))


def background_cell(width: int) -> int:
    """Background cell size (px) of an image ``width`` px wide (BG_CELLS_PER_WIDTH cells)."""
    return max(2, int(round(width / BG_CELLS_PER_WIDTH)))


def prepare(rgb: np.ndarray, window: tuple[int, int, int, int] | None = None) -> Frame:
    """The :class:`Frame` of an RGB uint8 image (H,W,3), or of the search window
    (x0, y0, x1, y1) px of it: the window is measured alone (its background, noise and
    components), with the whole image's background cell size."""
    h_img, w_img = rgb.shape[:2]
    cell = background_cell(w_img)
    x0, y0 = (0, 0) if window is None else window[:2]
    if window is not None:
        rgb = rgb[window[1] : window[3], window[0] : window[2]]
    rgb = np.ascontiguousarray(rgb)
    r, g, b = cv2.split(rgb)
    v = cv2.max(cv2.max(r, g), b)
    h, w = v.shape
    bg_rgb = background(rgb, cell)
    bg_v = bg_rgb.max(axis=2)
    bg_full = cv2.resize(bg_v, (w, h), interpolation=cv2.INTER_LINEAR)
    return Frame(rgb, v, cv2.subtract(v, bg_full), bg_rgb, cell, noise_sigma(v), (x0, y0), h_img * w_img)


@dataclass
class Blobs:
    """Connected components of one threshold level (label 0 = background).

    labels (h,w) int32 over the box ``origin`` (x0, y0) px of the bright pixels; stats
    (M+1, 5) OpenCV component stats; centres (M+1, 2) px (box coordinates); mass (M+1,)
    summed excess brightness (DN px); compact (M+1,) compactness in [0, 1] (1: a filled
    disc or square; :func:`compactness`)."""

    labels: np.ndarray
    stats: np.ndarray
    centres: np.ndarray
    mass: np.ndarray
    compact: np.ndarray
    origin: tuple[int, int]

    @property
    def count(self) -> int:
        return len(self.stats) - 1


def compactness(area, w, h) -> np.ndarray:
    """Compactness in [0, 1] of blobs of ``area`` px in ``w`` x ``h`` px boxes: fill
    (area / box, 1 at pi/4 = a disc) times aspect (short / long side). A disc or square
    scores 1; a caustic filament or network (elongated, or thin and bent across its box)
    scores 0.05-0.3. Blobs of at most 2 x 2 px are too small to tell: 1."""
    area, w, h = (np.asarray(x, float) for x in (area, w, h))
    fill = np.minimum(1.0, area / (w * h) / (math.pi / 4.0))
    c = fill * np.minimum(w, h) / np.maximum(w, h)
    return np.where(np.maximum(w, h) <= 2, 1.0, c)


def components(fr: Frame, t: float, max_blobs: int) -> Blobs | None:
    """Components of the pixels with ``v > t`` and ``excess > floor``; None when there
    are none or more than ``max_blobs``."""
    hi = cv2.threshold(fr.v, t, 255, cv2.THRESH_BINARY)[1]
    ex = cv2.threshold(fr.excess, fr.floor, 255, cv2.THRESH_BINARY)[1]
    mask = cv2.bitwise_and(hi, ex)
    # Labelling only the box around the bright pixels (2 px margin for ``measure``) skips
    # the dark rest of the frame: 0.02 ms instead of ~1.9 ms at 640x480.
    x, y, bw, bh = cv2.boundingRect(mask)
    if bw == 0:
        return None
    x0, y0 = max(0, x - 2), max(0, y - 2)
    x1, y1 = min(fr.v.shape[1], x + bw + 2), min(fr.v.shape[0], y + bh + 2)
    n, labels, stats, cents = cv2.connectedComponentsWithStatsWithAlgorithm(
        np.ascontiguousarray(mask[y0:y1, x0:x1]), 8, cv2.CV_32S, cv2.CCL_BBDT
    )
    if n - 1 > max_blobs:
        return None
    fg = labels != 0
    mass = np.bincount(labels[fg], weights=fr.excess[y0:y1, x0:x1][fg], minlength=n)
    comp = compactness(stats[:, cv2.CC_STAT_AREA], stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT])
    return Blobs(labels, stats, cents, mass, comp, (x0, y0))


@dataclass
class BlobMeasure:
    """One blob measured: centre (u, v) px (image coordinates), mass (DN px), unit chroma
    direction (2,) in the opponent plane, saturation (chroma / brightness of its
    background-subtracted colour, 0 for grey), diameter (px) of the disc of its area."""

    centre: tuple[float, float]
    mass: float
    chroma: np.ndarray
    saturation: float
    diameter: float


def box(st, shape, margin: int = 2) -> tuple[int, int, int, int]:
    """(xa, ya, xb, yb) of a component's stats row ``st`` grown by ``margin`` px, clipped."""
    x0, y0, bw, bh = (int(s) for s in st[:4])
    return (max(0, x0 - margin), max(0, y0 - margin), min(shape[1], x0 + bw + margin), min(shape[0], y0 + bh + margin))


def centroid(
    v_roi: np.ndarray, lab_roi: np.ndarray, lab: int, t_low: float, mode: str, xa: int, ya: int
) -> tuple[float, float] | None:
    """Centroid (u, v) px of blob ``lab`` in a box at (xa, ya): ``core`` weights the
    pixels above the middle of the blob's range ((t_low + peak) / 2) within the blob,
    ``weighted`` the brightness above ``t_low`` over the box (other blobs masked out)."""
    vf = v_roi.astype(np.float32)
    if mode == "core":
        peak = float(v_roi[lab_roi == lab].max())
        w = np.clip(vf - 0.5 * (t_low + peak), 0, None)
        w[lab_roi != lab] = 0.0
    else:
        w = np.clip(vf - t_low, 0, None)
        w[(lab_roi != lab) & (lab_roi != 0)] = 0.0
    m = cv2.moments(w)  # sums of w, x w and y w (box px), accumulated in float64
    if not m["m00"] > 0:
        return None
    return xa + m["m10"] / m["m00"], ya + m["m01"] / m["m00"]


def colour(fr: Frame, lab_roi: np.ndarray, lab: int, xa: int, ya: int) -> tuple[np.ndarray, float] | None:
    """Opponent chroma (a, b) (2,) of the blob's background-subtracted colour and its
    saturation |(a, b)| / summed brightness excess; None without a usable pixel.

    Pixels used: the blob's own and the unlabelled halo around it, each more than the
    floor above the local background and not white-clipped (some channel below CLIP_DN:
    a pixel clipped in one or two channels still orders them); the local
    background colour (the coarse per-channel background at the box centre) is
    subtracted from each, so the water's veil and light add nothing."""
    h, w = lab_roi.shape
    rgb = fr.rgb[ya : ya + h, xa : xa + w]
    lo = cv2.min(cv2.min(rgb[:, :, 0], rgb[:, :, 1]), rgb[:, :, 2])
    excess = fr.excess[ya : ya + h, xa : xa + w]
    use = (((lab_roi == lab) | (lab_roi == 0)) & (excess > fr.floor) & (lo < CLIP_DN)).view(np.uint8)
    n = cv2.countNonZero(use)
    if n == 0:
        return None
    # per-channel sums over the used pixels (cv2.mean over the mask x their count), minus the background's
    s = n * (np.array(cv2.mean(rgb, use)[:3]) - fr.bg_at(xa + 0.5 * w, ya + 0.5 * h))
    ab = np.array([s[0] - 0.5 * (s[1] + s[2]), SQ3_2 * (s[1] - s[2])])
    bright = n * cv2.mean(excess, use)[0]
    if bright <= 0:
        return None
    return ab, float(np.hypot(*ab)) / bright


def measure(fr: Frame, blobs: Blobs, lab: int, t: float, mode: str) -> BlobMeasure | None:
    """Centroid and colour of blob ``lab`` at level ``t`` (camera image coordinates), or None."""
    ox, oy = blobs.origin
    xa, ya, xb, yb = box(blobs.stats[lab], blobs.labels.shape)
    lab_roi = blobs.labels[ya:yb, xa:xb]
    c = centroid(fr.v[oy + ya : oy + yb, ox + xa : ox + xb], lab_roi, lab, 0.5 * t, mode, xa, ya)
    col = colour(fr, lab_roi, lab, ox + xa, oy + ya)
    if c is None or col is None:
        return None
    ab, sat = col
    norm = float(np.hypot(*ab))
    if norm <= 0:
        return None
    diameter = 2.0 * math.sqrt(float(blobs.stats[lab, cv2.CC_STAT_AREA]) / math.pi)
    u0, v0 = ox + fr.origin[0], oy + fr.origin[1]
    return BlobMeasure((c[0] + u0, c[1] + v0), float(blobs.mass[lab]), ab / norm, sat, diameter)
