"""The fast splat (blendgen/physics/particles/splat.py) against a brute-force oracle: every
particle's coverage law evaluated on every pixel of a small image, depth-tested per pixel and
summed with plain Python loops. Catches any grouping, clipping, compaction or sparse-product
error (a sample dropped, doubled or given to the wrong particle)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from blendgen.physics.particles import splat as ps

W, H = 48, 36


def _particles(rng, n: int, colours: int = 3) -> ps.Particles:
    f32 = lambda x: np.asarray(x, np.float32)
    a = f32(
        np.concatenate(
            [rng.uniform(0.1, 0.49, n // 3), rng.uniform(0.5, 3.0, n // 3), rng.uniform(3.0, 12.0, n - 2 * (n // 3))]
        )
    )  # specks, blocks, large
    b = f32(a * rng.uniform(0.6, 1.0, n))
    phi = rng.uniform(0, math.pi, n)
    return ps.Particles(
        f32(rng.uniform(-6, W + 6, n)),
        f32(rng.uniform(-6, H + 6, n)),
        a,
        np.minimum(a, b),
        f32(np.cos(phi)),
        f32(np.sin(phi)),
        f32(rng.uniform(0.5, 8.0, n)),
        f32(rng.uniform(0.2, 1.0, n)),
        f32(rng.uniform(0, 2, (n, colours))),
    )


def _alpha_full(p: ps.Particles, i: int) -> np.ndarray:
    """(H, W) coverage x opacity of particle i by the documented laws, on the whole image."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    if p.a[i] < ps.SPLAT_BELOW_PX:  # bilinear speck of alpha = area
        out = np.zeros((H, W))
        x0, y0 = math.floor(p.u[i]), math.floor(p.v[i])
        fx, fy = p.u[i] - x0, p.v[i] - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= x0 + dx < W and 0 <= y0 + dy < H:
                out[y0 + dy, x0 + dx] = wgt * math.pi * p.a[i] * p.b[i]
        return out * p.op[i]
    m = math.sqrt(p.a[i] * p.b[i])
    dx, dy = xx - p.u[i], yy - p.v[i]
    q = np.hypot((dx * p.c[i] + dy * p.s[i]) / p.a[i], (dy * p.c[i] - dx * p.s[i]) / p.b[i])
    alpha = np.clip(0.5 + m - m * q, 0, 1)
    x0, y0, sx, sy = (int(z[0]) for z in ps.boxes(p, np.array([i])))
    in_block = max(sx, sy) <= ps.GROUP_MAX_PX
    if in_block and p.a[i] < ps.NORMALISE_BELOW_PX:  # renormalised over its (square) box
        gy, gx = np.mgrid[y0 : y0 + max(sx, sy), x0 : x0 + max(sx, sy)].astype(np.float64)
        ddx, ddy = gx - p.u[i], gy - p.v[i]
        qq = np.hypot((ddx * p.c[i] + ddy * p.s[i]) / p.a[i], (ddy * p.c[i] - ddx * p.s[i]) / p.b[i])
        total = np.clip(0.5 + m - m * qq, 0, 1).sum()
        if total > 0:
            alpha = np.minimum(alpha * math.pi * p.a[i] * p.b[i] / total, 1.0)
    return alpha * p.op[i]


