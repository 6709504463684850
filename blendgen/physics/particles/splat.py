"""Anti-aliased, depth-tested splatting of projected particles into per-pixel sums.

The fast path of :func:`blendgen.physics.particles.field.render_particles`; the loop itself is
compiled (``particle_kernels.splat``: the particles binned by 32 x 32 screen tiles, each tile's
sums kept in a small buffer, a few nanoseconds per covered pixel sample).

Per pixel (flat index ``k``) the sums are, over the samples in front of the surface
(``alpha_i`` the coverage times the particle's blur opacity, ``d_i`` the range to its surface):
the transmittance ``T[k] = prod(1 - alpha_i)``,
``w[k] = sum alpha_i / d_i^2`` and ``wc[c][k] = sum alpha_i c_i / d_i^2`` (the weights of the
order-independent mean colour, McGuire & Bavoil 2013) and ``near[k] = min d_i``, at the pixels
some sample covers. Coverage: specks (semi-axis < 0.5 px) are splat bilinearly with alpha = their
area (px^2); larger ellipses get an anti-aliased ramp: with q the normalised elliptic radius (q = 1
on the rim) and m = sqrt(a b), the signed distance to the rim is ~ (q - 1) m and alpha =
clip(0.5 + m - m q, 0, 1). The rim is exact; only the 1-px ramp is approximate, so ellipses
with a < 4 px are renormalised to the exact area pi a b over their box (up to GROUP_MAX_PX).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blendgen.physics.particles import kernels as kern
from blendgen.physics.particles.kernels import ALPHA_MAX, GROUP_MAX_PX, NORMALISE_BELOW_PX, SPLAT_BELOW_PX

__all__ = [
    "ALPHA_MAX",
    "GROUP_MAX_PX",
    "NORMALISE_BELOW_PX",
    "SPLAT_BELOW_PX",
    "Particles",
    "Sums",
    "boxes",
    "over",
    "splat",
]


@dataclass
class Sums:
    """Per-pixel sums (module doc) at the covered pixels ``hit`` (n,) int64 (flat indices, each
    once, in tile order): ``acc`` (2 + C, n) float32 = [T, w, w c_1 .. w c_C] (the transmittance,
    the weights and the weighted colours); ``near`` (n,) float32 the nearest covering particle's
    surface range and ``far`` (n,) float32 the scene's range there (m)."""

    hit: np.ndarray
    acc: np.ndarray
    near: np.ndarray
    far: np.ndarray

    @property
    def trans(self) -> np.ndarray:
        """(n,) float32 transmittance T."""
        return self.acc[0]

    @property
    def wc(self) -> np.ndarray | None:
        """(1 + C, n) float32 [w, w c..], None without per-particle colours."""
        return self.acc[1:] if self.acc.shape[0] > 2 else None


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


def boxes(p: Particles, sel: np.ndarray):
    """Pixel boxes [x0, x0+sx) x [y0, y0+sy) (4 x (m,) int64) holding every centre with alpha > 0
    of the (non-speck) particles ``sel``."""
    out = np.array([kern.box(p.u[i], p.v[i], p.a[i], p.b[i], p.c[i], p.s[i]) for i in sel], np.int64)
    return tuple(out.reshape(-1, 4).T)


def splat(p: Particles, surf: np.ndarray, width: int, height: int) -> Sums:
    """All particles' depth-tested coverage in per-pixel sums (module doc).

    surf (H*W,) float32 scene range per pixel (inf or NaN = background)."""
    f32 = lambda x: np.ascontiguousarray(x, np.float32)
    hit, acc, near, far = kern.splat(
        f32(p.u),
        f32(p.v),
        f32(p.a),
        f32(p.b),
        f32(p.c),
        f32(p.s),
        f32(p.d),
        f32(p.op),
        _records(p.colour),
        f32(surf),
        int(width),
        int(height),
    )
    return Sums(hit, acc, near, far)


def over(
    p: Particles, surf: np.ndarray, scene: np.ndarray, img: np.ndarray, transfer: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`splat`, the background transfer and the compositing in one compiled pass
    (``particle_kernels.splat_over``), for particles with their own RGB colours (p.colour (M, 3)):
    the covered part of a pixel takes their weighted mean colour.

    surf (H*W,) the scene range the depth test uses, scene (H*W,) what the merged range shows
    where no particle covers, img (H*W*3,) float32 the background; transfer: the packed gain and
    add (``particle_kernels.transfer_params``, ``NO_TRANSFER``). Returns (out (H*W*3,), merged
    (H*W,) float32, mask (H*W,) bool = coverage >= 0.5). The same bytes as :func:`splat`, then
    ``particle_kernels.transfer`` and ``resolve``, without their per-pixel lists."""
    if np.shape(p.colour)[1:] != (3,):
        raise ValueError(f"over needs one RGB colour per particle (M, 3), got {np.shape(p.colour)}")
    if np.size(p.d) and not np.min(p.d) >= 0:  # the kernel's nearest range: a minimum of IEEE bits
        raise ValueError(f"over needs particle surface ranges d >= 0 m, got min {np.min(p.d)}")
    if np.size(p.colour) and not np.isfinite(p.colour).all():  # idle lanes add 0 x colour (kernel)
        raise ValueError("over needs finite particle colours (linear radiance), got inf or NaN")
    f32 = lambda x: np.ascontiguousarray(x, np.float32)
    out, merged, mask = (
        np.empty(height * width * 3, np.float32),
        np.empty(height * width, np.float32),
        np.zeros(height * width, bool),
    )
    kern.splat_over(
        f32(p.u),
        f32(p.v),
        f32(p.a),
        f32(p.b),
        f32(p.c),
        f32(p.s),
        f32(p.d),
        f32(p.op),
        _records(p.colour),
        f32(surf),
        f32(scene),
        f32(img),
        out,
        merged,
        mask,
        f32(transfer),
        int(width),
        int(height),
    )
    return out, merged, mask


def _records(colour: np.ndarray) -> np.ndarray:
    """colour (M, C) as a C-contiguous float32 array. The light field gives it as the transpose of
    planar (C, M) rows, which numpy's generic copy made 3x slower than stacking the rows (76 against
    22 us for 21000 particles)."""
    colour = np.asarray(colour, np.float32)
    if colour.ndim == 2 and not colour.flags.c_contiguous and colour.T.flags.c_contiguous and colour.shape[1]:
        return np.stack(colour.T, axis=1)
    return np.ascontiguousarray(colour)
