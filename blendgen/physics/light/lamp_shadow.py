"""Screen-space shadows of the vehicle lamp, fast fidelity: which surface points see the lamp.

Pure numpy (+ cv2 for one resampling). Camera frame (OpenCV: x right, y down, z forward),
metres, pinhole ``K`` (3, 3); the range pass ``range_m`` (H, W) is the distance from the
camera centre along each pixel's ray (inf: no surface).

A surface point ``X = r u`` is in the lamp's shadow when the segment from ``X`` to the lamp
``S`` passes behind a nearer surface. The segment's image is a straight line from X's pixel
toward the image of ``S`` (the epipole; at infinity for a lamp beside the camera, so every
segment runs the same way). It is marched in the image, the classic screen-space ray march
(e.g. McGuire & Mara, "Efficient GPU screen-space ray tracing", JCGT 3(4), 2014): at an image
offset ``delta`` from X's pixel the segment's parameter ``t`` follows in closed form from
the projective map (``A = K X``, ``B = K (S - X)``, ``D = B_xy A_z - A_xy B_z``):

    t(delta) = delta A_z^2 / (|D| - delta A_z B_z)

The samples' offsets tile the line into pieces (boundaries half-way between samples, at least
+- 0.5 px). The surface seen at a piece's centre or either end is a candidate occluder when its
range lies inside the piece's range interval, less a bias (half a pixel of the pass's own
range slope along the march, the smaller one-sided difference so that depth edges do not
inflate it: the rounding of a sample to a pixel), or at most ``THICKNESS_M`` in front of it
(objects are assumed that thick behind their visible face: a thin plate casts the shadow of
a 5 mm plate, under a pixel at metres of range). It occludes if, where the segment's range
equals the candidate's (a quadratic in ``t``), the pixel under the segment shows that same
surface: the crossing is located to the pixel however long the piece (tested: every shadow
edge within 1 px of the geometric one at 160-640 px, ``tests/test_lamp_shadow.py``).

Sampling: every pixel up to ``DENSE_PX``, then offsets growing by ``STEP_RATIO``. An occluder at
depth ``z`` is met at an offset ``delta ~ f |S_perp| / z``, where one step covers ``(STEP_RATIO - 1)
|S_perp|`` of it (metres, any z): with a 0.3 m lamp offset and 1.05, occluders wider than 1.5 cm
along the offset are never stepped over. The march stops where the segment is nearer than
the nearest surface of the frame (nothing can hide it there) or leaves the image (no data:
lit). Cost: the test runs on every ``GRID_PX``-th pixel (every 2nd at 240 px, every pixel at
120), the visibility is interpolated bilinearly, and the pixels where it is fractional (shadow edges) are marched
again at full
resolution, so edges are exact to the pixel; a shadow narrower than ``GRID_PX`` falling
between grid pixels is missed (documented limit).

Limits: the range pass sees only what the camera sees (an occluder outside the frame, or
hidden behind another surface, casts no shadow; an edge cast by a face the camera cannot see,
e.g. a slab's far rim, is drawn as if the object were ``THICKNESS_M`` thick); the lamp is a point (hard shadows, as the
reference's radius-0 spot).
"""

from __future__ import annotations

import functools

import numpy as np

#: Offsets (px) marched one by one before the steps start growing.
DENSE_PX = 16
#: Ratio between successive march offsets beyond DENSE_PX.
STEP_RATIO = 1.05
#: Assumed thickness (m) of an occluder behind its visible face.
THICKNESS_M = 0.005
#: Constant part (m) of the depth bias.
BIAS_M = 1e-3
#: Grid step (px) of the first pass.
GRID_PX = 4
#: The volume (veil) march: coarser, the veil is evaluated on 16-px blocks (steps of
#: 0.15 |S_perp|: occluders narrower than ~5 cm at a 0.3 m offset may be stepped over).
VOLUME_DENSE_PX, VOLUME_STEP_RATIO = 4, 1.15
#: Pixels per chunk of the march (bounds memory: chunk x offsets x a few float32).
CHUNK = 16384


