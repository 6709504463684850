"""Camera sensor effects applied after rendering (pure numpy + cv2).

Order used by :class:`SensorModel`: motion blur (linear radiance) -> electrons (blooming,
shot/read noise, full well) -> digital numbers (gain) -> response curve -> 8-bit Gaussian
noise -> uint8. Lens distortion (:func:`distort_image`, :func:`distort_passes`) is applied
by the caller to every pass alike, before the sensor. Every random draw comes from the ``numpy.random.Generator``
passed in, so a seed reproduces an image exactly.

Distortion uses OpenCV's model (k1, k2, p1, p2, k3) on the pixel grid of ``K``: a
scene point whose ideal (pinhole) image is pixel ``p`` appears at
``distort(p)``, exactly where ``cv2.projectPoints`` with those coefficients
puts it. Images are treated as undistorted unless distortion is configured.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from blendgen.physics.camera import srgb_lut

# --------------------------------------------------------------------------- sRGB

_A = 0.055
_LIN_KNEE = 0.0031308
_ENC_KNEE = 0.04045


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1), input clipped to [0, 1].

    Computed as ``min(12.92 x, 1.055 max(x, 0.0031308)^(1/2.4) - 0.055)``, equal to
    the piecewise definition (the curve is concave) and ~4x faster than np.where."""
    x = np.asarray(linear)
    dt = np.float64 if x.dtype == np.float64 else np.float32
    x = np.fmax(x.astype(dt, copy=False), dt(0))  # NaN -> 0
    np.fmin(x, dt(1), out=x)
    hi = np.maximum(x, dt(_LIN_KNEE))
    np.power(hi, dt(1.0 / 2.4), out=hi)
    hi *= dt(1.0 + _A)
    hi -= dt(_A)
    x *= dt(12.92)
    return np.minimum(x, hi, out=x)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded [0, 1] (or uint8) -> linear [0, 1]."""
    e = np.asarray(encoded)
    if e.dtype == np.uint8:
        e = e.astype(np.float32) / 255.0
    e = np.clip(e.astype(np.float64 if e.dtype == np.float64 else np.float32), 0.0, 1.0)
    hi = np.power((np.maximum(e, _ENC_KNEE) + _A) / (1.0 + _A), 2.4)
    return np.where(e <= _ENC_KNEE, e / 12.92, hi).astype(e.dtype, copy=False)


def to_uint8(linear: np.ndarray, noise_std: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """Linear radiance -> 8-bit sRGB, with additive Gaussian noise of ``noise_std``
    (8-bit units, 0-256) drawn after encoding, then rounded and clipped to 0..255."""
    if not (0.0 <= noise_std <= 256.0):
        raise ValueError(f"noise_std must be in [0, 256] (8-bit units), got {noise_std}")
    v = srgb_encode(linear).astype(np.float32) * np.float32(255.0)
    if noise_std > 0:
        if rng is None:
            raise ValueError("noise_std > 0 needs a numpy Generator (rng=np.random.default_rng(seed))")
        v += rng.standard_normal(v.shape, dtype=np.float32) * np.float32(noise_std)
    return np.clip(np.rint(v), 0, 255).astype(np.uint8)


#: Below this many electrons shot noise is drawn exactly (Poisson); above, Normal(mean, mean),
#: which has the same mean and variance (skewness 1/sqrt(mean) < 0.23). rng.poisson costs
#: ~100 ns a sample: a dim 640x480 frame took ~90 ms with the threshold at 1000.
POISSON_EXACT_BELOW = 20.0
#: The skewness a Normal of the same mean and variance may leave out: 1/sqrt(POISSON_EXACT_BELOW).
SKEW_EXACT = POISSON_EXACT_BELOW**-0.5


def _exact_poisson(lam: np.ndarray, read_noise_e: float) -> np.ndarray:
    """Flat indices of ``lam`` where Poisson(lam) + Normal(0, r) is skewed by more than
    :data:`SKEW_EXACT`: its skewness is ``lam / (lam + r^2)^1.5`` (third cumulant lam over the
    variance^1.5), which peaks at ``0.385 / r`` (lam = 2 r^2). So a sensor whose temporal dark
    noise exceeds 0.385 / SKEW_EXACT = 1.72 e- (the default IMX264 pixel's 2.3 e-) needs no exact
    draw: the read noise already hides the photon count's skew. Without read noise this is the
    ``lam < POISSON_EXACT_BELOW`` rule."""
    r2 = float(read_noise_e) ** 2
    if r2 == 0.0:
        return np.flatnonzero(lam < POISSON_EXACT_BELOW)
    if _no_exact_draws(read_noise_e):
        return np.empty(0, np.intp)
    low = np.flatnonzero(lam < POISSON_EXACT_BELOW)
    lo = lam.ravel()[low]
    return low[lo >= SKEW_EXACT * (lo + np.float32(r2)) ** 1.5]


@functools.cache
def _fused_kernels() -> bool:
    """Whether :mod:`sensor_kernels` (numba, the render extra) can be imported; without it the
    numpy chain makes the same image."""
    try:
        from blendgen.physics.camera import sensor_kernels  # noqa: F401
    except ImportError:
        return False
    return True


def _no_exact_draws(read_noise_e: float) -> bool:
    """True when the read noise alone hides the photon count's skew everywhere, so
    :func:`_exact_poisson` never asks for an exact draw (read noise above ~1.72 e-)."""
    r2 = float(read_noise_e) ** 2
    return r2 > 0.0 and 2.0 / (3.0**1.5 * math.sqrt(r2)) < SKEW_EXACT


def shot_read_noise_e(mean_e: np.ndarray, rng: np.random.Generator, read_noise_e: float = 0.0) -> np.ndarray:
    """Collected charge with photon shot noise and temporal dark noise, in electrons.

    ``Poisson(mean_e) + Normal(0, read_noise_e)``: one Normal of the same mean and variance,
    drawn exactly where that sum is skewed by more than :data:`SKEW_EXACT`
    (:func:`_exact_poisson`). Float32, same shape, not clipped."""
    if read_noise_e < 0:
        raise ValueError(f"read_noise_e must be >= 0 electrons, got {read_noise_e}")
    lam = np.fmax(np.asarray(mean_e, np.float32), np.float32(0))  # NaN -> 0
    e = rng.standard_normal(lam.shape, dtype=np.float32)
    sd = lam + np.float32(read_noise_e) ** 2
    e *= np.sqrt(sd, out=sd)  # shot and read noise: one Normal draw
    e += lam
    small = _exact_poisson(lam, read_noise_e)  # flat indices: one take and one put
    if small.size:
        v = rng.poisson(lam.ravel()[small]).astype(np.float32)
        if read_noise_e > 0:
            v += rng.standard_normal(small.size, dtype=np.float32) * np.float32(read_noise_e)
        e.ravel()[small] = v
    return e


# --------------------------------------------------------------------------- motion blur


def motion_blur_kernel(velocity_px) -> np.ndarray:
    """Normalised line kernel for a displacement ``velocity_px`` = (dx, dy) pixels
    during the exposure, centred on the mid-exposure position (sub-pixel splats)."""
    v = np.asarray(velocity_px, float).reshape(2)
    L = float(np.hypot(*v))
    R = int(np.ceil(L / 2.0)) + 1
    k = np.zeros((2 * R + 1, 2 * R + 1), np.float64)
    n = max(2, int(np.ceil(L * 4)) + 1)
    for s in np.linspace(-0.5, 0.5, n):
        x, y = R + s * v[0], R + s * v[1]
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        k[y0, x0] += (1 - fx) * (1 - fy)
        k[y0, x0 + 1] += fx * (1 - fy)
        k[y0 + 1, x0] += (1 - fx) * fy
        k[y0 + 1, x0 + 1] += fx * fy
    return (k / k.sum()).astype(np.float32)


def motion_blur(img: np.ndarray, velocity_px) -> np.ndarray:
    """Linear motion blur along ``velocity_px`` (dx, dy) px per exposure (apply in linear)."""
    v = np.asarray(velocity_px, float).reshape(2)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"velocity_px must be finite, got {velocity_px}")
    if np.hypot(*v) < 1e-3:
        return np.array(img, copy=True)
    src = np.asarray(img)
    out = cv2.filter2D(
        src.astype(np.float32) if src.dtype == np.uint8 else src,
        -1,
        motion_blur_kernel(v),
        borderType=cv2.BORDER_REFLECT,
    )
    if src.dtype == np.uint8:
        out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out


# --------------------------------------------------------------------------- distortion


def _dist5(dist) -> np.ndarray:
    d = np.asarray(dist, float).reshape(-1)
    if d.size not in (4, 5) or not np.all(np.isfinite(d)):
        raise ValueError(f"distortion must be 4 or 5 finite numbers (k1 k2 p1 p2 [k3]), got {dist}")
    return np.concatenate([d, np.zeros(5 - d.size)])


def distort_points(uv, K, dist) -> np.ndarray:
    """Ideal (pinhole) pixels (N, 2) -> distorted pixels (N, 2), as cv2.projectPoints."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    K = np.asarray(K, float)
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    pts = np.column_stack([x, y, np.ones_like(x)])
    out, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, _dist5(dist))
    return out.reshape(-1, 2)


