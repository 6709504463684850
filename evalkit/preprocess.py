"""Image preprocessing before a localizer: denoising, contrast, colour correction.

A preprocess spec is a comma-separated list of steps applied in order, each
``name`` or ``name:key=value:key=value``::

    clahe,grayworld
    median:k=5,clahe:clip=3:tile=8
    denoise:h=5,stretch:low=1:high=99

Steps (RGB uint8 in, RGB uint8 out, deterministic):

=============  ==========================================================================
``denoise``    ``cv2.fastNlMeansDenoisingColored`` (``h`` 5, ``hcolor`` 5, ``template`` 7,
               ``search`` 21); slow: ~0.1-0.3 s per 640x480 frame on one core
``bilateral``  ``cv2.bilateralFilter`` (``d`` 5, ``sigma_color`` 50, ``sigma_space`` 5)
``median``     ``cv2.medianBlur`` (``k`` 3, odd)
``gaussian``   ``cv2.GaussianBlur`` (``sigma`` 1.0 px)
``clahe``      CLAHE on the L channel of CIELAB (``clip`` 2.0, ``tile`` 8)
``stretch``    contrast stretch: luminance percentiles ``low`` 1 / ``high`` 99 -> 0 / 255,
               the same gain and offset on all channels (hue kept)
``gain``       brightness / contrast: ``alpha * x + beta`` (``alpha`` 1.5, ``beta`` 0)
``gamma``      ``255 (x / 255) ** (1 / g)`` (``g`` 1.5; > 1 brightens)
``grayworld``  gray-world white balance: each channel scaled to the mean of the channel
               means (gains limited to [1/``max_gain``, ``max_gain``], default 4)
=============  ==========================================================================

:class:`Preprocessed` wraps any localizer; :func:`parse_steps` validates a spec
(raises ``ValueError`` with the reason).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def _cv2():
    import cv2

    return cv2


def denoise(img, h=5.0, hcolor=5.0, template=7, search=21):
    """Non-local means denoising of a colour image."""
    return _cv2().fastNlMeansDenoisingColored(img, None, float(h), float(hcolor), int(template), int(search))


def bilateral(img, d=5, sigma_color=50.0, sigma_space=5.0):
    """Edge-preserving bilateral filter."""
    return _cv2().bilateralFilter(img, int(d), float(sigma_color), float(sigma_space))


def median(img, k=3):
    """Median filter with an odd k x k window."""
    k = int(k)
    if k < 1 or k % 2 == 0:
        raise ValueError(f"median: k must be odd and >= 1, got {k}")
    return _cv2().medianBlur(img, k)


def gaussian(img, sigma=1.0):
    """Gaussian blur (kernel size from sigma)."""
    return _cv2().GaussianBlur(img, (0, 0), float(sigma))


def clahe(img, clip=2.0, tile=8):
    """Contrast-limited adaptive histogram equalisation of CIELAB L."""
    cv2 = _cv2()
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB)
    op = cv2.createCLAHE(clipLimit=float(clip), tileGridSize=(int(tile), int(tile)))
    lab[:, :, 0] = op.apply(np.ascontiguousarray(lab[:, :, 0]))
    return cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)


def stretch(img, low=1.0, high=99.0):
    """Map luminance percentiles low/high to 0/255 with one gain and offset for all channels."""
    lum = img.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    lo, hi = np.percentile(lum, [float(low), float(high)])
    if hi - lo < 1.0:
        return img.copy()
    alpha = 255.0 / (hi - lo)
    return _affine(img, alpha, -lo * alpha)


def gain(img, alpha=1.5, beta=0.0):
    """Linear brightness/contrast: saturate(alpha * x + beta)."""
    return _affine(img, float(alpha), float(beta))


def _affine(img, alpha: float, beta: float):
    """round(alpha * x + beta) clipped to [0, 255] (cv2.convertScaleAbs would take |.|)."""
    return np.clip(np.rint(img.astype(np.float32) * np.float32(alpha) + np.float32(beta)), 0, 255).astype(np.uint8)


def gamma(img, g=1.5):
    """Gamma curve 255 (x/255)^(1/g) through a lookup table."""
    lut = np.clip(255.0 * (np.arange(256) / 255.0) ** (1.0 / float(g)) + 0.5, 0, 255).astype(np.uint8)
    return lut[img]


def grayworld(img, max_gain=4.0):
    """Gray-world white balance: scale each channel to the mean of the channel means."""
    means = img.reshape(-1, 3).astype(np.float64).mean(axis=0)
    target = means.mean()
    g = np.clip(target / np.maximum(means, 1e-6), 1.0 / float(max_gain), float(max_gain))
    out = img.astype(np.float32) * g.astype(np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


STEPS: dict[str, Callable[..., np.ndarray]] = {
    "denoise": denoise,
    "bilateral": bilateral,
    "median": median,
    "gaussian": gaussian,
    "clahe": clahe,
    "stretch": stretch,
    "gain": gain,
    "gamma": gamma,
    "grayworld": grayworld,
}


@dataclass(frozen=True)
class Step:
    """One preprocessing step: a name from :data:`STEPS` and its keyword params."""

    name: str
    params: dict = field(default_factory=dict)

    def __call__(self, img: np.ndarray) -> np.ndarray:
        return STEPS[self.name](img, **self.params)

    def __str__(self) -> str:
        return ":".join([self.name] + [f"{k}={v}" for k, v in self.params.items()])


def _value(text: str) -> Any:
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def parse_steps(spec: str | list | tuple | None) -> list[Step]:
    """``"median:k=5,clahe"`` (or a list of such strings / Steps) -> steps.

    Raises ``ValueError`` for unknown steps, unknown or malformed params, so a bad
    spec fails before any frame is processed."""
    import inspect

    if spec is None:
        return []
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    steps = []
    for item in items:
        if isinstance(item, Step):
            steps.append(item)
            continue
        parts = [p.strip() for p in str(item).split(":")]
        name = parts[0].lower()
        if not name:
            if len(parts) == 1:
                continue  # tolerate "a,,b" and a trailing comma
            raise ValueError(f"empty step name in {item!r}")
        if name not in STEPS:
            raise ValueError(f"unknown preprocessing step {name!r}; known: {', '.join(STEPS)}")
        allowed = list(inspect.signature(STEPS[name]).parameters)[1:]
        params = {}
        for p in parts[1:]:
            key, sep, val = p.partition("=")
            if not sep or key.strip() not in allowed:
                raise ValueError(
                    f"step {name!r}: bad parameter {p!r}; expected key=value with key in {', '.join(allowed)}"
                )
            params[key.strip()] = _value(val.strip())
        steps.append(Step(name, params))
    return steps


def apply_steps(image: np.ndarray, steps: list[Step]) -> np.ndarray:
    """Apply ``steps`` in order to an RGB uint8 image (the input is not modified)."""
    out = np.ascontiguousarray(image)
    for step in steps:
        out = np.ascontiguousarray(step(out))
    return out


class Preprocessed:
    """A localizer whose images go through preprocessing steps first.

    ``reset`` is forwarded unchanged; ``localize`` gets the processed image.
    ``preprocess_ms`` is the time of the last preprocessing (included in the
    runner's ``ms``).
    """

    def __init__(self, localizer: Any, steps: str | list):
        """localizer: any localizer object; steps: a spec string or list (:func:`parse_steps`)."""
        self.inner = localizer
        self.steps = parse_steps(steps)
        self.name = f"{getattr(localizer, 'name', type(localizer).__name__)}+" + "+".join(s.name for s in self.steps)
        self.preprocess_ms = 0.0

    @property
    def spec(self) -> str:
        """The normalised spec string of the steps."""
        return ",".join(str(s) for s in self.steps)

    @property
    def enforces_timeout(self) -> bool:
        return bool(getattr(self.inner, "enforces_timeout", False))

    @property
    def last_call_ms(self) -> float | None:
        inner = getattr(self.inner, "last_call_ms", None)
        return None if inner is None else inner + self.preprocess_ms

    def reset(self, camera: dict) -> None:
        self.inner.reset(camera)

    def localize(self, image: np.ndarray):
        start = time.perf_counter()
        img = apply_steps(image, self.steps)
        self.preprocess_ms = (time.perf_counter() - start) * 1e3
        return self.inner.localize(img)

    def close(self) -> None:
        close = getattr(self.inner, "close", None)
        if callable(close):
            close()
