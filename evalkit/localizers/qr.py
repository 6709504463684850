"""QR-code localizer: zxing-cpp (default) or OpenCV detector, payload check, ECC-aligned corners, PnP.

Detectors (``detector=``), measured on the quickstart demo (``dockbench bench localizers``):
``zxing`` (zxing-cpp, default: decodes the 21-module code down to ~1.4 px per
module, ~0.3 ms per 640x480 frame), ``aruco`` (cv2.QRCodeDetectorAruco) and ``classic``
(cv2.QRCodeDetector). Only a decoded payload equal to the marker's counts (unless
``allow_undecoded``).

Every detector gives the code's outer corners TL, TR, BR, BL in the code's own
orientation (zxing-cpp on the integer pixel grid, OpenCV with BR extrapolated, 1-3 px
off). Sub-pixel refinement (``refine=``) before PnP:

* ``ecc`` (default; used up to ECC_MAX_MODULE_PX = 5 px per module, ``finders`` above,
  where the template would need more pixels than 15 iterations converge on): direct
  alignment of the known code. The code's module matrix is
  rebuilt from the payload and error-correction level with segno (as blendgen makes
  it), drawn as a template with a 2-module quiet zone, and aligned to the linear-intensity
  image with cv2.findTransformECC (homography, started from the detector's quad). Every
  module edge votes, so it stays sub-pixel down to the decode limit (~0.15 px corner
  error at 1.5-7 px/module on synthetic oracles, where cornerSubPix on finder corners
  gives 0.2-0.4 px and runs away below ~3 px/module). The 4 aligned code corners go to
  IPPE_SQUARE. Falls back to ``finders`` when the alignment does not converge, correlates
  below ``min_ecc`` or moves a corner by more than 1.5 modules.
* ``finders``: the 12 outer corners of the three finder patterns predicted through the
  detected quad, refined with cornerSubPix on linear intensity, SOLVEPNP_IPPE on them.
* ``subpix``: cornerSubPix on the 4 corners; ``none``: the detector's corners.
Whatever fails falls back to IPPE_SQUARE on the detector's 4 corners.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from evalkit.localizers.pnp import estimate_dict, invert_T, solve_planar
from evalkit.localizers.square import (
    SUBPIX_CRITERIA,
    SquareMarkerLocalizer,
    _as_bool,
    linear_gray,
    refine_corners,
    square_pose_estimate,
)

DETECTORS = ("zxing", "aruco", "classic")
REFINES = ("ecc", "finders", "subpix", "none")


def qr_modules(payload: str) -> int | None:
    """Modules per side of the QR code blendgen makes for ``payload`` (segno, error level M,
    smallest version), or None if segno is unavailable."""
    try:
        import segno

        return 17 + 4 * int(segno.make_qr(payload, error="m", boost_error=False).version)
    except Exception:  # noqa: BLE001 - segno missing or payload not encodable
        return None


def finder_module_corners(n: int) -> np.ndarray:
    """Outer corners (12,2) of the three 7x7 finder patterns in module coordinates
    (x right, y down, the code spanning [0, n]^2): TL, TR and BL finders, each TL, TR, BR, BL."""
    sq = np.array([[0, 0], [7, 0], [7, 7], [0, 7]], float)
    return np.vstack([sq, sq + [n - 7, 0], sq + [0, n - 7]])


def module_to_marker(pts_mod: np.ndarray, n: int, size_m: float) -> np.ndarray:
    """Module coordinates (N,2) -> marker-frame points (N,3), metres (y up, z = 0)."""
    s = size_m / n
    return np.column_stack([-size_m / 2 + pts_mod[:, 0] * s, size_m / 2 - pts_mod[:, 1] * s, np.zeros(len(pts_mod))])


def refine_finder_corners(
    gray: np.ndarray, quad: np.ndarray, n: int, min_module_px: float = 2.0
) -> tuple[np.ndarray, np.ndarray] | None:
    """Sub-pixel finder-pattern corners predicted from the detected quad (4,2) px in
    ``gray`` (H,W): uint8 sRGB codes (decoded to linear intensity in the code's window
    here, so that corners are unbiased, see square.linear_gray) or float linear intensity.

    Returns (module coordinates (M,2), refined pixels (M,2)) of the M >= 8 corners that
    agree with one homography (RANSAC), or None when modules are smaller than
    ``min_module_px`` or too few corners agree."""
    code = np.array([[0, 0], [n, 0], [n, n], [0, n]], np.float32)
    module_px = float(np.min(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1))) / n
    if module_px < min_module_px:
        return None
    win = int(np.clip(np.floor(0.5 * module_px), 2, 5))  # stays inside the finder's 1-module ring
    H0 = cv2.getPerspectiveTransform(code, quad.astype(np.float32))
    mod = finder_module_corners(n)
    pred = cv2.perspectiveTransform(mod.reshape(-1, 1, 2).astype(np.float32), H0)
    h, w = gray.shape
    p = pred.reshape(-1, 2)
    if np.any(p < win + 1) or np.any(p[:, 0] >= w - win - 1) or np.any(p[:, 1] >= h - win - 1):
        return None
    x0, y0 = (int(v) for v in np.floor(p.min(axis=0)) - win - 2)
    x1, y1 = (int(v) for v in np.ceil(p.max(axis=0)) + win + 3)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    win_img = gray[y0:y1, x0:x1]
    if win_img.dtype == np.uint8:
        win_img = linear_gray(win_img)
    ref = (pred - np.array([x0, y0], np.float32)).copy()
    cv2.cornerSubPix(np.ascontiguousarray(win_img), ref, (win, win), (-1, -1), SUBPIX_CRITERIA)
    ref = ref.reshape(-1, 2).astype(np.float64) + (x0, y0)
    keep = np.all(np.isfinite(ref), axis=1) & (np.linalg.norm(ref - p, axis=1) <= 1.5 * win)
    if keep.sum() < 8:
        return None
    H, inl = cv2.findHomography(mod[keep], ref[keep], cv2.RANSAC, max(0.5, 0.1 * module_px))
    if H is None or inl is None or int(inl.sum()) < 8:
        return None
    idx = np.nonzero(keep)[0][inl.ravel().astype(bool)]
    return mod[idx], ref[idx]


class QrLocalizer(SquareMarkerLocalizer):
    """QR code (zxing-cpp by default, payload-checked) -> finder-corner PnP pose of the dock."""

    name = "qr"
    # one call per frame shared with the hybrid's QR (evalkit.memo); QrTrackLocalizer keeps more state: not shared
    memo_state = SquareMarkerLocalizer._roi_memo_state
    memo_after = SquareMarkerLocalizer._roi_memo_after
    memo_apply = SquareMarkerLocalizer._roi_memo_apply
    kinds = ("qr",)
    min_image_px = 21
    # Small codes: zxing-cpp reads twice as many of the demo's 2-4 m frames (1.4-2 px per
    # module) on a 2x bicubic resampling; done in the ROI only (full frame: 4x the cost).
    roi_upscale = 2.0

    def __init__(
        self,
        marker_id: str | None = None,
        detector: str = "zxing",
        allow_undecoded: bool = False,
        refine: str = "ecc",
        modules: int | None = None,
        roi: bool = True,
        binarizer: str = "LocalAverage",
        min_ecc: float = 0.6,
    ):
        """marker_id: manifest id (None: first qr marker). detector: "zxing" (zxing-cpp),
        "aruco" (cv2.QRCodeDetectorAruco) or "classic" (cv2.QRCodeDetector).
        allow_undecoded: accept a located code whose payload did not decode (zxing: one
        with checksum errors; OpenCV: a quad with empty text).
        refine: "ecc" (template alignment), "finders" (12 finder corners), "subpix"
        (cornerSubPix on the 4 corners) or "none" (see the module docstring).
        min_ecc: lowest ECC correlation (0-1) an alignment must reach to be used.
        modules: modules per side (None: the manifest's ``modules``, else from the payload).
        roi: search around the previous detection first (see SquareMarkerLocalizer).
        binarizer: zxing-cpp binarizer (LocalAverage, GlobalHistogram, FixedThreshold)."""
        if detector not in DETECTORS:
            raise ValueError(f"detector must be one of {', '.join(DETECTORS)}, got {detector!r}")
        if refine not in REFINES:
            raise ValueError(f"refine must be one of {', '.join(REFINES)}, got {refine!r}")
        super().__init__(marker_id, roi)
        self.detector = detector
        self.allow_undecoded = _as_bool(allow_undecoded)
        self.refine = refine
        self.modules = None if modules is None or str(modules) in ("None", "") else int(modules)
        self.binarizer = str(binarizer)
        self.min_ecc = float(min_ecc)
        self._read: Any = None  # gray image -> [(text, quad)], built by setup()
        self._n: int | None = None  # modules per side
        self._cells: np.ndarray | None = None

    def setup(self, marker: dict) -> dict | None:
        """Build the detector; module count from the params, the manifest or the payload."""
        if self.detector == "zxing":
            self._read = zxing_reader(self.binarizer, self.allow_undecoded)
        else:
            det = cv2.QRCodeDetectorAruco() if self.detector == "aruco" else cv2.QRCodeDetector()
            self._read = lambda gray: _opencv_read(det, gray)
        self._n = self.modules or marker.get("modules") or qr_modules(str(marker.get("payload", "")))
        self._cells = code_cells(str(marker.get("payload", "")), str(marker.get("error_correction", "M")))
        if self._cells is not None and self._cells.shape[0] != self._n:
            self._cells = None  # not the code blendgen makes for this payload: no template
        return marker

    def detect(self, gray: np.ndarray) -> list[np.ndarray]:
        """Quads (4,2) TL, TR, BR, BL of codes whose payload is the marker's."""
        want = self._marker.get("payload")
        return [quad for text, quad in self._read(gray) if text == want or (self.allow_undecoded and text is None)]

    def quad_pose(self, gray: np.ndarray, quad: np.ndarray) -> dict | None:
        """Finder-corner PnP when possible, else IPPE_SQUARE on the 4 corners."""
        m = self._marker
        if self.refine == "ecc" and self._cells is not None and module_size_px(quad, self._n) <= ECC_MAX_MODULE_PX:
            aligned = ecc_align_quad(gray, quad, self._cells, self.min_ecc)
            if aligned is not None:
                est = square_pose_estimate(aligned, m, self._K, self._dist)
                if est is not None:
                    return est
        if self.refine in ("ecc", "finders") and self._n:
            found = refine_finder_corners(gray, quad, self._n)
            if found is not None:
                obj = module_to_marker(found[0], self._n, float(m["size_m"]))
                pose = solve_planar(obj, found[1], self._K, self._dist)
                if pose is not None:
                    T_dm = np.asarray(m.get("T_dock_marker", np.eye(4)), np.float64).reshape(4, 4)
                    return estimate_dict(pose.T_cam_target @ invert_T(T_dm), m["id"], pose)
        if self.refine == "subpix":
            quad = refine_corners(linear_gray(gray), quad)
        return square_pose_estimate(quad, m, self._K, self._dist)


def code_cells(payload: str, error_correction: str = "M") -> np.ndarray | None:
    """Module matrix (n,n) uint8 (1 dark) of the QR code blendgen makes for ``payload``
    (segno, smallest version at the level, no boost), or None if it cannot be made."""
    try:
        import segno

        return np.array(segno.make_qr(payload, error=error_correction.lower(), boost_error=False).matrix, np.uint8)
    except Exception:  # noqa: BLE001 - segno missing or payload not encodable
        return None


ECC_MAX_MODULE_PX = 5.0  # above: finder corners are sharp and many px apart, cornerSubPix suffices


def module_size_px(quad: np.ndarray, n: int | None) -> float:
    """Mean side of the quad (4,2) px divided by the modules per side n (inf if unknown)."""
    if not n:
        return float("inf")
    return float(np.mean(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1))) / n