def undistort_points(uv, K, dist) -> np.ndarray:
    """Distorted pixels (N, 2) -> ideal pixels (N, 2) (iterative inverse, to ~1e-6 px)."""
    src = np.asarray(uv, np.float64).reshape(-1, 1, 2)
    K = np.asarray(K, float)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x spells the iterative variant apart
        out = cv2.undistortPointsIter(src, K, _dist5(dist), None, K, crit)
    else:  # OpenCV 5 folded it into undistortPoints
        out = cv2.undistortPoints(src, K, _dist5(dist), None, None, K, crit)
    return out.reshape(-1, 2)


@functools.lru_cache(maxsize=8)
def _maps_cached(K_t: tuple, dist_t: tuple, width: int, height: int):
    K = np.array(K_t).reshape(3, 3)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    src = undistort_points(np.column_stack([u.ravel(), v.ravel()]), K, np.array(dist_t))
    mx = src[:, 0].reshape(height, width).astype(np.float32)
    my = src[:, 1].reshape(height, width).astype(np.float32)
    mx.setflags(write=False)
    my.setflags(write=False)
    return mx, my


def distortion_maps(K, dist, width: int, height: int):
    """(map_x, map_y) float32 (H, W) for cv2.remap: the ideal pixel seen at each
    distorted output pixel. Cached per (K, dist, size)."""
    return _maps_cached(tuple(np.asarray(K, float).ravel()), tuple(_dist5(dist)), int(width), int(height))


