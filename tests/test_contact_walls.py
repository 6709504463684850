"""The pool's walls and floor (and open water's seabed) as obstacles to the hull: hand-computed
clearances, the closed loop's use of them (world z up vs NED inside), the tools layer's water box,
and the after-the-fact clearance of a run's frames."""

import math

import numpy as np
import pandas as pd
import pytest

from blendgen.vehicle.contact import PARTS, WATER_PARTS, Hull, WaterSolid, impact_speed, water_contact

R = 0.191 / 2  # REMUS hull radius (m)
HULL = Hull.from_vehicle(1.33, 0.191)
A = HULL.half_axis  # 0.665 - R = 0.5695 m
POOL = WaterSolid.pool((-7.5, -2.5, -8.0), (7.5, 2.5, 0.0))  # the paper pool, 15 x 5 x 8 m
OPEN = WaterSolid.open_water((-53.0, -60.0, -12.0), (67.0, 60.0, 0.0))  # +-60 m around the dock, seabed 12 m


def pose(origin, yaw_deg=0.0, pitch_up_deg=0.0):
    """T_world_body (world +z up, body FLU): body x at ``yaw_deg`` from world +x toward +y, nose
    ``pitch_up_deg`` above the horizontal."""
    y, p = math.radians(yaw_deg), math.radians(pitch_up_deg)
    x = np.array([math.cos(y) * math.cos(p), math.sin(y) * math.cos(p), math.sin(p)])
    left = np.array([-math.sin(y), math.cos(y), 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, left, np.cross(x, left)])
    T[:3, 3] = origin
    return T


def test_the_water_parts_are_contact_parts_and_the_surface_is_never_solid():
    assert set(WATER_PARTS) == {"pool_wall", "pool_floor", "seabed"} and set(WATER_PARTS) <= set(PARTS)
    assert [f[2] for f in POOL.faces] == ["pool_wall"] * 4 + ["pool_floor"]
    assert OPEN.faces == ((2, -1, "seabed"),)
    with pytest.raises(ValueError, match="surface is never solid"):
        WaterSolid((0, 0, -1), (1, 1, 0), ((2, 1, "pool_floor"),))
    with pytest.raises(ValueError, match="lo < hi"):
        WaterSolid.pool((0, 0, 0), (1, 1, -1))
    # a hull poking out of the surface is no contact: only the walls and floor count
    c = water_contact(POOL, HULL, pose([0.0, 0.0, 0.05], pitch_up_deg=60.0))
    assert c.clearance_m > 2.0


def test_capsule_parallel_to_a_wall():
    # along +x, 0.3 m from the wall y = 2.5: every axis point is 0.3 m off, the hull 0.3 - R
    c = water_contact(POOL, HULL, pose([1.0, 2.2, -1.5]))
    assert c.part == "pool_wall" and c.clearance_m == pytest.approx(0.3 - R, abs=1e-12)
    assert c.normal == pytest.approx([0.0, -1.0, 0.0]) and c.axis_x_m == 0.0
    assert c.point_world == pytest.approx([1.0, 2.5, -1.5])


def test_capsule_tilted_toward_a_wall_is_nearest_at_its_front_end():
    # yawed 30 deg toward the wall y = 2.5, origin 0.6 m from it: the front axis end is
    # A sin 30 closer, 0.6 - 0.28475 = 0.31525 m from the plane
    c = water_contact(POOL, HULL, pose([1.0, 1.9, -1.5], yaw_deg=30.0))
    assert c.part == "pool_wall" and c.clearance_m == pytest.approx(0.6 - A * 0.5 - R, abs=1e-12)
    assert c.axis_x_m == pytest.approx(A)
    assert c.point_world == pytest.approx([1.0 + A * math.cos(math.radians(30)), 2.5, -1.5])
    # the same yaw toward the opposite wall y = -2.5 puts the rear end nearest
    c = water_contact(POOL, HULL, pose([1.0, -1.9, -1.5], yaw_deg=30.0))
    assert c.clearance_m == pytest.approx(0.6 - A * 0.5 - R, abs=1e-12) and c.axis_x_m == pytest.approx(-A)
    assert c.normal == pytest.approx([0.0, 1.0, 0.0])
    # toward the end wall x = 7.5 head on: 7.5 - 6.5 - A - R
    c = water_contact(POOL, HULL, pose([6.5, 0.0, -1.5]))
    assert c.clearance_m == pytest.approx(1.0 - A - R, abs=1e-12) and c.normal == pytest.approx([-1.0, 0.0, 0.0])


