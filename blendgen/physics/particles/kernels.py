"""Compiled loops of the fast particle path (numba): drift, projection and blur, splat, transfer,
compositing, and the float32 transcendentals they need.

The budget: 60000 particles in the 600 m^3 pool at most 5 ms per 640x480 frame (docs/particles.md).
Written with numpy, every stage was a chain of ~10-40 passes over the particles or the
covered pixels; each loop here makes one or two passes, most of them vectorised by LLVM
(docs/particles.md, "Speed", says what that takes), and keeps the laws, so their oracles are
unchanged:

- :func:`drift` -- ``p + v dt + eta`` wrapped periodically into the region, rounded to float32
  and clamped inside it (``ParticleField.step``); the normals drawn in the same pass
  (:func:`splitmix64` words, :func:`box_muller`'s transform).
- :func:`project` -- camera frame, pinhole projection, culling, ellipse semi-axes
  (``particles.project_particles``); :func:`project_blurred` the same with the defocus and the
  motion streak, culling exactly the blurred footprints that miss the image.
- :func:`splat` -- depth-tested coverage of every particle in per-pixel sums, tile by tile
  (``particle_splat.splat``: bilinear specks, anti-aliased ellipses).
- :func:`transfer` -- the background's gain and add at the covered pixels (``particle_light``).
- :func:`resolve` -- ``out = (img gain + add) T + colour (1 - T)``, the mask and merged range.
- :func:`splat_over` -- the three above in one pass for particles with their own colours (the
  pipeline's case): each tile's sums composited while in L1, no per-pixel lists through memory.
- :func:`exp32`, :func:`log32`, the Box-Muller sin/cos: polynomials (Cephes) that vectorise,
  where a libm call would not (numba here has no vector math library).

Indices read from data (particle ids, flat pixels, tile pixels, kept ids) are cast to uint64
(``_U``) before indexing: numba then omits the negative-index wraparound (a compare and select
per access, per dimension), which callgrind showed made up most of the splat's ~100 instructions
per covered-pixel sample; the tile sums are a flat buffer for the same reason. Mixing uint64
and int64 in arithmetic gives float64 in numba, so the casts sit at the index only. Helpers
that take arrays are avoided in the hot loops even when inlined (reference counts per call).

numba (a well-kept JIT for numpy loops, LLVM) rather than C or Cython: no build step, the
loops read like the formulas, and it is part of the render extra (generation only; evalkit
never imports this). Compiled once per machine (``cache=True``: beside this file, like .pyc
files), single-threaded (the render workers are processes, pipeline/allocator.py).
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba as nb
    from llvmlite import ir
    from numba.core import cgutils, types
    from numba.extending import intrinsic
except ImportError as exc:  # pragma: no cover - the render extra installs it
    raise ImportError("the fast particle path needs numba: pip install 'dockbench[render]'") from exc

SPLAT_BELOW_PX = 0.5  # semi-axis below which a particle is a bilinear speck
NORMALISE_BELOW_PX = 4.0  # small ellipses: rescale coverage to the exact area
GROUP_MAX_PX = 16  # boxes up to this size are renormalised over the box
ALPHA_MAX = 1.0 - 1e-6  # keeps the transmittance T = prod(1 - alpha) > 0

_jit = nb.njit(cache=True, nogil=True)
_inline = nb.njit(cache=True, nogil=True, inline="always")  # helpers: no call (array arguments still
#                                                                cost reference counts: scalars in hot loops)
_F0, _F1, _HALF, _PI = np.float32(0.0), np.float32(1.0), np.float32(0.5), np.float32(np.pi)


# ----------------------------------------------------------------------------- exp
@intrinsic
def _f32_from_bits(typingctx, bits):
    """The float32 whose IEEE bits are the int32 ``bits`` (an LLVM bitcast)."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float32))

    return types.float32(types.int32), codegen


@intrinsic
def _prefetch(typingctx, arr, idx):
    """A software prefetch of arr[idx] (llvm.prefetch: read, kept in every cache level; x86's
    prefetcht0): a hint, never a fault (an index past the end is harmless), no value."""

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = builder.bitcast(builder.gep(ary.data, [args[1]]), ir.IntType(8).as_pointer())  # one declaration
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32])
        builder.call(
            cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0"), [ptr, i32(0), i32(3), i32(1)]
        )
        return context.get_dummy_value()

    return types.void(arr, types.uint64), codegen


_EXP = {"nsz"}  # as _VEC (below): no flag that lets a compile choose its own rounding
_exp_vec = nb.njit(cache=True, nogil=True, fastmath=_EXP, error_model="numpy")
_inline_exp = nb.njit(cache=True, nogil=True, fastmath=_EXP, error_model="numpy", inline="always")


@nb.njit(cache=True, nogil=True, fastmath=_EXP, error_model="numpy", inline="always")
def exp32(x):
    """exp(x) in float32 that LLVM can vectorise (a libm call cannot be, and numba here has no
    vector math library): Cody-Waite reduction ``x = k ln2 + r`` with ln2 split in two
    (0.693359375 - 2.12194440e-4), ``exp(r)`` by the Cephes expf polynomial (S. Moshier,
    Cephes Math Library, expf.c) and ``2^k`` built in the exponent bits. x is clamped to
    [-87.34, 88] (below: the smallest normal float, 1.18e-38). Relative error <= 1e-7 against
    float64 (``tests/test_particle_splat.py``), ~0.2 ns per value vectorised (numpy's: 0.5 ns)."""
    x = min(max(x, np.float32(-87.33654)), np.float32(88.0))
    k = np.floor(x * np.float32(1.4426950408889634) + _HALF)
    r = x - k * np.float32(0.693359375)
    r = r - k * np.float32(-2.12194440e-4)
    p = np.float32(1.9875691500e-4)
    p = p * r + np.float32(1.3981999507e-3)
    p = p * r + np.float32(8.3334519073e-3)
    p = p * r + np.float32(4.1665795894e-2)
    p = p * r + np.float32(1.6666665459e-1)
    p = p * r + np.float32(5.0000001201e-1)
    p = p * r * r + r + _F1
    return p * _f32_from_bits((np.int32(k) + np.int32(127)) << np.int32(23))


# ----------------------------------------------------------------------------- normal draws
@intrinsic
def _bits_of_f32(typingctx, x):
    """The int32 IEEE bits of the float32 ``x`` (an LLVM bitcast)."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.int32))

    return types.int32(types.float32), codegen


@_inline_exp
def log32(x):
    """ln(x) for float32 x > 0 normal, vectorisable: x = m 2^e with m in [sqrt(1/2), sqrt(2))
    from the exponent bits, ``ln m`` by the Cephes logf polynomial (S. Moshier, Cephes Math
    Library, logf.c) and ln 2 split in two as in :func:`exp32`. Relative error ~1e-7."""
    bits = _bits_of_f32(x)
    e = np.float32((bits >> np.int32(23)) - np.int32(127))
    m = _f32_from_bits((bits & np.int32(0x7FFFFF)) | np.int32(0x3F800000))  # [1, 2)
    big = m > np.float32(1.4142135623730951)
    m = m * _HALF if big else m
    e = e + _F1 if big else e
    t = m - _F1
    z = t * t
    p = np.float32(7.0376836292e-2)
    p = p * t - np.float32(1.1514610310e-1)
    p = p * t + np.float32(1.1676998740e-1)
    p = p * t - np.float32(1.2420140846e-1)
    p = p * t + np.float32(1.4249322787e-1)
    p = p * t - np.float32(1.6668057665e-1)
    p = p * t + np.float32(2.0000714765e-1)
    p = p * t - np.float32(2.4999993993e-1)
    p = p * t + np.float32(3.3333331174e-1)
    y = t * z * p + e * np.float32(-2.12194440e-4) - _HALF * z
    return t + y + e * np.float32(0.693359375)


@_inline_exp
def _sin_cos_octant(r):
    """(sin, cos) of phi = r 2 pi / 2^24 for an integer r in [0, 2^21] (phi in [0, pi/4]):
    the Cephes sinf / cosf polynomials (|error| ~1e-7)."""
    phi = np.float32(r) * np.float32(2.0 * math.pi / 2**24)
    z = phi * phi
    sin = phi + phi * z * (
        (np.float32(-1.9515295891e-4) * z + np.float32(8.3321608736e-3)) * z - np.float32(1.6666654611e-1)
    )
    cos = (
        _F1
        - _HALF * z
        + z
        * z
        * (
            (np.float32(2.443315711809948e-5) * z - np.float32(1.388731625493765e-3)) * z
            + np.float32(4.166664568298827e-2)
        )
    )
    return sin, cos


@_inline_exp
def _normal_pair(w):
    """Two standard normals (R cos theta, R sin theta) in float32 from one uint64 word: the top
    24 bits make U1 = k 2^-24, the next 24 the angle theta = 2 pi j 2^-24, and
    ``R = sqrt(-2 ln(1 - U1))``. The angle is reduced to its octant in integers (exact), so the
    polynomials only see [0, pi/4]; the octant's reflections and the quadrant's rotation are
    arithmetic, not branches (loops that call it are vectorised)."""
    k = np.int32(w >> np.uint64(40))  # U1 = k 2^-24 in [0, 1)
    j = np.int32((w >> np.uint64(16)) & np.uint64(0xFFFFFF))  # theta = 2 pi j 2^-24
    radius = np.sqrt(np.float32(-2.0) * log32(np.float32(np.int32(16777216) - k) * np.float32(2.0**-24)))
    odd = (j >> np.int32(21)) & np.int32(1)  # odd octant: pi/4 - phi, swapped
    r = j & np.int32(0x1FFFFF)
    s, c = _sin_cos_octant(r + odd * (np.int32(0x200000) - r - r))
    f = np.float32(odd)
    s, c = s + f * (c - s), c + f * (s - c)  # (sin, cos) within the quadrant
    q = j >> np.int32(22)
    f = np.float32(q & np.int32(1))  # rotate by q quarter turns
    sin_t = (s + f * (c - s)) * (_F1 - np.float32(2 * (q >> np.int32(1))))
    cos_t = (c + f * (s - c)) * (_F1 - np.float32(2 * (((q + np.int32(1)) >> np.int32(1)) & np.int32(1))))
    return radius * cos_t, radius * sin_t


@_exp_vec
def box_muller(bits):
    """(2, n) float32 standard normal pairs from n uint64 random words (``physics/particles/gauss.py``,
    :func:`_normal_pair`)."""
    n = bits.size
    out = np.empty((2, n), np.float32)
    for i in range(n):
        out[0, i], out[1, i] = _normal_pair(bits[i])
    return out


GAMMA = np.uint64(0x9E3779B97F4A7C15)  # SplitMix64's increment (physics/particles/gauss.py)


@_inline_exp
def splitmix64(seed, k):
    """Output k (>= 1) of the SplitMix64 stream from state ``seed`` (uint64): ``mix(seed + k
    GAMMA)``, Stafford's Mix13 finaliser (physics/particles/gauss.py; wraps modulo 2^64)."""
    z = seed + np.uint64(k) * GAMMA
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@_inline_exp
def _eta(seed, i, L):
    """Particle i's displacement noise (3 float64) ``L z``: z0, z1 from SplitMix64 word 2i + 1
    of ``seed``, z2 the cosine of word 2i + 2 (:func:`_normal_pair`); L 9 float64 row-major."""
    z0, z1 = _normal_pair(splitmix64(seed, 2 * i + 1))
    z2 = np.float64(_normal_pair(splitmix64(seed, 2 * i + 2))[0])
    z0, z1 = np.float64(z0), np.float64(z1)
    return (z0 * L[0] + z1 * L[1] + z2 * L[2], z0 * L[3] + z1 * L[4] + z2 * L[5], z0 * L[6] + z1 * L[7] + z2 * L[8])


