"""Fast fidelity: the water surface seen from below and caustics, in image space.

Runs before the water model (:func:`blendgen.physics.water.optics.apply_water`), on the clean
passes of one frame; physics in :mod:`blendgen.physics.surface.optics`. Both steps are skipped
entirely when the sequence has them off (``SequencePost.world`` None or False).

- Surface: a pixel whose ray points up meets the surface at ``r = (z_s - z_cam) / d_z``;
  when it hits nothing before (or only pool rim above the water), its clean radiance becomes Snell's window
  (``surface.window_radiance``, with the local wave normal) at that range, with depth 0
  (sky light is not dimmed by depth light), so the water model then attenuates it along the
  path and veils it like any surface. Totally reflected pixels show the clean scene along
  the mirrored ray where the camera's own image holds it (screen-space reflection, at the
  summed path length), else the veiling light of open water at the camera's depth; the
  reference traces the real reflection.
- Caustics: each surface point's sun-lit part ``J - albedo L_amb`` is multiplied by the
  focusing factor of its sun ray at its beam path (``caustic_map.frame_factor``: the surface's
  ray map carried forward, all preimages summed), binned as coarse as the pixel's footprint,
  with the water's scattering coefficient (mean over RGB) and phase mean cosine ``g`` as
  the turbidity. Pixels in the sun's shadow (the render's sun pass 0) are left out: they have
  no sunlight to focus, and the surface crossing of their beam is that of the lit surface
  casting the shadow, whose beam path is shorter (sharing its bins moved its pattern).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from blendgen.physics.light.surface_light import lit_pixels, surface_normals
from blendgen.physics.surface import caustic_map
from blendgen.physics.surface import optics as sf
from blendgen.pipeline.stagetimer import term


@functools.lru_cache(maxsize=8)
def waves_of(seed: int, wind_mps: float) -> sf.WaveField:
    """The sequence's surface waves (cached: the same for every frame)."""
    return sf.waves_for(seed, wind_mps)


#: Pixel stride of the wave-slope grid of :func:`add_surface` (2: slopes on every second
#: pixel in x and y, bilinearly interpolated; 1: every pixel). The waves' shortest
#: wavelength (0.25 m) spans many pixels wherever the surface is near enough to show it.
SLOPE_STRIDE = 2