def distort_image(
    img: np.ndarray, K, dist, interpolation: int = cv2.INTER_LINEAR, border: int = cv2.BORDER_REPLICATE
) -> np.ndarray:
    """Apply lens distortion to an ideal pinhole render (same size, same K)."""
    h, w = img.shape[:2]
    mx, my = distortion_maps(K, dist, w, h)
    return cv2.remap(img, mx, my, interpolation, borderMode=border)


# --------------------------------------------------------------------------- timing


def pose_timestamp(t_frame, latency_s: float):
    """Time of the pose an image shows: ``t_pose = t_frame - latency_s``.

    ``t_frame`` is the image's time stamp (when it reaches the localizer); the scene
    it shows was captured ``latency_s`` earlier. Scalars or arrays."""
    if latency_s < 0:
        raise ValueError(f"latency_s must be >= 0, got {latency_s}")
    return np.asarray(t_frame, float) - float(latency_s) if np.ndim(t_frame) else float(t_frame) - float(latency_s)


# --------------------------------------------------------------------------- pipeline

DN_MAX = 255

#: Default share of the charge above the full well that spills into neighbours (both image-formation
#: modes): a documented choice, not a measured camera (CMOS anti-blooming drains remove most of it;
#: a few % keeps a saturated LED's own colour in a halo around its clipped core, as cameras show).
BLOOM_FRACTION = 0.05


@dataclass(frozen=True)
class EmvaSheet:
    """The EMVA 1288 summary of a real sensor (one channel, 0 dB gain): quantum efficiency
    ``qe`` at ``wavelength_nm``, temporal dark noise ``read_noise_e`` (e- rms), saturation
    capacity ``full_well_e`` (e-), dark current ``dark_current_e_per_s`` (e-/s), pixel pitch
    ``pixel_um`` (um); ``source`` names the document the numbers come from."""

    name: str
    qe: float
    wavelength_nm: float
    read_noise_e: float
    full_well_e: float
    dark_current_e_per_s: float
    pixel_um: float
    source: str


