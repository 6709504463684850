"""The article's hybrid localizer: LED array far away, a square marker (QR) close in.

Two sub-localizers: ``far`` (default ``led``: coarse long-range guidance) and
``near`` (default ``qr``; ``aruco`` or ``apriltag`` work too). A mode, kept across
the frames of a sequence and cleared by ``reset``, says which one is tried first:

* the mode starts ``far``;
* after every successful frame the estimated distance d updates it with hysteresis:
  ``near`` when d < switch_m - hysteresis_m / 2, ``far`` when d > switch_m +
  hysteresis_m / 2, unchanged inside the band (so noise around switch_m does not
  make it flicker);
* ``immediate``: when the primary's own estimate crosses the band, the other
  sub-localizer is tried on the same frame and preferred if it succeeds;
* ``fallback``: when the primary finds nothing, the other one is tried.

The estimate is the sub-localizer's dict (so ``marker_id`` is the marker actually
used) plus ``"source"`` (``"far"`` or ``"near"``) and ``"mode"`` (the mode after the
frame).
"""
from __future__ import annotations

from typing import Any

import numpy as np


class HybridLocalizer:
    """Article's hybrid: LED array far, QR below switch_m (5 m) with hysteresis; keeps state per sequence."""

    name = "hybrid"

    def __init__(self, switch_m: float = 5.0, hysteresis_m: float = 0.5, near: str = "qr", far: str = "led",
                 near_params: dict | None = None, far_params: dict | None = None,
                 near_marker_id: str | None = None, far_marker_id: str | None = None,
                 fallback: bool = True, immediate: bool = True):
        """switch_m: distance (m) below which the near marker is preferred.
        hysteresis_m: width (m) of the band around switch_m inside which the mode is kept.
        near / far: localizer specs (registry names: qr, aruco, apriltag / led, or any spec)
        with constructor params near_params / far_params; near_marker_id / far_marker_id:
        manifest marker ids (None: each sub-localizer's default).
        fallback: try the other sub-localizer when the preferred one fails.
        immediate: switch within the frame whose estimate crosses the band."""
        from evalkit import registry

        self.switch_m = float(switch_m)
        self.hysteresis_m = float(hysteresis_m)
        if not (self.switch_m > 0 and 0 <= self.hysteresis_m < 2 * self.switch_m):
            raise ValueError(f"need switch_m > 0 and 0 <= hysteresis_m < 2 switch_m, "
                             f"got {self.switch_m}, {self.hysteresis_m}")
        self.fallback = _as_bool(fallback)
        self.immediate = _as_bool(immediate)
        subs = {}
        for role, spec, params, mid in (("near", near, near_params, near_marker_id),
                                        ("far", far, far_params, far_marker_id)):
            p = dict(params or {})
            if mid is not None:
                p["marker_id"] = mid
            subs[role] = registry.resolve(str(spec), p)
        self.subs = subs
        self.mode = "far"

    @property
    def band(self) -> tuple[float, float]:
        """(lower, upper) distance (m) of the hysteresis band."""
        h = self.hysteresis_m / 2.0
        return self.switch_m - h, self.switch_m + h

    def next_mode(self, distance: float, mode: str) -> str:
        """Mode after a frame whose estimate is ``distance`` (m), starting from ``mode``."""
        lo, hi = self.band
        if distance < lo:
            return "near"
        if distance > hi:
            return "far"
        return mode

    def reset(self, camera: dict) -> None:
        """New sequence: reset both sub-localizers and start in ``far`` mode."""
        for sub in self.subs.values():
            sub.reset(camera)
        self.mode = "far"

    def localize(self, image: np.ndarray) -> dict | None:
        """Estimate from the preferred sub-localizer (see the module docstring), or None."""
        first = self.mode
        other = "near" if first == "far" else "far"
        est, used = self._try(first, image), first
        if est is None:
            if self.fallback:
                est, used = self._try(other, image), other
        elif self.immediate and self.next_mode(est["distance"], first) != first:
            alt = self._try(other, image)
            if alt is not None:
                est, used = alt, other
        if est is None:
            return None
        self.mode = self.next_mode(est["distance"], self.mode)
        return {**est, "source": used, "mode": self.mode}

    def _try(self, role: str, image: np.ndarray) -> dict | None:
        est = self.subs[role].localize(image)
        if not isinstance(est, dict):
            return None
        try:
            d = float(est.get("distance"))
        except (TypeError, ValueError):
            return None
        return est if np.isfinite(d) and d >= 0 else None

    def close(self) -> Any:
        for sub in self.subs.values():
            close = getattr(sub, "close", None)
            if callable(close):
                close()


def _as_bool(v) -> bool:
    if isinstance(v, str):
        return v.strip().lower() in ("1", "true", "yes", "on")
    return bool(v)