def test_capsule_nose_down_over_the_floor():
    # 0.5 m above the floor z = -8, nose 20 deg down: the front end is A sin 20 lower
    c = water_contact(POOL, HULL, pose([0.0, 0.0, -7.5], pitch_up_deg=-20.0))
    assert c.part == "pool_floor" and c.clearance_m == pytest.approx(0.5 - A * math.sin(math.radians(20)) - R)
    assert c.normal == pytest.approx([0.0, 0.0, 1.0]) and c.point_world[2] == -8.0


def test_a_miss_by_1_mm_and_a_touch_by_1_mm():
    for gap in (0.001, -0.001):
        c = water_contact(POOL, HULL, pose([0.0, -2.5 + R + gap, -1.5]))
        assert c.part == "pool_wall" and c.clearance_m == pytest.approx(gap, abs=1e-12)
        c = water_contact(POOL, HULL, pose([0.0, 0.0, -8.0 + R + gap]))
        assert c.part == "pool_floor" and c.clearance_m == pytest.approx(gap, abs=1e-12)


def test_open_water_ignores_the_domain_sides_but_not_the_seabed():
    beyond_side = water_contact(OPEN, HULL, pose([0.0, 60.5, -1.5], yaw_deg=90.0))  # past y = 60
    assert beyond_side.part == "seabed" and beyond_side.clearance_m == pytest.approx(12.0 - 1.5 - R)
    c = water_contact(OPEN, HULL, pose([0.0, 0.0, -12.0 + R + 0.001]))
    assert c.part == "seabed" and c.clearance_m == pytest.approx(0.001, abs=1e-12)


def test_impact_speed_into_a_wall_is_the_contact_points_velocity_along_its_normal():
    T = pose([1.0, 2.5 - R, -1.5])
    c = water_contact(POOL, HULL, T)
    assert impact_speed(c, HULL, np.array([0.4, 0.3, 0.0]), np.zeros(3), T) == pytest.approx(0.3)
    assert impact_speed(c, HULL, np.array([0.0, -0.3, 0.0]), np.zeros(3), T) == pytest.approx(-0.3)  # leaving
    # tilted 30 deg toward the wall, front end touching, yawing at w (rad/s, about world +z): the front
    # end moves w x r with r = (A cos 30, A sin 30, 0) + R (0, 1, 0): its y velocity is w A cos 30
    T = pose([1.0, 2.5 - R - A * 0.5, -1.5], yaw_deg=30.0)
    c = water_contact(POOL, HULL, T)
    assert c.clearance_m == pytest.approx(0.0, abs=1e-12)
    w = 0.2
    assert impact_speed(c, HULL, np.zeros(3), np.array([0.0, 0.0, w]), T) == pytest.approx(
        w * A * math.cos(math.radians(30))
    )


# ---------------------------------------------------------------- in the closed loop
def _setup(start, water, current=(0.0, 0.0, 0.0), **kw):
    from blendgen.config.models import Dock, Pose
    from blendgen.vehicle import trajectories as tj
    from blendgen.vehicle.closed_loop import TrialSetup
    from blendgen.vehicle.visual_nav import CaptureSpec

    return TrialSetup(
        tj.T_world_dock_from_spec(Dock()),  # face centre at world (7, 0, -1.5), facing -x
        start,
        tj.T_body_cam_from_spec(Pose(xyz=[0.65, 0.0, 0.0])),
        CaptureSpec.from_dock([1.0, 1.0, 0.4], R),
        current_world=current,
        dock_size_m=(1.0, 1.0, 0.4),
        water=water,
        **kw,
    )


def _contact_world(setup, r):
    """The reported contact point (dock frame) back in the world frame."""
    p = np.array([r["contact_lateral_m"], r["contact_vertical_m"], r["contact_range_m"], 1.0])
    return (np.asarray(setup.T_world_dock) @ p)[:3]


START = {"range_m": 8.0, "lateral_m": 0.3, "vertical_m": 0.0, "heading_error_deg": 5.0}