def march_offsets(max_px: float, dense: int = DENSE_PX, ratio: float = STEP_RATIO) -> np.ndarray:
    """(S,) float32 image offsets (px): 1 .. ``dense``, then x ``ratio`` up to ``max_px``."""
    out = list(range(1, dense + 1))
    while out[-1] < max_px:
        out.append(out[-1] * ratio)
    return np.asarray(out, np.float32)


def range_slope(range_m: np.ndarray) -> np.ndarray:
    """(H, W, 2) float32 range change per pixel (m/px) of the pass along u and v: the smaller
    one-sided difference (a depth edge does not inflate the slope of the surfaces on either side)."""
    r = np.where(np.isfinite(range_m), range_m, 1e6).astype(np.float32)
    out = np.zeros((*r.shape, 2), np.float32)
    for k, axis in enumerate((1, 0)):
        d = np.abs(np.diff(r, axis=axis))
        lo = np.concatenate([np.full_like(np.take(d, [0], axis=axis), np.inf), d], axis=axis)
        hi = np.concatenate([d, np.full_like(np.take(d, [0], axis=axis), np.inf)], axis=axis)
        s = np.minimum(lo, hi)
        out[..., k] = np.where(np.isfinite(s), s, 0.0)
    return out


def _segment_range(t, xx, xs, ss):
    """|X + t (S - X)| from |X|^2, X.S, |S|^2 (broadcast)."""
    return np.sqrt(np.maximum(xx * (1 - t) ** 2 + 2 * t * (1 - t) * xs + t * t * ss, 0.0))


def _march(
    points: np.ndarray, lamp: np.ndarray, K: np.ndarray, table: np.ndarray, offsets: np.ndarray, z_min: float
) -> np.ndarray:
    """(N,) bool: is the segment from each point (N, 3) to ``lamp`` (3,) behind a surface of the pass.

    The march's offsets tile the segment's image into pieces (boundaries half-way between
    samples, at least +- 0.5 px). A surface seen at the piece's centre or either end is a
    candidate when its range lies within the piece's range interval (less the bias) or at most
    THICKNESS_M in front of it; it occludes if, where the segment's range equals it, the pixel
    under the segment shows that same surface (within the same tolerances)."""
    X = points.astype(np.float32)
    A = X @ K.T
    B = (lamp[None, :] - X) @ K.T
    az, bz = A[:, 2:3], B[:, 2:3]
    a = A[:, :2] / az  # the point's own pixel (N, 2)
    D = B[:, :2] * az - A[:, :2] * bz
    nd = np.sqrt(np.einsum("nk,nk->n", D, D))[:, None]
    e = D / np.maximum(nd, np.float32(1e-12))
    xx = np.einsum("nk,nk->n", X, X)[:, None]
    xs, ss = (X @ lamp)[:, None], float(lamp @ lamp)
    gaps = np.diff(offsets, prepend=0.0, append=2 * offsets[-1] - offsets[-2])
    bnd = np.concatenate([offsets - np.maximum(gaps[:-1] / 2, 0.5), offsets[-1:] + np.maximum(gaps[-1:] / 2, 0.5)])
    den = nd - bnd[None, :] * az * bz
    tb = np.minimum(np.where(den > 0, bnd[None, :] * az * az / np.where(den > 0, den, 1.0), 1.0), 1.0)
    rb = _segment_range(tb, xx, xs, ss)  # (N, S + 1)
    hi, lo = np.maximum(rb[:, :-1], rb[:, 1:]), np.minimum(rb[:, :-1], rb[:, 1:])
    ok = (tb[:, :-1] < 1) & ((X[:, 2:3] + tb[:, :-1] * (lamp[2] - X[:, 2:3])) > z_min)
    Rb, bias_b = _lookup(table, a, e, bnd[None, :], np.ones(rb.shape, bool))
    R, bias = _lookup(table, a, e, offsets[None, :], ok)
    out = np.zeros(len(X), bool)
    thick = np.float32(THICKNESS_M)
    for Rk, bk in ((R, bias), (Rb[:, :-1], bias_b[:, :-1]), (Rb[:, 1:], bias_b[:, 1:])):
        n, k = np.nonzero(ok & (Rk < hi - bk) & (Rk > lo - thick) & ~out[:, None])
        if n.size == 0:
            continue
        r, h_, l_ = Rk[n, k], hi[n, k], lo[n, k]
        a2, a1, a0 = (xx - 2 * xs + ss)[n, 0], 2 * (xs - xx)[n, 0], xx[n, 0] - r * r
        tc = (-a1 - np.sqrt(np.maximum(a1 * a1 - 4 * a2 * a0, 0.0))) / (2 * a2)
        tc = np.clip(tc, tb[n, k], tb[n, k + 1])
        dc = tc * nd[n, 0] / (az[n, 0] * np.maximum(az[n, 0] + tc * bz[n, 0], np.float32(1e-9)))
        Rc, bc = _lookup(table, a[n], e[n], dc[:, None], np.ones((n.size, 1), bool))
        hit = (Rc[:, 0] < h_ - bc[:, 0]) & (Rc[:, 0] > l_ - thick)
        out[n[hit]] = True
    return out


