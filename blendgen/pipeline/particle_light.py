"""Per-sequence glue between the particle renderer and the frame's light and camera.

``shader`` gives each particle its clean radiance J (before the water model, like the
clean render of any surface): what the render's lights give a surface -- the sun and fill
(Lambertian-sphere reflection of collimated light, radiometric: a white plane facing a sun of
strength S has radiance S / pi) and the ambient light field's mean radiance just below the
surface (``E_d0 / (4 pi mu_d)``, plan.ambient_radiance, 0 where the ambient is off) -- which
the water model then dims by the particle's own depth (physical) or the dock depth
(article), plus the lamps' and LEDs' light (particle_optics.particle_radiance), pre-divided
by that same depth factor so that it reaches the camera with inverse square and ``exp(-c d)``
along its own path only.
Then compose's water model attenuates and veils the particle over its own range.

``shaper`` gives the frame's :class:`Blur` of each footprint, applied in the projection:
thin-lens defocus (camera ``lens``, none = pinhole) and the streak of the particle's motion
relative to the camera over the exposure (its drift ``v_flow`` and the camera's motion between
the previous and this frame). ``background_transfer`` gives the :class:`Transfer` that keeps a
partly covered pixel's background at its own range once the water model runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blendgen.physics.camera import sensor as sens
from blendgen.physics.light import lamp_water
from blendgen.physics.light import sources as lt
from blendgen.physics.particles import kernels as kern
from blendgen.physics.particles import light_kernels as plk
from blendgen.physics.particles import optics as popt
from blendgen.physics.particles.field import ProjectedParticles
from blendgen.physics.water import optics


def material(occ) -> popt.ParticleMaterial:
    return popt.ParticleMaterial(occ.albedo, occ.forward_fraction, occ.forward_g)


def _depth_gain(post, water, T_world_cam: np.ndarray, p: ProjectedParticles) -> np.ndarray:
    """(3, M) float32 inverse of the depth factor the water model will apply to each particle's
    pixels (physical: exp(-Kd depth) at the depth compose.surface_depth computes from the range
    along the ray; article: exp(-Kd d) at the dock depth)."""
    if post.image_formation != "physical":
        g = np.broadcast_to(1.0 / optics.depth_light(water, post.light_depth_m), (3,))
        return np.repeat(np.asarray(g, np.float32)[:, None], p.u.size, axis=1)
    T = np.asarray(T_world_cam, float)
    kd = np.asarray(water.Kd, np.float32).reshape(3)
    return plk.depth_gain(*p.pc, p.surf_range, T[2, :3].astype(np.float32), np.float32(post.surface_z_m - T[2, 3]), kd)


def shader(post, water, T_world_cam, markers=None, T_cam_dock=None, lamp=None):
    """Callable(projected) -> (M, 3) clean radiance of each particle (module doc). The lamps'
    light reaches a particle as it reaches a surface or the veil: through the sequence's lamp
    model ``lamp`` (``physics/light/lamp_water.LampWater.beam``: direct + forward-scattered spread;
    built from ``post`` when not given); the LEDs' with ``c``."""
    if lamp is None and post.lamps:
        lamp = lamp_water.LampWater.build(lt.lamp_lights(post.lamps), water, post.lamp_forward_kept)
    lamps = list(lamp.lights) if lamp is not None else []
    leds = popt.led_point_lights(markers, T_cam_dock) if markers and T_cam_dock is not None else []
    mat = material(post.occlusion)
    amb = post.ambient_w_m2_sr
    R = np.asarray(T_world_cam, float)[:3, :3]
    suns = [(R.T @ np.asarray(d, float), e) for d, e in post.suns]
    lights = [(li, lamp.c_lamp, lamp.beam if lamp.spread else None) for li in lamps] + [
        (li, water.c, None) for li in leds
    ]

    def shade(p: ProjectedParticles) -> np.ndarray:
        gain = _depth_gain(post, water, T_world_cam, p) if lights else None
        out = popt.light_field(p.pc, mat, [amb] * 3, lights, gain)
        if suns:
            out += popt.sun_planar(p.pc, mat, suns)[None, :]
        return out.T

    return shade


def frame_interval(post, prev_pose, t_s) -> tuple[float, np.ndarray | None]:
    """(dt s, previous pose or None) from the last call's (t, T) and this frame's time."""
    if prev_pose is None:
        return 1.0 / post.fps, None
    t0, T0 = prev_pose
    if t0 is None or t_s is None or not t_s > t0:
        return 1.0 / post.fps, T0
    return float(t_s - t0), T0


@dataclass(frozen=True)
class Blur:
    """A frame's particle blur (``particles.project_particles``' ``blur``): the previous camera
    frame's point of each particle is ``M pc + o`` (M (3, 3), o (3,) float32), ``scale`` =
    exposure / frame interval turns that displacement into the streak; defocus diameter
    ``coc_k |z - focus_m| / z`` px (coc_k = 0: pinhole). All float32."""

    M: np.ndarray
    o: np.ndarray
    scale: np.float32
    coc_k: np.float32
    focus_m: np.float32


