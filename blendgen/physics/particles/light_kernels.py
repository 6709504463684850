"""Compiled light field at the particles (numba): ``particle_optics.radiance_planar``'s law in
vectorised loops, lights outer, particles inner.

Written with numpy the light field cost ~25 array passes per light (rays, distances, cone
profile, attenuation, phase), ~0.2 ms per light for 20000 particles; here each light is one
pass that LLVM vectorises (8 particles per instruction): no transcendental is a libm call --
``exp`` is ``particle_kernels.exp32`` and ``acos`` (in the Lambert sphere's phase) the
Abramowitz & Stegun 4.4.46 polynomial (|error| <= 2e-8 rad). The lamps' spread beam, a table
lookup, stays outside (``light_rays`` gives its distances and angles; ``particle_optics``).
``tests/test_particle_optics.py`` checks every term against the numpy laws (lights.irradiance,
the phase functions) in float64.
"""

from __future__ import annotations

import math

import numpy as np

from blendgen.physics.particles.kernels import _EXP, _F0, _F1, exp32, nb

_vec = nb.njit(cache=True, nogil=True, fastmath=_EXP, error_model="numpy")
_vec_inline = nb.njit(cache=True, nogil=True, fastmath=_EXP, error_model="numpy", inline="always")
_LAMBERT = np.float32(2.0 / (3.0 * math.pi**2))
_PI32 = np.float32(math.pi)
LIGHT_COLUMNS = 12  # position (3), unit axis (3), intensity (3), cos half, cos inner, power


@_vec_inline
def _acos(x):
    """arccos of x in [-1, 1] (Abramowitz & Stegun 4.4.46, |error| <= 2e-8 rad)."""
    t = min(max(x, -x), _F1)
    p = np.float32(-0.0012624911)
    p = p * t + np.float32(0.0066700901)
    p = p * t + np.float32(-0.0170881256)
    p = p * t + np.float32(0.0308918810)
    p = p * t + np.float32(-0.0501743046)
    p = p * t + np.float32(0.0889789874)
    p = p * t + np.float32(-0.2145988016)
    p = p * t + np.float32(1.5707963050)
    a = np.sqrt(_F1 - t) * p
    return _PI32 - a if x < _F0 else a


@_vec_inline
def _phase(mu, forward, g):
    """(1 - f) p_lambert + f p_HG(g) at the cosine mu of the scattering angle (1/sr)."""
    m = min(max(mu, -_F1), _F1)
    lam = _LAMBERT * (np.sqrt(_F1 - m * m) - _acos(m) * m)
    base = (_F1 + g * g) - (g + g) * m
    hg = ((_F1 - g * g) / np.float32(4.0 * math.pi)) / (base * np.sqrt(base))
    return (_F1 - forward) * lam + forward * hg


@_vec_inline
def _profile(cos_psi, cos_half, cos_inner, power):
    """``lights.PointLight.profile``: a hard (cos_inner = cos_half) or smoothstep edge between
    the inner and the half angle (cos_half < -1: none), times cos^power for power 0 or 1 (other
    powers go through the table path, ``particle_optics.light_field``: a pow would not vectorise)."""
    span = cos_inner - cos_half
    t = min(max((cos_psi - cos_half) / span, _F0), _F1) if span > _F0 else (_F1 if cos_psi >= cos_half else _F0)
    edge = t * t * (np.float32(3.0) - t - t) if span > _F0 else t
    return edge * (_F1 + power * (max(cos_psi, _F0) - _F1))


@_vec_inline
def _scatter(x, y, z, px, py, pz, forward, g):
    """p(theta) / d^2 (1/sr/m^2) at the particle (x, y, z) for light from (px, py, pz): the
    phase at the scattering angle between the light's ray and the ray to the camera (origin)."""
    rx, ry, rz = x - px, y - py, z - pz
    d2 = max(rx * rx + ry * ry + rz * rz, np.float32(1e-6))
    dist = max(np.sqrt(x * x + y * y + z * z), np.float32(1e-9))
    mu = -(rx * x + ry * y + rz * z) / (np.sqrt(d2) * dist)
    return _phase(mu, forward, g) / d2


@_vec
def light_rays(x, y, z, position, axis):
    """(2, M) float32: distance (m, >= 1 mm) from a light at ``position`` (3,) to each particle
    x, y, z (M,) and the cosine of the angle off its unit ``axis`` (3,)."""
    out = np.empty((2, x.size), np.float32)
    for i in range(x.size):
        rx, ry, rz = x[i] - position[0], y[i] - position[1], z[i] - position[2]
        d = max(np.sqrt(rx * rx + ry * ry + rz * rz), np.float32(1e-3))
        out[0, i] = d
        out[1, i] = (rx * axis[0] + ry * axis[1] + rz * axis[2]) / d
    return out