def test_a_wall_across_the_approach_path_ends_the_trial_as_a_wall_collision():
    from blendgen.vehicle.closed_loop import simulate_closed_loop

    free = simulate_closed_loop(_setup(START, None))
    assert free["outcome"] == "docked"  # no water box: the old behaviour
    walled = _setup(START, WaterSolid.pool((-7.5, -2.5, -8.0), (3.0, 2.5, 0.0)))  # end wall at x = 3
    r = simulate_closed_loop(walled)
    assert r["outcome"] == "collision" and r["contact_part"] == "pool_wall"
    assert _contact_world(walled, r)[0] == pytest.approx(3.0) and r["contact_range_m"] == pytest.approx(4.0)
    assert 0.3 < r["impact_speed_mps"] <= 0.55  # cruising at 0.5 m/s nearly straight at it
    # the frame before, the hull's front (axis end from the camera offset, + R) was short of x = 3
    # by less than one frame's travel (0.05 m at 0.5 m/s)
    last = r["frames"][-1]
    front = last["x_world"] + (last["x_cam_world"] - last["x_world"]) * A / 0.65 + R
    assert 3.0 - 0.06 < front < 3.0


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_cross_current_pushes_the_hull_into_the_side_wall_on_its_side(side):
    # world +y current (z up): the hull hits the wall at y = +1.2 m (and, mirrored, at -1.2); a sign
    # slip between the world frame and NED inside would send it the other way or nowhere
    from blendgen.vehicle.closed_loop import simulate_closed_loop

    lo, hi = (-7.5, -20.0 if side > 0 else -1.2, -8.0), (7.5, 1.2 if side > 0 else 20.0, 0.0)
    setup = _setup({**START, "lateral_m": 0.0}, WaterSolid.pool(lo, hi), current=(0.0, side * 1.0, 0.0))
    r = simulate_closed_loop(setup)
    assert r["outcome"] == "collision" and r["contact_part"] == "pool_wall"
    assert _contact_world(setup, r)[1] == pytest.approx(side * 1.2)
    assert r["impact_speed_mps"] > 0
    # open water with the same box: its sides are not walls
    o = simulate_closed_loop(_setup({**START, "lateral_m": 0.0}, WaterSolid.open_water(lo, hi), (0.0, side, 0.0)))
    assert o["contact_part"] not in WATER_PARTS and o["t_end"] > r["t_end"]


def test_the_floor_just_under_the_start_is_touched_at_the_first_frame_and_1_cm_lower_not():
    from blendgen.vehicle.closed_loop import simulate_closed_loop
    from blendgen.vehicle.docking import start_pose_world

    z0 = float(start_pose_world(_setup(START, None).T_world_dock, START)[2, 3])  # world z, about -1.5
    assert -1.6 < z0 < -1.4
    touching = _setup(START, WaterSolid.pool((-7.5, -2.5, z0 - R + 0.005), (7.5, 2.5, 0.0)))
    r = simulate_closed_loop(touching)
    assert r["outcome"] == "collision" and r["contact_part"] == "pool_floor" and r["t_end"] == 0.0
    assert r["frames"] == [] and math.isnan(r["final_range_m"])  # ended before the first frame's row
    assert _contact_world(touching, r)[2] == pytest.approx(z0 - R + 0.005)
    clear = simulate_closed_loop(_setup({**START}, WaterSolid.pool((-7.5, -2.5, z0 - R - 0.01), (7.5, 2.5, 0.0))))
    assert clear["t_end"] > 0.0


def test_the_dock_bench_passes_the_experiments_water_box(tmp_path):
    from blendgen.pipeline.scene_check import water_solid
    from blendgen.tools.apps.closed_loop import Bench, load_bench_experiment

    exp = load_bench_experiment("turbidity", None, ())
    bench = Bench.prepare(exp, tmp_path)
    water = bench.setup(exp.conditions[0], 0).water
    assert water == water_solid(exp) and water is not None
    assert water.lo == (-7.5, -2.5, -8.0) and water.hi[:2] == (7.5, 2.5)  # world frame, z up
    assert sorted({f[2] for f in water.faces}) == ["pool_floor", "pool_wall"]
    ow = exp.model_copy(update={"scene": exp.scene.model_copy(update={"kind": "open_water"})})
    assert water_solid(ow).faces == ((2, -1, "seabed"),)
    assert water_solid(ow).lo[2] == -exp.scene.world.seabed_depth_m


def test_the_paper_pool_changes_no_truth_trial_of_the_turbidity_experiment(tmp_path):
    from dataclasses import replace

    from blendgen.tools.apps.closed_loop import Bench, load_bench_experiment
    from blendgen.vehicle.closed_loop import simulate_closed_loop

    exp = load_bench_experiment("turbidity", None, ())
    bench = Bench.prepare(exp, tmp_path)
    for trial in range(3):
        s = bench.setup(exp.conditions[0], trial)
        a, b = simulate_closed_loop(s), simulate_closed_loop(replace(s, water=None))
        assert a["outcome"] == b["outcome"] == "docked" and a["t_end"] == b["t_end"]