@_inline_exp
def _moved(x, vk, eta, lok, l32, t32):
    """One coordinate moved, ``x + v dt + eta`` in float64 relative to the region's lower
    bound: (q, the float32 position clamped into [l32, t32] assuming it stayed inside)."""
    q = np.float64(x) + vk + eta - lok
    return q, min(max(np.float32(q + lok), l32), t32)


@_inline_exp
def _wrapped(x, vk, eta, lok, ext, l32, t32):
    """One coordinate moved and wrapped periodically: ``lo + mod(x + v dt + eta - lo, ext)`` in
    float64, rounded to float32 and clamped into [l32, t32]."""
    q = (np.float64(x) + vk + eta - lok) % ext
    return min(max(np.float32(q + lok), l32), t32)


# ----------------------------------------------------------------------------- drift
_exact = nb.njit(cache=True, nogil=True, error_model="numpy")  # IEEE order kept: no fast-math


@_exp_vec
def drift(xyz, v_dt, L, seed, lo, hi, lo32, top32):
    """New planar float32 positions (3, N): ``xyz + v_dt + L z`` in float64, z three standard
    normals per particle drawn from the SplitMix64 stream ``seed`` (uint64; :func:`_eta`,
    physics/particles/gauss.py ``drift_normals`` is the same in numpy), wrapped into [lo, hi) per axis
    (``lo + mod(x - lo, hi - lo)``, the mod only for coordinates that left), rounded to float32
    and clamped into [lo32, top32] (float32 rounding stays inside). xyz (3, N) float32; v_dt, lo,
    hi (3,) float64; L (3, 3) float64 (all zero: no noise, no draws); lo32, top32 (3,) float32.
    One pass draws and moves every particle (vectorised; the normals never reach memory) and
    marks those that left; a second one wraps only those, drawing their noise again."""
    n = xyz.shape[1]
    out = np.empty((3, n), np.float32)
    left = np.zeros(n, np.bool_)
    lm = (L[0, 0], L[0, 1], L[0, 2], L[1, 0], L[1, 1], L[1, 2], L[2, 0], L[2, 1], L[2, 2])
    noisy = np.any(L != 0.0)
    v0, v1, v2, lo0, lo1, lo2 = v_dt[0], v_dt[1], v_dt[2], lo[0], lo[1], lo[2]
    e0, e1, e2 = hi[0] - lo0, hi[1] - lo1, hi[2] - lo2
    for i in range(n):
        n0 = n1 = n2 = 0.0
        if noisy:
            n0, n1, n2 = _eta(seed, i, lm)
        q0, out[0, i] = _moved(xyz[0, i], v0, n0, lo0, lo32[0], top32[0])
        q1, out[1, i] = _moved(xyz[1, i], v1, n1, lo1, lo32[1], top32[1])
        q2, out[2, i] = _moved(xyz[2, i], v2, n2, lo2, lo32[2], top32[2])
        left[i] = ((q0 < 0.0) | (q0 >= e0)) | ((q1 < 0.0) | (q1 >= e1)) | ((q2 < 0.0) | (q2 >= e2))
    for i in np.flatnonzero(left):
        n0 = n1 = n2 = 0.0
        if noisy:
            n0, n1, n2 = _eta(seed, i, lm)
        out[0, i] = _wrapped(xyz[0, i], v0, n0, lo0, e0, lo32[0], top32[0])
        out[1, i] = _wrapped(xyz[1, i], v1, n1, lo1, e1, lo32[1], top32[1])
        out[2, i] = _wrapped(xyz[2, i], v2, n2, lo2, e2, lo32[2], top32[2])
    return out


# ----------------------------------------------------------------------------- projection
@nb.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _radial(du, dv):
    """Unit radial direction (c, s) of an image offset (du, dv) px from the principal point
    ((1, 0) at the point itself)."""
    norm = np.sqrt(du * du + dv * dv)
    inv = _F1 / max(norm, np.float32(1e-6))
    off_centre = norm > np.float32(1e-6)
    return du * inv if off_centre else _F1, dv * inv if off_centre else _F0


@nb.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _half_extents(a, b, c, s):
    """Half-widths (ex, ey) px of the pixel box of an ellipse (semi-axes a radial, b, radial
    direction (c, s)) holding every pixel centre it covers: the ellipse's extents grown by the
    anti-aliasing ramp (:func:`box`)."""
    grow = _F1 + _HALF / np.sqrt(a * b)
    return np.sqrt((a * c) ** 2 + (b * s) ** 2) * grow, np.sqrt((a * s) ** 2 + (b * c) ** 2) * grow


@nb.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _camera(px, py, pz, r, R, fx, sk, cx, fy, cy, fb, z_near):
    """One particle in the camera frame: (x, y, z, u, v, a, b, sec); R = the 9 entries of the
    world-from-camera rotation (row-major) and the 3 of off = -R^T t, as scalars."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22, o0, o1, o2 = R
    z = px * r02 + py * r12 + pz * r22 + o2
    x = px * r00 + py * r10 + pz * r20 + o0
    y = px * r01 + py * r11 + pz * r21 + o1
    iz = _F1 / max(z, z_near)
    xn, yn = x * iz, y * iz
    b = fb * r * iz
    sec = np.float32(math.sqrt(xn * xn + yn * yn + _F1))
    return x, y, z, fx * xn + sk * yn + cx, fy * yn + cy, b * sec, b, sec


@_exact
def project(xyz, radii, R, off, K, width, height, z_near, margin_px):
    """Camera-frame culling and projection (``particles.project_particles``'s law, float32).

    xyz (3, N) float32 world, radii (N,) float32 m, R (3, 3) float32 world-from-camera
    rotation, off (3,) float32 = -R^T t, K (3, 3) float32. Keeps particles with Z > z_near,
    the camera outside the sphere and the ellipse's box within ``2 + margin_px`` px of the
    image. Returns (idx (M,) int64, uv_ab_cs (6, M) float32 = u, v, a, b, c, s,
    surf_range (M,) float32 = ||p|| - r, pc (3, M) float32 = camera-frame x, y, z rows).
    Two passes: the test for every particle, without branches (vectorised), then the kept
    particles' columns (the same arithmetic)."""
    n = xyz.shape[1]
    fx, sk, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    fb = np.float32(0.5) * (fx + fy)
    m_extra = np.float32(2.0) + margin_px
    w1, h1 = np.float32(width - 1), np.float32(height - 1)
    Rs = (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2], off[0], off[1], off[2])
    keep = np.empty(n, np.bool_)
    for i in range(n):
        r = radii[i]
        x, y, z, u, v, a, b, sec = _camera(xyz[0, i], xyz[1, i], xyz[2, i], r, Rs, fx, sk, cx, fy, cy, fb, z_near)
        mm = a + m_extra
        keep[i] = (z > z_near) & (u > -mm) & (u < mm + w1) & (v > -mm) & (v < mm + h1) & (z * sec > r)
    m = np.count_nonzero(keep)
    idx = np.empty(m, np.int64)
    cols = np.empty((6, m), np.float32)
    rng = np.empty(m, np.float32)
    pc = np.empty((3, m), np.float32)
    j = 0
    for i in range(n):
        if not keep[i]:
            continue
        r = radii[i]
        x, y, z, u, v, a, b, sec = _camera(xyz[0, i], xyz[1, i], xyz[2, i], r, Rs, fx, sk, cx, fy, cy, fb, z_near)
        idx[j] = i
        cols[0, j], cols[1, j], cols[2, j], cols[3, j] = u, v, a, b
        cols[4, j], cols[5, j] = _radial(u - cx, v - cy)
        rng[j] = z * sec - r
        pc[0, j], pc[1, j], pc[2, j] = x, y, z
        j += 1
    return idx, cols, rng, pc