def shaper(post, K: np.ndarray, T_world_cam, prev_pose=None, t_s: float | None = None) -> Blur:
    """The frame's :class:`Blur`: defocus and motion streaks.

    Streak: each particle's image displacement over the exposure, its position now minus where it
    was ``dt`` earlier (drifted back by v_flow, seen from the previous pose, or from this pose
    when there is none), times exposure / dt (motion assumed uniform over dt). The earlier
    camera-frame point is ``M pc + o``, M = R0^T R, o = R0^T (t - t0), (R, t) this pose and
    (R0, t0) the previous one moved by v_flow dt. Defocus: thin-lens circle of confusion
    (``particle_optics.coc_scale``, pinhole without a lens)."""
    lens = post.lens
    K = np.asarray(K, float)
    dt, T_prev = frame_interval(post, prev_pose, t_s)
    T = np.asarray(T_world_cam, float)
    T0 = np.array(T_prev if T_prev is not None else T, float)
    T0[:3, 3] += np.asarray(post.occlusion.v_flow, float) * dt  # drifting back = camera ahead
    coc_k, focus = 0.0, 1.0
    if lens is not None:
        coc_k = popt.coc_scale(lens.focal_length_mm * 1e-3, lens.f_number, lens.focus_m, K[0, 0])
        focus = lens.focus_m
    return Blur(
        (T0[:3, :3].T @ T[:3, :3]).astype(np.float32),
        (T0[:3, :3].T @ (T[:3, 3] - T0[:3, 3])).astype(np.float32),
        np.float32(min(_exposure_s(post) / dt, 1.0)),
        np.float32(coc_k),
        np.float32(focus),
    )


def _exposure_s(post) -> float:
    """The sequence's exposure (s): the resolved one (``plan.resolved_sensor``), or the scene-metered
    default when a post was built without it."""
    s = post.sensor
    return (
        s.exposure_s if s.exposure_s is not None else sens.beacon_exposure_s(0.0, s.full_well_e, s.responsivity_e_per_s)
    )


@dataclass(frozen=True)
class Transfer:
    """What replaces the background's clean radiance J_bg on pixels a particle partly covers, so
    that compose's water model -- ``L = J D t(r) + B (1 - t(r))`` per pixel, t = exp(-c r), D the
    depth factor (physical: exp(-Kd depth) of the surface at range r; article: a constant applied
    to the whole pixel at the end) -- run at the particle's range r_p gives exactly
    ``T L_bg + (1 - T) L_p``, each layer through water at its own range:
    ``J_bg' = J_bg D_bg t_bg / (D_p t_p) + B (t_p - t_bg) / (D_p t_p)`` (article: D = 1 here).
    r_bg = inf (open water): t_bg = 0, only the veil term. A point at range r along a pixel's
    unit ray (world z dir_z) is at depth max(cam_depth - r dir_z, 0) (compose.surface_depth).

    c, kd, veil (3,) float32: the frame's beam attenuation, diffuse attenuation and the veil B
    the water model adds; K (3, 3) and rz (3,) float32 (the camera axes' world z) give dir_z.
    Evaluated at the covered pixels by particle_kernels.transfer, applied by resolve."""

    c: np.ndarray
    kd: np.ndarray
    veil: np.ndarray
    physical: bool
    K: np.ndarray
    rz: np.ndarray
    cam_depth_m: float

    def gain_add(self, hit: np.ndarray, near: np.ndarray, far: np.ndarray, width: int) -> np.ndarray:
        """(6, n) float32: the gain (3 rows) and add (3 rows) at the covered pixels hit (n,), with
        the particles' and the scene's range there near, far (n,)."""
        return kern.transfer(
            hit,
            near,
            far,
            int(width),
            self.K,
            self.rz,
            self.c,
            self.kd,
            self.veil,
            np.float32(self.cam_depth_m),
            self.physical,
        )

    def packed(self) -> np.ndarray:
        """(19,) float32: the transfer packed for the fused pass (particle_kernels.transfer_params)."""
        return kern.transfer_params(
            self.K, self.rz, self.c, self.kd, self.veil, np.float32(self.cam_depth_m), self.physical
        )


def background_transfer(
    water, veil_rgb, physical: bool, K=None, T_world_cam=None, cam_depth_m: float = 0.0
) -> Transfer:
    """The :class:`Transfer` of a frame: ``water`` its optics (c, Kd), ``veil_rgb`` (3,) the veil
    the water model adds; physical mode: the camera's K, pose (world z up) and depth (m)."""
    f32 = lambda x: np.asarray(x, np.float32).reshape(3)
    K32 = np.eye(3, dtype=np.float32) if K is None else np.asarray(K, np.float32)
    rz = np.zeros(3, np.float32) if T_world_cam is None else np.asarray(T_world_cam, np.float32)[2, :3].copy()
    return Transfer(f32(water.c), f32(water.Kd), f32(veil_rgb), bool(physical), K32, rz, float(cam_depth_m))