#: The default camera: Sony IMX264 (Pregius 2nd generation, 2/3", 3.45 um global-shutter pixel, monochrome
#: variant), a common machine-vision sensor in underwater cameras. Numbers as the camera makers' EMVA 1288
#: data sheets of IMX264 cameras give them, rounded (Basler ace acA2440-20gm / acA2440-35um and Teledyne
#: FLIR Blackfly S BFS-U3-50S5M EMVA 1288 summaries: QE ~70 % near 530 nm, temporal dark noise ~2.3 e-,
#: saturation capacity ~10.5 ke-, i.e. 73 dB dynamic range and 40.2 dB maximum SNR; dark current a few
#: e-/s at room temperature). Colour (Bayer) variants have a lower QE per channel; the model keeps one
#: QE for all three channels.
IMX264 = EmvaSheet(
    name="Sony IMX264",
    qe=0.70,
    wavelength_nm=530.0,
    read_noise_e=2.3,
    full_well_e=10500.0,
    dark_current_e_per_s=3.0,
    pixel_um=3.45,
    source="EMVA 1288 summaries of IMX264 cameras (Basler ace acA2440-20gm; Teledyne FLIR "
    "Blackfly S BFS-U3-50S5M), rounded",
)

#: f-number of the default lens (``config.models.Lens.f_number``), used to derive the responsivity.
DEFAULT_F_NUMBER = 2.8
_H_PLANCK, _C_LIGHT = 6.62607015e-34, 299792458.0


def responsivity_e_per_s(
    sheet: EmvaSheet = IMX264, f_number: float = DEFAULT_F_NUMBER, optics_transmission: float = 1.0
) -> float:
    """Electrons per second per pixel per unit radiance (W m^-2 sr^-1) of an on-axis scene.

    A lens of f-number N puts the irradiance ``E = pi L T / (4 N^2)`` on the sensor (object far
    beyond the focal length); a pixel of pitch p collects ``E p^2`` watts, i.e.
    ``E p^2 lambda / (h c)`` photons per second, of which the fraction QE become electrons. IMX264 at
    f/2.8, 530 nm, T = 1: 2.2e6 e-/s per W m^-2 sr^-1."""
    if not (f_number > 0 and 0 < optics_transmission <= 1):
        raise ValueError(
            f"f_number must be > 0 and optics_transmission in (0, 1], got {f_number}, {optics_transmission}"
        )
    e_px = math.pi * optics_transmission / (4.0 * f_number**2) * (sheet.pixel_um * 1e-6) ** 2
    photon_j = _H_PLANCK * _C_LIGHT / (sheet.wavelength_nm * 1e-9)
    return sheet.qe * e_px / photon_j


#: Highlight exposure: the brightest emitter (an LED core seen through clear water, at any range: radiance
#: does not fall with distance) is put at this share of the full well, the target of the highlight metering
#: of :class:`AutoExposure` (10 % headroom for shot noise and glow).
BEACON_FILL = 0.9

#: Electrons per unit scene radiance (W m^-2 sr^-1) of the scene-metered exposure used when the dock
#: carries no LED: 4 ms at 1e6 e-/s, which average metering (18 % grey) of the preview frames picked
#: (4.4-12 ms; the shortest at 2 m in clear water).
SCENE_EXPOSURE_E_PER_RADIANCE = 4000.0


def beacon_exposure_s(
    peak_radiance: float, full_well_e: float, responsivity: float, fill: float = BEACON_FILL
) -> float:
    """Exposure (s) that puts ``peak_radiance`` (W m^-2 sr^-1, the brightest LED channel) at ``fill``
    of the full well: ``t = fill * full_well / (responsivity * peak_radiance)``. Without an emitter
    (``peak_radiance <= 0``) the scene-metered exposure ``SCENE_EXPOSURE_E_PER_RADIANCE / responsivity``."""
    if peak_radiance <= 0:
        return SCENE_EXPOSURE_E_PER_RADIANCE / responsivity
    return fill * full_well_e / (responsivity * peak_radiance)