# ----------------------------------------------------------------------------- blur
# Loops without branches, compiled with numpy's error model (a float division by zero gives inf
# instead of raising, so no test and branch per division), are vectorised by LLVM: sqrt,
# division, min/max run 8 float32 lanes at a time (the blur: 10x). The only fast-math flag is
# "nsz": "reassoc", "contract", "afn" or "arcp" let each compile choose its own rounding, and a
# kernel compiled in its caller's process (inlined there) then differed from the cached one by up
# to 3e-5 -- a fresh machine's first dataset had other bytes (tests/test_kernel_determinism.py).
# No "nnan"/"ninf" either: inf and NaN keep their meaning. abs() still blocks it: max(x, -x).
_VEC = {"nsz"}
_jit_vec = nb.njit(cache=True, nogil=True, fastmath=_VEC, error_model="numpy")
_inline_vec = nb.njit(cache=True, nogil=True, fastmath=_VEC, error_model="numpy", inline="always")


@_inline_vec
def _moments(a, b, c, s, iso, du, dv):
    """One footprint blurred by adding second moments (``particle_optics.blurred_shapes``' law):
    (a', b', c', s', opacity). The major axis comes from the half-angle identities instead of
    ``atan2``/``cos``/``sin``: with ``r = sqrt((sxx - syy)^2 + 4 sxy^2)``, ``cos 2phi = (sxx -
    syy) / r``, ``cos phi = sqrt((1 + cos 2phi) / 2)``, ``sin phi = sign(sxy) sqrt((1 - cos 2phi)
    / 2)`` (phi in (-90, 90] deg; a circle keeps phi = 0)."""
    aa, bb = a * a, b * b
    k = np.float32(4.0 / 12.0)  # segment L^2 / 12 per axis, x 4 to match R^2 / 4
    sxx = aa * c * c + bb * s * s + iso + k * du * du  # 4 x the second-moment matrix
    syy = aa * s * s + bb * c * c + iso + k * dv * dv
    sxy = (aa - bb) * c * s + k * du * dv
    half_tr = _HALF * (sxx + syy)
    diff = sxx - syy
    root = np.sqrt(np.float32(0.25) * diff * diff + sxy * sxy)
    a2 = np.sqrt(half_tr + root)
    b2 = np.sqrt(max(half_tr - root, np.float32(1e-12)))
    cos2 = min(max(diff / max(root + root, np.float32(1e-30)), -_F1), _F1)
    cos2 = cos2 if root > _F0 else _F1
    sphi = np.sqrt(_HALF * (_F1 - cos2))
    op = min(a * b / max(a2 * b2, np.float32(1e-12)), _F1)
    return a2, b2, np.sqrt(_HALF * (_F1 + cos2)), -sphi if sxy < _F0 else sphi, op


@_jit_vec
def blur(a, b, c, s, iso, du, dv):
    """Footprints convolved with a defocus disc and a motion streak (:func:`_moments`). Per
    particle (M,) float32: semi-axes a (radial), b (px), radial direction (c, s); iso = squared
    defocus radius (px^2) and du, dv = streak (px), each (M,). Returns (5, M) float32 = a', b',
    c', s', opacity a b / (a' b')."""
    out = np.empty((5, a.size), np.float32)
    for i in range(a.size):
        out[0, i], out[1, i], out[2, i], out[3, i], out[4, i] = _moments(a[i], b[i], c[i], s[i], iso[i], du[i], dv[i])
    return out


@_inline_vec
def _blurred_one(px, py, pz, r, Rs, fx, sk, cx, fy, cy, fb, z_near, Ms, scale, coc_k, focus_m, w1, h1):
    """One particle of :func:`project_blurred` (world point px, py, pz, radius r; the constants of
    :func:`_blur_consts`): its blurred ellipse u, v, a', b', c', s' (px), surface range d (m),
    camera-frame x, y, z (m), opacity, and keep (whether the blurred footprint's pixel box meets
    the image)."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22, o0, o1, o2 = Ms
    x, y, z, u, v, a, b, sec = _camera(px, py, pz, r, Rs, fx, sk, cx, fy, cy, fb, z_near)
    c, s = _radial(u - cx, v - cy)
    x0 = m00 * x + m01 * y + m02 * z + o0  # where it was, seen from then
    y0 = m10 * x + m11 * y + m12 * z + o1
    z0 = m20 * x + m21 * y + m22 * z + o2
    iz = _F1 / max(z0, np.float32(1e-3))
    ahead = z0 > np.float32(1e-3)
    du = (u - (fx * x0 * iz + sk * y0 * iz + cx)) * scale if ahead else _F0
    dv = (v - (fy * y0 * iz + cy)) * scale if ahead else _F0
    dz = z - focus_m
    coc = coc_k * max(dz, -dz) / max(z, z_near)  # thin-lens blur diameter (px)
    a2, b2, c2, s2, op = _moments(a, b, c, s, np.float32(0.25) * coc * coc, du, dv)
    ex, ey = _half_extents(a2, b2, c2, s2)  # box(): the ellipse's pixel box
    speck = a2 < np.float32(SPLAT_BELOW_PX)  # _footprint: the 2 x 2 pixels
    lo_x = np.floor(u) if speck else np.ceil(u - ex)
    lo_y = np.floor(v) if speck else np.ceil(v - ey)
    hi_x = np.floor(u) + _F1 if speck else np.floor(u + ex)
    hi_y = np.floor(v) + _F1 if speck else np.floor(v + ey)
    keep = (z > z_near) & (z * sec > r) & (hi_x >= _F0) & (lo_x <= w1) & (hi_y >= _F0) & (lo_y <= h1)
    return u, v, a2, b2, c2, s2, z * sec - r, x, y, z, op, keep


@_inline_vec
def _blur_consts(R, off, K, M, o, width, height):
    """The scalars :func:`_blurred_one` takes: fx, skew, cx, fy, cy, the mean focal length (px),
    the rotation and offset (12), the streak's M and o (12), and the image's last column and row."""
    fx, sk, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    Rs = (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2], off[0], off[1], off[2])
    Ms = (M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2], M[2, 0], M[2, 1], M[2, 2], o[0], o[1], o[2])
    return fx, sk, cx, fy, cy, _HALF * (fx + fy), Rs, Ms, np.float32(width - 1), np.float32(height - 1)


@_jit_vec
def _blurred_keep(xyz, radii, R, off, K, z_near, M, o, scale, coc_k, focus_m, width, height, keep):
    """keep (N,) float32: 1 where :func:`project_blurred` keeps the particle, else 0. Branch-free,
    one array written: vectorised (16 float32 lanes here)."""
    fx, sk, cx, fy, cy, fb, Rs, Ms, w1, h1 = _blur_consts(R, off, K, M, o, width, height)
    for i in range(xyz.shape[1]):
        k = _blurred_one(
            xyz[0, i],
            xyz[1, i],
            xyz[2, i],
            radii[i],
            Rs,
            fx,
            sk,
            cx,
            fy,
            cy,
            fb,
            z_near,
            Ms,
            scale,
            coc_k,
            focus_m,
            w1,
            h1,
        )[11]
        keep[i] = _F1 if k else _F0


@_jit_vec
def _blurred_rows(pts, R, off, K, z_near, M, o, scale, coc_k, focus_m, width, height, out):
    """out (11, m) float32 rows u, v, a', b', c', s', d, x, y, z, opacity of the particles pts (4, m)
    = x, y, z, r (vectorised)."""
    fx, sk, cx, fy, cy, fb, Rs, Ms, w1, h1 = _blur_consts(R, off, K, M, o, width, height)
    for i in range(pts.shape[1]):
        u, v, a2, b2, c2, s2, d, x, y, z, op, k = _blurred_one(
            pts[0, i],
            pts[1, i],
            pts[2, i],
            pts[3, i],
            Rs,
            fx,
            sk,
            cx,
            fy,
            cy,
            fb,
            z_near,
            Ms,
            scale,
            coc_k,
            focus_m,
            w1,
            h1,
        )
        out[0, i], out[1, i], out[2, i], out[3, i], out[4, i], out[5, i] = u, v, a2, b2, c2, s2
        out[6, i], out[7, i], out[8, i], out[9, i], out[10, i] = d, x, y, z, op


@_jit
def project_blurred(xyz, radii, R, off, K, z_near, M, o, scale, coc_k, focus_m, width, height):
    """:func:`project` with the defocus and motion blur of ``particle_light.shaper`` in the same
    pass, keeping exactly the particles whose blurred footprint meets the width x height image
    (no margin guess). The streak: a particle's camera-frame point one frame earlier is
    ``M pc + o`` (M (3, 3), o (3,) float32), projected by K, times ``scale`` = exposure / frame
    interval; defocus: thin-lens circle of confusion ``coc_k |z - focus_m| / z`` px (coc_k = 0:
    pinhole); footprints add second moments (:func:`_moments`). Returns (idx (m,) int64,
    uv_ab_cs (6, m) float32 of the blurred ellipses, surf_range (m,), pc (3, m), opacity (m,)).

    Three passes: the test for every particle (:func:`_blurred_keep`), the kept ones' points
    gathered, and their rows computed again from them (:func:`_blurred_rows`; the same arithmetic,
    so the same bytes). Writing all 11 rows of every particle, ~70 % of them out of view in the
    bench pool, and then compacting them cost more: 0.47 -> 0.37 ms for 60000
    (docs/history/particles-speed.md)."""
    n = xyz.shape[1]
    keep = np.empty(n, np.float32)
    _blurred_keep(xyz, radii, R, off, K, z_near, M, o, scale, coc_k, focus_m, width, height, keep)
    idx = np.empty(n, np.int64)
    m = 0
    for i in range(n):  # branch-free: every index written, kept ones advance m
        idx[_U(m)] = i
        m += keep[i] > _F0
    idx = idx[:m]
    pts = np.empty((4, m), np.float32)
    for j in range(m):
        i = _U(idx[j])
        pts[0, j], pts[1, j], pts[2, j], pts[3, j] = xyz[0, i], xyz[1, i], xyz[2, i], radii[i]
    kept = np.empty((11, m), np.float32)
    _blurred_rows(pts, R, off, K, z_near, M, o, scale, coc_k, focus_m, width, height, kept)
    return idx, kept[:6], kept[6], kept[7:10], kept[10]


# ----------------------------------------------------------------------------- splat
# The helpers take and return scalars only: a numba function called with arrays pays their
# reference counts on every call (measured: ~30 ns per sample, 6x the sample's own work).
@_inline
def _coverage(x, y, u, v, ca, sa, cb, sb, k0, k1):
    """Anti-aliased coverage of pixel centre (x, y) (particle_splat module doc)."""
    dx, dy = np.float32(x) - u, np.float32(y) - v
    xr = dx * ca + dy * sa
    xt = dy * cb - dx * sb
    q = np.float32(math.sqrt(xr * xr + xt * xt))
    return min(max(k0 - k1 * q, _F0), _F1)


@_inline
def box(u, v, a, b, c, s):
    """Pixel box (x0, y0, sx, sy) holding every centre with alpha > 0 of an ellipse."""
    ex, ey = _half_extents(a, b, c, s)
    x0, y0 = int(np.ceil(u - ex)), int(np.ceil(v - ey))  # np's: inlined (math's: 3 ns)
    return x0, y0, int(np.floor(u + ex)) + 1 - x0, int(np.floor(v + ey)) + 1 - y0


@_inline
def _footprint(u, v, a, b, c, s):
    """An ellipse's (a >= SPLAT_BELOW_PX; specks: :func:`_speck_box`) pixel box and coverage law:
    (x0, y0, sx, sy, ca, sa, cb, sb, k0, k1) for :func:`_coverage`. sx = 0: nothing to draw."""
    ca = sa = cb = sb = k0 = k1 = _F0
    x0, y0, sx, sy = box(u, v, a, b, c, s)
    if max(sx, sy) > 0:
        k1 = np.float32(math.sqrt(a * b))
        ca, sa, cb, sb, k0 = c / a, s / a, c / b, s / b, _HALF + k1
    return x0, y0, max(sx, 0), max(sy, 0), ca, sa, cb, sb, k0, k1


AHEAD = 8  # the splat prefetches the data of the member this many ahead
TILE_PX = 32  # the splat's screen tiles: 32 x 32 pixels of sums stay in L1
LIST = max(GROUP_MAX_PX, TILE_PX) ** 2  # an ellipse's samples listed at most: a tile or a small box
_U = np.uint64  # indices read from data, cast: no wraparound test (module doc)


@_inline
def _image_pixel(t, tx0, ty0, width):
    """The flat image pixel (uint64) of tile pixel t (uint64, (y - ty0) TILE_PX + x - tx0) of the
    tile whose corner is (tx0, ty0)."""
    return _U((ty0 + np.int64(t // _U(TILE_PX))) * width + tx0 + np.int64(t % _U(TILE_PX)))


@_inline
def _speck_box(u, v):
    """A speck's 2 x 2 pixels: (x0, y0) of its top-left one and the bilinear fractions (fx, fy)."""
    x0f, y0f = np.floor(u), np.floor(v)  # np's floor is inlined; math.floor cost 3 ns each
    return int(x0f), int(y0f), u - x0f, v - y0f  # exact in float32


