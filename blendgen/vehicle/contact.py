"""Contact between the vehicle's hull and the dock (pure numpy; exact distances).

Dock frame (as in :mod:`blendgen.vehicle.docking`): origin at the centre of the marker face,
+z out of the face toward the approaching vehicle, +y up, +x right seen from in front.

The dock (:class:`DockSolid`) is the body box of the dock model, ``|x| <= w/2``, ``|y| <= h/2``,
``-depth <= z <= 0`` (``Dock.body_size_m`` = (w, h, depth)), with a conical funnel cut through it:
its mouth is the face's inscribed circle (radius ``min(w, h) / 2``, the same circle the capture
radius is taken from) at z = 0, narrowing over the body's depth to a throat that fits the hull
(radius = hull radius) at z = -depth. For the default 1 x 1 x 0.4 m dock and the 0.191 m REMUS
hull the cone's half-angle is atan((0.5 - 0.0955) / 0.4) = 45.3 deg. The rendered dock draws the
face and the box, not the funnel's inside; these are the dimensions of the dock model, not of a
measured dock. Parts: ``face_plate`` (z = 0 outside the mouth), ``funnel`` (the cone),
``rim`` (the mouth's edge, where plate and cone meet), ``side`` (the box's four sides, the frame
hit from the side), ``back`` (z = -depth outside the throat).

The hull (:class:`Hull`) is a capsule: the vehicle's length tip to tip (``VehicleParams.length``,
1.33 m) and diameter (0.191 m, Prestero 2001), centred on the body origin along body +x. Its
distance to the dock is the smallest distance from the capsule's axis segment to the dock's
surface minus the hull radius (negative = penetration); the distance to each part is exact (plane
regions by clamping, the cone in its meridian half-plane), the segment is sampled every
``<= 2 cm`` and the best sample refined (bounded Brent, 1e-7 m tolerance).

The water around them (:class:`WaterSolid`) is an axis-aligned box in the world frame (metres,
+z up) of which some faces are solid: a pool's four walls (``pool_wall``) and its floor
(``pool_floor``); in open water only the seabed (``seabed``: the domain's sides are not walls).
The water surface (the box's top) is never a collision. The hull's clearance to a face plane is
exact: the distance from a line segment to a plane is smallest at one of its ends, so it is the
smaller of the two axis ends' inward distances minus the hull radius (:func:`water_contact`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DOCK_PARTS = ("face_plate", "funnel", "side", "back", "rim")
WATER_PARTS = ("pool_wall", "pool_floor", "seabed")
PARTS = DOCK_PARTS + WATER_PARTS  # every ``contact_part`` a collision can name


@dataclass(frozen=True)
class DockSolid:
    """Dock body box with a conical funnel through it (module doc); metres."""

    half_w: float
    half_h: float
    depth: float
    mouth_r: float
    throat_r: float

    def __post_init__(self):
        if not (0 < self.throat_r <= self.mouth_r <= min(self.half_w, self.half_h) and self.depth > 0):
            raise ValueError(
                f"dock solid: need 0 < throat_r ({self.throat_r}) <= mouth_r ({self.mouth_r}) <= "
                f"min(w, h)/2 ({min(self.half_w, self.half_h)}) and depth > 0 ({self.depth}) m"
            )

    @classmethod
    def from_dock(cls, body_size_m, hull_radius_m: float) -> DockSolid:
        """From the dock model's (w, h, depth) (m) and the hull radius (m): module doc."""
        w, h, d = (float(v) for v in body_size_m)
        return cls(w / 2, h / 2, d, min(w, h) / 2, hull_radius_m)


