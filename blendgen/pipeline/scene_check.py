"""Scenes that exist: the dock, every camera path and every docking start inside the water.

The water is a box (world frame, metres, z up): a pool's walls and floor, or the open-water
domain (``OPEN_WATER_HALF_M`` around the dock, down to ``scene.world.seabed_depth_m``), up to
the water surface. In ``physical`` mode each condition's surface sits
``dock_water_depth_m`` above the dock's top, so the box's top is the lowest of them (the
camera must be under water in every condition); in ``article`` mode a depth condition only
dims the light and the surface is the scene's, z = 0. Each check names the config key, how
far out the scene is, and the key's allowed range (a rigid shift of the points along the
key's direction, exact for linear and circle paths and for start boxes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from blendgen.config.models import ConfigError, Experiment
from blendgen.vehicle import trajectories as tj
from blendgen.vehicle.contact import WaterSolid
from datasets_spec.io import BOUNDARY_ENDS

#: Half side (m) of the open-water domain around the dock (the reference medium's box).
OPEN_WATER_HALF_M = 60.0


@dataclass(frozen=True)
class WaterBox:
    """Axis-aligned water volume: ``lo``, ``hi`` (3,) world metres; ``what`` names it."""

    lo: np.ndarray
    hi: np.ndarray
    what: str


def surface_z(exp: Experiment) -> float:
    """World z of the lowest water surface over the conditions (see module doc)."""
    if exp.image_formation != "physical":
        return 0.0
    base = exp.scene.dock.water_depth_m
    depths = [c.dock_water_depth_m if c.dock_water_depth_m is not None else base for c in exp.conditions]
    return -base + min(depths)


def water_box(exp: Experiment) -> WaterBox:
    """The water volume every camera pose, the dock and the docking starts must lie in."""
    s, top = exp.scene, surface_z(exp)
    if s.kind == "pool":
        p = s.pool
        return WaterBox(
            np.array([-p.length_m / 2, -p.width_m / 2, -p.depth_m]),
            np.array([p.length_m / 2, p.width_m / 2, top]),
            "pool",
        )
    x, y = s.dock.position_xy_m
    h = OPEN_WATER_HALF_M
    return WaterBox(
        np.array([x - h, y - h, -s.world.seabed_depth_m]), np.array([x + h, y + h, top]), "open-water domain"
    )


def water_solid(exp: Experiment) -> WaterSolid:
    """:func:`water_box` as the closed loop's collision geometry (world frame, +z up, m): a pool's
    four walls and floor are solid, open water's seabed alone (the domain's sides are not walls);
    the surface never is (:class:`blendgen.vehicle.contact.WaterSolid`)."""
    box = water_box(exp)
    return (WaterSolid.pool if exp.scene.kind == "pool" else WaterSolid.open_water)(box.lo, box.hi)


def shift_range(points: np.ndarray, direction, box: WaterBox) -> tuple[float, float] | None:
    """(t_min, t_max): the shifts ``t`` along unit ``direction`` (3,) that keep every point
    (N, 3) inside ``box``; None when no shift does."""
    d = np.asarray(direction, float)
    lo, hi = -np.inf, np.inf
    for k in range(3):
        p = points[:, k]
        if abs(d[k]) < 1e-12:
            if np.any(p < box.lo[k] - 1e-9) or np.any(p > box.hi[k] + 1e-9):
                return None
            continue
        a, b = (box.lo[k] - p) / d[k], (box.hi[k] - p) / d[k]
        lo, hi = max(lo, float(np.max(np.minimum(a, b)))), min(hi, float(np.min(np.maximum(a, b))))
    return (lo, hi) if lo <= hi + 1e-9 else None


def where_out(p: np.ndarray, box: WaterBox) -> tuple[str, float]:
    """(what the point (3,) is beyond, by how many metres); ('', 0) inside the box."""
    over = [
        (p[2] - box.hi[2], "above the water surface"),
        (box.lo[2] - p[2], f"below the {box.what}'s floor" if box.what == "pool" else "below the seabed"),
    ]
    side = float(max(np.max(box.lo[:2] - p[:2]), np.max(p[:2] - box.hi[:2])))
    over.append((side, "outside the pool's walls" if box.what == "pool" else "outside the open-water domain"))
    d, what = max(over)
    return (what, float(d)) if d > 1e-9 else ("", 0.0)


def _first_out(points: np.ndarray, box: WaterBox) -> tuple[int, str, float] | None:
    """Index, place and distance of the first point outside ``box``; None when all are in."""
    for i, p in enumerate(points):
        what, d = where_out(p, box)
        if what:
            return i, what, d
    return None


def _allowed(name: str, value: float, rng: tuple[float, float] | None, floor: float | None = None) -> str:
    """``allowed lo <= name <= hi`` for a key whose shift range is ``rng``."""
    if rng is None:
        return f"no {name} fits (move the dock or the camera mount)"
    lo, hi = value + rng[0], value + rng[1]
    if floor is not None:
        lo = max(lo, floor)
    return f"allowed {lo:.2f} <= {name} <= {hi:.2f}" if lo <= hi else f"no {name} fits"


def check_dock(exp: Experiment, T_wd: np.ndarray, box: WaterBox) -> None:
    """The dock's body and markers (``trajectories.dock_corners``) inside the water."""
    pts = (np.c_[tj.dock_corners(exp.scene.dock), np.ones(8)] @ T_wd.T)[:, :3]
    bad = _first_out(pts, box)
    if bad is None:
        return
    _, what, d = bad
    dock = exp.scene.dock
    if what.startswith("below"):
        rng = shift_range(pts, [0, 0, -1.0], box)
        raise ConfigError(
            f"scene.dock.water_depth_m: {dock.water_depth_m:g} puts the dock {d:.2f} m {what}; "
            f"{_allowed('water_depth_m', dock.water_depth_m, rng, 0.0)}"
        )
    raise ConfigError(
        f"scene.dock.position_xy_m: {list(dock.position_xy_m)} puts the dock {d:.2f} m {what} "
        f"(x in [{box.lo[0]:g}, {box.hi[0]:g}], y in [{box.lo[1]:g}, {box.hi[1]:g}])"
    )