@dataclass(frozen=True)
class SensorModel:
    """EMVA 1288 photon-transfer camera: linear radiance (H, W, 3) -> uint8 (H, W, 3).

    Mean electrons ``mu_e = L * responsivity_e_per_s * exposure_s`` plus the dark signal
    ``dark_current_e_per_s * exposure_s``; charge above the full well spills into neighbours (``bloom_fraction`` of
    it, Gaussian ``bloom_sigma_px``);
    with ``noise`` the collected charge is Poisson (shot noise) plus Normal(0,
    ``read_noise_e``) (temporal dark noise); it saturates at ``full_well_e``; digital
    numbers ``y = K e`` with the system gain ``K = gain * 255 / full_well_e`` DN/e-
    saturate at 255; the response curve ('srgb' or 'linear') maps y/255 to the 8-bit
    code; finally the article's additive Gaussian ``noise_std`` (8-bit units). A flat
    field therefore has variance ``K^2 sigma_d^2 + K mu_y`` in the linear response:
    its photon-transfer slope is K. The article's ``noise_std`` (sigma in 8-bit codes after the
    response curve) is thus, in the linear response, an extra read noise of ``noise_std / K``
    electrons on top of the sensor's own."""

    exposure_s: float = 0.01
    responsivity_e_per_s: float = 1e6
    full_well_e: float = 10000.0
    read_noise_e: float = 0.0
    gain: float = 1.0
    noise: bool = False
    response: str = "srgb"
    bloom_fraction: float = 0.0
    bloom_sigma_px: float = 2.0
    noise_std: float = 0.0
    dark_current_e_per_s: float = 0.0

    @property
    def K(self) -> float:
        """System gain (DN per electron)."""
        return self.gain * DN_MAX / self.full_well_e

    def electrons(self, linear: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Collected charge (H, W, 3) float32 electrons, saturated at the full well."""
        mu = np.asarray(linear, np.float32) * np.float32(self.responsivity_e_per_s * self.exposure_s)
        np.fmax(mu, np.float32(0), out=mu)  # NaN and negatives -> 0
        if self.bloom_fraction > 0:
            mu = self._bloom(mu, out=mu)  # mu is our own array
        if self.dark_current_e_per_s > 0:  # thermal charge: Poisson too
            mu += np.float32(self.dark_current_e_per_s * self.exposure_s)
        if self.noise:
            if rng is None:
                raise ValueError("shot/read noise needs a numpy Generator")
            mu = shot_read_noise_e(np.minimum(mu, np.float32(4 * self.full_well_e)), rng, self.read_noise_e)
        np.minimum(mu, np.float32(self.full_well_e), out=mu)
        return np.fmax(mu, np.float32(0), out=mu)

    def _signal_fused(self, linear: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """:meth:`electrons` times the system gain over full scale, clipped at 1 (H, W, 3)
        float32, by :mod:`sensor_kernels` (one pass before the bloom, one after the normal
        draws): bit-identical to the numpy chain, the random stream the same."""
        from blendgen.physics.camera import sensor_kernels as sk

        mu = sk.charge(linear, np.float32(self.responsivity_e_per_s * self.exposure_s))
        if self.bloom_fraction > 0:
            mu = self._bloom(mu, out=mu)
        normals = rng.standard_normal(mu.shape, dtype=np.float32)
        dark = np.float32(self.dark_current_e_per_s * self.exposure_s if self.dark_current_e_per_s > 0 else 0.0)
        return sk.shot_read_signal(mu, normals, dark, self.read_noise_e, self.full_well_e, np.float32(self.K / DN_MAX))

    def _bloom(self, mu: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Spill ``bloom_fraction`` of the charge above the full well with a Gaussian of
        ``bloom_sigma_px``; only the box around saturated pixels (+- 4 sigma) is filtered.
        ``out``: the array to add the spill to (``mu`` itself: in place); default a copy of ``mu``."""
        fw = np.float32(self.full_well_e)
        h, w = mu.shape[:2]
        over = (mu > fw).reshape(h, -1)  # (H, W*C): rows and columns without a
        rows = np.flatnonzero(over.any(axis=1))  # reduction over the short channel axis
        if rows.size == 0:
            return mu if out is mu else (mu.copy() if out is None else out)
        cols = np.flatnonzero(over[rows[0] : rows[-1] + 1].any(axis=0).reshape(w, -1).any(axis=1))
        pad = int(np.ceil(4 * self.bloom_sigma_px))
        y0, y1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, h)
        x0, x1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, w)
        win = np.maximum(mu[y0:y1, x0:x1] - fw, 0) * np.float32(self.bloom_fraction)
        spill = cv2.GaussianBlur(win, (0, 0), self.bloom_sigma_px, borderType=cv2.BORDER_CONSTANT)
        out = mu.copy() if out is None else out
        out[y0:y1, x0:x1] += spill.reshape(win.shape)
        return out

    def apply(self, linear: np.ndarray, rng: np.random.Generator | None = None, velocity_px=None) -> np.ndarray:
        """Linear radiance -> 8-bit image; ``velocity_px`` (dx, dy) blurs over the exposure."""
        x = np.asarray(linear, np.float32)
        if velocity_px is not None:
            x = motion_blur(x, velocity_px)
        if self.noise and rng is not None and _no_exact_draws(self.read_noise_e) and _fused_kernels():
            y = self._signal_fused(x, rng)  # the same numbers as the branch below, in two passes
        elif self.noise or self.bloom_fraction > 0:
            y = self.electrons(x, rng)
            y *= np.float32(self.K / DN_MAX)  # y / 255 in [0, gain]
        else:  # noise-free: the same numbers in one pass (the encode clips at 0 and 1)
            y = x * np.float32(self.responsivity_e_per_s * self.exposure_s * self.K / DN_MAX)
            np.fmax(y, np.float32(0), out=y)  # NaN and negatives -> 0
            if self.dark_current_e_per_s > 0:
                y += np.float32(self.dark_current_e_per_s * self.exposure_s * self.K / DN_MAX)
            if self.gain < 1:
                np.minimum(y, np.float32(self.gain), out=y)  # the full well saturates first
        np.minimum(y, np.float32(1.0), out=y)
        if self.response == "linear":
            v = y * np.float32(DN_MAX)
            if self.noise_std > 0:
                v += rng.standard_normal(v.shape, dtype=np.float32) * np.float32(self.noise_std)
            return np.clip(np.rint(v), 0, DN_MAX).astype(np.uint8)
        if self.noise_std == 0:  # the same codes by table lookup (srgb_lut: exact for every float32)
            return srgb_lut.encode_uint8(y, srgb_encode)
        return to_uint8(y, self.noise_std, rng)


