"""Anti-aliased, depth-tested splatting of projected particles into per-pixel sums.

The fast path of :func:`blendgen.physics.particles.render_particles`. Every particle's
coverage samples are computed in blocks of particles whose pixel boxes have the same size,
laid out ``(k samples, m particles)`` so that every numpy loop runs along the long particle
axis (short inner axes such as (m, 4) or (m, 3) cost ~20x more per element), depth-tested,
stripped of zero-coverage samples and scattered into full-frame sums in two passes:
``np.minimum.at`` (nearest range) and one sparse product (pixels x samples, entries
alpha / d^2) @ (samples x [1, colour, log(1 - alpha) d^2 / alpha]) for all the other sums at
once (scipy's CSC kernel: one cache line per sample). Cost: a few nanoseconds per covered pixel sample plus tens of microseconds per
box size.

Per pixel (flat index ``k``) the sums are, over the samples in front of the surface
(``alpha_i`` the coverage times the particle's blur opacity, ``d_i`` the range to its surface):
``log_t[k] = sum log(1 - alpha_i)`` (so the transmittance ``T = prod(1 - alpha_i)``),
``w[k] = sum alpha_i / d_i^2`` and ``wc[c][k] = sum alpha_i c_i / d_i^2`` (the weights of the
order-independent mean colour, McGuire & Bavoil 2013) and ``near[k] = min d_i`` (inf: no
particle). Coverage: specks (semi-axis < 0.5 px) are splat bilinearly with alpha = their area (px^2),
larger ellipses get the anti-aliased ramp of :func:`coverage`, renormalised to the exact
area pi a b below 4 px.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

SPLAT_BELOW_PX = 0.5                 # semi-axis below which a particle is a bilinear speck
NORMALISE_BELOW_PX = 4.0             # small ellipses: rescale coverage to the exact area
GROUP_MAX_PX = 16                    # boxes up to this size are drawn in broadcast blocks
ALPHA_MAX = 1.0 - 1e-6               # keeps log(1 - alpha) finite
_F0, _F1 = np.float32(0.0), np.float32(1.0)


@dataclass
class Sums:
    """Per-pixel sums (module doc) at the covered pixels ``hit`` (n,) int64 (flat, ascending):
    log_t (n,) and ``wc`` (n, 1 + C) float32 = [w, w c_1 .. w c_C] (None without per-particle
    colours); ``near`` (H*W,) float32 for the whole frame (inf where nothing covers); ``trans``
    (n,) the transmittance T itself when the splat has it (then log_t may be None)."""
    hit: np.ndarray
    log_t: np.ndarray | None
    wc: np.ndarray | None
    near: np.ndarray
    trans: np.ndarray | None = None

    def transmittance(self) -> np.ndarray:
        """T = prod(1 - alpha_i) (n,) float32 at the covered pixels."""
        return self.trans if self.trans is not None else np.exp(self.log_t)


@dataclass
class Particles:
    """What the splat needs per particle (all (M,) float32 unless noted): centre u, v (px),
    semi-axes a (radial), b (px), radial direction c, s, surface range d (m), blur opacity
    op, colour (M, C) (C = 0: one colour for all, no colour sums)."""
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    s: np.ndarray
    d: np.ndarray
    op: np.ndarray
    colour: np.ndarray


class _Samples:
    """Live samples (alpha > 0, in front of the surface) gathered block by block."""

    def __init__(self, surf: np.ndarray, width: int, height: int):
        self.surf, self.width, self.height = surf, width, height
        self.owner, self.pix, self.alpha = [], [], []

    def add(self, p: Particles, sel, x, y, alpha, clip: bool = True) -> None:
        """Samples (k, m) of particles sel (m,) at integer pixels x, y (int64) with coverage x
        opacity ``alpha`` float32: clipped to the image (``clip``: some may be outside),
        depth-tested (a sample counts only where
        the scene surface is farther than the particle's surface range d) and kept if alpha > 0."""
        if clip:
            inside = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
            alpha = np.where(inside, alpha, _F0)
            x, y = np.clip(x, 0, self.width - 1), np.clip(y, 0, self.height - 1)
        pix = y * self.width + x
        live = (alpha > _F0) & (self.surf.take(pix) > p.d.take(sel))
        idx = np.flatnonzero(live)
        self.owner.append(np.tile(sel, alpha.shape[0]).take(idx))   # (k, m) row-major: sel repeats
        self.pix.append(pix.take(idx))
        self.alpha.append(alpha.take(idx))

    def sums(self, p: Particles) -> Sums:
        """Scatter the samples: minimum.at and one sparse product (module doc)."""
        n_pix, n_col = self.width * self.height, p.colour.shape[1]
        pix = np.concatenate(self.pix) if self.pix else np.zeros(0, np.int64)
        alpha = np.concatenate(self.alpha) if self.alpha else np.zeros(0, np.float32)
        owner = np.concatenate(self.owner) if self.owner else np.zeros(0, np.int64)
        d = p.d.take(owner)
        log1m = np.log1p(-np.minimum(alpha, np.float32(ALPHA_MAX)))
        near = np.full(n_pix, np.inf, np.float32)
        np.minimum.at(near, pix, d)
        hit = np.flatnonzero(near < np.inf)               # covered pixels; samples -> their slot
        slot = np.empty(n_pix, np.int32)                   # scipy's CSC index type: no copies
        slot[hit] = np.arange(hit.size, dtype=np.int32)
        cpix = slot.take(pix)
        if not n_col:
            return Sums(hit, np.bincount(cpix.astype(np.intp), log1m, hit.size).astype(np.float32), None, near)
        # one product for all sums: entries w = alpha / d^2, rows [1, colour, log(1 - alpha) / w]
        rows = np.empty((p.colour.shape[0], 2 + n_col), np.float32)
        rows[:, 0] = 1.0
        rows[:, 1:-1] = p.colour
        w = alpha / np.maximum(d, np.float32(1e-3)) ** 2
        per_sample = rows.take(owner, axis=0)
        per_sample[:, -1] = log1m / w                      # alpha > 0, so w > 0
        mat = sparse.csc_array((w, cpix, np.arange(pix.size + 1, dtype=np.int32)), shape=(hit.size, pix.size))
        total = np.asarray(mat @ per_sample, np.float32)
        return Sums(hit, total[:, -1], total[:, :-1], near)


def specks(acc: _Samples, p: Particles, sel: np.ndarray) -> None:
    """Sub-pixel particles: bilinear splat of alpha = ellipse area (px^2) x opacity onto 4 pixels."""
    u, v = p.u.take(sel), p.v.take(sel)
    x0f, y0f = np.floor(u), np.floor(v)
    fx, fy = u - x0f, v - y0f
    gx = np.array([[0], [1], [0], [1]], np.int64)
    gy = np.array([[0], [0], [1], [1]], np.int64)
    area = np.float32(np.pi) * p.a.take(sel) * p.b.take(sel) * p.op.take(sel)
    ex, ey = _F1 - fx, _F1 - fy
    alpha = np.stack([ex * ey, fx * ey, ex * fy, fx * fy]) * area
    x0, y0 = x0f.astype(np.int64), y0f.astype(np.int64)
    border = (x0 < 0) | (y0 < 0) | (x0 + 2 > acc.width) | (y0 + 2 > acc.height)
    for part in (np.flatnonzero(~border), np.flatnonzero(border)):
        if part.size:
            acc.add(p, sel.take(part), x0.take(part) + gx, y0.take(part) + gy, alpha[:, part],
                    clip=bool(border[part[0]]))


def _ramp(p: Particles, sel: np.ndarray):
    """Per-particle coefficients (m,) of the coverage ramp (:func:`coverage`)."""
    a, b, c, s = p.a.take(sel), p.b.take(sel), p.c.take(sel), p.s.take(sel)
    m = np.sqrt(a * b)
    return c / a, s / a, c / b, s / b, np.float32(0.5) + m, m


def boxes(p: Particles, sel: np.ndarray):
    """Pixel boxes [x0, x0+sx) x [y0, y0+sy) holding every centre with alpha > 0."""
    u, v, a, b, c, s = (x.take(sel) for x in (p.u, p.v, p.a, p.b, p.c, p.s))
    grow = _F1 + np.float32(0.5) / np.sqrt(a * b)                # alpha > 0 <=> q < k0/k1
    ex = np.sqrt((a * c) ** 2 + (b * s) ** 2) * grow
    ey = np.sqrt((a * s) ** 2 + (b * c) ** 2) * grow
    x0, y0 = np.ceil(u - ex).astype(np.int64), np.ceil(v - ey).astype(np.int64)
    return x0, y0, np.floor(u + ex).astype(np.int64) + 1 - x0, np.floor(v + ey).astype(np.int64) + 1 - y0


def coverage(dx, dy, ca, sa, cb, sb, k0, k1):
    """Anti-aliased coverage of pixel centres at offsets (dx, dy) from an ellipse centre.

    With q the normalised elliptic radius (q = 1 on the rim) and m = sqrt(a b), the
    signed distance to the rim is ~ (q - 1) m, and alpha = clip(0.5 - distance, 0, 1)
    = clip(k0 - k1 q) (k0 = 0.5 + m, k1 = m). The rim is exact; only the 1-px ramp is
    approximate (small ellipses are renormalised to their exact area). Broadcasts."""
    xr = dx * ca + dy * sa
    xt = dy * cb - dx * sb
    q = np.sqrt(xr * xr + xt * xt)
    return np.clip(k0 - k1 * q, _F0, _F1)


def block(acc: _Samples, p: Particles, sel, x0, y0, size: int, border: bool = True) -> None:
    """Ellipses whose box fits in size x size px: one broadcast (size^2, m) block
    (``border``: some boxes cross the image border)."""
    g = np.arange(size, dtype=np.int64)
    gx, gy = np.tile(g, size)[:, None], np.repeat(g, size)[:, None]
    alpha = coverage((x0 - p.u.take(sel)).astype(np.float32) + gx.astype(np.float32),
                     (y0 - p.v.take(sel)).astype(np.float32) + gy.astype(np.float32), *_ramp(p, sel))
    a, b = p.a.take(sel), p.b.take(sel)
    small = a < np.float32(NORMALISE_BELOW_PX)
    if small.any():                                       # exact area pi a b for small ones
        total = alpha.sum(axis=0)
        scale = np.where(small & (total > 0), np.float32(np.pi) * a * b / np.maximum(total, np.float32(1e-12)),
                         _F1).astype(np.float32)
        alpha = np.minimum(alpha * scale, _F1)
    alpha *= p.op.take(sel)
    acc.add(p, sel, x0 + gx, y0 + gy, alpha, border)


def large(acc: _Samples, p: Particles, sel, x0, y0, sx, sy, width: int, height: int) -> None:
    """Large ellipses: variable boxes clipped to the image, flattened with np.repeat."""
    x1, y1 = np.minimum(x0 + sx, width), np.minimum(y0 + sy, height)
    x0, y0 = np.maximum(x0, 0), np.maximum(y0, 0)
    sx, sy = np.maximum(x1 - x0, 0), np.maximum(y1 - y0, 0)
    n = sx * sy
    k = np.repeat(np.arange(len(sel)), n)
    local = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
    ly = local // sx[k]
    px, py = x0[k] + (local - ly * sx[k]), y0[k] + ly
    owner = sel[k]
    prm = [x[k] for x in _ramp(p, sel)]
    alpha = coverage((px - p.u[owner]).astype(np.float32), (py - p.v[owner]).astype(np.float32), *prm)
    alpha *= p.op[owner]
    acc.add(p, owner, px[None, :], py[None, :], alpha[None, :], clip=False)


def splat(p: Particles, surf: np.ndarray, width: int, height: int) -> Sums:
    """All particles' depth-tested coverage in per-pixel sums (module doc).

    surf (H*W,) float32 scene range per pixel (inf = background, no NaN)."""
    acc = _Samples(surf, width, height)
    speck = p.a < np.float32(SPLAT_BELOW_PX)
    sel = np.flatnonzero(speck)
    if sel.size:
        specks(acc, p, sel)
    sel = np.flatnonzero(~speck)
    if sel.size:
        x0, y0, sx, sy = boxes(p, sel)
        size = np.maximum(sx, sy)
        big = np.flatnonzero(size > GROUP_MAX_PX)
        if big.size:
            large(acc, p, sel[big], x0[big], y0[big], sx[big], sy[big], width, height)
        # groups of one box size, interior boxes apart from those crossing the border
        border = (x0 < 0) | (y0 < 0) | (x0 + size > width) | (y0 + size > height)
        key = 2 * size + border
        order = np.flatnonzero((size <= GROUP_MAX_PX) & (size > 0))
        order = order[np.argsort(key[order], kind="stable")]
        for grp in np.split(order, np.flatnonzero(np.diff(key[order])) + 1) if order.size else ():
            block(acc, p, sel[grp], x0[grp], y0[grp], int(size[grp[0]]), bool(border[grp[0]]))
    return acc.sums(p)