def check_surfaces(exp: Experiment) -> None:
    """Physical mode: no condition's surface above the pool's rim (z = 0), where the walls end."""
    if exp.image_formation != "physical" or exp.scene.kind != "pool":
        return
    base = exp.scene.dock.water_depth_m
    for i, c in enumerate(exp.conditions):
        if c.dock_water_depth_m is not None and c.dock_water_depth_m > base + 1e-9:
            raise ConfigError(
                f"conditions[{i}].dock_water_depth_m: {c.dock_water_depth_m:g} puts the water "
                f"surface {c.dock_water_depth_m - base:.2f} m above the pool's rim (a depth "
                "condition moves the surface, not the dock); allowed <= scene.dock.water_depth_m "
                f"({base:g}): put the dock at the deepest condition"
            )


def check_scene(exp: Experiment) -> None:
    """Raise ConfigError (one line: the key, how far out, the allowed range) when the dock,
    a kinematic camera path or a docking start box is not inside the water, or (physical
    mode) a condition's surface is above the pool's rim."""
    check_surfaces(exp)
    T_wd = tj.T_world_dock_from_spec(exp.scene.dock)
    T_bc = tj.T_body_cam_from_spec(exp.camera.T_body_cam)
    box = water_box(exp)
    check_dock(exp, T_wd, box)
    for i, traj in enumerate(exp.trajectories):
        if traj.kind == "docking":
            check_start_box(i, traj, T_wd, box)
        else:
            smp = tj.sample(traj, T_wd, exp.camera.fps, exp.camera.latency_s, seed=0, fluid=exp.fluid)
            check_camera_path(exp, i, traj, (smp.T_world_body @ T_bc)[:, :3, 3], T_wd, box)


def check_camera_path(exp: Experiment, i: int, traj, cams: np.ndarray, T_wd: np.ndarray, box: WaterBox) -> None:
    """Every camera centre (N, 3) of kinematic path ``trajectories[i]`` inside the water."""
    bad = _first_out(cams, box)
    if bad is None:
        return
    k, what, d = bad
    x_d, z_d = T_wd[:3, 0], T_wd[:3, 2]
    if what.startswith(("above", "below")):
        name = "vertical_m" if traj.kind == "linear" else "height_m"
        value, rng = getattr(traj, name), shift_range(cams, [0, 0, 1.0], box)
    elif (
        traj.kind == "linear"
        and shift_range(cams[-1:], z_d, box) is not None
        and shift_range(cams[:1], z_d, box) is not None
    ):
        name, value = "start_range_m", traj.start_range_m
        t = shift_range(cams[:1], z_d, box)
        rng = (traj.end_range_m - value, t[1])
    elif traj.kind == "linear":
        name, value, rng = "lateral_m", traj.lateral_m, shift_range(cams, x_d, box)
    else:
        name, value = "radius_m", traj.radius_m
        rng = (0.05 - value, _largest_radius(traj, cams, T_wd, box) - value)
    raise ConfigError(
        f"trajectories[{i}].{name}: {value:g} puts the camera {d:.2f} m {what} at "
        f"t = {k / exp.camera.fps:.2f} s ({traj.id!r}); {_allowed(name, value, rng)}"
    )