# --------------------------------------------------------------------------- auto-exposure


@dataclass(frozen=True)
class AutoExposure:
    """Exposure control between frames (what a camera's AE loop does; ISO 2720 / camera
    practice: meter the previous frame, aim a statistic at a share of the full scale, follow
    with a first-order lag, clamp to the shutter's limits).

    The metered value ``m`` is a statistic of the per-pixel brightest channel of the frame's
    linear radiance (the signal before clipping; a real AE meters clipped DN, which only
    under-estimates ``m`` when pixels saturate): its ``mean`` (average metering, ``target``
    ~0.18: middle grey) or its ``percentile`` (highlight metering, e.g. 99.9 with target 0.9:
    the brightest 0.1 % of the pixels, small bright emitters such as LEDs, just below the full
    well). The exposure that puts ``m`` at ``target * full_well`` is
    ``t* = target * full_well / (m * responsivity)``; the next frame's exposure moves toward
    it in log space with ``alpha = 1 - exp(-dt / time_constant_s)`` (0: at once), clamped to
    ``[min_exposure_s, max_exposure_s]``."""

    metering: str = "percentile"
    percentile: float = 99.9
    target: float = 0.9
    min_exposure_s: float = 1e-5
    max_exposure_s: float = 0.05
    time_constant_s: float = 0.3

    def metered(self, linear: np.ndarray) -> float:
        """The metered radiance ``m`` of an (H, W, 3) linear image, on every 2nd pixel in each
        direction (a camera's AE meters a reduced grid; a quarter of the cost)."""
        x = np.asarray(linear, np.float32)[::2, ::2]
        v = np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2]).ravel()
        if self.metering == "mean":
            return float(np.mean(v, dtype=np.float64))
        k = int(round(self.percentile / 100.0 * (v.size - 1)))
        return float(np.partition(v, k)[k])

    def next_exposure(self, linear: np.ndarray, exposure_s: float, camera: SensorModel, dt_s: float) -> float:
        """The exposure (s) of the next frame, after a frame of ``linear`` radiance taken at ``exposure_s``."""
        m = self.metered(linear)
        if not (m > 0 and math.isfinite(m)):
            want = self.max_exposure_s
        else:
            want = self.target * camera.full_well_e / (m * camera.responsivity_e_per_s)
        want = min(max(want, self.min_exposure_s), self.max_exposure_s)
        alpha = 1.0 if self.time_constant_s <= 0 else 1.0 - math.exp(-dt_s / self.time_constant_s)
        t = math.exp(math.log(exposure_s) + alpha * (math.log(want) - math.log(exposure_s)))
        return min(max(t, self.min_exposure_s), self.max_exposure_s)
