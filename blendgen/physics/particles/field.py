"""Small-obstacle (particle) occlusion: a 3-D Poisson particle field, drift, and a
depth-tested, anti-aliased renderer (compiled loops in particle_kernels.py: no OpenCV drawing,
no Blender; the splatting itself is in particle_splat.py).

The article (section 2.2.3) draws ``Poisson(rho * V_cam)`` blobs in image space.
Here the obstacles live in the world instead, which gives the same statistics and
more:

- **Field**: ``N_total`` particles uniformly distributed in an axis-aligned box
  (the "bounded region", V_env = its volume), radii uniform in ``[r_min, r_max]``.
  With ``count_dist="poisson"`` the total is ``Poisson(rho * V_env)``, so the field
  is a homogeneous Poisson point process and the count in *any* sub-volume (the
  camera frustum included) is ``Poisson(rho * V_sub)`` -- the article's model --
  while staying consistent from frame to frame. ``"uniform"`` draws the total
  uniformly in ``[0, n_max]``; ``"fixed"`` uses exactly ``n_total`` (then the count
  in a sub-volume is binomial).
- **Drift**: ``p(t+dt) = p(t) + v_flow dt + eta``, ``eta ~ N(0, Sigma)`` per step,
  then wrapped periodically into the region (a particle leaving through one face
  re-enters through the opposite one), so the density stays constant forever.
- **Rendering**: a sphere of radius r at camera point (X, Y, Z), range d = ||p||,
  projects (first order in r/d) to an ellipse centred on ``(fx X/Z + cx, fy Y/Z + cy)``
  with tangential semi-axis ``b = f r / Z`` (the article's ``r_pix``, f = (fx+fy)/2)
  and radial semi-axis ``a = f r d / Z^2`` (off-axis stretching; a = b on the axis).
  Coverage is anti-aliased (area-conserving); ellipses under half a pixel are splat
  bilinearly with alpha = their area in px^2, so far specks dim pixels in proportion.
  A particle covers a pixel only if its range ``d - r`` is less than the rendered
  surface range there (``range_m``, inf = background). Particles are composited
  "over" in depth order; for one particle colour that equals
  ``out = img * T + colour * (1 - T)``, ``T = prod(1 - alpha_i)``, which is
  order-independent and therefore computed fully vectorised.

Units: metres, world +z up, OpenCV camera frame, ``T_world_cam`` 4x4 (geometry.py).
Positions are stored as float32 (12 bytes per particle: 1e6 particles = 12 MB);
keep region coordinates within a few hundred metres of the origin (float32 keeps
~10 um resolution at 100 m).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from blendgen.physics.particles import kernels as kern
from blendgen.physics.particles import optics as popt
from blendgen.physics.particles import splat as psplat

COUNT_DISTS = ("poisson", "uniform", "fixed")
MODES = ("backscatter", "silhouette")
MAX_PARTICLES = 20_000_000  # 240 MB of float32 positions
DEFAULT_R_MIN_M = 0.005
DEFAULT_R_MAX_M = 0.02
DEFAULT_AMBIENT_RGB = (0.60, 0.70, 0.62)  # light grey-green veiling/ambient light (linear)
SILHOUETTE_ALBEDO = 0.05


# ----------------------------------------------------------------------------- field
def _as_rng(rng) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _check_region(region_min, region_max) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(region_min, float).reshape(-1)
    hi = np.asarray(region_max, float).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"region_min/region_max must be finite (3,) vectors, got {lo}, {hi}")
    scale = np.maximum(1.0, np.maximum(np.abs(lo), np.abs(hi)))  # float32 must resolve it
    if np.any(hi - lo < 1e-6 * scale):
        raise ValueError(
            f"region must be non-empty: region_max - region_min >= 1e-6 * max(1, |coord|) "
            f"m on every axis, got min={lo.tolist()} max={hi.tolist()}"
        )
    return lo, hi


def _check_radii(r_min: float, r_max: float) -> None:
    if not (math.isfinite(r_min) and math.isfinite(r_max)) or r_min < 0 or r_max < r_min:
        raise ValueError(f"radii must satisfy 0 <= r_min <= r_max < inf, got r_min={r_min}, r_max={r_max}")


def _draw_count(rng, mean: float, count_dist: str, n_max, n_total) -> int:
    """Total particle count for ``count_dist`` (see ParticleField.sample)."""
    if n_max is not None and (not float(n_max).is_integer() or n_max < 0):
        raise ValueError(f"n_max must be an integer >= 0, got {n_max}")
    if count_dist == "poisson":
        n = int(rng.poisson(mean))
        return n if n_max is None else min(n, int(n_max))
    if count_dist == "uniform":
        bound = n_max if n_max is not None else (n_total if n_total is not None else round(mean))
        if bound is None or not float(bound).is_integer() or bound < 0:
            raise ValueError(f"uniform counts need an integer upper bound n_max >= 0, got {bound}")
        return int(rng.integers(0, int(bound), endpoint=True))
    if count_dist == "fixed":
        n = n_total if n_total is not None else round(mean)
        if not float(n).is_integer():
            raise ValueError(f"fixed counts need an integer n_total >= 0, got {n}")
        if n_max is not None and n > n_max:
            raise ValueError(f"n_total={n} exceeds n_max={n_max}: allowed 0 <= n_total <= n_max")
        return int(n)
    raise ValueError(f"count_dist must be one of {COUNT_DISTS}, got {count_dist!r}")


@dataclass(frozen=True, eq=False)
class ParticleField:
    """Spherical small obstacles in an axis-aligned world box.

    positions (N,3) float32 world metres, radii (N,) float32 metres,
    region_min / region_max (3,) float64 world metres (positions lie in [min, max)).
    The positions are kept planar: ``positions`` is the (N, 3) view of :attr:`xyz` (3, N),
    C-contiguous rows x, y, z that the compiled loops read (an (N, 3) layout kept them from
    being vectorised: the projection's culling pass 0.4 -> 0.04 ms for 60000).
    """

    positions: np.ndarray
    radii: np.ndarray
    region_min: np.ndarray
    region_max: np.ndarray

    def __post_init__(self):
        pos = np.ascontiguousarray(np.asarray(self.positions, np.float32).reshape(-1, 3).T).T  # planar
        radii = np.asarray(self.radii, np.float32).reshape(-1)
        lo, hi = _check_region(self.region_min, self.region_max)
        if radii.shape[0] != pos.shape[0]:
            raise ValueError(f"positions (N,3) and radii (N,) disagree: {pos.shape} vs {radii.shape}")
        if radii.size and not (np.all(np.isfinite(radii)) and radii.min() >= 0):
            raise ValueError("radii must be finite and >= 0 m")
        for name, val in (("positions", pos), ("radii", radii), ("region_min", lo), ("region_max", hi)):
            object.__setattr__(self, name, val)

    @property
    def xyz(self) -> np.ndarray:
        """(3, N) float32 C-contiguous x, y, z rows (the storage of ``positions``)."""
        return self.positions.T

    @property
    def n(self) -> int:
        return int(self.radii.shape[0])

    @property
    def volume(self) -> float:
        """Region volume V_env (m^3)."""
        return float(np.prod(self.region_max - self.region_min))

    @property
    def density(self) -> float:
        """Realised density N / V_env (1/m^3)."""
        return self.n / self.volume

    @classmethod
    def sample(
        cls,
        rng,
        region_min,
        region_max,
        n_total: float | None = None,
        density: float | None = None,
        r_min: float = DEFAULT_R_MIN_M,
        r_max: float = DEFAULT_R_MAX_M,
        count_dist: str = "poisson",
        n_max: int | None = None,
        size_dist: str = "uniform",
        size_slope: float = 3.5,
    ) -> ParticleField:
        """Draw a field. Give exactly one of ``n_total`` (expected/total count in the
        region) or ``density`` (rho, 1/m^3; then the mean count is rho * V_env).

        count_dist: "poisson" -> N ~ Poisson(mean) (clipped at n_max if given);
        "uniform" -> N uniform on {0..n_max} (n_max defaults to n_total);
        "fixed" -> N = n_total exactly (must be an integer <= n_max).
        ``rng`` is a numpy Generator or a seed; the same seed gives the same field.
        size_dist: "uniform" radii in [r_min, r_max] (the article) or "power_law"
        dN/dr ~ r^-size_slope on [r_min, r_max] (marine snow, particle_optics.sample_radii).
        """
        rng = _as_rng(rng)
        lo, hi = _check_region(region_min, region_max)
        _check_radii(float(r_min), float(r_max))
        if (n_total is None) == (density is None):
            raise ValueError("give exactly one of n_total or density")
        vol = float(np.prod(hi - lo))
        mean = float(n_total) if n_total is not None else float(density) * vol
        if not math.isfinite(mean) or mean < 0 or mean > MAX_PARTICLES:
            raise ValueError(
                f"expected particle count must be in [0, {MAX_PARTICLES}], got {mean} "
                f"(n_total={n_total}, density={density}, V_env={vol:.6g} m^3)"
            )
        n = _draw_count(rng, mean, count_dist, n_max, n_total)
        if n > MAX_PARTICLES:
            raise ValueError(f"particle count must be <= {MAX_PARTICLES}, got {n}")
        xyz = rng.random((3, n), dtype=np.float32)  # planar, in place: ~16 bytes/particle
        xyz *= (hi - lo).astype(np.float32)[:, None]
        xyz += lo.astype(np.float32)[:, None]
        _clamp32(xyz, lo, hi)  # float32 rounding stays inside
        return cls(xyz.T, popt.sample_radii(rng, n, size_dist, r_min, r_max, size_slope), lo, hi)

    def step(self, dt: float, v_flow, sigma, rng) -> ParticleField:
        """Drift one time step: ``p + v_flow*dt + eta``, eta ~ N(0, Sigma), wrapped
        periodically into the region (density stays constant). Radii are kept.

        v_flow (3,) m/s world; sigma (3,) = per-axis std-devs (m) or (3,3) = the
        covariance Sigma (m^2) of the displacement noise *per step* (the article's
        model; scale it with dt yourself for a diffusion). Returns a new field.
        Positions are re-rounded to float32 each step (~0.5 um at 5 m from the origin).
        The normal draws are float32 Box-Muller on a SplitMix64 stream seeded by one word of
        ``rng`` (physics/particles/gauss.py: exact, cut at 5.77 sigma), drawn inside the compiled move.
        """
        rng = _as_rng(rng)
        if not (math.isfinite(dt) and dt >= 0):
            raise ValueError(f"dt must be finite and >= 0, got {dt}")
        v = np.asarray(v_flow, float).reshape(-1)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"v_flow must be a finite (3,) vector in m/s, got {v_flow}")
        L = _noise_factor_cached(tuple(np.asarray(sigma, float).reshape(-1).tolist()))
        seed = np.uint64(0)
        if L is not None:  # one word per step: the normals' SplitMix64 stream
            seed = rng.integers(0, 2**64, dtype=np.uint64)
        lo, hi = self.region_min, self.region_max
        xyz = kern.drift(self.xyz, v * dt, _ZERO_L if L is None else L, np.uint64(seed), lo, hi, *self._bounds32)
        return self._moved(xyz)

    @property
    def _bounds32(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`_bounds32` of the region, computed once per field lineage (the drift's per-step
        validation and float32 bounds were ~0.3 ms of Python per frame in the pipeline, where the
        frame's work has evicted the interpreter's data from the caches)."""
        b = self.__dict__.get("_b32")
        if b is None:
            b = _bounds32(self.region_min, self.region_max)
            object.__setattr__(self, "_b32", b)
        return b

    def _moved(self, xyz: np.ndarray) -> ParticleField:
        """The field at planar positions xyz (3, N) float32 C-contiguous, the same radii and region
        (already checked: no second validation)."""
        new = object.__new__(ParticleField)
        for name, val in (
            ("positions", xyz.T),
            ("radii", self.radii),
            ("region_min", self.region_min),
            ("region_max", self.region_max),
            ("_b32", self._bounds32),
        ):
            object.__setattr__(new, name, val)
        return new


_ZERO_L = np.zeros((3, 3))


@functools.lru_cache(maxsize=16)
def _noise_factor_cached(sigma: tuple) -> np.ndarray | None:
    """:func:`_noise_factor` of a sigma given as a flat tuple (1 or 3 std-devs or the 9 covariance
    entries; cached: not to be modified); None when it is zero (no noise, no draw)."""
    s = np.array(sigma, float)
    L = _noise_factor(s.reshape(3, 3) if s.size == 9 else (s.reshape(()) if s.size == 1 else s))
    return np.ascontiguousarray(L, float) if np.any(L) else None


def _noise_factor(sigma) -> np.ndarray:
    """(3,3) L with L L^T = Sigma from per-axis std-devs (3,) or a covariance (3,3)."""
    s = np.asarray(sigma, float)
    if s.shape == (3,) or s.shape == ():
        s = np.broadcast_to(s, (3,))
        if not np.all(np.isfinite(s)) or np.any(s < 0):
            raise ValueError(f"sigma std-devs must be finite and >= 0 (m), got {s.tolist()}")
        return np.diag(s)
    if s.shape != (3, 3) or not np.all(np.isfinite(s)) or not np.allclose(s, s.T):
        raise ValueError(f"sigma must be (3,) std-devs or a symmetric (3,3) covariance, got {s.tolist()}")
    w, V = np.linalg.eigh(s)
    if w.min() < -1e-12 * max(1.0, w.max()):
        raise ValueError(f"covariance sigma must be positive semi-definite, eigenvalues {w.tolist()}")
    return V * np.sqrt(np.clip(w, 0.0, None))


def _bounds32(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float32 bounds (3,) lo32 >= lo and top32 < hi: the closed range float32 positions
    must stay in so that they lie in [lo, hi) (lo, hi float64)."""
    lo32, hi32 = lo.astype(np.float32), hi.astype(np.float32)
    lo32 = np.where(lo32 < lo, np.nextafter(lo32, np.float32(np.inf)), lo32)
    top = np.where(hi32 >= hi, np.nextafter(hi32, np.float32(-np.inf)), hi32)
    return lo32.astype(np.float32), top.astype(np.float32)


def _clamp32(xyz: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """In place: keep planar float32 positions (3, N) in [lo, hi) despite rounding (lo, hi float64)."""
    lo32, top = _bounds32(lo, hi)
    np.clip(xyz, lo32[:, None], top[:, None], out=xyz)
    return xyz


# ----------------------------------------------------------------------------- frustum
def frustum_volume(K: np.ndarray, width: int, height: int, z_near: float, z_far: float) -> float:
    """Volume (m^3) of the image pyramid between planar depths z_near and z_far.

    The image spans u in [-0.5, W-0.5], v in [-0.5, H-0.5] (pixel centres at
    integers), so its cross-section at depth z has area W H z^2 / (fx fy) (skew
    does not change the area): V = W H / (fx fy) * (z_far^3 - z_near^3) / 3.
    """
    if not (0 <= z_near <= z_far) or not math.isfinite(z_far):
        raise ValueError(f"need 0 <= z_near <= z_far < inf, got {z_near}, {z_far}")
    return width * height / (K[0, 0] * K[1, 1]) * (z_far**3 - z_near**3) / 3.0


def _to_camera(field: ParticleField, T_world_cam: np.ndarray, z_min: float, z_max: float):
    """Indices and camera-frame centres (M,3) float32 of particles with z_min < Z <= z_max."""
    T = np.asarray(T_world_cam, float)
    if T.shape != (4, 4):
        raise ValueError(f"T_world_cam must be 4x4, got {T.shape}")
    R = T[:3, :3].astype(np.float32)
    t = T[:3, 3].astype(np.float32)
    P = field.xyz  # explicit row sums: no BLAS threads here
    z = P[0] * R[0, 2] + P[1] * R[1, 2] + P[2] * R[2, 2] - np.float32(t @ R[:, 2])
    idx = np.flatnonzero((z > z_min) & (z <= z_max))
    d = P[:, idx].T - t
    pc = np.empty_like(d)
    for k in range(3):
        pc[:, k] = d[:, 0] * R[0, k] + d[:, 1] * R[1, k] + d[:, 2] * R[2, k]
    return idx, pc


def count_in_frustum(
    field: ParticleField, K: np.ndarray, T_world_cam: np.ndarray, width: int, height: int, z_near: float, z_far: float
) -> int:
    """Number of particle centres inside the image pyramid with z_near < Z <= z_far.

    Its expectation is rho * V(frustum & region); for a frustum inside the region
    that is rho * frustum_volume(...)."""
    _, pc = _to_camera(field, T_world_cam, z_near, z_far)
    u, v = _project(K, pc)
    return int(np.count_nonzero((u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)))


def _project(K: np.ndarray, pc: np.ndarray):
    z = pc[:, 2]
    u = (K[0, 0] * pc[:, 0] + K[0, 1] * pc[:, 1]) / z + K[0, 2]
    v = K[1, 1] * pc[:, 1] / z + K[1, 2]
    return u.astype(np.float32), v.astype(np.float32)


# ----------------------------------------------------------------------------- rendering
@dataclass
class ProjectedParticles:
    """Image-space footprint of the particles that can touch the image (float32 arrays)."""

    u: np.ndarray  # (M,) centre column (px)
    v: np.ndarray  # (M,) centre row (px)
    a: np.ndarray  # (M,) radial semi-axis (px)
    b: np.ndarray  # (M,) tangential semi-axis (px) = f r / Z
    c: np.ndarray  # (M,) cos of the radial direction in the image
    s: np.ndarray  # (M,) sin of the radial direction
    surf_range: np.ndarray  # (M,) range to the particle surface, ||p|| - r (m)
    pc: np.ndarray | None = None  # (3, M) centres in the camera frame (m): x, y, z rows
    index: np.ndarray | None = None  # (M,) indices into the field
    opacity: np.ndarray | None = None  # (M,) peak opacity after blur (None: 1)

    def subset(self, keep: np.ndarray) -> ProjectedParticles:
        """The particles selected by ``keep`` (bool mask or indices)."""
        return ProjectedParticles(
            *(
                None if x is None else x[..., keep]
                for x in (
                    self.u,
                    self.v,
                    self.a,
                    self.b,
                    self.c,
                    self.s,
                    self.surf_range,
                    self.pc,
                    self.index,
                    self.opacity,
                )
            )
        )


def project_particles(
    field: ParticleField,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    width: int,
    height: int,
    z_near: float = 0.05,
    margin_px: float = 0.0,
    blur=None,
) -> ProjectedParticles:
    """Project the particles that can touch the image (vectorised culling, float32).

    Keeps particles with Z > z_near, the camera outside the sphere, and the ellipse
    overlapping the image (1.5 px + ``margin_px`` margin: room for blur added later). With
    ``blur`` (``pipeline/particle_light.Blur``: defocus and motion streak) the footprints are the
    blurred ellipses, with their ``opacity``, and exactly those that meet the image are kept
    (``particle_kernels.project_blurred``; ``margin_px`` unused)."""
    T = np.asarray(T_world_cam, float)
    if T.shape != (4, 4):
        raise ValueError(f"T_world_cam must be 4x4, got {T.shape}")
    R = T[:3, :3].astype(np.float32)
    off = (-(T[:3, 3] @ T[:3, :3])).astype(np.float32)  # -R^T t
    xyz, radii, K32 = field.xyz, np.ascontiguousarray(field.radii, np.float32), np.asarray(K, np.float32)
    if blur is not None:
        idx, cols, surf_range, pc, op = kern.project_blurred(
            xyz,
            radii,
            R,
            off,
            K32,
            np.float32(z_near),
            blur.M,
            blur.o,
            blur.scale,
            blur.coc_k,
            blur.focus_m,
            int(width),
            int(height),
        )
        return ProjectedParticles(*cols, surf_range, pc, idx, op)
    idx, cols, surf_range, pc = kern.project(
        xyz, radii, R, off, K32, int(width), int(height), np.float32(z_near), np.float32(margin_px)
    )
    return ProjectedParticles(*cols, surf_range, pc, idx)


def _water_callable(water) -> Callable | None:
    """None | callable(rgb (M,3), range (M,)) -> (M,3) | {beta, colour} (article's blend)."""
    if water is None or callable(water):
        return water
    get = water.get if isinstance(water, Mapping) else (lambda key, d=None: getattr(water, key, d))
    beta = get("beta")
    colour = get("colour", get("color", get("water_colour")))
    if beta is None or colour is None:
        raise ValueError("water must be None, a callable (rgb, range) -> rgb, or have 'beta' and 'colour'")
    beta = np.broadcast_to(np.asarray(beta, np.float32), (3,))
    colour = np.broadcast_to(np.asarray(colour, np.float32), (3,))

    def blend(rgb, rng):
        w = 1.0 - np.exp(-beta[None, :] * rng[:, None])
        return rgb * (1.0 - w) + colour[None, :] * w

    return blend


def _particle_colour(mode: str, colour, ambient) -> np.ndarray:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if colour is not None:
        return np.broadcast_to(np.asarray(colour, np.float32), (3,)).copy()
    amb = np.broadcast_to(np.asarray(ambient, np.float32), (3,))
    return (amb if mode == "backscatter" else SILHOUETTE_ALBEDO * amb).astype(np.float32)


# fmt: off
def render_particles(image_linear: np.ndarray, range_m: np.ndarray, field: ParticleField,
                     K: np.ndarray, T_world_cam: np.ndarray, water=None, mode: str = "backscatter",
                     z_near: float = 0.05, colour=None, ambient=DEFAULT_AMBIENT_RGB,
                     shade: Callable | None = None, blur=None, margin_px: float = 0.0,
                     merged_range: bool = False, background=None):
    """Draw the particle field into a linear RGB image with a depth test.

    image_linear (H,W,3) float, range_m (H,W) float (range along each pixel ray to
    the rendered surface, inf or NaN = background). Returns (image_out (H,W,3) float32,
    occluder_mask (H,W) bool = particle coverage >= 0.5, particle_range (H,W)
    float32 = range of the nearest particle covering the pixel, inf elsewhere; with
    ``merged_range`` instead ``range_m`` as float32 with that range at the covered pixels).
    Inputs are not modified.

    Colour: ``shade(projected) -> (M, 3)`` linear radiance per particle (the physical
    light field: particle_optics.particle_radiance); else ``colour`` (3,) linear RGB, else
    "backscatter" = ``ambient`` (a bright speck lit by the veiling light) or "silhouette" =
    0.05 * ambient (dark). ``blur`` (particle_light.Blur, from particle_light.shaper): the
    footprints blurred by defocus and motion streaks (:func:`project_particles`); without it
    ``margin_px`` keeps particles up to that far outside the image.

    Compositing: coverage T = prod(1 - alpha_i) is exact and order-independent; with one
    colour ``out = img T + colour (1 - T)`` equals painter's "over". With per-particle
    colours the covered part takes the weighted mean colour, weights alpha_i / d_i^2
    (weighted blended order-independent transparency, McGuire & Bavoil 2013, JCGT 2(2)):
    exact where particles do not overlap, nearer ones dominate where they do.

    Water: particles must be attenuated by *their own* range, not the surface's.
    Either (a) pass ``image_linear`` already through the water model and give
    ``water`` -- a callable ``water(rgb (M,3), range (M,)) -> (M,3)`` or an object /
    mapping with ``beta`` (1/m, scalar or per RGB) and ``colour`` (the article's
    blend ``c (1-w) + colour w``, ``w = 1 - exp(-beta d)``) -- and each covered
    pixel gets the colour at its nearest particle's range. Or (b) keep ``water=None``
    on a clean image and apply water to ``image_out`` with the merged range
    ``np.where(particle_range < inf, particle_range, range_m)``. That is exact on partly
    covered pixels only with ``background`` (pipeline/particle_light.Transfer): the background's
    clean radiance is replaced by ``img gain + add`` so that, once the water model runs at the
    particle's range r_p, the pixel shows ``T L_bg + (1 - T) L_p`` with each layer seen through
    water at its own range. Without it a defocused disc's faint rim shows the background at the
    particle's range: a bright or dark ring. The compositing, mask and merged range are one
    compiled pass over the covered pixels (particle_kernels.resolve); with ``shade`` and no
    ``water`` (the pipeline's case) the splat, transfer and compositing are one pass, tile by
    tile (particle_splat.over: the same bytes, no per-pixel lists through memory).
    """
    img = np.asarray(image_linear, np.float32)
    h, w = img.shape[:2]
    if img.shape != (h, w, 3) or np.shape(range_m) != (h, w):
        raise ValueError(f"need image (H,W,3) and range_m (H,W), got {img.shape} and {np.shape(range_m)}")
    if not z_near > 0:
        raise ValueError(f"z_near must be > 0 m, got {z_near}")
    col = _particle_colour(mode, colour, ambient)
    water_fn = _water_callable(water)
    p = project_particles(field, K, T_world_cam, w, h, z_near, margin_px, blur)
    surf = np.ascontiguousarray(range_m, np.float32).reshape(-1)     # NaN = no surface hit = background
    colours = (np.asarray(shade(p), np.float32).reshape(-1, 3) if shade is not None
               else np.zeros((p.u.size, 0), np.float32))
    scene = surf if merged_range else np.full(h * w, np.inf, np.float32)
    if shade is not None and water_fn is None:              # the pipeline's case: one fused pass
        tp = background.packed() if background is not None else kern.NO_TRANSFER
        out, merged, mask = psplat.over(_splat_input(p, colours), surf, scene, img.reshape(-1), tp, w, h)
        return out.reshape(h, w, 3), mask.reshape(h, w), merged.reshape(h, w)
    sums = psplat.splat(_splat_input(p, colours), surf, w, h)
    hit = sums.hit
    colour_px = col[:, None] if shade is None else np.zeros((3, 0), np.float32)   # (3, 0): w c / w
    if water_fn is not None:
        wc = sums.wc
        c = wc[1:] / np.where(wc[0] > 0, wc[0], np.float32(1.0)) if shade is not None \
            else np.broadcast_to(col[:, None], (3, hit.size))
        colour_px = np.ascontiguousarray(
            np.asarray(water_fn(np.ascontiguousarray(c.T), sums.near), np.float32).T)
    out, merged, mask = np.empty_like(img), np.empty(h * w, np.float32), np.zeros(h * w, bool)
    gain_add = background.gain_add(hit, sums.near, sums.far, w) if background is not None and hit.size \
        else np.zeros((6, 0), np.float32)
    kern.resolve(out.reshape(-1), np.ascontiguousarray(img).reshape(-1), merged, scene, mask, hit, sums.acc,
                 sums.near, colour_px, gain_add, w)
    return out, mask.reshape(h, w), merged.reshape(h, w)
# fmt: on


def _splat_input(p: ProjectedParticles, colours: np.ndarray) -> psplat.Particles:
    op = p.opacity if p.opacity is not None else np.ones(p.u.size, np.float32)
    return psplat.Particles(p.u, p.v, p.a, p.b, p.c, p.s, p.surf_range, op, colours)


# ----------------------------------------------------------------------------- visibility
def visible_fraction_from_masks(marker_mask: np.ndarray, occluder_mask: np.ndarray, expected_area_px: float) -> float:
    """Share of a marker left visible: |marker & ~occluder| / expected area, in [0, 1].

    expected_area_px is the marker's unoccluded projected area (px); 0 -> 0.0."""
    if not (math.isfinite(expected_area_px) and expected_area_px >= 0):
        raise ValueError(f"expected_area_px must be finite and >= 0, got {expected_area_px}")
    if np.shape(marker_mask) != np.shape(occluder_mask):
        raise ValueError(f"mask shapes differ: {np.shape(marker_mask)} vs {np.shape(occluder_mask)}")
    if expected_area_px == 0:
        return 0.0
    seen = np.count_nonzero(np.asarray(marker_mask, bool) & ~np.asarray(occluder_mask, bool))
    return float(min(1.0, seen / expected_area_px))


def led_visible_fraction(led_pixels, index_image: np.ndarray, led_index_values, occluder_mask: np.ndarray) -> float:
    """Share of LEDs whose centre pixel (u, v) is inside the image, shows an LED
    (index_image value in ``led_index_values``) and is not occluded."""
    uv = np.rint(np.asarray(led_pixels, float)).reshape(-1, 2)
    if uv.shape[0] == 0:
        raise ValueError("led_pixels must hold at least one LED centre (N,2)")
    if np.shape(index_image) != np.shape(occluder_mask):
        raise ValueError(f"shapes differ: {np.shape(index_image)} vs {np.shape(occluder_mask)}")
    h, w = np.shape(index_image)
    ok = np.all(np.isfinite(uv), axis=1)
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    u, v = uv[ok, 0].astype(int), uv[ok, 1].astype(int)
    seen = (
        np.isin(np.asarray(index_image)[v, u], np.atleast_1d(led_index_values)) & ~np.asarray(occluder_mask, bool)[v, u]
    )
    return float(np.count_nonzero(seen)) / uv.shape[0]