def _largest_radius(traj, cams: np.ndarray, T_wd: np.ndarray, box: WaterBox) -> float:
    """Largest circle radius (m) whose camera centres stay inside ``box`` (bisection; the
    points move radially from the dock's face centre, inside the convex box)."""
    centre = T_wd[:3, 3] + np.array([0.0, 0.0, traj.height_m])
    rel = (cams - centre) / traj.radius_m
    lo, hi = 0.0, traj.radius_m
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if _first_out(centre + mid * rel, box) is None else (lo, mid)
    return lo


def check_start_box(i: int, traj, T_wd: np.ndarray, box: WaterBox) -> None:
    """The corners of a docking trial's random start box (vehicle position: range along the
    dock normal, lateral, vertical) inside the water."""
    st = traj.start
    o, x_d, y_d, z_d = T_wd[:3, 3], T_wd[:3, 0], T_wd[:3, 1], T_wd[:3, 2]
    corners = {
        (r, a, v): o + r * z_d + a * x_d + v * y_d
        for r in st.range_m
        for a in (-st.lateral_m, st.lateral_m)
        for v in (-st.vertical_m, st.vertical_m)
    }
    pts = np.array(list(corners.values()))
    bad = _first_out(pts, box)
    if bad is None:
        return
    _, what, d = bad
    flat = np.array([o + r * z_d + a * x_d for r in st.range_m for a in (-st.lateral_m, st.lateral_m)])
    if what.startswith(("above", "below")):
        rng = shift_range(flat, y_d, box)
        name, value, hi = "vertical_m", st.vertical_m, None if rng is None else min(rng[1], -rng[0])
    elif (
        shift_range(np.array([o + r * z_d for r in st.range_m]), x_d, box) is not None
        and _first_out(np.array([o + r * z_d for r in st.range_m]), box) is None
    ):
        rng = shift_range(np.array([o + r * z_d for r in st.range_m]), x_d, box)
        name, value, hi = "lateral_m", st.lateral_m, min(rng[1], -rng[0])
    else:
        near = np.array(
            [
                o + st.range_m[0] * z_d + a * x_d + v * y_d
                for a in (-st.lateral_m, st.lateral_m)
                for v in (-st.vertical_m, st.vertical_m)
            ]
        )
        rng = shift_range(near, z_d, box)
        name, value = "range_m", st.range_m[1]
        hi = None if rng is None else st.range_m[0] + rng[1]
    allowed = f"no {name} fits" if hi is None or hi < 0 else f"allowed {name} <= {hi:.2f}"
    raise ConfigError(
        f"trajectories[{i}].start.{name}: {value if name != 'range_m' else list(st.range_m)} "
        f"puts a start {d:.2f} m {what} ({traj.id!r}); {allowed}"
    )


def check_frames(
    exp: Experiment,
    traj_index: int,
    trial: int | None,
    frames: list[dict],
    end: str = "path",
    nearest_m: float | None = None,
) -> None:
    """A sequence must have frames, and every camera pose inside the water (``trial`` None: a
    kinematic path, the same for every trial; ``end``: how the path ends, a boundary part
    when the hull touches the water's walls, floor or seabed; ``nearest_m`` the path's nearest
    camera distance to the dock before contact, for the message)."""
    traj = exp.trajectories[traj_index]
    which = f"{traj.id!r}" + ("" if trial is None else f" trial {trial}")
    if not frames and end in BOUNDARY_ENDS:
        raise ConfigError(
            f"trajectories[{traj_index}].start: {which} starts with the vehicle's hull touching the "
            f"{end.replace('_', ' ')}, so it has no frame; narrow the start ranges"
        )
    if not frames:
        d = exp.render.max_distance_m
        raise ConfigError(
            f"render.max_distance_m: {d:g} leaves trajectories[{traj_index}] ({which}) no frame "
            "(no camera pose that close to the dock before contact); allowed: "
            + (
                "above the path's nearest camera distance"
                if nearest_m is None
                else f"max_distance_m >= {nearest_m:.2f}"
            )
        )
    cams = np.array([np.asarray(f["T_world_cam"])[:3, 3] for f in frames])
    bad = _first_out(cams, water_box(exp))
    if bad is not None:
        k, what, dist = bad
        raise ConfigError(
            f"trajectories[{traj_index}].start: {which} brings the camera "
            f"{dist:.2f} m {what} at t = {frames[k]['t']:.2f} s; narrow the start ranges"
        )