def _lookup(table, a, e, dl, ok):
    """Range pass at the pixels nearest ``a + dl e`` (N, S) (inf where not ``ok`` or outside) and
    its bias: half a pixel of the pass's range slope along the march direction, plus BIAS_M.
    ``table`` (H, W, 3): range, slope along u, slope along v (:func:`_table`)."""
    h, w = table.shape[:2]
    qu = np.rint(a[:, :1] + dl * e[:, :1]).astype(np.int32)
    qv = np.rint(a[:, 1:] + dl * e[:, 1:]).astype(np.int32)
    ok = ok & (qu >= 0) & (qu < w) & (qv >= 0) & (qv < h)
    got = table.reshape(-1, 3)[np.where(ok, qv * w + qu, 0)]
    R = np.where(ok, got[..., 0], np.float32(np.inf))
    bias = np.float32(BIAS_M) + 0.5 * (got[..., 1] * np.abs(e[:, :1]) + got[..., 2] * np.abs(e[:, 1:]))
    return R, bias


def _table(range_m: np.ndarray, slope: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) float32: range, and its slope along u and v (:func:`range_slope`)."""
    slope = range_slope(range_m) if slope is None else slope
    return np.concatenate([range_m[..., None].astype(np.float32), slope.astype(np.float32)], axis=-1)


def occluded(
    points: np.ndarray,
    lamp,
    K,
    range_m: np.ndarray,
    table: np.ndarray | None = None,
    max_px: float | None = None,
    z_min: float | None = None,
    coarse: bool = False,
) -> np.ndarray:
    """(N,) bool: which camera-frame points (N, 3) are hidden from the point ``lamp`` (3,) by a
    surface of ``range_m`` (H, W) under the pinhole ``K`` (module doc). ``max_px`` bounds the
    march (None: the image diagonal); ``z_min`` (m) the nearest surface depth (None: 0); ``coarse``:
    the volume's march steps (VOLUME_DENSE_PX, VOLUME_STEP_RATIO)."""
    K = np.asarray(K, np.float32)
    lamp = np.asarray(lamp, np.float32).reshape(3)
    h, w = range_m.shape
    table = _table(range_m) if table is None else table
    steps = (VOLUME_DENSE_PX, VOLUME_STEP_RATIO) if coarse else (DENSE_PX, STEP_RATIO)
    offsets = march_offsets(float(np.hypot(h, w)) if max_px is None else max(float(max_px), 1.0), *steps)
    z0 = 0.0 if z_min is None else float(z_min)
    out = np.zeros(len(points), bool)
    for i in range(0, len(points), CHUNK):
        out[i : i + CHUNK] = _march(points[i : i + CHUNK], lamp, K, table, offsets, z0)
    return out


