"""The geometry of the reference's caustic spot (``blender/caustic_sun.py``): the grid across
the in-water sun beam that photons are binned in and the spot's light texture is looked up
with, and the normalisation that makes a flat surface's pattern 1. No Blender here.

A spot light ``D_SPOT`` upstream of the grid centre ``c`` along the beam ``t`` reaches a
point ``P`` along the direction ``(p, q, -D) / |.|`` in its frame ``(e1, e2, -t)``, where
``(p, q) = D ((P - c) e1, (P - c) e2) / (D + s)`` and ``s = (P - c) t``: binning photons
at those projective coordinates makes the binning and the light texture's lookup agree
exactly, whatever the point's depth. They also undo the spot's inverse square with no
weight: a bin holds the photons of a cross-section ``((D + s) / D)^2`` times its own area,
which is the factor the spot's irradiance ``E (D / (D + s))^2`` at ``P`` lacks.

Normalisation: an orthographic "sun" camera with pixel pitch ``a`` sends ``1 / a^2`` rays per
m^2 across the beam in air; a flat surface passes the share ``T`` (Fresnel) of them and
squeezes them across the in-water beam by ``cos(theta_air) / cos(theta_water)`` (the same
surface patch is ``cos theta_air`` of a unit area across the air beam, ``cos theta_water``
across the water beam). ``M`` = photons per bin over that flat count: 1 on average, so the
spot keeps the plain sun's energy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blendgen.physics.surface import optics as sf

D_SPOT = 1000.0  # m: the spot's rays are within 8 mrad of parallel over a 15 m pool
OFFSET = 100.0  # m, added to recorded plane coordinates (photon recorders' emission stays positive)


@dataclass
class Grid:
    """The cross-section grid: ``c`` (3,) centre on the surface plane (world, m), ``t`` (3,)
    the beam in water (unit), ``e1``/``e2`` (3,) across it (the spot's x and y), ``lo`` (2,)
    lower corner (m, projective), ``bin_m``, ``shape`` (rows along e2, columns along e1)."""

    c: np.ndarray
    t: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    lo: np.ndarray
    bin_m: float
    shape: tuple[int, int]

    def coords(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) world points -> (N, 2) projective ``(p, q)`` (m) and ``s`` (N,) (m), their
        distance beyond ``c`` along the beam."""
        d = np.asarray(P, float) - self.c
        s = d @ self.t
        k = (D_SPOT / (D_SPOT + s))[:, None]
        return k * np.stack([d @ self.e1, d @ self.e2], axis=1), s

    def size(self) -> np.ndarray:
        """(2,) extent (m) along e1 and e2."""
        return np.array([self.shape[1], self.shape[0]]) * self.bin_m


def beam_axes(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors across the beam ``t``: ``e1`` horizontal and ``e2`` completing the
    right-handed frame ``(e1, e2, -t)`` of the spot (a spot light shines along its local -z)."""
    t = np.asarray(t, float)
    e1 = np.cross([0.0, 0.0, 1.0], t) if abs(t[2]) < 1 - 1e-9 else np.array([1.0, 0.0, 0.0])
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(-t, e1)
    return e1, e2 / np.linalg.norm(e2)


def grid_for(surface: dict, t, bin_m: float) -> Grid:
    """The grid covering the surface rectangle (``centre_xy``, ``half_xy``, ``z``) seen along
    the beam ``t``, plus two bins each side."""
    (cx, cy), (hx, hy), z = surface["centre_xy"], surface["half_xy"], float(surface["z"])
    t = np.asarray(t, float) / np.linalg.norm(t)
    c = np.array([cx, cy, z], float)
    e1, e2 = beam_axes(t)
    corners = np.array([[cx + a * hx, cy + b * hy, z] for a in (-1, 1) for b in (-1, 1)])
    pq, _ = Grid(c, t, e1, e2, np.zeros(2), bin_m, (0, 0)).coords(corners)
    lo, hi = pq.min(axis=0) - 2 * bin_m, pq.max(axis=0) + 2 * bin_m
    n = np.ceil((hi - lo) / bin_m).astype(int)
    return Grid(c, t, e1, e2, lo, float(bin_m), (int(n[1]), int(n[0])))


def transmittance(air) -> float:
    """Fresnel transmittance of a flat surface for the sun travelling along ``air``."""
    return 1.0 - float(sf.fresnel_reflectance(np.array([-air[2]]), 1.0, sf.N_WATER)[0])


def photon_pitch(bin_m: float, per_bin: float, renders: int, air, t) -> float:
    """Pixel pitch (m) of the sun camera that gives a flat surface ``per_bin`` refracted
    photons per bin over ``renders`` renders."""
    rho_t = per_bin / (bin_m * bin_m * renders * transmittance(air))
    return 1.0 / math.sqrt(rho_t * -t[2] / -air[2])


def pattern(grid: Grid, P: np.ndarray, pitch_m: float, renders: int, air) -> np.ndarray:
    """(rows, cols) float32 ``M``: the photons landed at ``P`` (N, 3) per bin over the count
    a flat surface gives a bin at ``c`` (so a flat surface gives ``((D + s) / D)^2``)."""
    pq, _ = grid.coords(P)
    rows, cols = grid.shape
    hi = grid.lo + grid.size()
    hist, _, _ = np.histogram2d(pq[:, 1], pq[:, 0], bins=[rows, cols], range=[[grid.lo[1], hi[1]], [grid.lo[0], hi[0]]])
    rho_t = (-air[2]) / (-grid.t[2]) / (pitch_m * pitch_m)
    flat = rho_t * grid.bin_m * grid.bin_m * renders * transmittance(air)
    return (hist / flat).astype(np.float32)


def lookup(grid: Grid, M: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``M`` at world points ``P`` (N, 3), bilinear between bin centres, 1 outside the grid:
    what the spot's light texture gives each point (before the inverse square)."""
    pq, _ = grid.coords(P)
    x = (pq - grid.lo) / grid.bin_m - 0.5  # bin-centre units
    rows, cols = grid.shape
    inside = (x[:, 0] >= -0.5) & (x[:, 0] <= cols - 0.5) & (x[:, 1] >= -0.5) & (x[:, 1] <= rows - 0.5)
    i0 = np.clip(np.floor(x).astype(int), 0, [cols - 2, rows - 2])
    f = np.clip(x - i0, 0.0, 1.0)
    m = (
        M[i0[:, 1], i0[:, 0]] * (1 - f[:, 0]) * (1 - f[:, 1])
        + M[i0[:, 1], i0[:, 0] + 1] * f[:, 0] * (1 - f[:, 1])
        + M[i0[:, 1] + 1, i0[:, 0]] * (1 - f[:, 0]) * f[:, 1]
        + M[i0[:, 1] + 1, i0[:, 0] + 1] * f[:, 0] * f[:, 1]
    )
    return np.where(inside, m, 1.0)