@_inline
def _speck_pixel(q, x0, y0, fx, fy, scale, tx0, ty0, tx1, ty1):
    """Pixel q (0..3) of a speck's 2 x 2 block (top-left (x0, y0), bilinear fractions fx, fy,
    alpha at full cover ``scale``): (x, y, alpha), alpha 0 outside the tile [tx0, tx1) x [ty0, ty1)."""
    x, y = x0 + (q & 1), y0 + (q >> 1)
    inside = (x >= tx0) & (x < tx1) & (y >= ty0) & (y < ty1)
    alpha = (fx if q & 1 else _F1 - fx) * (fy if q >> 1 else _F1 - fy) * scale
    return x, y, alpha if inside else _F0


@_jit_vec
def _clipped_boxes(u, v, a, b, c, s, width, height, box4):
    """box4 (4, M) int64: each particle's pixel box clipped to the image, [xa, xb] x [ya, yb]
    inclusive (xa = 1, xb = 0 off the image); one branch-free pass (vectorised)."""
    for i in range(u.size):
        ui, vi = u[i], v[i]
        ex, ey = _half_extents(a[i], b[i], c[i], s[i])
        ex0, ey0 = int(np.ceil(ui - ex)), int(np.ceil(vi - ey))
        ex1, ey1 = int(np.floor(ui + ex)), int(np.floor(vi + ey))  # inclusive ends
        sx0, sy0 = int(np.floor(ui)), int(np.floor(vi))
        speck = a[i] < np.float32(SPLAT_BELOW_PX)
        x0, y0 = (sx0 if speck else ex0), (sy0 if speck else ey0)
        x1, y1 = (sx0 + 1 if speck else max(ex1, ex0 - 1)), (sy0 + 1 if speck else max(ey1, ey0 - 1))
        xa, ya = max(x0, 0), max(y0, 0)
        xb, yb = min(x1, width - 1), min(y1, height - 1)
        off = (xb < xa) | (yb < ya)
        box4[0, i], box4[1, i] = (1 if off else xa), ya
        box4[2, i], box4[3, i] = (0 if off else xb), yb