def _march_bound(points: np.ndarray, lamp: np.ndarray, K: np.ndarray, z_min: float, diag: float) -> float:
    """Longest image offset (px) at which any point's segment is still farther than ``z_min``."""
    X = points.astype(np.float64)
    denom = X[:, 2] - lamp[2]
    ts = np.clip(np.where(denom > 1e-9, (X[:, 2] - z_min) / np.where(denom > 1e-9, denom, 1.0), 0.0), 0.0, 1.0)
    A, B = X @ K.T, (lamp[None, :] - X) @ K.T
    Y = A + ts[:, None] * B
    yz = np.maximum(Y[:, 2], 1e-9)
    d = np.hypot(Y[:, 0] / yz - A[:, 0] / A[:, 2], Y[:, 1] / yz - A[:, 1] / A[:, 2])
    return float(min(np.max(d, initial=0.0) + 2.0, diag))


@functools.lru_cache(maxsize=4)
def _grid_maps(h: int, w: int, step: int):
    """cv2.remap maps from a grid sampled at every ``step``-th pixel (0, step, ...) to (h, w)."""
    mx, my = np.meshgrid(np.arange(w, dtype=np.float32) / step, np.arange(h, dtype=np.float32) / step)
    return mx, my


def visibility(
    lamp, K, rays: np.ndarray, range_m: np.ndarray, step: int = GRID_PX, mask: np.ndarray | None = None
) -> np.ndarray:
    """(H, W) float32 in {0, 1}: 1 where the
    surface point of each pixel sees the point ``lamp`` (3,), camera frame; 1 where no surface.
    rays (H, W, 3) unit pixel rays; range_m (H, W); mask (H, W) bool: the only pixels tested
    (e.g. those the lamp's cone reaches; None: all). Coarse pass + full-resolution edges (module doc)."""
    import cv2

    K = np.asarray(K, np.float64)
    lamp = np.asarray(lamp, np.float64).reshape(3)
    h, w = range_m.shape
    step = int(max(1, min(step, min(h, w) // 120)))  # small images: every pixel (they are cheap)
    surf = np.isfinite(range_m) & (range_m > 0)
    hit = surf if mask is None else surf & mask
    if not hit.any():
        return np.ones((h, w), np.float32)
    r = np.where(surf, range_m, np.inf).astype(np.float32)
    pts = rays * np.where(surf, r, 0.0)[..., None]
    z_min = float(pts[..., 2][surf].min())
    table = _table(r)
    cg, ch = hit[::step, ::step], pts[::step, ::step]
    bound = _march_bound(ch[cg], lamp, K, z_min, float(np.hypot(h, w)))
    coarse = np.ones(cg.shape, np.float32)
    coarse[cg] = 1.0 - occluded(ch[cg], lamp, K, r, table, bound, z_min)
    vis = cv2.remap(coarse, *_grid_maps(h, w, step), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    edge = hit & (vis > 1e-4) & (vis < 1 - 1e-4)
    vis[edge] = 1.0 - occluded(pts[edge], lamp, K, r, table, bound, z_min)
    vis[~hit] = 1.0
    return vis


def _pixel_rays(K: np.ndarray, h: int, w: int) -> np.ndarray:
    """(H, W, 3) float32 unit rays through the pixel centres of the pinhole K."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    d = np.dstack([x, y, np.ones_like(x)])
    return (d / np.linalg.norm(d, axis=2, keepdims=True)).astype(np.float32)


def volume_visibility(lamp, K, range_m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) float32 in {0, 1}: which points of the water (N, 3), camera frame, see the point
    ``lamp`` (3,) past the surfaces of the range pass (H, W): the same march as :func:`visibility`.
    Points nearer than every surface of the frame (and the lamp) see it without a march."""
    K = np.asarray(K, np.float64)
    lamp = np.asarray(lamp, np.float64).reshape(3)
    h, w = range_m.shape
    surf = np.isfinite(range_m) & (range_m > 0)
    out = np.ones(len(points), np.float32)
    if not surf.any():
        return out
    r = np.where(surf, range_m, np.inf).astype(np.float32)
    z_min = float((_pixel_rays(K, h, w)[..., 2] * np.where(surf, r, 0.0))[surf].min())
    test = points[:, 2] > max(z_min, lamp[2])
    if test.any():
        bound = _march_bound(points[test], lamp, K, z_min, float(np.hypot(h, w)))
        out[test] = 1.0 - occluded(points[test], lamp, K, r, None, bound, z_min, coarse=True)
    return out