_ECC_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 15, 1e-2)
_TEMPLATE_QUIET = 2  # modules of white drawn around the template


def ecc_align_quad(gray: np.ndarray, quad: np.ndarray, cells: np.ndarray, min_ecc: float = 0.6, coarse: int = 0):
    """Code corners (4,2) TL, TR, BR, BL px aligned by cv2.findTransformECC (homography)
    of the code template ``cells`` (n,n; 1 dark) to ``gray`` (H,W uint8 sRGB), started
    from the detected ``quad`` (4,2); None if it fails, correlates below ``min_ecc`` or
    moves a corner by more than 1.5 modules (``max_move_modules``). coarse > 0: first
    align both images smoothed with a coarse x coarse Gaussian (wider basin, for starts
    several modules off such as the previous frame's corners); the move limit is then
    3 modules."""
    n = cells.shape[0]
    module_px = float(np.mean(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1))) / n
    s = int(np.clip(round(module_px), 2, 4))  # template px per module, ~ the image's
    q = _TEMPLATE_QUIET
    tmpl = np.pad(np.where(cells > 0, 0.0, 1.0).astype(np.float32), q, constant_values=1.0)
    tmpl = cv2.resize(tmpl, None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
    tmpl = cv2.GaussianBlur(tmpl, (0, 0), max(0.5, 0.5 * s / module_px))
    a, b = q * s - 0.5, (q + n) * s - 0.5  # template px of the code's edges
    code_t = np.array([[a, a], [b, a], [b, b], [a, b]], np.float32)
    span = quad.max(axis=0) - quad.min(axis=0)
    h, w = gray.shape
    x0, y0 = (int(max(0, v)) for v in np.floor(quad.min(axis=0) - 0.5 * span))
    x1, y1 = (int(v) for v in np.minimum([w, h], np.ceil(quad.max(axis=0) + 0.5 * span)))
    img = np.ascontiguousarray(linear_gray(gray[y0:y1, x0:x1]))
    H = cv2.getPerspectiveTransform(code_t, (quad - (x0, y0)).astype(np.float32)).astype(np.float32)
    try:
        if coarse:
            _, H = cv2.findTransformECC(tmpl, img, H, cv2.MOTION_HOMOGRAPHY, _ECC_CRITERIA, None, int(coarse))
        rho, H = cv2.findTransformECC(tmpl, img, H, cv2.MOTION_HOMOGRAPHY, _ECC_CRITERIA, None, 1)
    except cv2.error:  # not converged / singular
        return None
    if not (np.isfinite(rho) and rho >= min_ecc and np.all(np.isfinite(H))):
        return None
    out = cv2.perspectiveTransform(code_t.reshape(-1, 1, 2), H.astype(np.float64)).reshape(-1, 2) + (x0, y0)
    max_move_px = (3.0 if coarse else 1.5) * module_px
    if not np.all(np.isfinite(out)) or np.max(np.linalg.norm(out - quad, axis=1)) > max_move_px:
        return None
    return out


def zxing_reader(binarizer: str = "LocalAverage", with_errors: bool = False):
    """A function gray (H,W uint8) -> [(payload or None, quad (4,2) TL, TR, BR, BL px)] with
    zxing-cpp, QR codes only, no rotated/inverted/downscaled retries (a QR is found in any
    in-plane rotation; the dock's codes are dark on light). zxing-cpp reports corners on
    the pixel-edge grid (pixel i spans [i, i+1)): -0.5 moves them to pixel centres."""
    import zxingcpp

    try:
        binz = getattr(zxingcpp.Binarizer, binarizer)
    except AttributeError:
        raise ValueError(
            f"unknown zxing-cpp binarizer {binarizer!r} (LocalAverage, GlobalHistogram, FixedThreshold)"
        ) from None
    fmt = zxingcpp.BarcodeFormat.QRCode

    def read(gray: np.ndarray):
        out = []
        for b in zxingcpp.read_barcodes(
            gray,
            formats=fmt,  # type: ignore[arg-type]  # stub wants BarcodeFormats
            try_rotate=False,
            try_downscale=False,
            try_invert=False,
            binarizer=binz,
            return_errors=with_errors,
        ):
            p = b.position
            quad = (
                np.array([[c.x, c.y] for c in (p.top_left, p.top_right, p.bottom_right, p.bottom_left)], np.float64)
                - 0.5
            )
            out.append((b.text if b.valid else None, quad))
        return out

    return read


def _opencv_read(det, gray: np.ndarray):
    """[(payload or None, quad (4,2))] from an OpenCV QR detector (one code)."""
    text, pts, _ = det.detectAndDecode(gray)
    if pts is None:
        return []
    return [(text or None, np.asarray(pts, np.float64).reshape(-1, 2))]


class QrTrackLocalizer(QrLocalizer):
    """QR tracking: once the payload decoded in a sequence, also codes located but not decoded (ECC-verified)."""

    name = "qr_track"

    def __init__(
        self, marker_id: str | None = None, min_ecc: float = 0.8, roi: bool = True, binarizer: str = "LocalAverage"
    ):
        """Pose of a QR whose payload was decoded earlier in the same sequence, from codes
        that zxing-cpp locates (its three finder patterns) but can no longer decode.

        Identity: only after a decode of this marker's payload in the sequence (``reset``
        clears it); every located-but-undecoded code must then align with the known
        module matrix (ECC correlation >= ``min_ecc``, stricter than the decoded case)
        or it is dropped: no finder-corner or 4-corner fallback for undecoded codes.
        Candidates: codes zxing-cpp locates without decoding, OpenCV's QR locator, and
        the previous frame's corners (ECC coarse-to-fine: template tracking). On the
        synthetic oracles the right code aligns at rho >= 0.9 down to 1 px/module and
        another payload of the same version at rho < 0.7 (hence min_ecc 0.8).
        Estimates of tracked frames carry ``"tracked": True``. Reported as its own
        localizer (never mixed into ``qr``); off unless asked for (``-l qr_track``).
        roi, binarizer: as for ``qr``."""
        super().__init__(
            marker_id,
            detector="zxing",
            allow_undecoded=True,
            refine="ecc",
            roi=roi,
            binarizer=binarizer,
            min_ecc=min_ecc,
        )
        self._seen = False
        self._tracking = False
        self._locator = cv2.QRCodeDetector()

    def reset(self, camera: dict) -> None:
        """New sequence: forget the decode."""
        super().reset(camera)
        self._seen = False
        self._tracking = False

    def detect(self, gray: np.ndarray) -> list[np.ndarray]:
        """Decoded quads of the payload; after a decode in this sequence, else the located ones."""
        want = self._marker.get("payload")
        found = self._read(gray)
        decoded = [quad for text, quad in found if text == want]
        self._tracking = not decoded
        if decoded:
            return decoded
        if not self._seen or self._cells is None:
            return []
        located = [quad for text, quad in found if text is None]
        if not located:  # zxing found no finder triple: OpenCV's locator (finder patterns, no decode)
            ok, pts = self._locator.detect(gray)
            if ok and pts is not None:
                located = [np.asarray(pts, np.float64).reshape(-1, 2)]
        return located

    def _detect_roi_first(self, gray: np.ndarray) -> list[np.ndarray]:
        """Located quads; while tracking, also the last frame's code corners as a start
        for the ECC alignment (template tracking when no locator finds the code)."""
        quads = super()._detect_roi_first(gray)
        if self._seen and self._tracking and self._last_quad is not None and self._misses <= 1:
            quads = quads + [self._last_quad]
        return quads

    def quad_pose(self, gray: np.ndarray, quad: np.ndarray) -> dict | None:
        """Decoded: as ``qr``. Tracked: ECC alignment with the known code or nothing."""
        if not self._tracking:
            est = super().quad_pose(gray, quad)
            self._seen = self._seen or est is not None
            return est
        if self._last_quad is not None and np.array_equal(quad, self._last_quad):
            starts = [(quad, 3)]  # last frame's corners: coarse-to-fine (moves of a few modules)
        else:  # a locator's corner order may start at another finder: ECC decides
            starts = [(np.roll(quad, -k, axis=0), 0) for k in range(4)]
        if self._cells is None:
            return None
        for start, coarse in starts:
            aligned = ecc_align_quad(gray, start, self._cells, self.min_ecc, coarse)
            if aligned is not None:
                est = square_pose_estimate(aligned, self._marker, self._K, self._dist)
                return None if est is None else {**est, "tracked": True}
        return None
