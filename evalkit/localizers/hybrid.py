"""Hybrid localizer: per frame, the pose of the marker (QR or LED array) with the smaller predicted range error.

Two sub-localizers: ``near`` (default ``qr``; ``aruco`` or ``apriltag`` work too) and
``far`` (default ``led``). The hybrid switches on what each marker can deliver, not on a
fixed distance; how it chooses is ``prefer`` (below; default ``uncertainty``).

Near range. A code is readable only while its modules (cells) are large enough in the
image: at distance d a module of side ``m`` metres spans ``f m / d`` px (f: focal length,
px). With the decoder's limit ``min_px_per_module`` (default 1.3: zxing-cpp decoded the
demo's 21-module code out to 2.85 m, i.e. 1.39 px/module, and never below) the near
range is ``near_range_m = f m / min_px_per_module`` (demo: 554 px x 0.15/21 m / 1.3 =
3.0 m); ``switch_m`` overrides it. The module size comes from the manifest
(``module_size_m``, else ``size_m / modules`` for QR, ``size_m / (markerSize + 2)``
cells for ArUco/AprilTag).

``prefer="near"`` is the article's rule: an estimate from the near marker (payload/id
checked, full pose) is taken whenever the near marker is found, the LED array answers
otherwise. Per frame (the distance known before it: the previous estimate of the sequence):
* previous distance within the near range: near first, the LED if the near marker fails;
* otherwise the LED first; the near marker is tried only when the LED says the range is
  within the near range (or the LED failed): beyond it a decode is impossible and
  skipped, which keeps far frames at LED cost. When tried after an LED estimate, the
  near localizer first searches where that pose projects the near marker
  (``set_roi_hint``: an upscaled ROI, which is what lets small codes decode).
``prefer="uncertainty"`` (default) chooses per frame by each pose's predicted range
error: both run within the near range (far first; the QR skipped beyond it, and also
when even its best case, keypoint noise at ``min_sigma_px`` and a range 0.8 x the LED's,
predicts a larger error than the LED pose's: then it cannot win), and of two
estimates the one with the smaller

    sigma_Z = 0.87 Z^2 sigma_px / (f S)

wins (:func:`range_sigma_m`; Z the estimate's range, f the focal length in px, S the
marker's keypoint span (diagonal) in m, sigma_px the keypoint noise: the pose's RMS
reprojection residual corrected for the 6 pose parameters it absorbed, not below
``min_sigma_px``). The formula is the range error of a square of 4 points: Z = f R / r
for the half-diagonal R and its image r, whose mean over 4 points has
sigma_r = sqrt(3/4) sigma_px / 2 = 0.43 sigma_px, so sigma_Z = Z^2 0.43 sigma_px / (f S / 2).
On the demo dock the LED array (0.85 m diagonal) beats the 0.21 m QR by 4x in S: the LED
answers wherever it is fully seen and fits, the QR close in (LED array out of view) or
when the LED fit is poor. The hybrid is then never worse than its better part, where the
article's rule took QR poses with 20-24 cm of range error at 2-3 m (physical-mode
turbidity experiment) over LED poses ten times better.
``prefer="footprint"`` (option) chooses by expected precision instead: within the near
range both markers are run and the one spanning more pixels (f * its keypoint span / d)
wins, which is the LED array whenever it is fully seen (0.6 m against 0.15 m on the demo,
where the LED's distance error is ~0.04 % against ~0.3 % for the QR at 2-2.5 m); the QR
answers when the LED array is out of view (close in) or lost.

The estimate is the sub-localizer's dict (``marker_id`` is the marker actually used,
and reaches estimates.parquet) plus ``"source"`` (``"near"`` / ``"far"``),
``"near_range_m"`` and ``"range_sigma_m"`` (its predicted range error, m).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from evalkit.localizers.square import FULL_POSE_WITH_ID


class HybridLocalizer:
    """Hybrid of a near marker (QR) and the LED array: per frame the pose with the smaller predicted range error."""

    name = "hybrid"
    outputs = FULL_POSE_WITH_ID

    def __init__(
        self,
        near: str = "qr",
        far: str = "led",
        near_params: dict | None = None,
        far_params: dict | None = None,
        near_marker_id: str | None = None,
        far_marker_id: str | None = None,
        min_px_per_module: float = 1.3,
        switch_m: float | None = None,
        prefer: str = "uncertainty",
        min_sigma_px: float = 0.1,
    ):
        """near / far: localizer specs (registry names: qr, aruco, apriltag / led, or any
        spec) with constructor params near_params / far_params; near_marker_id /
        far_marker_id: manifest marker ids (None: each sub-localizer's default).
        min_px_per_module: smallest module (cell) size in px the near marker's decoder
        reads; sets the near range (see the module docstring). switch_m: near range in
        metres given directly (None: derived). prefer: "uncertainty" (default: within the
        near range both are run and the pose with the smaller predicted range error wins),
        "near" (the article's: the near marker whenever it is found) or "footprint" (the
        marker spanning more pixels); see the module docstring. min_sigma_px: floor of
        the keypoint noise (px) a pose's residual can claim: 0.1 px, the median centroid
        error of the LED core centroid on the demo (evalkit.localizers.led, step 3) and
        below the QR's ~0.15 px aligned-corner error."""
        from evalkit import registry

        if prefer not in PREFER:
            raise ValueError(f"prefer must be one of {', '.join(PREFER)}, got {prefer!r}")
        self.prefer = prefer
        self.min_sigma_px = float(min_sigma_px)
        if not self.min_sigma_px > 0:
            raise ValueError(f"min_sigma_px must be > 0, got {self.min_sigma_px}")
        self._f: float | None = None
        self._span_m: dict[str, float] = {}
        self.min_px_per_module = float(min_px_per_module)
        self.switch_m = None if switch_m is None or str(switch_m) in ("None", "") else float(switch_m)
        if not self.min_px_per_module > 0 or (self.switch_m is not None and not self.switch_m > 0):
            raise ValueError(
                f"need min_px_per_module > 0 and switch_m > 0, got {self.min_px_per_module}, {self.switch_m}"
            )
        subs = {}
        for role, spec, params, mid in (
            ("near", near, near_params, near_marker_id),
            ("far", far, far_params, far_marker_id),
        ):
            p = dict(params or {})
            if mid is not None:
                p["marker_id"] = mid
            subs[role] = registry.resolve(str(spec), p)
        self.subs = subs
        self.near_range_m = self.switch_m if self.switch_m is not None else float("inf")
        self._last_d: float | None = None
        self._last_far_T: np.ndarray | None = None
        self._ran: set[str] = set()

    def reset(self, camera: dict) -> None:
        """New sequence: reset both sub-localizers, derive the near range, forget the last distance."""
        for sub in self.subs.values():
            sub.reset(camera)
        self._last_d = None
        self._last_far_T = None
        self._span_m = {str(m.get("id")): marker_span_m(m) for m in camera.get("markers") or [] if isinstance(m, dict)}
        if self.switch_m is not None:
            self.near_range_m = self.switch_m
            return
        module_m = near_module_size_m(self.subs["near"], camera)
        K = camera.get("K")
        self._f = (
            None
            if K is None
            else float(0.5 * (np.asarray(K, float).reshape(3, 3)[0, 0] + np.asarray(K, float).reshape(3, 3)[1, 1]))
        )
        if module_m is None or K is None:
            self.near_range_m = float("inf")  # unknown: always worth trying
            return
        K = np.asarray(K, float).reshape(3, 3)
        f = 0.5 * (K[0, 0] + K[1, 1])
        self.near_range_m = f * module_m / self.min_px_per_module

    def localize(self, image: np.ndarray) -> dict | None:
        """The chosen estimate (``prefer``, module docstring), or None."""
        self._ran = set()
        if self.prefer == "footprint":
            est, used = self._by_footprint(image)
        elif self.prefer == "uncertainty":
            est, used = self._by_uncertainty(image)
        else:
            est, used = self._near_first(image)
        if "far" not in self._ran:  # its prior is the previous *frame's* pose: none now
            forget = getattr(self.subs["far"], "forget_prior", None)
            if callable(forget):
                forget()
        self._last_d = None if est is None else float(est["distance"])
        self._last_far_T = est.get("T_cam_dock") if est is not None and used == "far" else None
        if est is None:
            return None
        return {**est, "source": used, "near_range_m": self.near_range_m, "range_sigma_m": self._sigma(est)}

    def _near_first(self, image: np.ndarray) -> tuple[dict | None, str]:
        """prefer=near: (estimate, role) with the near marker whenever it is found."""
        if self._last_d is not None and self._last_d <= self.near_range_m:
            if self._last_far_T is not None:
                self._hint(self._last_far_T)  # the QR was not found last frame: look where the LED put it
            est, used = self._try("near", image), "near"
            if est is None:
                est, used = self._try("far", image), "far"
        else:
            est, used = self._try("far", image), "far"
            if est is None or est["distance"] <= self.near_range_m:
                if est is not None and est.get("T_cam_dock") is not None:
                    self._hint(est["T_cam_dock"])  # look for the QR where the LED pose puts it
                near = self._try("near", image)
                if near is not None:
                    est, used = near, "near"
        return est, used

    def _by_footprint(self, image: np.ndarray) -> tuple[dict | None, str]:
        """prefer=footprint: far always; near too within the near range (or when far
        fails); of two estimates the one whose marker spans more pixels (f span / d)."""
        far = self._try("far", image)
        if far is not None and far["distance"] > self.near_range_m:
            return far, "far"
        if far is not None and far.get("T_cam_dock") is not None:
            self._hint(far["T_cam_dock"])
        near = self._try("near", image)
        if near is None or far is None:
            return (near, "near") if near is not None else (far, "far")
        px = {
            role: self._span_m.get(str(e.get("marker_id")), 0.0) / max(float(e["distance"]), 1e-9)
            for role, e in (("near", near), ("far", far))
        }
        return (near, "near") if px["near"] > px["far"] else (far, "far")

    def _by_uncertainty(self, image: np.ndarray) -> tuple[dict | None, str]:
        """prefer=uncertainty: far always; near too within the near range (or when far
        fails); of two estimates the one with the smaller predicted range error."""
        far = self._try("far", image)
        if far is not None and far["distance"] > self.near_range_m:
            return far, "far"
        if far is not None and far.get("T_cam_dock") is not None:
            self._hint(far["T_cam_dock"])
        if far is not None and self._sigma(far) < self._near_best_sigma(far):
            return far, "far"  # the near marker could not win: not run
        near = self._try("near", image)
        if near is None or far is None:
            return (near, "near") if near is not None else (far, "far")
        return (near, "near") if self._sigma(near) < self._sigma(far) else (far, "far")

    def _near_best_sigma(self, far: dict) -> float:
        """The smallest predicted range error (m) a near estimate could have on this frame:
        its keypoint noise at the floor ``min_sigma_px`` and its range NEAR_RANGE_FLOOR x
        the far estimate's; 0 when the near marker's span or the focal length is unknown
        (then it is always run)."""
        marker = getattr(self.subs["near"], "_marker", None)
        span = self._span_m.get(str(marker.get("id")), 0.0) if isinstance(marker, dict) else 0.0
        if not span or not self._f:
            return 0.0
        return range_sigma_m(NEAR_RANGE_FLOOR * float(far["distance"]), self._f, span, None, None, self.min_sigma_px)

    def _sigma(self, est: dict) -> float:
        """Predicted range error (m) of an estimate (:func:`range_sigma_m`); inf when the
        marker's span or the focal length is unknown."""
        span = self._span_m.get(str(est.get("marker_id")), 0.0)
        if not span or not self._f:
            return float("inf")
        return range_sigma_m(
            float(est["distance"]), self._f, span, est.get("reproj_err_px"), est.get("n_points"), self.min_sigma_px
        )

    def _hint(self, T_cam_dock) -> None:
        """Tell the near localizer where to look first (if it takes hints)."""
        hint = getattr(self.subs["near"], "set_roi_hint", None)
        if callable(hint):
            hint(T_cam_dock)

    def _try(self, role: str, image: np.ndarray) -> dict | None:
        self._ran.add(role)
        est = self.subs[role].localize(image)
        if not isinstance(est, dict):
            return None
        try:
            d = float(est["distance"])
        except (KeyError, TypeError, ValueError):
            return None
        return est if np.isfinite(d) and d >= 0 else None

    def close(self) -> Any:
        for sub in self.subs.values():
            close = getattr(sub, "close", None)
            if callable(close):
                close()


PREFER = ("uncertainty", "near", "footprint")
#: prefer=uncertainty skips the near marker when even a near estimate this fraction of the
#: far one's range, with keypoint noise at the floor, would predict a larger range error:
#: 0.8 is twice the evaluation's default 10 % distance tolerance (``dockbench evaluate
#: --max-rel-error``), so a near estimate shorter than that disagrees with a far one that
#: fits, and one of the two fails anyway.
NEAR_RANGE_FLOOR = 0.8


def keypoint_sigma_px(reproj_rms_px, n_points, floor_px: float) -> float:
    """Keypoint noise (px) from a pose fit's RMS reprojection residual over ``n_points``
    points: rms sqrt(2N / (2N - 6)) (the 6 pose parameters absorb part of the noise), not
    below ``floor_px``; ``floor_px`` when the residual or N (> 3) is unknown."""
    try:
        rms, n = float(reproj_rms_px), int(n_points)
    except (TypeError, ValueError):
        return floor_px
    if not np.isfinite(rms) or n <= 3:
        return floor_px
    return max(floor_px, rms * float(np.sqrt(2.0 * n / (2.0 * n - 6.0))))


def range_sigma_m(
    distance_m: float, f_px: float, span_m: float, reproj_rms_px=None, n_points=None, floor_px: float = 0.1
) -> float:
    """Predicted range error (m) of a planar marker's pose: 0.87 Z^2 sigma_px / (f S) for
    range Z (m), focal length f (px), keypoint span S (m) and keypoint noise sigma_px
    (:func:`keypoint_sigma_px`); derivation in the module docstring."""
    sigma_px = keypoint_sigma_px(reproj_rms_px, n_points, floor_px)
    return 0.87 * distance_m**2 * sigma_px / (f_px * span_m)


def marker_span_m(marker: dict) -> float:
    """Largest distance (m) between two keypoints of a manifest marker (0 if unknown)."""
    try:
        kp = np.asarray(marker["keypoints"], float).reshape(-1, 3)
    except (KeyError, TypeError, ValueError):
        return 0.0
    if len(kp) < 2 or not np.all(np.isfinite(kp)):
        return 0.0
    return float(np.max(np.linalg.norm(kp[:, None, :] - kp[None, :, :], axis=2)))


def near_module_size_m(sub: Any, camera: dict) -> float | None:
    """Module (cell) side in metres of the marker the near sub-localizer uses, or None."""
    marker = getattr(sub, "_marker", None)
    if not isinstance(marker, dict):
        return None
    if marker.get("module_size_m"):
        return float(marker["module_size_m"])
    size = marker.get("size_m")
    if not size:
        return None
    if marker.get("kind") == "qr":
        n = marker.get("modules") or getattr(sub, "_n", None)
        return float(size) / int(n) if n else None
    if marker.get("dictionary"):
        import cv2

        try:
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, marker["dictionary"]))
        except (AttributeError, cv2.error):
            return None
        return float(size) / (d.markerSize + 2)
    return None