@_jit
def _bins(u, v, a, b, c, s, op, width, height):
    """Particles binned by the TILE_PX tiles their footprint's clipped box meets (counting sort,
    field order within a tile): (start (n_tiles + 1,) int64, members (E,) int64, samples = the
    total clipped box area, an upper bound on the covered pixels)."""
    tiles_x, tiles_y = (width + TILE_PX - 1) // TILE_PX, (height + TILE_PX - 1) // TILE_PX
    box4 = np.empty((4, u.size), np.int64)
    _clipped_boxes(u, v, a, b, c, s, width, height, box4)
    start = np.zeros(tiles_x * tiles_y + 1, np.int64)
    samples = 0
    for i in range(u.size):
        xa, ya, xb, yb = box4[0, i], box4[1, i], box4[2, i], box4[3, i]
        if xb >= xa:
            samples += (xb - xa + 1) * (yb - ya + 1)
            for ty in range(ya // TILE_PX, yb // TILE_PX + 1):
                for tx in range(xa // TILE_PX, xb // TILE_PX + 1):
                    start[_U(ty * tiles_x + tx + 1)] += 1
    for k in range(tiles_x * tiles_y):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    members = np.empty(start[-1], np.int64)
    for i in range(u.size):
        xa, ya, xb, yb = box4[0, i], box4[1, i], box4[2, i], box4[3, i]
        if xb >= xa:
            for ty in range(ya // TILE_PX, yb // TILE_PX + 1):
                for tx in range(xa // TILE_PX, xb // TILE_PX + 1):
                    k = _U(ty * tiles_x + tx)
                    members[_U(fill[k])] = i
                    fill[k] += 1
    return start, members, samples


@_jit
def _tile_near(surf, width, height):
    """(n_tiles,) float32: per TILE_PX tile the nearest scene range in it (a coarse depth
    bound, like GPUs' hierarchical z): a particle nearer than it passes the depth test at every
    pixel of the tile without reading the range pass. The minimum is taken on the IEEE bits as
    int32 (ordered like the floats for ranges >= 0, and vectorised; NaN = no surface sorts
    above inf); a negative range gives a bound no particle (range > 0) is nearer than, so the
    per-pixel test decides there. One streaming pass over the range, which also brings it into
    cache for the samples."""
    tiles_x, tiles_y = (width + TILE_PX - 1) // TILE_PX, (height + TILE_PX - 1) // TILE_PX
    bits = surf.view(np.int32)
    out = np.empty(tiles_x * tiles_y, np.float32)
    low = np.empty(tiles_x, np.int32)
    for ty in range(tiles_y):
        low[:] = np.int32(0x7FFFFFFF)
        for y in range(ty * TILE_PX, min(ty * TILE_PX + TILE_PX, height)):
            row = bits[y * width : (y + 1) * width]
            for tx in range(tiles_x):
                seg = row[tx * TILE_PX : min(tx * TILE_PX + TILE_PX, width)]
                m = low[tx]
                for k in range(seg.size):  # k >= 0: no wraparound, vectorised
                    m = min(m, seg[k])
                low[tx] = m
        for tx in range(tiles_x):
            out[ty * tiles_x + tx] = _f32_from_bits(low[tx])
    return out


@_inline
def _ellipse_samples(xs, ys, xe, ye, tx0, ty0, tx1, ty1, u, v, ca, sa, cb, sb, k0, k1, buf):
    """An ellipse's coverage over the pixels [xs, xe) x [ys, ye), row by row: the samples with
    coverage > 0 inside the tile [tx0, tx1) x [ty0, ty1) listed in buf, coverage at buf[k], the
    tile pixel (y - ty0) TILE_PX + x - tx0 at buf[LIST + k] (exact in float32). Returns (their
    count, the sum of the coverage over all the pixels, in the tile or not). Written always and
    counted when kept: no branch on the rim, where about half a small ellipse's box is
    outside it and the branch mispredicted (the update loop over the list has none)."""
    total = _F0
    n = 0
    for y in range(ys, ye):  # rows and columns: no integer division per sample
        row_in = (y >= ty0) & (y < ty1)
        for x in range(xs, xe):
            cov = _coverage(x, y, u, v, ca, sa, cb, sb, k0, k1)
            buf[_U(n)] = cov
            buf[_U(LIST + n)] = np.float32((y - ty0) * TILE_PX + x - tx0)
            n += (cov > _F0) & row_in & (x >= tx0) & (x < tx1)
            total += cov
    return n, total


REC = 8  # floats per particle record: u, v, a, b, c, s, d, op


@_jit_vec
def _particle_records(u, v, a, b, c, s, d, op):
    """(M REC,) float32: particle i's u, v, a, b, c, s, d, op at [REC i, REC i + REC) (two to a
    cache line). The tile loop reads its members, scattered over the particles, from one line
    each (one prefetch) instead of eight arrays: 0.1-0.25 ms less on the captured 640x480 bench
    frames (docs/history/particles-speed.md)."""
    rec = np.empty(u.size * REC, np.float32)
    for i in range(u.size):
        r = i * REC
        rec[r], rec[r + 1], rec[r + 2], rec[r + 3] = u[i], v[i], a[i], b[i]
        rec[r + 4], rec[r + 5], rec[r + 6], rec[r + 7] = c[i], s[i], d[i], op[i]
    return rec


# fmt: off
@_exact
def _tile_sums(tx0, ty0, tx1, ty1, members, m0, m1, rec, colour, n_col, surf, zmin, width, acc,
               near, touched, buf):
    """The depth-tested samples of the tile [tx0, tx1) x [ty0, ty1)'s particles ``members[m0:m1]``
    (their data in ``rec``, :func:`_particle_records`; colour (M n_col,)) into its sums acc
    (TILE_PX^2 (2 + n_col),) flat and near (TILE_PX^2,); returns the count of
    touched tile pixels, listed in ``touched`` in first-touch order (:func:`splat`'s law). Specks:
    2 x 2 pixels, bilinear; ellipses: anti-aliased (:func:`_coverage`), covered samples listed first
    (:func:`_ellipse_samples`), small ones renormalised over their box. zmin: the tile's nearest
    scene range (:func:`_tile_near`). Unsigned indices, numpy's error model, no helper taking arrays
    (reference counts per call), and the data of the member AHEAD places on prefetched (members
    are scattered over the arrays): docs/particles.md, "Speed", says what each saved."""
    n_touched = 0
    last = members.size - 1
    for k in range(m0, m1):
        i = _U(members[k])
        p = _U(members[min(k + AHEAD, last)])      # a later member's data on its way to the cache
        _prefetch(rec, p * _U(REC))
        _prefetch(colour, p * _U(n_col))
        r, ci = i * _U(REC), i * _U(n_col)
        ui, vi, ai, bi = rec[r], rec[r + _U(1)], rec[r + _U(2)], rec[r + _U(3)]
        cs, sn, di, opi = rec[r + _U(4)], rec[r + _U(5)], rec[r + _U(6)], rec[r + _U(7)]
        dd = max(di, np.float32(1e-3))
        if not ai < np.float32(SPLAT_BELOW_PX):                   # an anti-aliased ellipse
            x0, y0, sx, sy, ca, sa, cb, sb, k0, k1 = _footprint(ui, vi, ai, bi, cs, sn)
            if max(sx, sy) <= GROUP_MAX_PX and ai < np.float32(NORMALISE_BELOW_PX):   # small: its box
                n_cov, total = _ellipse_samples(x0, y0, x0 + sx, y0 + sy, tx0, ty0, tx1, ty1, ui, vi, ca, sa,
                                                cb, sb, k0, k1, buf)
                scale = _PI * ai * bi / max(total, np.float32(1e-12)) if total > _F0 else _F1
            else:                                                      # its box, clipped to the tile
                n_cov = _ellipse_samples(max(x0, tx0), max(y0, ty0), min(x0 + sx, tx1), min(y0 + sy, ty1), tx0,
                                         ty0, tx1, ty1, ui, vi, ca, sa, cb, sb, k0, k1, buf)[0]
                scale = _F1
            col0, col1, col2 = (colour[ci], colour[ci + _U(1)], colour[ci + _U(2)]) if n_col == 3 \
                else (_F0, _F0, _F0)
            for q in range(n_cov):
                alpha = min(buf[_U(q)] * scale, _F1) * opi
                t = _U(int(buf[_U(LIST + q)]))
                if not alpha > _F0 or (not di < zmin and surf[_image_pixel(t, tx0, ty0, width)] <= di):
                    continue                                            # as below
                touched[_U(n_touched)] = t
                n_touched += near[t] == np.inf
                near[t] = min(near[t], di)
                o = t * _U(2 + n_col)
                acc[o] *= _F1 - min(alpha, np.float32(ALPHA_MAX))
                w = alpha / (dd * dd)
                acc[o + _U(1)] += w
                if n_col == 3:                                        # the usual case, unrolled
                    acc[o + _U(2)] += w * col0
                    acc[o + _U(3)] += w * col1
                    acc[o + _U(4)] += w * col2
                else:
                    for j in range(n_col):
                        acc[o + _U(2 + j)] += w * colour[ci + _U(j)]
            continue
        w_d = _F1 / (dd * dd)                                            # a speck: 2 x 2 pixels
        x0, y0, fx, fy = _speck_box(ui, vi)
        scale = _PI * ai * bi * opi
        for q in range(4):
            x, y, alpha = _speck_pixel(q, x0, y0, fx, fy, scale, tx0, ty0, tx1, ty1)
            if not alpha > _F0 or (not di < zmin and surf[_U(y * width + x)] <= di):   # depth test:
                continue                         # nearer than the tile's nearest surface, or NaN: none
            t = _U((y - ty0) * TILE_PX + x - tx0)
            touched[_U(n_touched)] = t           # listed for the write-out at its first touch
            n_touched += near[t] == np.inf             # (no branch: it mispredicted half the time)
            near[t] = min(near[t], di)
            o = t * _U(2 + n_col)
            acc[o] *= _F1 - min(alpha, np.float32(ALPHA_MAX))
            w = alpha * w_d
            acc[o + _U(1)] += w
            if n_col == 3:                                   # the usual case, unrolled
                acc[o + _U(2)] += w * colour[ci]
                acc[o + _U(3)] += w * colour[ci + _U(1)]
                acc[o + _U(4)] += w * colour[ci + _U(2)]
            else:
                for j in range(n_col):
                    acc[o + _U(2 + j)] += w * colour[ci + _U(j)]
    return n_touched
# fmt: on


@_jit
def _tile_buffers(n_acc):
    """A tile's empty sums for :func:`_tile_sums`: acc (TILE_PX^2 n_acc,) = [T = 1, w = 0, w c = 0..]
    per tile pixel, near (TILE_PX^2,) = inf, touched (TILE_PX^2 + 1,) uint64 (+ 1: written before
    the count) and buf (2 LIST,) float32 for an ellipse's covered samples."""
    acc = np.zeros(TILE_PX * TILE_PX * n_acc, np.float32)
    for t in range(TILE_PX * TILE_PX):
        acc[t * n_acc] = _F1
    return (
        acc,
        np.full(TILE_PX * TILE_PX, np.inf, np.float32),
        np.empty(TILE_PX * TILE_PX + 1, np.uint64),
        np.empty(2 * LIST, np.float32),
    )


@_jit
def splat(u, v, a, b, c, s, d, op, colour, surf, width, height):
    """All particles' depth-tested coverage in per-pixel sums (particle_splat module doc).

    Per particle (M,) float32: centre u, v (px), semi-axes a, b (px), radial direction c, s,
    surface range d (m), blur opacity op; colour (M, C) float32. surf (H*W,) float32 scene
    range (inf or NaN = background). Returns (hit (n,) int64 covered pixels, tile by tile, sums
    (2 + C, n) float32 = [T, w, w c..], near (n,) float32 the nearest covering particle's
    surface range, far (n,) float32 the scene's range there). Coverage per :func:`_footprint`,
    small ellipses (a < NORMALISE_BELOW_PX, box up to GROUP_MAX_PX) scaled to the exact area pi a b
    over their box (it holds every pixel centre with alpha > 0); a sample counts only where the
    scene surface is farther than the particle's surface (depth test) and alpha > 0:
    T *= 1 - alpha, w += alpha / d^2.

    Tiled: the particles are binned by the TILE_PX x TILE_PX tiles they meet and each tile's
    sums are accumulated in a small buffer (L1-resident, :func:`_tile_sums`) and then written
    out at its covered pixels; a full-frame scratch walked in particle order missed the caches
    at every sample."""
    n_col = colour.shape[1]
    n_acc = 2 + n_col
    start, members, samples = _bins(u, v, a, b, c, s, op, width, height)
    cap = min(samples, width * height)  # each pixel at most once
    hit = np.empty(cap, np.int64)
    out = np.empty((n_acc, cap), np.float32)
    rng = np.empty(cap, np.float32)
    far = np.empty(cap, np.float32)
    acc, near, touched, buf = _tile_buffers(n_acc)
    col = colour.reshape(-1)
    rec = _particle_records(u, v, a, b, c, s, d, op)
    tnear = _tile_near(surf, width, height)
    tiles_x = (width + TILE_PX - 1) // TILE_PX
    n = 0
    for tile in range(start.size - 1):
        if start[tile + 1] == start[tile]:
            continue
        tx0, ty0 = (tile % tiles_x) * TILE_PX, (tile // tiles_x) * TILE_PX
        n_touched = _tile_sums(
            tx0,
            ty0,
            min(tx0 + TILE_PX, width),
            min(ty0 + TILE_PX, height),
            members,
            start[tile],
            start[tile + 1],
            rec,
            col,
            n_col,
            surf,
            tnear[tile],
            width,
            acc,
            near,
            touched,
            buf,
        )
        for q in range(n_touched):  # write out, reset
            t = touched[q]
            pix = _image_pixel(t, tx0, ty0, width)
            hit[n], rng[n], far[n] = pix, near[t], surf[_U(pix)]
            o = t * _U(n_acc)
            if n_acc == 5:  # RGB, unrolled
                out[0, n], out[1, n], out[2, n] = acc[o], acc[o + _U(1)], acc[o + _U(2)]
                out[3, n], out[4, n] = acc[o + _U(3)], acc[o + _U(4)]
                acc[o + _U(1)], acc[o + _U(2)], acc[o + _U(3)], acc[o + _U(4)] = _F0, _F0, _F0, _F0
            else:
                for j in range(n_acc):
                    out[j, n] = acc[o + _U(j)]
                    acc[o + _U(j)] = _F0
            acc[o] = _F1
            near[t] = np.inf
            n += 1
    return hit[:n], out[:, :n], rng[:n], far[:n]


# ----------------------------------------------------------------------------- compositing
@_inline_exp
def _gain_add(
    xf, yf, r_p, r_bg, physical, c0, c1, c2, k0, k1, k2, v0, v1, v2, cam_depth, fx, sk, cx, fy, cy, rz0, rz1, rz2
):
    """The background transfer's (gain, add) per channel (6 float32) at pixel (xf, yf) (px), the
    particle's and the scene's range r_p, r_bg (m): :func:`transfer`'s law, scalars only (a helper
    taking arrays costs reference counts per call)."""
    finite = r_bg < np.inf
    dr = r_bg - r_p if finite else _F0
    t0 = exp32(-c0 * dr) if finite or not c0 > _F0 else _F0
    t1 = exp32(-c1 * dr) if finite or not c1 > _F0 else _F0
    t2 = exp32(-c2 * dr) if finite or not c2 > _F0 else _F0
    if not physical:  # the depth factors are 1: 3 exps instead of 9
        return t0, t1, t2, (_F1 - t0) * v0, (_F1 - t1) * v1, (_F1 - t2) * v2
    y = (yf - cy) / fy
    x = (xf - cx - sk * y) / fx
    dz = (x * rz0 + y * rz1 + rz2) / np.sqrt(x * x + y * y + _F1)
    dp = max(cam_depth - r_p * dz, _F0)
    ddep = max(cam_depth - (r_bg if finite else r_p) * dz, _F0) - dp
    return (
        t0 * exp32(-k0 * ddep),
        t1 * exp32(-k1 * ddep),
        t2 * exp32(-k2 * ddep),
        (_F1 - t0) * exp32(k0 * dp) * v0,
        (_F1 - t1) * exp32(k1 * dp) * v1,
        (_F1 - t2) * exp32(k2 * dp) * v2,
    )


@nb.njit(cache=True, nogil=True, fastmath=_EXP, error_model="numpy")
def transfer(hit, near, far, width, K, rz, c, kd, veil, cam_depth, physical):
    """The background transfer at the covered pixels (``particle_light.Transfer``): (6, n) float32
    = gain (3 rows) and add (3 rows) per channel k, ``gain = tr exp(-Kd_k (depth_bg - depth_p))``,
    ``add = (1 - tr) exp(Kd_k depth_p) veil_k``, ``tr = exp(-c_k (r_bg - r_p))`` (0 where the
    background is open water, r_bg = inf, and c_k > 0). Depths ``max(cam_depth - r dir_z, 0)``,
    dir_z the world z of the pixel's unit ray (from K (3, 3) and rz (3,) = the camera axes'
    world z); article (``physical`` False): the depth factors are 1, so only the 3 exps of tr
    are evaluated (5x faster; exp32(0) = 1 exactly, so the bytes are the same). hit (n,) int64
    flat pixels, near, far (n,) float32 the particle's and the scene's range there (m): no
    gather, so that the loop is vectorised (with one it was 10x slower). One loop per mode, each
    with the mode a constant (:func:`_gain_add`): no branch in the loop."""
    n = hit.size
    out = np.empty((6, n), np.float32)
    tp = transfer_params(K, rz, c, kd, veil, cam_depth, physical)
    if physical:
        _transfer_loop(hit, near, far, width, tp, True, out)
    else:
        _transfer_loop(hit, near, far, width, tp, False, out)
    return out


@_inline_exp
def _transfer_loop(hit, near, far, width, tp, physical, out):
    """:func:`transfer`'s loop, ``physical`` a constant where it is inlined."""
    c0, c1, c2, k0, k1, k2, v0, v1, v2, cam_depth, fx, sk, cx, fy, cy, rz0, rz1, rz2 = _transfer_consts(tp)
    inv_w = 1.0 / width
    for j in range(hit.size):
        pix = hit[j]
        row = np.floor((np.float64(pix) + 0.5) * inv_w)  # pix // width, vectorisable
        out[0, j], out[1, j], out[2, j], out[3, j], out[4, j], out[5, j] = _gain_add(
            np.float32(np.float64(pix) - row * width),
            np.float32(row),
            near[j],
            far[j],
            physical,
            c0,
            c1,
            c2,
            k0,
            k1,
            k2,
            v0,
            v1,
            v2,
            cam_depth,
            fx,
            sk,
            cx,
            fy,
            cy,
            rz0,
            rz1,
            rz2,
        )


@_inline_exp
def transfer_params(K, rz, c, kd, veil, cam_depth, physical):
    """:func:`transfer`'s inputs packed as (19,) float32: [physical, c (3), kd (3), veil (3),
    cam_depth, fx, skew, cx, fy, cy, rz (3)] (:data:`NO_TRANSFER`: gain 1, add 0)."""
    tp = np.empty(19, np.float32)
    tp[0] = _F1 if physical else _F0
    for k in range(3):
        tp[1 + k], tp[4 + k], tp[7 + k], tp[16 + k] = c[k], kd[k], veil[k], rz[k]
    tp[10], tp[11], tp[12], tp[13], tp[14], tp[15] = cam_depth, K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    return tp


@_inline_exp
def _transfer_consts(tp):
    """The 18 scalars of a packed transfer (:func:`transfer_params`) after its mode flag: c (3), kd
    (3), veil (3), cam_depth, fx, skew, cx, fy, cy, rz (3)."""
    return (
        tp[1],
        tp[2],
        tp[3],
        tp[4],
        tp[5],
        tp[6],
        tp[7],
        tp[8],
        tp[9],
        tp[10],
        tp[11],
        tp[12],
        tp[13],
        tp[14],
        tp[15],
        tp[16],
        tp[17],
        tp[18],
    )


NO_TRANSFER = np.zeros(19, np.float32)  # article, c = 0, veil = 0: gain exp(0) = 1, add 0 exactly


@_inline
def _copy(dst, src, start, stop):
    """dst[start:stop] = src[start:stop] as a plain loop (vectorised; numba's slice assignment,
    which guards against overlap, copied 3x slower)."""
    d, s = dst[start:stop], src[start:stop]
    for k in range(d.size):  # k >= 0: no wraparound test, so LLVM vectorises
        d[k] = s[k]


@_jit
def resolve(out, img, merged, rng, mask, hit, acc, near, colour, gain_add, width):
    """The particles over the background at the covered pixels hit (n,), ``out = (img gain + add)
    T + colour (1 - T)``, with the occluder mask and the merged range; the other pixels copied.

    out, img (H*W*3,) float32 interleaved: the result and the background; merged, rng (H*W,)
    float32: the result (the nearest particle's range where covered) and the scene's range; mask
    (H*W,) bool, set where 1 - T >= 0.5; acc (2 + C, n) float32 = [T, w, w c..] (``splat``);
    near (n,) float32 the particles' range. colour: (3, n) float32 per pixel, (3, 1) one for
    all, or (3, 0): the weighted mean ``w c / w``. gain_add: (6, n) float32 from
    :func:`transfer`, or (6, 0) for none (gain 1, add 0). The hits come tile by tile (rows of
    TILE_PX-pixel bands in order): each band of the image is copied just before its pixels are
    composited, so that they are written while in cache (a whole-image copy first, then the
    scattered writes, cost half again as much)."""
    n = hit.size
    per_pixel, one = colour.shape[1] == n and n > 0, colour.shape[1] == 1
    mean, with_bg = not (per_pixel or one), gain_add.shape[1] == n
    height = rng.size // width
    inv_w = 1.0 / width
    done = 0  # rows [0, done) copied
    for j in range(n):
        pix = _U(hit[j])
        row = int((np.float64(pix) + 0.5) * inv_w)
        if row >= done:  # a new band: copy up to its end
            end = min((row // TILE_PX + 1) * TILE_PX, height)
            _copy(out, img, done * width * 3, end * width * 3)
            _copy(merged, rng, done * width, end * width)
            done = end
        keep = acc[0, j]
        cov = _F1 - keep
        o, o1, o2 = pix * _U(3), pix * _U(3) + _U(1), pix * _U(3) + _U(2)
        w = acc[1, j]
        inv = _F1 / w if w > _F0 else _F1
        if mean and with_bg:  # the lit case: unrolled
            out[o] = (img[o] * gain_add[0, j] + gain_add[3, j]) * keep + acc[2, j] * inv * cov
            out[o1] = (img[o1] * gain_add[1, j] + gain_add[4, j]) * keep + acc[3, j] * inv * cov
            out[o2] = (img[o2] * gain_add[2, j] + gain_add[5, j]) * keep + acc[4, j] * inv * cov
        else:  # any colour source and transfer (no helper: the
            for ch in range(3):  # arrays it took cost reference counts per pixel)
                col = colour[ch, j] if per_pixel else (colour[ch, 0] if one else acc[2 + ch, j] * inv)
                bg = img[o + _U(ch)]
                if with_bg:
                    bg = bg * gain_add[ch, j] + gain_add[3 + ch, j]
                out[o + _U(ch)] = bg * keep + col * cov
        mask[pix] = cov >= _HALF
        merged[pix] = near[j]
    _copy(out, img, done * width * 3, out.size)
    _copy(merged, rng, done * width, merged.size)


# ----------------------------------------------------------------------------- splat over, fused
@_inline_exp
def _compact_transfer(tx0, ty0, n, ct, cnear, cfar, tp, physical, cga):
    """:func:`_gain_add` at a tile's n touched pixels (tile pixel ct, ranges cnear, cfar) into cga
    (6, n): compact inputs, one array written, ``physical`` a constant where it is inlined: the
    loop is vectorised."""
    c0, c1, c2, k0, k1, k2, v0, v1, v2, cam_depth, fx, sk, cx, fy, cy, rz0, rz1, rz2 = _transfer_consts(tp)
    for q in range(n):
        t = ct[q]
        cga[0, q], cga[1, q], cga[2, q], cga[3, q], cga[4, q], cga[5, q] = _gain_add(
            np.float32(tx0 + t % np.int32(TILE_PX)),
            np.float32(ty0 + t // np.int32(TILE_PX)),
            cnear[q],
            cfar[q],
            physical,
            c0,
            c1,
            c2,
            k0,
            k1,
            k2,
            v0,
            v1,
            v2,
            cam_depth,
            fx,
            sk,
            cx,
            fy,
            cy,
            rz0,
            rz1,
            rz2,
        )


# The fused pass keeps a tile's sums planar (T, w, w c, near: one plane each), so that an ellipse's
# row of pixels is a row of consecutive floats in every plane and its update one vectorised loop
# of LANES lanes. Lanes that do not count (outside the ellipse's box or the tile, alpha = 0) add
# identities: T x 1, w + 0, near min inf -- the same bytes, and full-width loads and stores
# (LLVM made masked stores of a select, which are slow on this CPU and stalled the loads after
# them: a select per lane and masked stores measured no faster than the per-sample list).
INF_BITS = np.int32(0x7F800000)  # the IEEE bits of float32 inf
LANES = 16  # an ellipse's row segment: 16 float32 lanes (one AVX-512 register)
PAD = LANES  # lanes before and after each plane's TILE_PX^2 pixels
PLANE = TILE_PX * TILE_PX + 2 * PAD  # floats per plane
_NEAR = 5  # planes: T, w, w c0, w c1, w c2, near


@_jit
def _planar_buffers():
    """A tile's empty planar sums (6 PLANE,) float32: T = 1, w = w c = 0, near = inf."""
    acc = np.zeros(6 * PLANE, np.float32)
    acc[:PLANE] = _F1
    acc[_NEAR * PLANE :] = np.inf
    return acc


@_inline
def _lanes_coverage(cov, co, x0, y, u, v, ca, sa, cb, sb, k0, k1, sx):
    """cov[co + j] = the coverage (:func:`_coverage`) of pixel (x0 + j, y) for j < sx, 0 for the
    other lanes (vectorised)."""
    for j in range(LANES):
        c = _coverage(np.float32(x0 + j), np.float32(y), u, v, ca, sa, cb, sb, k0, k1)
        cov[_U(co + j)] = c if j < sx else _F0


@_inline
def _lanes_update(acc, tb, x0, sx, tx0, tx1, cov, co, scale, opi, di, dd, col0, col1, col2):
    """Pixels x0 .. x0 + LANES - 1 of one row of an ellipse (coverage cov[co:], :func:`_tile_sums`'
    update: T *= 1 - alpha, w += alpha / d^2, w c += w colour, near = min(near, d)) into the planar
    sums; lane j is at acc[k PLANE + tb + j] (tb = PAD + the tile pixel of x0). A lane counts where
    j < sx, x0 + j is in the tile [tx0, tx1) and alpha > 0; the others add identities (module
    comment above): no branch, vectorised. The nearest range is a minimum of the IEEE bits as
    int32 (ranges are >= 0, so ordered alike): LLVM turned the float minimum into a masked store."""
    dbits = _bits_of_f32(di)
    for j in range(LANES):
        x = x0 + j
        alpha = min(cov[_U(co + j)] * scale, _F1) * opi
        ok = (j < sx) & (x >= tx0) & (x < tx1) & (alpha > _F0)
        t = _U(tb + j)
        w = alpha / (dd * dd)
        keep = _F1 - min(alpha, np.float32(ALPHA_MAX)) if ok else _F1
        w = w if ok else _F0
        acc[t] = acc[t] * keep
        acc[_U(PLANE) + t] = acc[_U(PLANE) + t] + w
        acc[_U(2 * PLANE) + t] = acc[_U(2 * PLANE) + t] + w * col0
        acc[_U(3 * PLANE) + t] = acc[_U(3 * PLANE) + t] + w * col1
        acc[_U(4 * PLANE) + t] = acc[_U(4 * PLANE) + t] + w * col2
        near = _bits_of_f32(acc[_U(5 * PLANE) + t])
        acc[_U(5 * PLANE) + t] = _f32_from_bits(min(near, dbits if ok else INF_BITS))


@_inline
def _planar_add(acc, t, alpha, w, di, col0, col1, col2):
    """One sample's update of the planar sums at acc[k PLANE + t] (scalar)."""
    acc[t] *= _F1 - min(alpha, np.float32(ALPHA_MAX))
    acc[_U(PLANE) + t] += w
    acc[_U(2 * PLANE) + t] += w * col0
    acc[_U(3 * PLANE) + t] += w * col1
    acc[_U(4 * PLANE) + t] += w * col2
    acc[_U(5 * PLANE) + t] = min(acc[_U(5 * PLANE) + t], di)


@_inline
def _lanes_tested(acc, tb, x0, sx, tx0, tx1, y, cov, co, scale, opi, di, dd, col0, col1, col2, surf, width):
    """:func:`_lanes_update` with the per-pixel depth test (a particle not nearer than the tile's
    nearest surface): scalar, the range read only where the lane would count."""
    for j in range(min(sx, LANES)):
        x = x0 + j
        alpha = min(cov[_U(co + j)] * scale, _F1) * opi
        if x < tx0 or x >= tx1 or not alpha > _F0 or surf[_U(y * width + x)] <= di:
            continue
        _planar_add(acc, _U(tb + j), alpha, alpha / (dd * dd), di, col0, col1, col2)


# fmt: off
@_exact
def _planar_sums(tx0, ty0, tx1, ty1, members, m0, m1, rec, colour, surf, zmin, width, acc, cbuf, touched):
    """:func:`_tile_sums`' law into planar sums (:func:`_planar_buffers`), every pixel taking the
    tile's particles in member order (so the same bytes): an ellipse row by row, LANES pixels at a
    time (:func:`_lanes_update`); a small one's coverage over its box first (cbuf rows of
    GROUP_MAX_PX, summed in row-major order as :func:`_ellipse_samples` does), then scaled; a
    speck's 2 x 2 pixels one by one. colour (M 3,); zmin the tile's nearest scene range.
    Returns the count of covered tile pixels listed in ``touched`` (int32, first-touch order)
    when the tile had specks only, else -1 (an ellipse's rows are not listed: the pixels are
    found by a scan, :func:`_planar_over`; listing each row's lanes cost more than the scan)."""
    last = members.size - 1
    n_touched, rows = 0, False
    for k in range(m0, m1):
        i = _U(members[k])
        p = _U(members[min(k + AHEAD, last)])      # a later member's data on its way to the cache
        _prefetch(rec, p * _U(REC))
        _prefetch(colour, p * _U(3))
        r, ci = i * _U(REC), i * _U(3)
        ui, vi, ai, bi = rec[r], rec[r + _U(1)], rec[r + _U(2)], rec[r + _U(3)]
        cs, sn, di, opi = rec[r + _U(4)], rec[r + _U(5)], rec[r + _U(6)], rec[r + _U(7)]
        dd = max(di, np.float32(1e-3))
        col0, col1, col2 = colour[ci], colour[ci + _U(1)], colour[ci + _U(2)]
        tested = not di < zmin                                       # depth test per pixel
        if not ai < np.float32(SPLAT_BELOW_PX):                      # an anti-aliased ellipse
            x0, y0, sx, sy, ca, sa, cb, sb, k0, k1 = _footprint(ui, vi, ai, bi, cs, sn)
            rows = True
            if max(sx, sy) <= GROUP_MAX_PX and ai < np.float32(NORMALISE_BELOW_PX):   # small: its box
                total = _F0
                for q in range(sy):
                    _lanes_coverage(cbuf, q * LANES, x0, y0 + q, ui, vi, ca, sa, cb, sb, k0, k1, sx)
                    for j in range(sx):
                        total += cbuf[_U(q * LANES + j)]
                scale = _PI * ai * bi / max(total, np.float32(1e-12)) if total > _F0 else _F1
                for q in range(max(0, ty0 - y0), min(sy, ty1 - y0)):
                    y = y0 + q
                    tb = PAD + (y - ty0) * TILE_PX + x0 - tx0
                    if tested:
                        _lanes_tested(acc, tb, x0, sx, tx0, tx1, y, cbuf, q * LANES, scale, opi, di, dd, col0, col1,
                                      col2, surf, width)
                    else:
                        _lanes_update(acc, tb, x0, sx, tx0, tx1, cbuf, q * LANES, scale, opi, di, dd, col0, col1, col2)
            else:                                                     # its box, clipped to the tile
                xs, xe = max(x0, tx0), min(x0 + sx, tx1)
                for y in range(max(y0, ty0), min(y0 + sy, ty1)):
                    for xc in range(xs, xe, LANES):
                        _lanes_coverage(cbuf, 0, xc, y, ui, vi, ca, sa, cb, sb, k0, k1, xe - xc)
                        tb = PAD + (y - ty0) * TILE_PX + xc - tx0
                        if tested:
                            _lanes_tested(acc, tb, xc, xe - xc, tx0, tx1, y, cbuf, 0, _F1, opi, di, dd, col0, col1,
                                          col2, surf, width)
                        else:
                            _lanes_update(acc, tb, xc, xe - xc, tx0, tx1, cbuf, 0, _F1, opi, di, dd, col0, col1, col2)
            continue
        w_d = _F1 / (dd * dd)                                            # a speck: 2 x 2 pixels
        x0, y0, fx, fy = _speck_box(ui, vi)
        scale = _PI * ai * bi * opi
        for q in range(4):
            x, y, alpha = _speck_pixel(q, x0, y0, fx, fy, scale, tx0, ty0, tx1, ty1)
            if not alpha > _F0 or (tested and surf[_U(y * width + x)] <= di):
                continue
            t = _U((y - ty0) * TILE_PX + x - tx0)
            touched[_U(n_touched)] = np.int32(t)
            n_touched += acc[_U(_NEAR * PLANE + PAD) + t] == np.inf
            _planar_add(acc, t + _U(PAD), alpha, alpha * w_d, di, col0, col1, col2)
    return -1 if rows else n_touched
# fmt: on


@_exp_vec
def _planar_over(tx0, ty0, ty1, n, acc, surf, img, out, merged, mask, tp, width, ct, cnear, cfar, cga):
    """A tile's covered pixels (near < inf in the planar sums acc) over the background img at the
    same pixels of out (which holds img already): :func:`resolve`'s law with :func:`transfer`'s
    gain and add (tp, :func:`transfer_params`), the mask and the merged range; the sums reset.
    The covered pixels: the n listed in ct (n >= 0, :func:`_planar_sums`) or, for n = -1, found
    by a scan in raster order; their ranges gathered (cnear, cfar (TILE_PX^2,)) and the transfer
    evaluated on them in one vectorised loop (cga (6, TILE_PX^2))."""
    if n < 0:
        n = 0
        for t in range((ty1 - ty0) * TILE_PX):  # written always, counted when covered
            ct[_U(n)] = np.int32(t)
            n += acc[_U(_NEAR * PLANE + PAD + t)] < np.inf
    for q in range(n):
        t = _U(ct[q])
        cnear[q] = acc[_U(_NEAR * PLANE + PAD) + t]
        cfar[q] = surf[_image_pixel(t, tx0, ty0, width)]
    if tp[0] > _F0:
        _compact_transfer(tx0, ty0, n, ct, cnear, cfar, tp, True, cga)
    else:
        _compact_transfer(tx0, ty0, n, ct, cnear, cfar, tp, False, cga)
    for q in range(n):
        t = _U(ct[q])
        pix = _image_pixel(t, tx0, ty0, width)
        o = t + _U(PAD)
        keep = acc[o]
        cov = _F1 - keep
        w = acc[o + _U(PLANE)]
        inv = _F1 / w if w > _F0 else _F1
        p0, p1, p2 = pix * _U(3), pix * _U(3) + _U(1), pix * _U(3) + _U(2)
        out[p0] = (img[p0] * cga[0, q] + cga[3, q]) * keep + acc[o + _U(2 * PLANE)] * inv * cov
        out[p1] = (img[p1] * cga[1, q] + cga[4, q]) * keep + acc[o + _U(3 * PLANE)] * inv * cov
        out[p2] = (img[p2] * cga[2, q] + cga[5, q]) * keep + acc[o + _U(4 * PLANE)] * inv * cov
        mask[pix] = cov >= _HALF
        merged[pix] = cnear[q]
        acc[o], acc[o + _U(PLANE)], acc[o + _U(2 * PLANE)] = _F1, _F0, _F0
        acc[o + _U(3 * PLANE)], acc[o + _U(4 * PLANE)], acc[o + _U(5 * PLANE)] = _F0, _F0, np.inf


@_jit
def splat_over(u, v, a, b, c, s, d, op, colour, surf, scene, img, out, merged, mask, tp, width, height):
    """:func:`splat`, :func:`transfer` and :func:`resolve` in one pass, tile by tile, for particles
    with their own colours (colour (M, 3): the covered part takes the weighted mean colour).
    Inputs as :func:`splat`'s and :func:`resolve`'s (scene (H*W,): the merged range where no
    particle covers; img, out (H*W*3,); merged (H*W,); mask (H*W,) bool, False on entry: only
    covered pixels are set); tp: :func:`transfer_params` or
    :data:`NO_TRANSFER`. Each band of TILE_PX image rows is copied to out and merged, then each of
    its tiles' sums (planar, :func:`_planar_sums`) is composited over it while still in L1
    (:func:`_planar_over`): no per-pixel lists through memory. Same bytes as the three kernels in
    sequence (tests/test_particle_splat.py)."""
    start, members, samples = _bins(u, v, a, b, c, s, op, width, height)
    acc = _planar_buffers()
    cbuf = np.zeros(GROUP_MAX_PX * LANES, np.float32)
    ct = np.empty(TILE_PX * TILE_PX + 1, np.int32)
    cnear, cfar = np.empty(TILE_PX * TILE_PX, np.float32), np.empty(TILE_PX * TILE_PX, np.float32)
    cga = np.empty((6, TILE_PX * TILE_PX), np.float32)
    col = colour.reshape(-1)
    rec = _particle_records(u, v, a, b, c, s, d, op)
    tnear = _tile_near(surf, width, height)
    tiles_x, tiles_y = (width + TILE_PX - 1) // TILE_PX, (height + TILE_PX - 1) // TILE_PX
    for ty in range(tiles_y):
        ty0, ty1 = ty * TILE_PX, min(ty * TILE_PX + TILE_PX, height)
        _copy(out, img, ty0 * width * 3, ty1 * width * 3)  # the band, just before its pixels
        _copy(merged, scene, ty0 * width, ty1 * width)
        for tx in range(tiles_x):
            tile = ty * tiles_x + tx
            if start[tile + 1] == start[tile]:
                continue
            tx0 = tx * TILE_PX
            n = _planar_sums(
                tx0,
                ty0,
                min(tx0 + TILE_PX, width),
                ty1,
                members,
                start[tile],
                start[tile + 1],
                rec,
                col,
                surf,
                tnear[tile],
                width,
                acc,
                cbuf,
                ct,
            )
            _planar_over(tx0, ty0, ty1, n, acc, surf, img, out, merged, mask, tp, width, ct, cnear, cfar, cga)