def _oracle(p: ps.Particles, surf: np.ndarray):
    log_t, w, near = np.zeros((H, W)), np.zeros((H, W)), np.full((H, W), np.inf)
    wc = np.zeros((H, W, p.colour.shape[1]))
    for i in range(p.u.size):
        al = _alpha_full(p, i) * (surf > p.d[i])
        log_t += np.log1p(-np.minimum(al, ps.ALPHA_MAX))
        wi = al / max(float(p.d[i]), 1e-3) ** 2
        w += wi
        wc += wi[..., None] * p.colour[i]
        near = np.where(al > 0, np.minimum(near, p.d[i]), near)
    return log_t, w, wc, near


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_splat_matches_brute_force_oracle(seed):
    rng = np.random.default_rng(seed)
    p = _particles(rng, 60)
    surf = np.full((H, W), np.inf, np.float32)
    surf[10:25, 15:35] = 3.0  # a near "dock": particles behind it vanish
    sums = ps.splat(p, surf.reshape(-1), W, H)
    log_t, w, wc, near = _oracle(p, surf)
    assert np.array_equal(np.sort(sums.hit), np.flatnonzero(np.isfinite(near)))  # each pixel once
    trans_f, wc_f = np.ones(H * W), np.zeros((H * W, sums.wc.shape[0]))
    trans_f[sums.hit], wc_f[sums.hit] = sums.trans, sums.wc.T
    assert np.allclose(trans_f.reshape(H, W), np.exp(log_t), rtol=1e-4, atol=1e-5)
    assert np.allclose(wc_f[:, 0].reshape(H, W), w, rtol=1e-4, atol=1e-5)
    assert np.allclose(wc_f[:, 1:].reshape(H, W, -1), wc, rtol=1e-4, atol=1e-5)
    assert np.allclose(sums.near, near.reshape(-1)[sums.hit])


@pytest.mark.parametrize("seed", [3, 4])
def test_splat_matches_the_oracle_over_a_rough_range_pass(seed):
    """Per-pixel ranges scattered across the particles' (NaN = no surface, -0.0, inf): the tile's
    nearest-range bound (particle_kernels._tile_near) may only skip tests that would pass."""
    rng = np.random.default_rng(seed)
    p = _particles(rng, 60)
    surf = rng.uniform(0.3, 9.0, (H, W)).astype(np.float32)
    surf[rng.random((H, W)) < 0.1] = np.nan
    surf[:4, :5], surf[30:, 40:] = -0.0, np.inf
    sums = ps.splat(p, surf.reshape(-1), W, H)
    log_t, w, wc, near = _oracle(p, np.where(np.isnan(surf), np.inf, surf))
    assert np.array_equal(np.sort(sums.hit), np.flatnonzero(np.isfinite(near)))
    trans_f, w_f = np.ones(H * W), np.zeros(H * W)
    trans_f[sums.hit], w_f[sums.hit] = sums.trans, sums.wc[0]
    assert np.allclose(trans_f.reshape(H, W), np.exp(log_t), rtol=1e-4, atol=1e-5)
    assert np.allclose(w_f.reshape(H, W), w, rtol=1e-4, atol=1e-5)


def test_prefetch_is_a_hint_on_any_array_at_any_index():
    """The splat's software prefetch (particle_kernels._prefetch) compiles for arrays of
    several dtypes in one function (a second pointer type once broke the intrinsic's single
    declaration), never faults on an index past the end, and changes no value."""
    import numba as nb

    from blendgen.physics.particles.kernels import _prefetch

    @nb.njit
    def touched_sum(f, i, k):
        _prefetch(f, np.uint64(k))
        _prefetch(i, np.uint64(k))
        return f.sum() + i.sum()

    f, i = np.arange(3, dtype=np.float32), np.arange(5, dtype=np.int64)
    assert touched_sum(f, i, 1) == 13.0
    assert touched_sum(f, i, 1 << 40) == 13.0
    assert f.tolist() == [0.0, 1.0, 2.0] and i.tolist() == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("mode", ["physical", "article", "none"])
