"""Hull-dock contact geometry: hand-computed contacts and 1 mm misses, and the closed loop's use of it."""

import math

import numpy as np
import pytest

from blendgen.vehicle.contact import DockSolid, Hull, hull_contact, impact_speed, surface_distance

R = 0.191 / 2  # REMUS hull radius (m)
SOLID = DockSolid.from_dock((1.0, 1.0, 0.4), R)  # mouth 0.5 m at z = 0, throat R at z = -0.4 m
HULL = Hull.from_vehicle(1.33, 0.191)  # axis half-length 0.665 - R


def pose_along(front_centre, direction):
    """T_dock_body of a hull whose body +x points along ``direction`` (3,) (dock frame) and whose
    front axis end (the centre of the nose's hemisphere) is at ``front_centre`` (3,)."""
    x = np.asarray(direction, float) / np.linalg.norm(direction)
    up = np.array([0.0, 1.0, 0.0]) if abs(x[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    z = np.cross(x, up)
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = np.asarray(front_centre, float) - HULL.half_axis * x
    return T


def test_solid_and_hull_from_the_dock_model_and_the_vehicle():
    assert (SOLID.half_w, SOLID.half_h, SOLID.depth, SOLID.mouth_r, SOLID.throat_r) == pytest.approx(
        (0.5, 0.5, 0.4, 0.5, R)
    )
    assert HULL.half_axis + HULL.radius == pytest.approx(1.33 / 2)
    with pytest.raises(ValueError, match="throat_r"):
        DockSolid.from_dock((1.0, 1.0, 0.4), 0.6)


def test_capsule_touching_the_funnel_cone_at_a_known_point_and_missing_it_by_1_mm():
    # the cone's meridian runs from A = (0.5, 0) to B = (R, -0.4) in (rho, z); take the point
    # Q = A + 0.1 (B - A) and the cone's normal there toward the cavity, n = (-0.4, 0.5 - R) / |.|
    a, b = np.array([0.5, 0.0]), np.array([R, -0.4])
    q = a + 0.1 * (b - a)
    n = np.array([-0.4, 0.5 - R]) / math.hypot(0.4, 0.5 - R)
    for gap in (0.0, 0.001):
        c2 = q + (R + gap) * n  # the nose hemisphere's centre, the hull along the axis (-z)
        con = hull_contact(SOLID, HULL, pose_along([c2[0], 0.0, c2[1]], [0.0, 0.0, -1.0]))
        assert con.part == "funnel"
        assert con.clearance_m == pytest.approx(gap, abs=1e-7)
        assert con.point_dock == pytest.approx([q[0], 0.0, q[1]], abs=1e-6)
        assert con.normal == pytest.approx([n[0], 0.0, n[1]], abs=1e-6)


def test_grazing_the_rim_and_the_impact_speed_along_its_normal():
    # nose hemisphere centre at the rim point (0.5, 0, 0) + R (-sin 20, 0, cos 20): the contact
    # normal is that direction, so a straight approach at 0.3 m/s hits at 0.3 cos 20 deg
    th = math.radians(20.0)
    c = np.array([0.5 - R * math.sin(th), 0.0, R * math.cos(th)])
    T = pose_along(c, [0.0, 0.0, -1.0])
    con = hull_contact(SOLID, HULL, T)
    assert con.part == "rim" and con.clearance_m == pytest.approx(0.0, abs=1e-7)
    assert con.point_dock == pytest.approx([0.5, 0.0, 0.0], abs=1e-6)
    v = impact_speed(con, HULL, np.array([0.0, 0.0, -0.3]), np.zeros(3), T)
    assert v == pytest.approx(0.3 * math.cos(th), abs=1e-6)
    # moving along the face (across the normal's x) only: -(v . n) = 0.2 sin 20 deg
    v_side = impact_speed(con, HULL, np.array([0.2, 0.0, 0.0]), np.zeros(3), T)
    assert v_side == pytest.approx(0.2 * math.sin(th), abs=1e-6)


def test_the_frame_hit_from_the_side_and_a_1_mm_miss():
    # the hull flies across the face (-x) at mid-depth beside the dock: its tip 1 mm from the side x = 0.5
    for gap, want in ((0.001, 0.001), (-0.01, -0.01)):
        tip_x = 0.5 + gap
        con = hull_contact(SOLID, HULL, pose_along([tip_x + R, 0.1, -0.2], [-1.0, 0.0, 0.0]))
        assert con.part == "side" and con.clearance_m == pytest.approx(want, abs=1e-7)
        assert con.normal == pytest.approx([1.0, 0.0, 0.0])


def test_the_face_plate_outside_the_mouth_1_mm_off():
    # axis parallel to the dock axis over the plate (rho = 0.54 m > 0.5 m mouth), tip 1 mm off
    T = pose_along([0.3, 0.45, 0.001 + R], [0.0, 0.0, -1.0])
    con = hull_contact(SOLID, HULL, T)
    assert con.part == "face_plate" and con.clearance_m == pytest.approx(0.001, abs=1e-7)
    assert con.normal == pytest.approx([0.0, 0.0, 1.0])
    assert impact_speed(con, HULL, np.array([0.0, 0.0, -0.25]), np.zeros(3), T) == pytest.approx(0.25)


def test_a_turn_adds_omega_x_r_at_the_contact_point():
    # rim contact at 20 deg (as above): the hull point touching is r = (R sin20, 0, -a - R cos20) from
    # the body origin (a = axis half-length); yawing at omega = (0, w, 0): omega x r = w (r_z, 0, -r_x),
    # and -(omega x r) . n with n = (-sin20, 0, cos20) is -w a sin20
    th, w = math.radians(20.0), -0.5
    T = pose_along([0.5 - R * math.sin(th), 0.0, R * math.cos(th)], [0.0, 0.0, -1.0])
    con = hull_contact(SOLID, HULL, T)
    got = impact_speed(con, HULL, np.zeros(3), np.array([0.0, w, 0.0]), T)
    assert got == pytest.approx(-w * HULL.half_axis * math.sin(th), abs=1e-6)


def test_signed_distance_inside_the_material_and_in_the_cavity():
    d, q, part = surface_distance(np.array([[0.45, 0.45, -0.1], [0.0, 0.0, -0.1], [0.0, 2.0, 0.0]]), SOLID)
    assert d[0] == pytest.approx(-0.05)  # 5 cm inside, nearest the sides x/y = 0.5
    # on the axis 0.1 m deep: the cone's radius there is 0.5 - 0.1 (0.5 - R) / 0.4; distance along its normal
    r_cone = 0.5 - 0.1 * (0.5 - R) / 0.4
    assert d[1] == pytest.approx(r_cone * 0.4 / math.hypot(0.4, 0.5 - R), abs=1e-9)
    assert d[2] == pytest.approx(1.5) and part[2] in (0, 2)  # 1.5 m above the top edge (plate and side tie)


# ---------------------------------------------------------------- in the closed loop
def _closed_loop_setup(start):
    from blendgen.config.models import Dock, Pose
    from blendgen.vehicle import trajectories as tj
    from blendgen.vehicle.closed_loop import TrialSetup
    from blendgen.vehicle.visual_nav import CaptureSpec

    return TrialSetup(
        tj.T_world_dock_from_spec(Dock()),
        start,
        tj.T_body_cam_from_spec(Pose(xyz=[0.65, 0.0, 0.0])),
        CaptureSpec.from_dock([1.0, 1.0, 0.4], R),
        dock_size_m=(1.0, 1.0, 0.4),
    )


def test_a_hull_flying_into_the_frame_from_the_side_ends_the_trial_as_a_side_collision():
    from blendgen.vehicle.closed_loop import simulate_closed_loop

    # body origin beside the dock at mid-depth, nose (0.665 m ahead) 3 cm from the side x = 0.5,
    # turned 90 deg toward it, surging at 0.5 m/s: the next frame (0.1 s) it is in the frame
    start = {"range_m": -0.2, "lateral_m": 0.5 + 0.665 + 0.03, "vertical_m": 0.0, "heading_error_deg": 90.0}
    r = simulate_closed_loop(_closed_loop_setup({**start, "speed_mps": 0.5}))
    assert r["outcome"] == "collision" and r["contact_part"] == "side"
    assert r["contact_lateral_m"] == pytest.approx(0.5) and r["contact_range_m"] == pytest.approx(-0.2, abs=0.01)
    assert r["t_end"] == pytest.approx(0.1) and math.isnan(r["cross_lateral_m"])  # no entry-plane crossing
    assert 0.4 < r["impact_speed_mps"] <= 0.5  # surge speed straight into the side, slowed by drag
    # 10 cm further out it has not reached the side yet at 0.1 s: not a collision at that frame
    far = simulate_closed_loop(_closed_loop_setup({**start, "lateral_m": start["lateral_m"] + 0.1, "speed_mps": 0.5}))
    assert far["t_end"] > 0.1


def test_a_hull_grazing_the_funnel_rim_is_a_rim_collision():
    from blendgen.geometry import invert_T, make_T
    from blendgen.vehicle.closed_loop import Observation, simulate_closed_loop

    setup = _closed_loop_setup({"range_m": 8.0, "lateral_m": 0.45, "vertical_m": 0.0, "heading_error_deg": 0.0})

    def biased(k, t, T_world_cam):  # the dock seen 0.45 m to the side: guidance aims at the rim
        T_cd = invert_T(T_world_cam) @ setup.T_world_dock @ make_T(np.eye(3), [0.45, 0.0, 0.0])
        return Observation({"distance": float(T_cd[2, 3]), "T_cam_dock": T_cd}, {})

    r = simulate_closed_loop(setup, biased)
    assert r["outcome"] == "collision" and r["contact_part"] == "rim"
    assert math.hypot(r["contact_lateral_m"], r["contact_vertical_m"]) == pytest.approx(0.5, abs=1e-6)
    assert 0.15 < r["impact_speed_mps"] < 0.3  # final approach speed 0.2 m/s, normal tilted toward the axis