@functools.lru_cache(maxsize=4)
def _upsample_maps(h: int, w: int, stride: int):
    """cv2.remap maps taking a grid sampled at every ``stride``-th pixel to (h, w)."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float32) / stride, np.arange(h, dtype=np.float32) / stride)
    return u, v


def surface_slopes(waves: sf.WaveField, cam_xy, rays, r_all, t: float, stride: int):
    """Wave slopes (sx, sy), each (H, W) float32, where each pixel's ray meets the mean surface
    (``r_all`` (H, W) range, inf where it does not; ``rays`` (H, W, 3) world unit vectors),
    evaluated on every ``stride``-th pixel and interpolated bilinearly (0 where no ray rises)."""
    import cv2

    rh, dh = r_all[::stride, ::stride], rays[::stride, ::stride]
    ok = np.isfinite(rh)
    g = np.zeros((*rh.shape, 2), np.float32)
    r = rh[ok].astype(np.float32)
    sx, sy = waves.slope(np.float32(cam_xy[0]) + r * dh[..., 0][ok], np.float32(cam_xy[1]) + r * dh[..., 1][ok], t)
    g[ok, 0], g[ok, 1] = sx, sy
    if stride > 1:
        g = cv2.remap(g, *_upsample_maps(*r_all.shape, stride), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return g[..., 0], g[..., 1]


@term("surface")
def add_surface(
    rgb,
    range_m,
    depth,
    wp,
    rays,
    K,
    T_world_cam,
    surface_z_m: float,
    t: float,
    below_radiance,
    stride: int | None = None,
):
    """Pixels that see the surface from below: (rgb, range_m, depth) new arrays; the inputs
    when none does. ``rays`` (H, W, 3) unit world directions of the pixels; K (3, 3);
    ``below_radiance`` (3,) the veil at the camera's depth. Inside Snell's window: the window
    radiance at the surface's range, depth 0. Totally reflected pixels: the clean scene where
    the mirrored ray from the surface meets it, when the camera's own image holds that point
    (:func:`_mirror`), else ``below_radiance`` (open water). Wave slopes on the
    :data:`SLOPE_STRIDE` grid (``stride`` overrides it). The same as :func:`shade_surface` of
    :func:`surface_geometry`, which a frame seen through several waters makes once."""
    geo = surface_geometry(range_m, depth, wp, rays, K, T_world_cam, surface_z_m, t, stride)
    return shade_surface(rgb, range_m, depth, geo, wp, below_radiance)


class SurfaceGeometry:
    """What :func:`add_surface` needs of a frame whatever the water, on the pixels that see the
    surface (flat indices ``up`` (m,)): range ``r`` (m,) to it, incidence cosine ``cos_up`` and
    Fresnel reflectance ``R`` (m,), the sun's disc (m,) (None: no sun), and the mirrored pixels:
    their indices ``idx`` into the m, the pixel ``src`` each reflects, its path ``path`` (m)
    and depth ``depth`` (m)."""

    def __init__(self, up, r, cos_up, R, sun, idx, src, path, depth):
        self.up, self.r, self.cos_up, self.R, self.sun = up, r, cos_up, R, sun
        self.idx, self.src, self.path, self.depth = idx, src, path, depth

    def seen_past(self, range_m: np.ndarray) -> SurfaceGeometry:
        """This geometry (made from a frame's own range pass) on the pixels where a sequence's
        range pass ``range_m`` (H, W) (the frame's with particles in front) has nothing nearer
        than the surface: the pixels :func:`surface_geometry` of ``range_m`` would shade. A
        mirrored pixel keeps its mirror march through the frame's own passes."""
        keep = ~(np.asarray(range_m).ravel()[self.up] < self.r)
        if keep.all():
            return self
        at = np.cumsum(keep) - 1  # position of each kept pixel among the kept
        mirrored = keep[self.idx]
        sun = None if self.sun is None else self.sun[keep]
        return SurfaceGeometry(
            self.up[keep],
            self.r[keep],
            self.cos_up[keep],
            self.R[keep],
            sun,
            at[self.idx[mirrored]],
            self.src[mirrored],
            self.path[mirrored],
            self.depth[mirrored],
        )


@term("surface")
def surface_geometry(range_m, depth, wp, rays, K, T_world_cam, surface_z_m: float, t: float, stride=None):
    """The water-independent part of :func:`add_surface` (same arguments); None when no pixel
    sees the surface."""
    T = np.asarray(T_world_cam, float)
    d = rays
    rise = np.float32(max(surface_z_m - T[2, 3], 0.0))
    with np.errstate(divide="ignore"):
        r_all = np.where(d[..., 2] > 1e-4, rise / np.maximum(d[..., 2], np.float32(1e-4)), np.inf)
    # the surface is hit first: nothing else on the ray, or only geometry above the water
    # (a depth condition moves the surface, not the pool: its rim may stand above it)
    up = np.isfinite(r_all) & ~(range_m < r_all)
    if not up.any():
        return None
    gx, gy = surface_slopes(
        waves_of(wp.wave_seed, wp.wind_mps),
        T[:2, 3],
        d,
        np.where(up, r_all, np.inf),
        t,
        SLOPE_STRIDE if stride is None else stride,
    )
    r, du, sx, sy = r_all[up].astype(np.float32), d[up], gx[up], gy[up]
    norm = np.sqrt(sx * sx + sy * sy + 1)
    cos_up = (du[:, 2] - sx * du[:, 0] - sy * du[:, 1]) / norm
    depth = np.broadcast_to(np.asarray(depth, np.float32), range_m.shape)
    R = sf.fresnel_reflectance(cos_up)
    sun = None
    if wp.sun_irradiance > 0:  # the sun's disc in Snell's window
        nrm = np.stack([-sx, -sy, np.ones_like(sx)], -1) / norm[:, None]
        sun = sf.sun_disc_radiance(
            du, nrm, cos_up, R, -np.asarray(wp.sun_travel_dir, np.float32), wp.sun_irradiance, 1.0 / float(K[0, 0])
        )
    idx, src, path, m_h = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros(0)
    tir = R >= 1.0
    if tir.any():
        n = np.stack([-sx[tir], -sy[tir], np.ones_like(sx[tir])], -1) / norm[tir, None]
        src, m_r, m_h, ok = _mirror(
            T[:3, 3] + r[tir, None] * du[tir],
            du[tir] - 2 * cos_up[tir, None] * n,
            K,
            T,
            range_m,
            depth,
            np.flatnonzero(up)[tir],
        )
        idx = np.flatnonzero(tir)[ok]
        path = r[idx] + m_r
    return SurfaceGeometry(np.flatnonzero(up), r, cos_up, R, sun, idx, src, path, m_h)


@term("surface")
def shade_surface(rgb, range_m, depth, geo: SurfaceGeometry | None, wp, below_radiance):
    """(rgb, range_m, depth) with the surface of ``geo`` (made from this range and depth) seen
    in water whose veil at the camera is ``below_radiance`` (3,): new arrays (the inputs when
    no pixel sees the surface)."""
    if geo is None:
        return rgb, range_m, depth
    J = sf.window_radiance(geo.cos_up, [wp.sky_radiance] * 3, below_radiance, reflectance=geo.R)
    if geo.sun is not None:
        J += geo.sun[:, None]
    rr, hh = geo.r.copy(), np.zeros_like(geo.r)
    J[geo.idx], rr[geo.idx], hh[geo.idx] = np.asarray(rgb).reshape(-1, 3)[geo.src], geo.path, geo.depth
    depth = np.array(np.broadcast_to(depth, range_m.shape), np.float32)
    rgb, range_m = rgb.copy(), range_m.copy()
    rgb.reshape(-1, 3)[geo.up], range_m.reshape(-1)[geo.up], depth.reshape(-1)[geo.up] = J, rr, hh
    return rgb, range_m, depth


def _mirror(start, d_refl, K, T, range_m, depth, pixels=None, max_m: float = 60.0):
    """Screen-space reflection: the pixel (flat index), path (m, (n,): from the surface to
    it) and depth (n,) of the surface the camera itself sees where each reflected ray from the
    surface points ``start`` (n, 3) along ``d_refl`` (n, 3) (world) meets it
    (``surface_kernels.reflect``: a march through the range pass, parallax included), and
    which rays meet one (n,) bool (in the image, a surface below the water, within ``max_m``).
    With the rays' flat ``pixels`` (n,), only one ray per 2 x 2 block of pixels is marched
    and its block takes its hit (the reflection at half resolution: a quarter of the cost)."""
    w = range_m.shape[1]
    marched = which = np.arange(len(d_refl))
    if pixels is not None:  # each 2 x 2 block's first ray (its top-left pixel if it has it)
        block = (pixels // w // 2) * (w // 2 + 1) + (pixels % w) // 2
        _, marched, which = np.unique(block, return_index=True, return_inverse=True)
    pix, dist = _march(np.asarray(start)[marched], np.asarray(d_refl)[marched], K, T, range_m, max_m)
    pix, dist = pix[which], dist[which]
    ok = pix >= 0
    ok[ok] = depth.ravel()[pix[ok]] > 0
    at = pix[ok]
    return at, dist[ok].astype(np.float32), depth.ravel()[at], ok


def _march(start, d_refl, K, T, range_m, max_m: float):
    """``surface_kernels.reflect`` on rays (n, 3) from ``start`` along ``d_refl``: (pixel, distance) (n,)."""
    from blendgen.physics.surface.kernels import reflect

    n = len(d_refl)
    pix, dist = np.empty(n, np.int64), np.empty(n, np.float64)
    reflect(
        np.ascontiguousarray(start, np.float64),
        np.ascontiguousarray(d_refl, np.float64),
        np.ascontiguousarray(T[:3, 3], np.float64),
        np.ascontiguousarray(T[:3, :3].T, np.float64),
        np.asarray(K, np.float64),
        np.ascontiguousarray(range_m, np.float32),
        float(max_m),
        pix,
        dist,
    )
    return pix, dist


def facing_normals(rays, range_m) -> np.ndarray:
    """(h, w, 3) float32 unit normals of the surface seen at each pixel, turned towards the
    camera (``surface_light.surface_normals`` of the camera-relative hit points); 0 where a
    neighbour is missing (object edges, open water)."""
    return surface_normals(
        np.asarray(rays, np.float32) * np.where(np.isfinite(range_m), range_m, np.nan).astype(np.float32)[..., None]
    )


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(h, w) dot products of the vectors (h, w, 3) ``u`` with ``v`` ((h, w, 3) or (3,)),
    summed in component order (the products einsum sums, without its loop overhead)."""
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def footprint_m(rays, range_m, normals, px_rad: float, beam=None, beam_cos=None) -> np.ndarray:
    """(h, w) width (m) of surface each pixel stands for, ``r px_rad / |cos(incidence)|``
    (``px_rad`` the pixel's angle, ``normals`` :func:`facing_normals`; inf where there is
    none). ``beam`` (3,), a unit light direction: the width of that patch moved up the beam
    onto a horizontal plane instead (times ``sqrt(|n.beam| / |beam_z|)``: a wall's patch
    shrinks, a floor's stays); ``beam_cos`` (h, w): ``n.beam`` when the caller has it."""
    cos = np.abs(_dot(rays, normals))
    with np.errstate(invalid="ignore", divide="ignore"):
        f = range_m * np.float32(px_rad) / cos
        if beam is not None:
            b = np.asarray(beam, np.float32)
            nb = _dot(normals, b) if beam_cos is None else beam_cos
            f = f * np.sqrt(np.abs(nb) / max(abs(float(b[2])), 1e-3))
    return np.where(np.isfinite(f) & (cos > 1e-3), f, np.inf).astype(np.float32)


@term("caustics")
def add_caustics(
    rgb,
    albedo,
    range_m,
    depth,
    wp,
    rays,
    K,
    T_world_cam,
    t: float,
    scattering: float,
    g: float = 0.9,
    emissive=None,
    sun_pass=None,
):
    """Sun-lit surfaces times their focusing factor (module docstring); a new (H, W, 3) array.
    ``depth`` (H, W) metres below the surface of each pixel's surface point; ``rays`` (H, W, 3)
    unit world directions; ``emissive`` (H, W) bool: pixels of light sources (LEDs), whose own
    light is not sunlight and is left alone. Every pixel reads a map binned as coarse as its
    footprint, so it sees the pattern's mean over it (the anti-aliasing a render's pixel
    filter does). The focused part of a pixel is its sunlight: the render's ``sun_pass`` (H, W,
    3) (the sun's light group: its light alone, shadows and all) when given, else
    :func:`sunlight`'s estimate from the ``albedo`` pass. So the light an LED spills into the
    pixels around its own, or a fill light, is not refocused. The same as
    :func:`shade_caustics` of :func:`caustic_geometry`, which a frame seen through several
    waters makes once."""
    geo = caustic_geometry(rgb, albedo, range_m, depth, wp, rays, K, T_world_cam, t, emissive, sun_pass)
    return shade_caustics(rgb, geo, scattering, g)


class CausticGeometry:
    """What :func:`add_caustics` needs of a frame whatever the water: the sun-lit pixels (flat
    indices ``at`` (m,)), their clean radiance ``base`` and sunlight ``lit`` (m, 3) float32, and
    their rays' :class:`caustic_map.FrameCaustics` (deposits and sharp maps made once)."""

    def __init__(self, at: np.ndarray, base: np.ndarray, lit: np.ndarray, caustics: caustic_map.FrameCaustics):
        self.at, self.base, self.lit, self.caustics = at, base, lit, caustics
        self._gain: dict = {}

    def gain(self, scattering: float, g: float) -> np.ndarray:
        """Focusing factor - 1 (m,) float32 of the sun-lit pixels in water of ``scattering`` (1/m)
        and HG ``g``, made once per water (the sequences of a frame that share a water share it)."""
        key = (float(scattering), float(g))
        if key not in self._gain:
            self._gain[key] = self.caustics.factor(scattering, g) - 1
        return self._gain[key]


@term("caustics")
def caustic_geometry(
    rgb, albedo, range_m, depth, wp, rays, K, T_world_cam, t: float, emissive=None, sun_pass=None
) -> CausticGeometry | None:
    """The water-independent part of :func:`add_caustics` (same arguments); None when no
    pixel is sun-lit."""
    T = np.asarray(T_world_cam, float)
    depth = np.broadcast_to(np.asarray(depth, np.float32), range_m.shape)
    sun = sf.refracted_sun(wp.sun_travel_dir)
    normals = facing_normals(rays, range_m)
    cos_i = -_dot(normals, sun.astype(np.float32))
    # sun-facing surfaces only: one turned away from the beam (or grazed by it) has no sunlight to focus
    hit = np.isfinite(range_m) & (depth > 0) & (cos_i > 0.02)
    if emissive is not None:
        hit &= ~emissive
    if sun_pass is not None:  # in the sun's shadow: no sunlight to focus, and not its crossing's path
        hit &= lit_pixels(sun_pass)
    if not hit.any():
        return None
    at = np.flatnonzero(hit)  # flat pixel indices: take/put, not masks
    d = np.take(np.asarray(rays).reshape(-1, 3), at, axis=0)
    r = range_m[hit].astype(np.float32)
    h = depth[hit]
    back = (-sun[:2] / -sun[2]).astype(np.float32)  # horizontal run per metre of rise
    x = np.float32(T[0, 3]) + r * d[:, 0] + h * back[0]
    y = np.float32(T[1, 3]) + r * d[:, 1] + h * back[1]
    path = h / np.float32(-sun[2])  # slant path of the beam to the point
    foot = footprint_m(rays, range_m, normals, 1.0 / float(K[0, 0]), sun, cos_i)[hit]
    fc = caustic_map.FrameCaustics(
        waves_of(wp.wave_seed, wp.wind_mps), x, y, path, foot, t, sf.sun_deflection(wp.sun_travel_dir)
    )
    shape = (*range_m.shape, 3)
    rows = lambda img: np.take(
        np.broadcast_to(np.asarray(img, np.float32), shape).reshape(-1, 3),  # noqa: E731
        at,
        axis=0,
    )
    base = rows(rgb)
    lit = (
        rows(sun_pass)
        if sun_pass is not None
        else sunlight(base, None if albedo is None else rows(albedo), cos_i.ravel()[at], wp)
    )
    return CausticGeometry(at, base, lit, fc)


@term("caustics")
def shade_caustics(rgb, geo: CausticGeometry | None, scattering: float, g: float = 0.9, hidden=None):
    """``rgb`` (H, W, 3) with the sun-lit pixels of ``geo`` (made from this ``rgb``) focused in
    water of ``scattering`` (1/m) and HG ``g``: a new float32 array (``rgb`` when none is lit).
    ``hidden`` (H, W) bool: pixels where something in front (a particle) hides the surface ``geo``
    was made from; they keep ``rgb`` as it is, and the others add their focused sunlight to the
    ``rgb`` given (a particle-composited frame whose caustics are the clean frame's)."""
    if geo is None:
        return rgb
    gain = geo.gain(scattering, g)  # M - 1
    out = np.array(rgb, np.float32)
    if hidden is None:
        shaded = geo.lit * gain[:, None]
        shaded += geo.base
        _put_rows(out.reshape(-1, 3), geo.at, shaded)
        return out
    keep = ~np.asarray(hidden, bool).ravel()[geo.at]
    at, flat = geo.at[keep], out.reshape(-1, 3)
    flat[at] += geo.lit[keep] * gain[keep][:, None]
    return out


def _put_rows(flat: np.ndarray, at: np.ndarray, rows: np.ndarray) -> None:
    """Rows ``at`` (m,) of the C-contiguous ``flat`` (n, c) set to ``rows`` (m, c): each row one
    copy of its bytes (np.put on a row-sized void view; a 2-D fancy assignment is ~4x slower)."""
    row = np.dtype((np.void, flat.dtype.itemsize * flat.shape[1]))
    np.put(flat.view(row).reshape(-1), at, np.ascontiguousarray(rows, flat.dtype).view(row).reshape(-1))


def sunlight(rgb: np.ndarray, albedo: np.ndarray | None, cos_i: np.ndarray, wp) -> np.ndarray:
    """(m, 3) the sunlight in pixels of clean radiance ``rgb`` (m, 3): without an ``albedo``
    (m, 3) all of it; else less the ambient term ``albedo wp.ambient_radiance``, and at most
    what the sun gives a Lambertian surface, ``albedo E cos(i) / pi`` (E = wp.sun_lamp_w_m2
    when > 0; ``cos_i`` (m,) the sun's incidence cosine)."""
    if albedo is None:
        return rgb
    lit = rgb - albedo * np.float32(wp.ambient_radiance)
    np.maximum(lit, 0, out=lit)
    if wp.sun_lamp_w_m2 > 0:
        cap = albedo * (np.float32(wp.sun_lamp_w_m2 / math.pi) * cos_i)[:, None]
        lit = np.minimum(lit, cap, out=lit if cap.dtype == lit.dtype else None)
    return lit