@pytest.mark.parametrize("seed", [5, 6, 7])
def test_fused_pass_gives_the_bytes_of_splat_transfer_and_resolve(seed, mode):
    """particle_splat.over (splat, background transfer and compositing fused per tile, the sums
    planar) against the three kernels in sequence, byte for byte: image, merged range and mask,
    over a rough range pass (NaN, inf, a near dock) whose merged range keeps the scene's values.
    Specks, small and large ellipses over partial tiles and the image's edges; seed 7 has specks
    only (their tiles list the covered pixels instead of scanning them)."""
    from blendgen.physics.particles import kernels as kern

    rng = np.random.default_rng(seed)
    p = _particles(rng, 80)
    if seed == 7:
        a = rng.uniform(0.35, 0.49, p.a.size).astype(np.float32)
        p = dataclasses.replace(p, a=a, b=(a * rng.uniform(0.8, 1.0, a.size)).astype(np.float32))
    surf = rng.uniform(0.3, 9.0, (H, W)).astype(np.float32)
    surf[rng.random((H, W)) < 0.1], surf[30:, 40:], surf[10:25, 15:35] = np.nan, np.inf, 3.0
    surf = surf.reshape(-1)
    img = rng.uniform(0, 2, H * W * 3).astype(np.float32)
    K = np.array([[40.0, 0.5, 23.5], [0, 41.0, 17.5], [0, 0, 1]], np.float32)
    args = (
        K,
        np.array([0.2, -0.9, 0.1], np.float32),
        np.array([0.3, 0.1, 0.05], np.float32),
        np.array([0.2, 0.08, 0.03], np.float32),
        np.array([0.02, 0.05, 0.04], np.float32),
        np.float32(4.0),
    )
    sums = ps.splat(p, surf, W, H)
    if mode == "none":
        tp, gain_add = kern.NO_TRANSFER, np.zeros((6, 0), np.float32)
    else:
        tp = kern.transfer_params(*args, mode == "physical")
        gain_add = kern.transfer(sums.hit, sums.near, sums.far, W, *args, mode == "physical")
    out, merged, mask = np.empty_like(img), np.empty(H * W, np.float32), np.zeros(H * W, bool)
    kern.resolve(out, img, merged, surf, mask, sums.hit, sums.acc, sums.near, np.zeros((3, 0), np.float32), gain_add, W)
    got = ps.over(p, surf, surf, img, tp, W, H)
    assert np.array_equal(got[0], out) and np.array_equal(got[2], mask)
    assert np.array_equal(got[1], merged, equal_nan=True)
    assert mask.any() and not mask.all()


def test_fused_pass_refuses_negative_or_nan_ranges_and_colours():
    """The fused pass keeps the nearest range as a minimum of IEEE bits, valid for ranges >= 0,
    and its idle lanes add 0 x colour: a negative or NaN range, or a non-finite colour, is refused
    with a clear error, not drawn wrongly."""
    rng = np.random.default_rng(3)
    p = _particles(rng, 6)
    surf = np.full(H * W, 5.0, np.float32)
    img = np.zeros(H * W * 3, np.float32)
    for bad in (-0.1, np.nan):
        d = p.d.copy()
        d[2] = bad
        with pytest.raises(ValueError, match="d >= 0"):
            ps.over(dataclasses.replace(p, d=d), surf, surf, img, np.zeros(19, np.float32), W, H)
    colour = p.colour.copy()
    colour[1, 2] = np.inf  # the row's idle lanes add 0 x colour: refused, not NaN
    with pytest.raises(ValueError, match="finite particle colours"):
        ps.over(dataclasses.replace(p, colour=colour), surf, surf, img, np.zeros(19, np.float32), W, H)