# ---------------------------------------------------------------- after the fact
def _frames(rows, cam=0.65):
    """Frames-table rows (trial, t, origin xyz, yaw deg, pitch-up deg) as a run would log them."""
    out = []
    for trial, t, o, yaw, pitch in rows:
        x = pose(o, yaw, pitch)[:3, 0]
        out.append(
            {
                "localizer": "truth",
                "condition": "c",
                "trial": trial,
                "t": t,
                "x_world": o[0],
                "y_world": o[1],
                "z_world": o[2],
                "x_cam_world": o[0] + cam * x[0],
                "y_cam_world": o[1] + cam * x[1],
            }
        )
    return pd.DataFrame(out)


def test_after_the_fact_clearance_per_trial_exact_from_the_camera_and_bounded_without():
    from blendgen.vehicle.water_clearance import trial_water_clearance

    rows = [
        (0, 0.0, [0.0, 0.0, -1.5], 0.0, 0.0),
        (0, 0.1, [1.0, 1.9, -1.5], 30.0, 0.0),  # tilted toward y = 2.5: 0.6 - A/2 - R
        (1, 0.0, [1.0, 2.2, -1.5], 0.0, 0.0),  # parallel: 0.3 - R
        (1, 0.1, [0.0, 0.0, -7.5], 0.0, -20.0),  # nose down over the floor: 0.5 - A sin 20 - R
        (2, 0.0, [7.2, 0.0, -1.5], 0.0, 0.0),  # 0.3 m from the end wall, pointing at it: penetrates
    ]
    f = _frames(rows)
    exact = trial_water_clearance(f, POOL, HULL, cam_forward_m=0.65)
    for i, (_, _, o, yaw, pitch) in enumerate(rows):  # each frame alone equals water_contact
        one = trial_water_clearance(f.iloc[[i]], POOL, HULL, cam_forward_m=0.65)
        assert one["min_clearance_m"].iloc[0] == pytest.approx(
            water_contact(POOL, HULL, pose(o, yaw, pitch)).clearance_m
        )
    want = [0.6 - A / 2 - R, 0.3 - R, 0.3 - A - R]
    assert exact["min_clearance_m"].tolist() == pytest.approx(want)
    assert exact["t_s"].tolist() == [0.1, 0.0, 0.0] and exact["part"].tolist() == ["pool_wall"] * 3
    assert exact["touched"].tolist() == [False, False, True] and set(exact["method"]) == {"camera"}
    bound = trial_water_clearance(f.drop(columns=["x_cam_world", "y_cam_world"]), POOL, HULL, cam_forward_m=0.65)
    assert set(bound["method"]) == {"origin"}
    # every axis end taken toward every face: origin distance - A - R
    assert bound["min_clearance_m"].tolist() == pytest.approx([0.6 - A - R, 0.3 - A - R, 0.3 - A - R])
    assert (bound["min_clearance_m"] <= exact["min_clearance_m"] + 1e-12).all()  # a lower bound
    with pytest.raises(ValueError, match="not on the body x axis"):
        trial_water_clearance(f, POOL, HULL, cam_forward_m=0.5)


def test_after_the_fact_clearance_of_a_simulated_run_matches_the_loop_that_hit_the_wall():
    from blendgen.vehicle.closed_loop import simulate_closed_loop
    from blendgen.vehicle.water_clearance import trial_water_clearance

    walls = WaterSolid.pool((-7.5, -20.0, -8.0), (7.5, 1.2, 0.0))
    free = simulate_closed_loop(_setup({**START, "lateral_m": 0.0}, None, current=(0.0, 1.0, 0.0)))
    hit = simulate_closed_loop(_setup({**START, "lateral_m": 0.0}, walls, current=(0.0, 1.0, 0.0)))
    f = pd.DataFrame(free["frames"]).assign(trial=0)
    got = trial_water_clearance(f, walls, HULL, cam_forward_m=0.65).iloc[0]
    assert got["touched"] and got["part"] == "pool_wall"
    # the first frame the run without walls is inside the wall is where the walled run stopped
    first = trial_water_clearance(f[f["t"] <= hit["t_end"] + 1e-9], walls, HULL, cam_forward_m=0.65).iloc[0]
    before = trial_water_clearance(f[f["t"] < hit["t_end"] - 1e-9], walls, HULL, cam_forward_m=0.65).iloc[0]
    assert first["min_clearance_m"] <= 0 < before["min_clearance_m"]
