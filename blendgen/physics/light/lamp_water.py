"""The vehicle lamp in water, fast fidelity: lamp-lit surfaces and the backscatter veil.

Pure numpy. Camera frame (OpenCV: x right, y down, z forward), metres, linear RGB
radiance (W/m^2/sr per channel). Lamps are :class:`physics.light.sources.PointLight` cones.
The Jaffe (1990) / McGlamery (1980) decomposition of an image under artificial light:

- **direct** (lamp-lit surface): a Lambertian surface of albedo ``rho`` at range ``r``
  along the pixel ray, at distance ``d`` from a lamp of intensity ``I(psi)`` (W/sr),
  reflects ``rho / pi * I(psi) cos(i) / d^2 * exp(-c' d)`` and the camera sees it times
  ``exp(-c r)`` (:func:`surface_radiance`), times the lamp's visibility from the point: a
  screen-space shadow test on the range pass (:mod:`blendgen.physics.light.lamp_shadow`; an
  occluder outside the frame casts no shadow -- documented limitation).
- **backscatter** (the veil in front of the camera): the single-scattering integral along
  each pixel ray ``x = t u``, ``t`` in ``[0, r]``,

      V = int_0^r  b p(theta) I(psi) / d(t)^2 exp(-c' d(t)) exp(-c' t) dt

  with ``theta`` the scattering angle between the lamp's ray and the direction to the
  camera, ``p`` the water's phase function (1/sr; ``optics.hg_phase`` or ``ff_phase``),
  evaluated on a coarse grid of rays at geometric range nodes, accumulated (trapezoid)
  and interpolated per pixel at its own range (:func:`backscatter_table`, :func:`backscatter`).
- **multiple scattering**: ``c' = c - F b``, one documented factor ``F``
  (:data:`FORWARD_KEPT`): the share of scattered light that is not lost to a smooth light
  field because ocean scattering is forward-peaked (Petzold's mean cosine ~0.92; the
  "effective attenuation" of beam-spread models, Mobley's Ocean Optics Web Book, "The Beam
  Spread Function"). It applies where the light field is smooth on the scale of the
  forward-scattering angles: the lamp's beam (surfaces and veil) and the veil's way back
  to the camera. The image of a surface keeps ``c`` on its way to the camera (it is the
  beam transmittance; its forward-scattered part is blur/glow, not image). ``F = 0`` is
  single scattering, what the pipeline's 0-bounce reference renders. The light F keeps is
  not held inside the sharp cone: it spreads in angle with the phase function's forward lobe
  (:mod:`blendgen.physics.light.beam_spread`, :meth:`LampWater.beam`: ``exp(-c d) P + spread``,
  whose sum over angles is ``exp(-c' d)`` as before), on surfaces, in the veil and on the
  small particles in the beam (``pipeline/particle_light.py``): a particle is a surface
  element in the same beam. The dock's LEDs keep ``c`` (single scattering) on surfaces and
  particles: F was fitted to the lamp's cone only.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from blendgen.physics.light.sources import PointLight

#: ``F``: share of scattered light kept by a smooth light field (forward-peaked water),
#: ``c' = c - F b``. 0 = pure single scattering. Fitted (one value for both waters) to
#: the mean backscatter veil of Cycles renders with 32 volume bounces, HG g = 0.9, waters
#: ``mild`` and ``moderate``, no surface (``dockbench bench lamp``): mean ratio fast/reference
#: 0.98 and 1.01, 12x12-px block error 8 % and 13 % (docs/LAMP.md).
FORWARD_KEPT = 0.85

#: Geometric range nodes of the veil integral (m): first node, last node, count.
T_MIN_M, T_MAX_M, N_NODES = 0.02, 60.0, 64
#: Coarse grid step (px) of the veil's rays.
GRID_PX = 16
#: Closest approach to a lamp counted (m): a ray grazing the source stays finite.
MIN_LAMP_DISTANCE_M = 0.05


@dataclass(frozen=True)
class LampWater:
    """What the fast lamp model needs: the lights and the water's coefficients (3,), 1/m.

    ``c_lamp`` is the effective attenuation ``c - F b`` of smooth light fields: on the
    lamp's path and on the veil's path to the camera; ``c`` stays on a surface's image."""

    lights: tuple[PointLight, ...]
    sigma_s: np.ndarray
    c: np.ndarray
    c_lamp: np.ndarray
    phase: object  # callable cos(theta) (N,) -> 1/sr (N,)
    shadows: bool = True  # screen-space shadows of the lamps on surfaces (physics/light/lamp_shadow.py)
    veil_shadows: bool = True  # and in the veil (with ``shadows``; False: surfaces only, for comparison)
    spread: bool = False  # the beam's forward-scattered light spreads in angle (physics/light/beam_spread.py)
    tables: tuple = ()  # per light, its beam table (beam_spread.beam_table) when ``spread``

    def beam(self, light: PointLight, cos_psi: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(…, 3) float32 relative beam of ``light`` at angle ``cos_psi`` (…) and distance ``d``
        (…, m): the direct beam plus its forward-scattered light spread in angle (the light's
        :func:`beam_spread.beam_table`, read by :func:`beam_spread.lookup`; beyond its last
        distance, ``D_MAX``, attenuated on with ``c'``); times ``I0 / d^2`` it is the irradiance
        normal to the ray. Without spread: the sharp profile times ``exp(-c' d)``."""
        from blendgen.physics.light import beam_spread

        d = np.asarray(d, np.float32)
        c_lamp = self.c_lamp.astype(np.float32)
        if not self.spread:
            return light.profile(cos_psi)[..., None] * np.exp(-d[..., None] * c_lamp)
        k = next(i for i, li in enumerate(self.lights) if li is light)
        shape = np.shape(cos_psi)
        out = beam_spread.lookup(
            self.tables[k], np.reshape(cos_psi, (shape[0], -1)), np.reshape(d, (shape[0], -1))
        ).reshape(*shape, 3)
        if d.size and float(d.max()) > beam_spread.D_MAX:
            out *= np.exp(-np.maximum(d - np.float32(beam_spread.D_MAX), 0)[..., None] * c_lamp)
        return out

    @classmethod
    def build(
        cls, lights: list[PointLight], water, forward_kept: float | None = None, shadows: bool = True
    ) -> LampWater:
        """From lights and an ``optics.WaterOptics`` (its phase function and coefficients);
        ``forward_kept`` F (None: :data:`FORWARD_KEPT`); ``shadows``: the lamps' shadow test."""
        from blendgen.physics.light import beam_spread

        b, c = np.asarray(water.sigma_s, float), np.asarray(water.c, float)
        key = (
            ("ff", float(water.ff_ior), float(water.ff_backscatter)) if water.phase == "ff" else ("hg", float(water.g))
        )
        phase = beam_spread.phase_of(key)
        forward_kept = FORWARD_KEPT if forward_kept is None else float(forward_kept)
        spread = 0 < forward_kept < 1 and bool(np.any(b > 0))
        tables = tuple(beam_spread.beam_table(li, c, b, forward_kept, key) for li in lights) if spread else ()
        return cls(
            tuple(lights),
            b,
            c,
            lamp_attenuation(water, forward_kept),
            phase,
            bool(shadows),
            spread=spread,
            tables=tables,
        )


def lamp_attenuation(water, forward_kept: float | None = None) -> np.ndarray:
    """(3,) effective attenuation ``c' = c - F b`` (1/m) of the lamp's light inside its beam,
    whatever it falls on: water (the veil), a surface or a particle (each is lit by the same
    beam: the forward-scattered light kept in it reaches them alike). ``water``: an
    ``optics.WaterOptics``; ``forward_kept`` F (None: :data:`FORWARD_KEPT`)."""
    forward_kept = FORWARD_KEPT if forward_kept is None else float(forward_kept)
    return np.asarray(water.c, float) - forward_kept * np.asarray(water.sigma_s, float)


def range_nodes() -> np.ndarray:
    """(N_NODES + 1,) range nodes (m): 0, then geometric from T_MIN_M to T_MAX_M."""
    return np.concatenate([[0.0], np.geomspace(T_MIN_M, T_MAX_M, N_NODES)])


def backscatter_table(model: LampWater, rays: np.ndarray, t: np.ndarray, visible=None) -> np.ndarray:
    """Cumulative single-scatter veil (N, T, 3) float32 along unit rays (N, 3) up to each node t (T,)
    (trapezoid rule; scalar geometry (N, T) first, the RGB attenuation once per light).
    ``visible``: None, or one (N, T) array per light, 0 where the node is in that lamp's shadow."""
    rays32, t32 = rays.astype(np.float32), t.astype(np.float32)
    x = rays32[:, None, :] * t32[None, :, None]  # (N, T, 3)
    f = np.zeros(x.shape, np.float32)
    for i, light in enumerate(model.lights):
        v = x - np.asarray(light.position_m, np.float32)
        d = np.maximum(np.sqrt(np.einsum("ntk,ntk->nt", v, v)), np.float32(MIN_LAMP_DISTANCE_M))
        v /= d[..., None]
        cos_scatter = -np.einsum("ntk,nk->nt", v, rays32)  # lamp ray vs direction to camera
        geo = model.phase(cos_scatter).astype(np.float32) / (d * d)
        if visible is not None:
            geo *= visible[i]
        lit = model.beam(light, v @ np.asarray(light.axis, np.float32), d)  # (N, T, 3)
        lit *= np.exp(-t32[None, :, None] * model.c_lamp.astype(np.float32))  # c' t to the camera
        f += geo[..., None] * lit * np.asarray(light.intensity_w_sr * model.sigma_s, np.float32)
    steps = 0.5 * (f[:, 1:] + f[:, :-1]) * np.diff(t32)[None, :, None]
    out = np.zeros_like(f)
    np.cumsum(steps, axis=1, out=out[:, 1:])
    return out


@functools.lru_cache(maxsize=4)
def _block_rays(K_t: tuple, gw: int, gh: int, step: int) -> np.ndarray:
    """(gh*gw, 3) unit rays through the centres of ``step`` x ``step`` pixel blocks."""
    K = np.array(K_t).reshape(3, 3)
    u, v = np.meshgrid((np.arange(gw) + 0.5) * step - 0.5, (np.arange(gh) + 0.5) * step - 0.5)
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    rays = np.dstack([x, y, np.ones_like(x)]).reshape(-1, 3)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _block_min_max(r: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Per ``step`` x ``step`` block (edge-padded) min and max of r (H, W) -> 2 x (gh, gw)."""
    h, w = r.shape
    gh, gw = -(-h // step), -(-w // step)
    p = np.pad(r, ((0, gh * step - h), (0, gw * step - w)), mode="edge").reshape(gh, step, gw, step)
    return p.min(axis=(1, 3)), p.max(axis=(1, 3))


def _table_at(table: np.ndarray, t: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The cumulative table (N, T, 3) at one range per ray r (N,), linear between nodes -> (N, 3)."""
    k = np.clip(np.searchsorted(t, r, side="right") - 1, 0, len(t) - 2)
    frac = ((r - t[k]) / (t[k + 1] - t[k]))[:, None]
    n = np.arange(len(r))
    return table[n, k] * (1 - frac) + table[n, k + 1] * frac


def _volume_visibility(model: LampWater, K, range_m, rays: np.ndarray, t: np.ndarray, r_far: np.ndarray):
    """Per light, (N, T) float32: 1 where the veil's node ``t`` (T,) on ray (N, 3) sees the lamp
    (:func:`lamp_shadow.volume_visibility`); nodes past the ray's farthest surface ``r_far`` (N,)
    are never read and are not tested. Single scattering: a node in the lamp's shadow adds no
    veil (the reference's shadow volume, e.g. behind the dock); the F factor's light, scattered
    on into the shadow volume, is not added (documented approximation)."""
    from blendgen.physics.light import lamp_shadow

    need = t[None, :] <= np.fmin(r_far, t[-1])[:, None] + 1e-6  # (N, T), and the next node
    need[:, 1:] |= need[:, :-1]
    pts = (rays[:, None, :] * t[None, :, None])[need]
    out = []
    for light in model.lights:
        v = np.ones(need.shape, np.float32)
        v[need] = lamp_shadow.volume_visibility(light.position_m, K, range_m, pts)
        out.append(v)
    return out


def backscatter(model: LampWater, K: np.ndarray, range_m: np.ndarray, step: int = GRID_PX) -> np.ndarray:
    """The lamps' backscatter veil (H, W, 3) in front of surfaces at ``range_m`` (H, W).

    On ``step``-px blocks: one ray per block, its cumulative veil read at the block's nearest
    and farthest surface; both maps and both ranges are upsampled bilinearly and each pixel
    interpolates between them at its own range (exact at both ends of a depth edge, e.g. the
    dock's outline against open water)."""
    import cv2

    h, w = range_m.shape
    step = int(min(step, max(4, min(w, h) // 24)))  # at least ~24 rays across small images
    t = range_nodes()
    r = np.fmin(range_m.astype(np.float32, copy=False), np.float32(t[-1]))  # inf, NaN -> the last node
    rmin, rmax = _block_min_max(r, step)
    gh, gw = rmin.shape
    rays = _block_rays(tuple(np.asarray(K, float).ravel()), gw, gh, step)
    visible = (
        _volume_visibility(model, K, range_m, rays, t, rmax.ravel()) if model.shadows and model.veil_shadows else None
    )
    table = backscatter_table(model, rays, t, visible)
    vmin = _table_at(table, t, rmin.ravel().astype(np.float64)).reshape(gh, gw, 3).astype(np.float32)
    vmax = _table_at(table, t, rmax.ravel().astype(np.float64)).reshape(gh, gw, 3).astype(np.float32)
    size = (gw * step, gh * step)
    up = [cv2.resize(a, size, interpolation=cv2.INTER_LINEAR)[:h, :w] for a in (vmin, vmax, rmin, rmax)]
    a = np.clip((r - up[2]) / np.maximum(up[3] - up[2], np.float32(1e-3)), 0.0, 1.0)[..., None]
    return up[0] + a * (up[1] - up[0])


def _shadow_test(K, rays, range_m):
    """callable(light, lit (H, W) bool) -> (H, W) visibility of the light from each surface point."""
    from blendgen.physics.light import lamp_shadow

    def visible(light, lit):
        return lamp_shadow.visibility(light.position_m, K, rays, range_m, mask=lit)

    return visible


def surface_radiance(
    model: LampWater,
    rays: np.ndarray,
    range_m: np.ndarray,
    albedo: np.ndarray,
    normals: np.ndarray | None,
    K: np.ndarray | None = None,
) -> np.ndarray:
    """Lamp light reflected by Lambertian surfaces, as seen by the camera (H, W, 3):
    ``albedo / pi * sum I(psi) cos(i) exp(-c' d) / d^2 * visible * exp(-c r)``
    (``surface_light.lambert_radiance`` on every pixel, then the camera path).

    rays (H, W, 3) unit pixel rays; range_m (H, W) (inf/NaN: no surface, 0); albedo (H, W, 3);
    normals (H, W, 3) unit, camera frame, the normal pass (None: from the range pass);
    K (3, 3) the pinhole of the pass, needed by the shadow test (None or ``model.shadows``
    False: no shadows, every surface sees the lamps)."""
    from blendgen.physics.light import surface_light

    visible = _shadow_test(K, rays, range_m) if model.shadows and K is not None else None
    out = surface_light.lambert_radiance(
        model.lights, rays, range_m, albedo, model.c_lamp, normals, 1, visible, beam=model.beam
    )
    if out is None:
        return np.zeros(albedo.shape, np.float32)
    r = np.where(np.isfinite(range_m) & (range_m > 0), range_m, 0.0).astype(np.float32)
    out *= np.exp(-r[..., None] * model.c.astype(np.float32))
    return out


def lamp_radiance(
    model: LampWater,
    K: np.ndarray,
    rays: np.ndarray,
    range_m: np.ndarray,
    albedo: np.ndarray,
    normals: np.ndarray | None,
) -> np.ndarray:
    """Everything the lamps add to the camera image (H, W, 3): lit surfaces + backscatter."""
    out = surface_radiance(model, rays, range_m, albedo, normals, K)
    if np.any(model.sigma_s > 0):
        out += backscatter(model, K, range_m)
    return out