@pytest.mark.parametrize("seed", [0, 1])
def test_binned_boxes_are_the_footprints_clipped_to_the_image(seed):
    """particle_kernels._clipped_boxes (one vectorised pass for the binning) against the scalar
    laws particle by particle: an ellipse's box (``box``), a speck's 2 x 2 pixels at floor(u, v),
    clipped to the image, (xa, xb) = (1, 0) when nothing is left. Extremes included: semi-axes
    at the speck threshold and of zero, tiny b, boxes over every edge and far off the image."""
    from blendgen.physics.particles import kernels as kern

    rng = np.random.default_rng(seed)
    n = 400
    a = np.concatenate(
        [
            rng.uniform(0.0, 0.49, n // 4),
            rng.uniform(0.5, 4.0, n // 4),
            rng.uniform(4.0, 60.0, n // 4),
            np.full(n - 3 * (n // 4), ps.SPLAT_BELOW_PX),
        ]
    )
    a[:3] = 0.0
    b = a * rng.uniform(0.0, 1.0, n)
    b[3:6] = 1e-6
    phi = rng.uniform(0, 2 * math.pi, n)
    u, v = rng.uniform(-80, W + 80, n), rng.uniform(-80, H + 80, n)
    u[6:10], v[6:10] = [-0.5, W - 0.5, -1e4, 1e4], [-0.5, H - 0.5, 1e4, -1e4]
    f32 = lambda x: np.asarray(x, np.float32)
    u, v, a, b, c, s = f32(u), f32(v), f32(a), f32(b), f32(np.cos(phi)), f32(np.sin(phi))
    got = np.empty((4, n), np.int64)
    kern._clipped_boxes(u, v, a, b, c, s, W, H, got)
    for i in range(n):
        if a[i] < ps.SPLAT_BELOW_PX:
            x0, y0, sx, sy = math.floor(u[i]), math.floor(v[i]), 2, 2
        else:
            x0, y0, sx, sy = kern.box(u[i], v[i], a[i], b[i], c[i], s[i])
            sx, sy = max(sx, 0), max(sy, 0)
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + sx, W) - 1, min(y0 + sy, H) - 1
        want = (1, ya, 0, yb) if xb < xa or yb < ya else (xa, ya, xb, yb)
        assert tuple(got[:, i]) == want, (i, u[i], v[i], a[i], b[i])


@pytest.mark.parametrize("width, height", [(48, 36), (33, 31), (640, 480), (1, 1)])
def test_tile_nearest_range_is_the_nan_ignoring_minimum(width, height):
    from blendgen.physics.particles.kernels import TILE_PX, _tile_near

    rng = np.random.default_rng(width)
    surf = rng.uniform(0.0, 20.0, (height, width)).astype(np.float32)
    surf[rng.random((height, width)) < 0.2] = np.nan
    surf[: min(3, height), : min(3, width)] = np.inf
    got = _tile_near(surf.reshape(-1), width, height)
    tiles = [
        surf[ty : ty + TILE_PX, tx : tx + TILE_PX]
        for ty in range(0, height, TILE_PX)
        for tx in range(0, width, TILE_PX)
    ]
    ref = np.array([np.min(t[~np.isnan(t)]) if np.any(~np.isnan(t)) else np.nan for t in tiles], np.float32)
    assert np.array_equal(got, ref, equal_nan=True)


def test_splat_without_colours_skips_the_colour_sums():
    p = _particles(np.random.default_rng(3), 30, colours=0)
    sums = ps.splat(p, np.full(W * H, np.inf, np.float32), W, H)
    assert sums.wc is None and sums.near.size == sums.hit.size > 0


def test_splat_of_nothing_is_empty():
    p = _particles(np.random.default_rng(4), 3)
    far = ps.Particles(*(x[:0] for x in (p.u, p.v, p.a, p.b, p.c, p.s, p.d, p.op, p.colour)))
    sums = ps.splat(far, np.full(W * H, np.inf, np.float32), W, H)
    assert sums.hit.size == 0 and sums.near.size == 0 and sums.wc.shape == (4, 0)


def test_splat_leaves_no_trace_between_frames():
    """The kernel's tile buffers are reset after each tile: a frame splat after other frames (other
    sizes of colour too) gives the same sums as the first time."""
    rng = np.random.default_rng(5)
    first, other, grey = _particles(rng, 60), _particles(rng, 60), _particles(rng, 40, colours=0)
    surf = np.full(W * H, np.inf, np.float32)
    a = ps.splat(first, surf, W, H)
    for p in (other, grey, other):
        ps.splat(p, surf, W, H)
    b = ps.splat(first, surf, W, H)
    for x, y in ((a.hit, b.hit), (a.trans, b.trans), (a.wc, b.wc), (a.near, b.near)):
        assert np.array_equal(x, y)


def test_footprints_across_tile_corners_are_summed_once_per_pixel():
    """Specks and ellipses centred on the corner of four 32-px tiles (pixels 31 | 32): every
    tile draws its part, no sample is lost or doubled (against the brute-force oracle)."""
    f32 = lambda x: np.asarray(x, np.float32)
    a = f32([0.3, 0.45, 2.0, 7.0, 0.2])
    p = ps.Particles(
        f32([31.5, 31.9, 32.0, 31.2, 47.6]),
        f32([31.5, 32.2, 31.7, 32.4, 35.5]),
        a,
        a * f32(0.8),
        f32([1, 0.6, 0.8, 1, 1]),
        f32([0, 0.8, 0.6, 0, 0]),
        f32([1, 2, 3, 4, 5]),
        f32([1, 1, 0.5, 0.7, 1]),
        f32(np.arange(15).reshape(5, 3) / 15),
    )
    surf = np.full((H, W), np.inf, np.float32)
    sums = ps.splat(p, surf.reshape(-1), W, H)
    log_t, w, wc, near = _oracle(p, surf)
    assert np.array_equal(np.sort(sums.hit), np.flatnonzero(np.isfinite(near)))
    assert np.allclose(sums.trans, np.exp(log_t).reshape(-1)[sums.hit], rtol=1e-5, atol=1e-6)
    assert np.allclose(sums.wc[1:].T, wc.reshape(-1, 3)[sums.hit], rtol=1e-5, atol=1e-6)


def test_vectorisable_exp_is_as_accurate_as_float32_allows():
    from blendgen.physics.particles.kernels import exp32

    x = np.concatenate([np.random.default_rng(0).uniform(-87.0, 88.0, 2000), [-87.0, -1e-6, 0.0, 1e-6, 1.0, 88.0]])
    got = np.array([exp32(np.float32(v)) for v in x.astype(np.float32)], np.float64)
    ref = np.exp(x.astype(np.float32).astype(np.float64))
    assert np.max(np.abs(got - ref) / ref) < 1.5e-7  # numpy's own float32 exp: ~2e-7
    assert exp32(np.float32(-200.0)) == pytest.approx(1.1754944e-38, rel=1e-5)  # clamped, no garbage
    assert exp32(np.float32(0.0)) == 1.0


@pytest.mark.parametrize("physical", [True, False])
def test_background_transfer_matches_the_two_layer_formula(physical):
    """particle_kernels.transfer against its law written out in float64 numpy (the particle_light
    Transfer doc): gain = t_bg/t_p x D_bg/D_p, add = (1 - t_bg/t_p) B / D_p; open water: t_bg = 0."""
    from blendgen.geometry import intrinsics_from_hfov
    from blendgen.physics.particles.kernels import transfer

    rng = np.random.default_rng(1)
    w, h, n = 64, 48, 500
    K = intrinsics_from_hfov(w, h, math.radians(70.0))
    rz = np.array([0.1, -0.9, 0.3]) / np.linalg.norm([0.1, -0.9, 0.3])
    hit = rng.choice(w * h, n, replace=False).astype(np.int64)
    near = rng.uniform(0.2, 6.0, n)
    far = near + rng.uniform(0.0, 10.0, n)
    far[:60] = np.inf
    c, kd, B, cam = np.array([0.6, 0.25, 0.15]), np.array([0.5, 0.1, 0.05]), np.array([0.02, 0.05, 0.07]), 3.0
    got = transfer(
        hit,
        near.astype(np.float32),
        far.astype(np.float32),
        w,
        K.astype(np.float32),
        rz.astype(np.float32),
        c.astype(np.float32),
        kd.astype(np.float32),
        B.astype(np.float32),
        np.float32(cam),
        physical,
    )
    y = (hit // w - K[1, 2]) / K[1, 1]
    x = (hit % w - K[0, 2] - K[0, 1] * y) / K[0, 0]
    dz = (x * rz[0] + y * rz[1] + rz[2]) / np.sqrt(x * x + y * y + 1)
    depth = lambda r: np.maximum(cam - r * dz, 0.0) if physical else np.zeros(n)
    finite = np.isfinite(far)
    tr = np.where(finite, np.exp(-c[:, None] * np.where(finite, far - near, 0.0)), 0.0)
    gain = tr * np.exp(-kd[:, None] * (depth(np.where(finite, far, near)) - depth(near)))
    add = (1 - tr) * np.exp(kd[:, None] * depth(near)) * B[:, None]
    assert np.allclose(got[:3], gain, rtol=2e-5, atol=1e-7) and np.allclose(got[3:], add, rtol=2e-5, atol=1e-8)