@dataclass(frozen=True)
class Hull:
    """Capsule hull along body +x, centred on the body origin: ``half_axis`` (m) from the origin to
    each end of the axis segment, ``radius`` (m). Tip to tip: 2 (half_axis + radius)."""

    half_axis: float
    radius: float

    @classmethod
    def from_vehicle(cls, length_m: float, diameter_m: float) -> Hull:
        """From the vehicle's length (tip to tip) and diameter (m)."""
        r = diameter_m / 2
        if length_m < diameter_m or r <= 0:
            raise ValueError(f"hull: need length ({length_m} m) >= diameter ({diameter_m} m) > 0")
        return cls(length_m / 2 - r, r)

    def axis_points(self, T_dock_body: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Points (N,3) of the axis segment at body x = ``s`` (N,) m, in the dock frame."""
        T = np.asarray(T_dock_body, float)
        return T[:3, 3] + np.outer(np.asarray(s, float), T[:3, 0])


@dataclass(frozen=True)
class Contact:
    """Closest approach of hull and dock: ``clearance_m`` (distance surface to surface; negative =
    penetration), ``part`` (:data:`PARTS`), ``point_dock`` (3,) the dock surface point,
    ``normal`` (3,) unit outward normal of the dock there (toward the hull), ``axis_x_m`` the body
    x of the hull's axis point closest to it."""

    clearance_m: float
    part: str
    point_dock: np.ndarray
    normal: np.ndarray
    axis_x_m: float


def _plate(p: np.ndarray, z0: float, hw: float, hh: float, hole_r: float):
    """Nearest points (N,3) on the plane region z = z0, |x| <= hw, |y| <= hh, outside the disc
    of radius ``hole_r`` (which lies inside the rectangle)."""
    x, y = p[:, 0], p[:, 1]
    rho = np.hypot(x, y)
    cx, cy = np.clip(x, -hw, hw), np.clip(y, -hh, hh)
    inside = rho < hole_r
    scale = hole_r / np.maximum(rho, 1e-12)
    qx = np.where(inside, np.where(rho > 1e-12, x * scale, hole_r), cx)
    qy = np.where(inside, y * scale, cy)
    return np.column_stack([qx, qy, np.full(len(p), z0)])


def _cone(p: np.ndarray, solid: DockSolid):
    """Nearest points (N,3) on the funnel cone: the meridian segment (mouth_r, 0) -> (throat_r,
    -depth) turned about the z axis (a surface of revolution: exact in the meridian plane)."""
    rho = np.hypot(p[:, 0], p[:, 1])
    a = np.array([solid.mouth_r, 0.0])
    b = np.array([solid.throat_r, -solid.depth])
    ab = b - a
    t = np.clip(((rho - a[0]) * ab[0] + (p[:, 2] - a[1]) * ab[1]) / (ab @ ab), 0.0, 1.0)
    qr, qz = a[0] + t * ab[0], a[1] + t * ab[1]
    safe = rho > 1e-12
    ux = np.where(safe, p[:, 0] / np.where(safe, rho, 1.0), 1.0)
    uy = np.where(safe, p[:, 1] / np.where(safe, rho, 1.0), 0.0)
    return np.column_stack([qr * ux, qr * uy, qz])


def _sides(p: np.ndarray, solid: DockSolid) -> list[np.ndarray]:
    """Nearest points on the four side rectangles of the box (x = +-hw, y = +-hh; -depth <= z <= 0)."""
    hw, hh, d = solid.half_w, solid.half_h, solid.depth
    z = np.clip(p[:, 2], -d, 0.0)
    out = []
    for sx in (-hw, hw):
        out.append(np.column_stack([np.full(len(p), sx), np.clip(p[:, 1], -hh, hh), z]))
    for sy in (-hh, hh):
        out.append(np.column_stack([np.clip(p[:, 0], -hw, hw), np.full(len(p), sy), z]))
    return out


def _inside(p: np.ndarray, solid: DockSolid) -> np.ndarray:
    """(N,) bool: point inside the dock's material (in the box, outside the funnel's cavity)."""
    z = p[:, 2]
    in_box = (np.abs(p[:, 0]) <= solid.half_w) & (np.abs(p[:, 1]) <= solid.half_h) & (z <= 0) & (z >= -solid.depth)
    cavity_r = solid.mouth_r + (solid.mouth_r - solid.throat_r) * z / solid.depth
    return in_box & (np.hypot(p[:, 0], p[:, 1]) >= cavity_r)


def surface_distance(p: np.ndarray, solid: DockSolid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distance (N,) from points ``p`` (N,3) (dock frame, m) to the dock's surface (negative
    inside its material), the nearest surface points (N,3) and the part index (N,) into :data:`DOCK_PARTS`."""
    p = np.atleast_2d(np.asarray(p, float))
    cands = [
        (0, _plate(p, 0.0, solid.half_w, solid.half_h, solid.mouth_r)),
        (1, _cone(p, solid)),
        *((2, q) for q in _sides(p, solid)),
        (3, _plate(p, -solid.depth, solid.half_w, solid.half_h, solid.throat_r)),
    ]
    dist = np.stack([np.linalg.norm(p - q, axis=1) for _, q in cands])  # (parts, N)
    best = np.argmin(dist, axis=0)
    idx = np.arange(len(p))
    q = np.stack([c for _, c in cands])[best, idx]
    part = np.array([k for k, _ in cands])[best]
    d = dist[best, idx]
    return np.where(_inside(p, solid), -d, d), q, part


_NORMALS = {0: (0.0, 0.0, 1.0), 3: (0.0, 0.0, -1.0)}


def _normal(p: np.ndarray, q: np.ndarray, d: float, part: int, solid: DockSolid) -> np.ndarray:
    """Unit outward normal of the dock at ``q`` toward the hull axis point ``p``."""
    if abs(d) > 1e-9:
        n = (p - q) / d  # d < 0 (inside) flips p - q outward
        return n / np.linalg.norm(n)
    if part in _NORMALS:
        return np.array(_NORMALS[part])
    if part == 1:  # cone: inward to the axis and out of the face
        rho = max(math.hypot(q[0], q[1]), 1e-12)
        n = np.array([-q[0] / rho * solid.depth, -q[1] / rho * solid.depth, solid.mouth_r - solid.throat_r])
        return n / np.linalg.norm(n)
    big = np.abs(q[:2] / np.array([solid.half_w, solid.half_h]))
    k = int(np.argmax(big))
    n = np.zeros(3)
    n[k] = math.copysign(1.0, q[k])
    return n


def hull_contact(solid: DockSolid, hull: Hull, T_dock_body: np.ndarray) -> Contact:
    """Closest approach of the hull at pose ``T_dock_body`` (4x4, body FLU in the dock frame) to the
    dock: sample the axis every <= 2 cm, refine the best sample (bounded Brent)."""
    from scipy.optimize import minimize_scalar

    n = max(3, int(math.ceil(2 * hull.half_axis / 0.02)) + 1)
    s = np.linspace(-hull.half_axis, hull.half_axis, n)
    d, _, _ = surface_distance(hull.axis_points(T_dock_body, s), solid)
    i = int(np.argmin(d))
    lo, hi = s[max(i - 1, 0)], s[min(i + 1, n - 1)]

    def f(x: float) -> float:
        return float(surface_distance(hull.axis_points(T_dock_body, np.array([x])), solid)[0][0])

    x = float(minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-7}).x)
    x = x if f(x) <= d[i] else float(s[i])
    p = hull.axis_points(T_dock_body, np.array([x]))
    dd, q, part = surface_distance(p, solid)
    normal = _normal(p[0], q[0], float(dd[0]), int(part[0]), solid)
    on_rim = abs(q[0][2]) < 1e-9 and abs(math.hypot(q[0][0], q[0][1]) - solid.mouth_r) < 1e-9
    return Contact(float(dd[0]) - hull.radius, "rim" if on_rim else DOCK_PARTS[int(part[0])], q[0], normal, x)


@dataclass(frozen=True)
class WaterSolid:
    """The water's solid boundary (module doc): the box ``lo`` .. ``hi`` (world frame, m, +z up)
    and its solid ``faces``, each (axis 0/1/2 = x/y/z, side -1 = the ``lo`` plane or +1 = the
    ``hi`` plane, part name in :data:`WATER_PARTS`). The top (z = ``hi[2]``, the surface) is
    never solid."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    faces: tuple[tuple[int, int, str], ...]

    def __post_init__(self):
        if not all(a < b for a, b in zip(self.lo, self.hi)):
            raise ValueError(f"water box: need lo < hi on every axis, got lo {self.lo}, hi {self.hi} m")
        for axis, side, part in self.faces:
            if axis not in (0, 1, 2) or side not in (-1, 1) or part not in WATER_PARTS or (axis, side) == (2, 1):
                raise ValueError(f"water box: bad face ({axis}, {side}, {part!r}); the surface is never solid")

    @classmethod
    def pool(cls, lo, hi) -> WaterSolid:
        """A pool: the four walls (x = lo/hi, y = lo/hi) and the floor (z = lo) are solid."""
        walls = tuple((k, s, "pool_wall") for k in (0, 1) for s in (-1, 1))
        return cls(_vec3(lo), _vec3(hi), (*walls, (2, -1, "pool_floor")))

    @classmethod
    def open_water(cls, lo, hi) -> WaterSolid:
        """Open water: only the seabed (z = lo) is solid; the domain's sides are not walls."""
        return cls(_vec3(lo), _vec3(hi), ((2, -1, "seabed"),))


def _vec3(v) -> tuple[float, float, float]:
    x, y, z = (float(c) for c in v)
    return (x, y, z)


@dataclass(frozen=True)
class WaterContact:
    """Closest approach of the hull to the water's solid faces: ``clearance_m`` (surface to face;
    negative = penetration), ``part`` (:data:`WATER_PARTS`), ``point_world`` (3,) the face point
    nearest the hull (world, m), ``normal`` (3,) the face's unit normal into the water (toward the
    hull), ``axis_x_m`` the body x of the hull's axis point nearest the face (+-half axis at an
    end; 0 when the axis is parallel to the face)."""

    clearance_m: float
    part: str
    point_world: np.ndarray
    normal: np.ndarray
    axis_x_m: float


def water_contact(water: WaterSolid, hull: Hull, T_world_body: np.ndarray) -> WaterContact:
    """Closest approach of the hull at pose ``T_world_body`` (4x4, body FLU in the world frame,
    +z up) to the solid faces of ``water``: exact (module doc). Clearance to a face = min over
    the axis ends of their distance inside its plane - hull radius."""
    T = np.asarray(T_world_body, float)
    o, ax = T[:3, 3], T[:3, 0]
    ends = np.array([-hull.half_axis, hull.half_axis])
    best = None
    for axis, side, part in water.faces:
        plane = water.hi[axis] if side > 0 else water.lo[axis]
        inward = -side * ((o[axis] + ends * ax[axis]) - plane)  # (2,) distance inside the water, m
        d = float(inward.min())
        if best is None or d < best[0]:
            x = 0.0 if abs(inward[0] - inward[1]) < 1e-12 else float(ends[int(np.argmin(inward))])
            best = (d, axis, side, part, x)
    if best is None:
        return WaterContact(math.inf, "", np.full(3, math.nan), np.zeros(3), 0.0)
    d, axis, side, part, x = best
    normal = np.zeros(3)
    normal[axis] = -float(side)
    point = o + x * ax
    point[axis] = water.hi[axis] if side > 0 else water.lo[axis]
    return WaterContact(d - hull.radius, part, point, normal, x)


def impact_speed(
    contact: Contact | WaterContact, hull: Hull, v_dock: np.ndarray, omega_dock: np.ndarray, T_dock_body
) -> float:
    """Speed (m/s) of the hull's contact point into the dock along the dock's outward normal:
    -(v + omega x r) . n, with ``v_dock`` (3,) the body origin's velocity and ``omega_dock`` (3,) the
    angular velocity (rad/s), both in the dock frame; r from the body origin to the hull's surface
    point facing the dock (axis point - radius x normal). A :class:`WaterContact` works the same
    way in the world frame (``v_dock``, ``omega_dock``, ``T_dock_body`` world-frame): the speed
    into the wall or floor along its normal into the water."""
    T = np.asarray(T_dock_body, float)
    axis_pt = T[:3, 3] + contact.axis_x_m * T[:3, 0]
    r = axis_pt - hull.radius * contact.normal - T[:3, 3]
    v = np.asarray(v_dock, float) + np.cross(np.asarray(omega_dock, float), r)
    return float(-(v @ contact.normal))


__all__ = [
    "PARTS",
    "DOCK_PARTS",
    "WATER_PARTS",
    "DockSolid",
    "Hull",
    "Contact",
    "WaterSolid",
    "WaterContact",
    "surface_distance",
    "hull_contact",
    "water_contact",
    "impact_speed",
]
