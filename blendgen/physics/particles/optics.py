"""Marine snow / small obstacles as physical particles: sizes, radiance and camera optics.

Numpy around compiled loops (the light field: particle_light_kernels; the blur's moments:
particle_kernels). Camera frame = OpenCV (x right, y down, z forward), metres.

Sizes (:func:`sample_radii`)
    ``power_law``: the number size spectrum of marine particles and aggregates is a power
    law ``n(D) = dN/dD ~ D^-xi`` over sub-millimetre to centimetre sizes (Jackson et al.
    1997, Deep-Sea Res. I 44:1739, aggregates; Stemmann & Boss 2012, Annu. Rev. Mar. Sci.
    4:263, review of in-situ camera spectra, slopes roughly 2 to 4.5; Lombard et al. 2019,
    Front. Mar. Sci. 6:196, the Underwater Vision Profiler's ~0.1 mm to a few cm range).
    Default ``xi = 3.5`` (inside the reported range), radii 0.25 mm to 15 mm (diameters
    0.5 mm to 3 cm). Sampled by the inverse CDF of the truncated law.
    ``uniform``: the article's radius uniform in ``[r_min, r_max]`` (its section 2.2.3).

Radiance (:func:`particle_radiance`)
    A particle of albedo ``omega`` under irradiance ``E`` (W/m^2) coming from one direction
    scatters ``I = E pi r^2 omega p(theta)`` W/sr (``p`` the phase function, 1/sr,
    integral 1, ``theta`` the scattering angle, 0 = forward), so its projected disc has
    the mean radiance ``L = omega E p(theta)`` (W/m^2/sr), independent of its size.
    ``p = (1 - f) p_lambert + f p_HG(g)``: the reflection of a Lambertian sphere (van de
    Hulst 1957, Light Scattering by Small Particles, sec. 12.41: backward-peaked, fully
    lit face toward the light) plus a forward Henyey-Greenstein lobe (Henyey & Greenstein
    1941) for light transmitted through and diffracted around the porous, nearly
    index-matched aggregates. Under the isotropic-equivalent ambient light field of mean
    radiance ``L_amb`` (scalar irradiance ``4 pi L_amb``) any such particle has
    ``L = omega L_amb``. Lamps and LEDs are ``lights.PointLight``: inverse square, cone
    profile and beam attenuation ``exp(-c d)`` along the light's path. Attenuation and
    veiling between particle and camera are the water model's, as for any surface.

Optics (:func:`coc_px`, :func:`coc_scale`, :func:`blurred_shapes`)
    Thin-lens circle of confusion (e.g. Potmesil & Chakravarty 1981, ACM TOG): an object
    at distance ``s`` with the lens focused at ``s_f`` blurs to a disc of diameter
    ``c = A |s - s_f| / s * f / (s_f - f)`` on the sensor, ``A = f / N``; in pixels
    ``c_px = c / pitch = c f_px / f``. The particle's disc, the defocus disc and its
    motion streak (a segment of length ``L`` px over the exposure) are combined by adding
    their second moments (exact for convolution): a disc of radius ``R`` has ``R^2 / 4``
    per axis, a segment ``L^2 / 12`` along itself, so the footprint is the ellipse of the
    summed moments and its opacity falls by the area ratio (the light is spread, not
    created).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blendgen.physics.light import sources as lt
from blendgen.physics.particles import kernels as kern
from blendgen.physics.particles import light_kernels as plk

SIZE_DISTS = ("power_law", "uniform")
MARINE_SNOW_R_MIN_M = 0.00025  # 0.5 mm diameter
MARINE_SNOW_R_MAX_M = 0.015  # 3 cm diameter
MARINE_SNOW_SLOPE = 3.5  # n(D) ~ D^-3.5 (Stemmann & Boss 2012: ~2 to 4.5)
ARTICLE_R_MIN_M = 0.005
ARTICLE_R_MAX_M = 0.02


# ----------------------------------------------------------------------------- sizes
def sample_radii(
    rng: np.random.Generator, n: int, dist: str, r_min: float, r_max: float, slope: float = MARINE_SNOW_SLOPE
) -> np.ndarray:
    """(n,) float32 radii (m): ``uniform`` in [r_min, r_max] or the truncated ``power_law``
    ``dN/dr ~ r^-slope`` on [r_min, r_max] (inverse CDF; slope 1 is log-uniform)."""
    if dist not in SIZE_DISTS:
        raise ValueError(f"size_dist must be one of {SIZE_DISTS}, got {dist!r}")
    u = rng.random(n, dtype=np.float32)
    if dist == "uniform" or r_max <= r_min:
        u *= np.float32(r_max - r_min)
        u += np.float32(r_min)
        return u
    if r_min <= 0:
        raise ValueError(f"power_law sizes need r_min_m > 0, got {r_min}")
    if abs(slope - 1.0) < 1e-9:
        return (r_min * (r_max / r_min) ** u.astype(np.float64)).astype(np.float32)
    k = 1.0 - slope
    lo, hi = r_min**k, r_max**k
    return ((lo + u.astype(np.float64) * (hi - lo)) ** (1.0 / k)).astype(np.float32)


def power_law_mean_area(r_min: float, r_max: float, slope: float) -> float:
    """E[pi r^2] (m^2) of the truncated power law (for coverage expectations)."""

    def moment(j):
        e = j + 1.0 - slope
        return math.log(r_max / r_min) if abs(e) < 1e-12 else (r_max**e - r_min**e) / e

    return math.pi * moment(2) / moment(0)


# ----------------------------------------------------------------------------- phase
def lambert_sphere_phase(cos_theta: np.ndarray) -> np.ndarray:
    """Phase function (1/sr, integral 1) of a Lambertian sphere; theta = scattering angle
    (0 forward). ``p = 2/(3 pi^2) (sin a + (pi - a) cos a)``, a = pi - theta the phase angle
    (so cos a = -cos theta, pi - a = theta). Keeps the input's float dtype."""
    mu = np.clip(np.asarray(cos_theta), -1.0, 1.0)
    return (2.0 / (3.0 * math.pi**2)) * (np.sqrt(1.0 - mu * mu) - np.arccos(mu) * mu)