@_vec
def radiance(x, y, z, lights, c_light, beams, gain, mat, amb):
    """(3, M) float32 mean radiance of each particle's disc toward the camera (at the origin):
    ``amb + gain sum_lights E p(theta) albedo`` (``particle_optics.particle_radiance``).

    x, y, z (M,) float32 camera-frame centres (m); lights (L, LIGHT_COLUMNS) float32 rows (module
    constant); c_light (L, 3) attenuation (1/m) along each light's path; beams (L, 3, M) float32
    or (L, 3, 0): a light's relative beam (profile x attenuation, the lamp's spread) where given,
    used for the lights whose row has power < 0; gain (3, M) or (3, 0) (1) the factor on the
    lights' part; mat (3,) = albedo, forward fraction, HG g; amb (3,) the ambient term."""
    n = x.size
    art = np.zeros((3, n), np.float32)
    albedo, forward, g = mat[0], mat[1], mat[2]
    for li in range(lights.shape[0]):
        L = lights[li]
        px, py, pz, ax, ay, az = L[0], L[1], L[2], L[3], L[4], L[5]
        i0, i1, i2, cos_half, cos_inner, power = L[6], L[7], L[8], L[9], L[10], L[11]
        c0, c1, c2 = c_light[li, 0], c_light[li, 1], c_light[li, 2]
        if power < _F0:  # the beam given (a table lookup)
            for i in range(n):
                ph = _scatter(x[i], y[i], z[i], px, py, pz, forward, g) * albedo
                art[0, i] += beams[li, 0, i] * i0 * ph
                art[1, i] += beams[li, 1, i] * i1 * ph
                art[2, i] += beams[li, 2, i] * i2 * ph
            continue
        for i in range(n):
            rx, ry, rz = x[i] - px, y[i] - py, z[i] - pz
            d = max(np.sqrt(rx * rx + ry * ry + rz * rz), np.float32(1e-3))
            ph = _scatter(x[i], y[i], z[i], px, py, pz, forward, g) * albedo
            prof = _profile((rx * ax + ry * ay + rz * az) / d, cos_half, cos_inner, power) * ph
            art[0, i] += prof * exp32(-c0 * d) * i0
            art[1, i] += prof * exp32(-c1 * d) * i1
            art[2, i] += prof * exp32(-c2 * d) * i2
    out = np.empty((3, n), np.float32)
    gained = gain.shape[1] == n
    for k in range(3):
        for i in range(n):
            out[k, i] = (art[k, i] * gain[k, i] if gained else art[k, i]) + amb[k]
    return out


@_vec
def sun_radiance(x, y, z, suns, reflect):
    """(M,) float32 Lambert-sphere reflection of collimated lights (``particle_optics.
    sun_planar``): suns (S, 4) = travel direction (3, camera frame), irradiance (W/m^2);
    reflect = albedo (1 - forward fraction)."""
    out = np.zeros(x.size, np.float32)
    for s in range(suns.shape[0]):
        dx, dy, dz, e = suns[s, 0], suns[s, 1], suns[s, 2], suns[s, 3] * reflect
        for i in range(x.size):
            inv_v = np.float32(-1.0) / max(np.sqrt(x[i] * x[i] + y[i] * y[i] + z[i] * z[i]), np.float32(1e-9))
            m = min(max((x[i] * dx + y[i] * dy + z[i] * dz) * inv_v, -_F1), _F1)
            out[i] += e * _LAMBERT * (np.sqrt(_F1 - m * m) - _acos(m) * m)
    return out


@_vec
def depth_gain(x, y, z, d, rz, cam_depth, kd):
    """(3, M) float32 ``exp(Kd_k depth)``, depth = max(cam_depth - d dir_z, 0) of each particle's
    surface at range d (M,) along its ray (world z of the unit ray from the camera-axes' world z
    rz (3,)): the inverse of the depth factor the water model applies (particle_light)."""
    out = np.empty((3, x.size), np.float32)
    for i in range(x.size):
        dist = max(np.sqrt(x[i] * x[i] + y[i] * y[i] + z[i] * z[i]), np.float32(1e-9))
        depth = max(cam_depth - d[i] * (x[i] * rz[0] + y[i] * rz[1] + z[i] * rz[2]) / dist, _F0)
        out[0, i], out[1, i], out[2, i] = exp32(kd[0] * depth), exp32(kd[1] * depth), exp32(kd[2] * depth)
    return out