def hg_phase(cos_theta: np.ndarray, g: float) -> np.ndarray:
    """Henyey-Greenstein phase function (1/sr, integral 1). Keeps the input's float dtype."""
    mu = np.asarray(cos_theta)
    base = (1.0 + g * g) - (2.0 * g) * mu
    return ((1.0 - g * g) / (4.0 * math.pi)) / (base * np.sqrt(base))


@dataclass(frozen=True)
class ParticleMaterial:
    """Albedo (fraction of the geometric cross-section scattered), share of that in the
    forward lobe and the lobe's HG asymmetry."""

    albedo: float = 0.3
    forward_fraction: float = 0.5
    forward_g: float = 0.9

    def phase(self, cos_theta: np.ndarray) -> np.ndarray:
        """Mixed phase function (1/sr) at the cosines of the scattering angles."""
        f = self.forward_fraction
        out = lambert_sphere_phase(cos_theta) * (1.0 - f)
        return out + hg_phase(cos_theta, self.forward_g) * f if f > 0 else out


def _columns(points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contiguous float32 x, y, z (M,) of points (M, 3): the planar layout every per-particle
    loop here runs on (numpy loops over a short last axis, (M, 3), cost ~20x more per element)."""
    pts = np.asarray(points, np.float32).reshape(-1, 3)
    return tuple(np.ascontiguousarray(pts[:, k]) for k in range(3))


def light_rows(point_lights: list, tabled=()) -> np.ndarray:
    """(L, LIGHT_COLUMNS) float32 rows of ``lights.PointLight``s for the compiled light field
    (particle_light_kernels): position, axis, intensity, cos of the half angle (-2: isotropic),
    cos of the inner angle (= cos half: a hard edge), cosine power; -1 for the lights whose
    index is in ``tabled`` (their beam is given as a table lookup)."""
    rows = np.empty((len(point_lights), plk.LIGHT_COLUMNS), np.float32)
    for k, li in enumerate(point_lights):
        half, edge = float(li.half_angle_rad), float(li.edge_rad)
        cos_half = -2.0 if half >= math.pi else math.cos(half)
        cos_inner = math.cos(max(half - edge, 0.0)) if edge > 0 and half < math.pi else cos_half
        rows[k, :3], rows[k, 3:6] = np.asarray(li.position_m, float), np.asarray(li.axis, float)
        rows[k, 6:9] = np.asarray(li.intensity_w_sr, float).reshape(3)
        rows[k, 9:] = cos_half, cos_inner, -1.0 if k in tabled else float(li.cosine_power)
    return rows


def light_field(xyz, material: ParticleMaterial, ambient_rgb, lights: list, gain=None) -> np.ndarray:
    """(3, M) float32 :func:`particle_radiance` on columns xyz = (x, y, z) (M,) float32, compiled
    (``particle_light_kernels.radiance``). lights: (PointLight, c (3,) attenuation along its path
    1/m, beam) triples, beam None (profile x exp(-c d)) or callable(light, cos_psi (1, M), d (1, M))
    -> (1, M, 3) replacing it (the lamp's spread beam, ``LampWater.beam``); gain None or (3, M)."""
    x, y, z = (np.ascontiguousarray(v, np.float32) for v in xyz)
    n = x.size
    amb = (np.float32(material.albedo) * np.asarray(ambient_rgb, np.float32).reshape(3)).astype(np.float32)
    tabled = [k for k, (li, _, beam) in enumerate(lights) if beam is not None or li.cosine_power not in (0, 1)]
    beams = np.zeros((len(lights), 3, n if tabled else 0), np.float32)
    for k in tabled:  # beams given, or profiles the kernel has not: numpy
        li, c, beam = lights[k]
        d, cos_psi = plk.light_rays(x, y, z, np.asarray(li.position_m, np.float32), np.asarray(li.axis, np.float32))
        if beam is not None:
            beams[k] = beam(li, cos_psi[None, :], d[None, :])[0].T
        else:
            beams[k] = li.profile(cos_psi)[None, :] * np.exp(-np.asarray(c, np.float32).reshape(3, 1) * d[None, :])
    rows = light_rows([li for li, _, _ in lights], tabled)
    c = np.array([np.asarray(cl, np.float32).reshape(3) for _, cl, _ in lights], np.float32).reshape(-1, 3)
    g = np.zeros((3, 0), np.float32) if gain is None else np.ascontiguousarray(gain, np.float32).reshape(3, n)
    mat = np.array([material.albedo, material.forward_fraction, material.forward_g], np.float32)
    return plk.radiance(x, y, z, rows, c, beams, g, mat, amb)


def radiance_planar(
    xyz, material: ParticleMaterial, ambient_rgb, point_lights: list, c_per_m, light_gain=None, beam=None
) -> list:
    """:func:`particle_radiance` on columns: xyz = (x, y, z) (M,) float32, light_gain None or
    3 x (M,) (per channel), beam None or the lights' beam (:func:`light_field`); returns 3 x (M,)
    float32."""
    c = np.asarray(c_per_m, np.float32).reshape(3)
    gain = None if light_gain is None else np.stack([np.asarray(g, np.float32) for g in light_gain])
    return list(light_field(xyz, material, ambient_rgb, [(li, c, beam) for li in point_lights], gain))


def particle_radiance(
    points_cam: np.ndarray,
    material: ParticleMaterial,
    ambient_rgb,
    point_lights: list,
    c_per_m,
    light_gain: np.ndarray | None = None,
) -> np.ndarray:
    """Mean radiance (M, 3) float32 of each particle's disc toward the camera (at the origin).

    points_cam (M, 3) particle centres; ambient_rgb (3,) mean radiance of the light field at
    the particles (already dimmed for their depth by the caller, or to be dimmed later);
    point_lights: lights.PointLight list (lamps, LEDs); c_per_m (3,) beam attenuation along
    the lights' paths; light_gain (M,) or (M, 3) factor on the point lights' part (the caller's
    compensation for a depth factor the water model applies to every surface later)."""
    xyz = _columns(points_cam)
    gain = None
    if light_gain is not None:
        g = np.broadcast_to(np.asarray(light_gain, np.float32).reshape(xyz[0].size, -1), (xyz[0].size, 3))
        gain = [g[:, k] for k in range(3)]
    return np.stack(radiance_planar(xyz, material, ambient_rgb, point_lights, c_per_m, gain), axis=1)


def sun_planar(xyz, material: ParticleMaterial, suns_cam) -> np.ndarray:
    """:func:`sun_radiance` on columns xyz = (x, y, z) (M,): (M,) float32 (grey), compiled."""
    x, y, z = (np.ascontiguousarray(v, np.float32) for v in xyz)
    suns = np.array([[*np.asarray(d, float).reshape(3), float(e)] for d, e in suns_cam], np.float32).reshape(-1, 4)
    return plk.sun_radiance(x, y, z, suns, np.float32(material.albedo * (1.0 - material.forward_fraction)))


def sun_radiance(points_cam: np.ndarray, material: ParticleMaterial, suns_cam) -> np.ndarray:
    """(M, 1) float32 radiance of Lambertian-sphere reflection of collimated lights, e.g. the
    sun: ``omega E (1 - f) p_lambert(theta)`` per light (``suns_cam``: (travel direction (3,)
    camera frame, irradiance normal to the beam W/m^2)). Only the reflecting part: the
    forward lobe would need the light behind the particle, i.e. looking toward the sun."""
    return sun_planar(_columns(points_cam), material, suns_cam)[:, None]


def led_point_lights(markers: list[dict], T_cam_dock: np.ndarray, strength_scale: float = 1.0) -> list:
    """The LED arrays' LEDs as point lights in the camera frame.

    A flat Lambertian LED disc of radius r and radiance ``L = strength x colour`` (the
    render's emission, W/m^2/sr) has on-axis intensity ``I = L pi r^2`` (W/sr); it faces
    the dock's +z. Modelled as a hemisphere emitter (half-angle 90 deg) without the
    cos falloff (an upper bound off-axis). ``strength_scale`` is the hook for a physical
    LED intensity (docs/light.md): multiply the manifest's strength by it."""
    T = np.asarray(T_cam_dock, float)
    axis = T[:3, 2] / np.linalg.norm(T[:3, 2])
    out = []
    for m in markers:
        if m.get("kind") != "led_array":
            continue
        pts = np.asarray(m["keypoints"], float) @ T[:3, :3].T + T[:3, 3]
        area = math.pi * float(m["led_radius_m"]) ** 2
        strength = float(m.get("strength", 1.0)) * strength_scale
        for p, col in zip(pts, m.get("colors") or [[1.0, 1.0, 1.0]] * len(pts)):
            out.append(lt.PointLight(p, axis, strength * area * np.asarray(col, float), math.pi / 2, 0.0))
    return out


# ----------------------------------------------------------------------------- optics
def coc_scale(focal_length_m: float, f_number: float, focus_m: float, fx_px: float) -> float:
    """k (px) of the thin-lens circle of confusion ``c_px = k |s - s_f| / s`` (module doc):
    ``k = A f / (s_f - f) * f_px / f``, A = f / N."""
    if not (focus_m > focal_length_m > 0 and f_number > 0):
        raise ValueError(
            f"need focus_m > focal_length > 0 and f_number > 0, got {focus_m}, {focal_length_m}, {f_number}"
        )
    return (focal_length_m / f_number) / (focus_m - focal_length_m) * fx_px


def coc_px(z_m: np.ndarray, focal_length_m: float, f_number: float, focus_m: float, fx_px: float) -> np.ndarray:
    """Thin-lens circle-of-confusion diameter (px) at object distances z_m (module doc)."""
    z = np.asarray(z_m, np.float64)
    return coc_scale(focal_length_m, f_number, focus_m, fx_px) * np.abs(z - focus_m) / z


def blurred_shapes(a, b, c, s, extra_iso_r2=None, streak_uv=None):
    """Ellipse (a radial, b tangential semi-axes px, radial direction (c, s)) convolved with a
    disc of squared radius ``extra_iso_r2`` (M,) px^2 and a streak ``streak_uv`` (M, 2) px
    (full length over the exposure): returns (a', b', c', s', opacity) float32, opacity =
    a b / (a' b'). Second moments add (module doc): disc R^2/4 per axis, segment L^2/12.
    One compiled pass (``particle_kernels.blur``)."""
    a, b, c, s = (np.ascontiguousarray(x, np.float32).reshape(-1) for x in (a, b, c, s))
    zero = np.zeros(a.size, np.float32)
    column = lambda x: zero if x is None else np.ascontiguousarray(np.broadcast_to(x, a.shape), np.float32)
    du, dv = (zero, zero) if streak_uv is None else (column(streak_uv[:, 0]), column(streak_uv[:, 1]))
    out = kern.blur(a, b, c, s, column(extra_iso_r2), du, dv)
    return out[0], out[1], out[2], out[3], out[4]
