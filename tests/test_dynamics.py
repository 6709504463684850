"""AUV 6-DOF model, thrusters, autopilot, station keeping and docking trials."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blendgen.geometry import make_T
from blendgen.vehicle.control import Autopilot, Sensors, step_metrics, step_response
from blendgen.vehicle.docking import (
    random_start,
    simulate_docking_trial,
    start_pose_world,
    station_keep_run,
    station_keeping_signs_ok,
    station_keeping_table,
    thrust_unit_N,
)
from blendgen.vehicle.dynamics import DT_MAX, AUVModel, Plant, T_world_body_to_eta, VehicleParams, eta_to_T_world_body
from blendgen.vehicle.thrusters import ThrusterSet


def _dock(yaw_deg=30.0, depth=1.0):
    yaw = math.radians(yaw_deg)
    zd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    yd = np.array([0.0, 0.0, 1.0])
    return make_T(np.column_stack([np.cross(yd, zd), yd, zd]), [2.0, 1.0, -depth])


# ---------------------------------------------------------------- dynamics ------
@pytest.mark.parametrize("damping", [True, False])
def test_kinetic_energy_does_not_grow(damping):
    """Thrusters off, no current, neutral buoyancy, CG at CB (g = 0): C is skew, so
    0.5 nu^T M nu is conserved without damping (RK4 drift tiny) and decays with it."""
    p = VehicleParams(r_g=(0.0, 0.0, 0.0)).neutral(1025.0)
    model = AUVModel(p, 1025.0, damping=damping)
    s = [1.0, 2.0, 5.0, 0.1, 0.2, 0.3, 1.0, 0.5, -0.3, 0.5, 0.3, -0.4]
    E = [model.kinetic_energy(s[6:])]
    for _ in range(1000):
        s = model.rk4_step(s, [0.0] * 6, (0.0, 0.0, 0.0), 0.02)
        E.append(model.kinetic_energy(s[6:]))
    E = np.array(E)
    if damping:
        assert np.all(np.diff(E) <= 1e-9 * E[0])
        assert E[-1] < 0.05 * E[0]
    else:
        assert np.max(np.abs(E - E[0])) < 1e-5 * E[0]


def test_restoring_buoyancy_sign_and_density():
    p = VehicleParams()
    assert p.net_weight(1025) == pytest.approx(38.17, abs=0.05)
    # sinks at all three densities; W - B = (m - rho V) g in ratio 6:4:8
    nw = [p.net_weight(r) for r in (1025, 1075, 975)]
    assert all(w > 0 for w in nw)
    assert nw[1] / nw[0] == pytest.approx(4 / 6) and nw[2] / nw[0] == pytest.approx(8 / 6)
    # free-falling from rest: sinks (NED z grows -> world z decreases)
    model = AUVModel(p, 1025.0)
    s = [0.0, 0.0, 2.0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    for _ in range(100):
        s = model.rk4_step(s, [0.0] * 6, (0.0, 0.0, 0.0), 0.02)
    assert s[2] > 2.0
    assert eta_to_T_world_body(s[:6])[2, 3] < -2.0


def test_current_carries_unpowered_vehicle():
    """A neutral vehicle in a steady current drifts with it (relative velocity -> 0)."""
    p = VehicleParams().neutral(1025.0)
    model = AUVModel(p, 1025.0)
    s = [0.0, 0.0, 3.0, 0, 0, 0.4, 0, 0, 0, 0, 0, 0]
    vc = (0.3, -0.2, 0.0)
    for _ in range(3000):
        s = model.rk4_step(s, [0.0] * 6, vc, 0.02)
    eta = np.array(s[:6])
    from blendgen.vehicle.dynamics import R_ned_frd

    v_ned = R_ned_frd(*eta[3:]) @ np.array(s[6:9])
    assert np.allclose(v_ned, vc, atol=0.01)


# ---------------------------------------------------------------- frames --------
@settings(max_examples=50, deadline=None)
@given(
    st.floats(-50, 50),
    st.floats(-50, 50),
    st.floats(0, 40),
    st.floats(-1.2, 1.2),
    st.floats(-1.2, 1.2),
    st.floats(-3.1, 3.1),
)
def test_ned_world_pose_roundtrip(x, y, z, phi, theta, psi):
    eta = np.array([x, y, z, phi, theta, psi])
    T = eta_to_T_world_body(eta)
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
    assert T[2, 3] == pytest.approx(-z)  # depth z -> world z = -depth
    assert np.allclose(T_world_body_to_eta(T), eta, atol=1e-9)


def test_ned_world_axes():
    # level, heading east (psi = +90 deg): NED east = world -y; body FLU up = world +z
    T = eta_to_T_world_body([0, 0, 2.0, 0, 0, math.pi / 2])
    assert np.allclose(T[:3, 0], [0, -1, 0], atol=1e-12)  # forward
    assert np.allclose(T[:3, 1], [1, 0, 0], atol=1e-12)  # left (= north when facing east)
    assert np.allclose(T[:3, 2], [0, 0, 1], atol=1e-12)  # up
    assert T[2, 3] == pytest.approx(-2.0)
    # nose up (theta > 0 in NED) -> forward axis has a positive world z component
    T = eta_to_T_world_body([0, 0, 2.0, 0, 0.3, 0])
    assert T[2, 0] == pytest.approx(math.sin(0.3))
    # roll starboard-down (phi > 0) -> left axis tilts up
    T = eta_to_T_world_body([0, 0, 2.0, 0.2, 0, 0])
    assert T[2, 1] > 0


def test_commanded_deeper_goes_to_more_negative_world_z():
    p = VehicleParams()
    plant = Plant(p, 1025.0)
    ap = Autopilot(p, 1025.0, plant.thrusters)
    plant.set_pose_ned([0, 0, 2.0, 0, 0, 0])
    plant.n = ap.hover_speeds()
    z0 = plant.T_world_body()[2, 3]
    for _ in range(1500):
        eta, nu = plant.s[:6], plant.s[6:]
        tau = ap.track(eta, nu, Sensors().read(eta), 3.5, 0.0, 0.0, 0.02)
        plant.step(ap.thruster_command(tau), (0, 0, 0), 0.02)
    T = plant.T_world_body()
    assert z0 == pytest.approx(-2.0)
    assert T[2, 3] == pytest.approx(-3.5, abs=0.03)
    assert np.allclose(T[:3, 2], [0, 0, 1], atol=0.01)  # still upright


# ---------------------------------------------------------------- thrusters -----
def test_thruster_allocation_and_propeller():
    th = ThrusterSet()
    assert np.allclose(th.B[3], 0.0)  # roll uncontrolled
    assert np.linalg.matrix_rank(th.B) == 5
    tau = np.array([5.0, -8.0, -30.0, 0.0, 2.0, -3.0])
    assert np.allclose(th.B @ th.allocate(tau), tau, atol=1e-9)
    rho = 1025.0
    n = np.array([50.0, -50.0, 100.0, -100.0, 10.0, 0.0])
    T = th.speed_to_thrust(n, rho)
    assert T[0] > 0 > T[1] and abs(T[1]) < T[0]  # reverse weaker
    assert T[0] == pytest.approx(rho * 0.0125 * 0.1**4 * 2500)
    assert np.allclose(th.thrust_to_speed(T, rho), n)
    assert np.all(np.abs(th.thrust_to_speed(np.full(6, 1e4), rho)) <= 100.0)
    # first-order lag: 63 % after one time constant (0.2 s)
    n_ = np.zeros(6)
    for _ in range(10):
        n_ = th.lag_step(n_, np.full(6, 100.0), 0.02)
    assert np.allclose(n_, 100 * (1 - math.exp(-1)), rtol=1e-9)


def test_prioritized_allocation_keeps_moments_when_saturated():
    th = ThrusterSet()
    rho = 1025.0
    hi = th.max_thrust(rho)
    tau = np.array([0.0, -300.0, -40.0, 0.0, 3.0, 8.0])  # sway far beyond authority
    T = th.allocate_prioritized(tau, rho)
    assert np.all(T <= hi + 1e-9) and np.all(T >= -0.7 * hi - 1e-9)
    got = th.B @ T
    assert got[5] == pytest.approx(8.0) and got[4] == pytest.approx(3.0)  # moments kept
    assert got[2] == pytest.approx(-40.0)  # heave kept
    assert -300.0 < got[1] < -40.0  # sway saturated
    small = np.array([1.0, -2.0, -30.0, 0.0, 1.0, 1.0])
    assert np.allclose(th.allocate_prioritized(small, rho), th.allocate(small))


def test_sensors_quantise_and_clip():
    s = Sensors()
    r = s.read([0, 0, 1.23456, math.radians(120.0), math.radians(-12.345), math.radians(-0.04)])
    assert r["depth_m"] == pytest.approx(1.23)
    assert r["pitch_deg"] == pytest.approx(-12.3)
    assert r["roll_deg"] == pytest.approx(90.0)
    assert r["heading_deg"] == 0.0  # 359.96 -> 360.0 -> wraps to 0
    assert s.read([0, 0, -2.0, 0, 0, 0])["depth_m"] == 0.0
    assert s.read([0, 0, 80.0, 0, 0, 0])["depth_m"] == 50.0
    assert s.read([0, 0, 1, 0, 0, math.radians(-90)])["heading_deg"] == pytest.approx(270.0)


# ---------------------------------------------------------------- station keeping
def test_hover_at_neutral_density_needs_no_vertical_thrust():
    res = station_keep_run(1025.0, duration_s=20.0, params=VehicleParams().neutral(1025.0))
    assert np.all(np.abs(res["thrust_N"]) < 0.05)
    assert res["pos_error_m"] < 0.01


@pytest.fixture(scope="module")
def sk_table():
    return station_keeping_table()


def test_station_keeping_table(sk_table):
    df = sk_table
    assert list(df.index) == [
        "benchmark",
        "density 1075",
        "density 975",
        "flow up",
        "flow down",
        "flow forward",
        "flow backward",
        "flow left",
        "flow right",
    ]
    assert all(station_keeping_signs_ok(df).values())
    assert df.attrs["unit_N"] == pytest.approx(thrust_unit_N())
    assert df.loc["benchmark", "vertical"] == pytest.approx(6.0, abs=0.2)
    assert df.loc["density 1075", "vertical"] == pytest.approx(4.0, abs=0.2)
    assert df.loc["density 975", "vertical"] == pytest.approx(8.0, abs=0.2)
    # compensating thrust ~ drag at the relative velocity
    assert abs(df.loc["flow left", "lateral_N"]) * 2 == pytest.approx(131 * 0.25 + 13.2 * 0.5, rel=0.05)
    assert (df["pos_error_m"] < 0.05).all()


# ---------------------------------------------------------------- step responses
@pytest.mark.parametrize(
    "axis,step,duration,max_os,max_settle,max_rise",
    [
        ("depth", 1.0, 30.0, 5.0, 15.0, 8.0),
        ("depth", -1.0, 30.0, 5.0, 15.0, 8.0),
        ("heading", 30.0, 25.0, 5.0, 12.0, 6.0),
        ("heading", -90.0, 30.0, 5.0, 15.0, 8.0),
        ("speed", 0.5, 25.0, 5.0, 12.0, 6.0),
    ],
)
def test_step_responses_settle(axis, step, duration, max_os, max_settle, max_rise):
    t, y = step_response(axis, step, duration)
    m = step_metrics(t, y, y[0] + step, band=0.02)
    assert m["overshoot_pct"] < max_os
    assert m["settling_time_s"] < max_settle
    assert m["rise_time_s"] < max_rise
    assert np.all(np.isfinite(y))


# ---------------------------------------------------------------- docking -------
def test_docking_start_pose_matches_start_dict():
    Td = _dock()
    start = {"range_m": 8.0, "lateral_m": 1.0, "vertical_m": -0.3, "heading_error_deg": 10.0}
    T = start_pose_world(Td, start)
    p_dock = Td[:3, :3].T @ (T[:3, 3] - Td[:3, 3])
    assert np.allclose(p_dock, [1.0, -0.3, 8.0])
    # forward axis = -z_dock rotated 10 deg to the left (CCW seen from above)
    f = T[:3, 0]
    a = -Td[:3, 2]
    assert math.degrees(math.atan2(np.cross(a, f)[2], a @ f)) == pytest.approx(10.0)
    assert np.allclose(T[:3, 2], [0, 0, 1])


def test_docking_no_current_reaches_face_on_axis():
    Td = _dock()
    start = {"range_m": 10.0, "lateral_m": 1.2, "vertical_m": -0.4, "heading_error_deg": 12.0}
    r = simulate_docking_trial(Td, start, seed=0)
    n = len(r["t"])
    assert r["T_world_body"].shape == (n, 4, 4) and r["thrust"].shape == (n, 6)
    assert np.allclose(np.diff(r["t"]), 0.1)
    assert set(r["sensors"]) == {"depth_m", "heading_deg", "pitch_deg", "roll_deg"}
    assert np.allclose(r["p_dock"][0], [1.2, -0.4, 10.0], atol=1e-9)
    assert r["stop_reason"] == "reached"
    assert r["final_distance_m"] <= 0.5
    assert abs(r["final_lateral_m"]) < 0.3 and abs(r["final_vertical_m"]) < 0.15
    # world z of the body origin matches the depth sensor (z = -depth)
    assert np.allclose(r["T_world_body"][:, 2, 3], -r["sensors"]["depth_m"], atol=0.006)


def test_lateral_current_disturbs_heading_and_path():
    Td = _dock()
    start = {"range_m": 9.0, "lateral_m": 0.0, "vertical_m": 0.0, "heading_error_deg": 0.0}
    calm = simulate_docking_trial(Td, start, seed=1)
    xd = Td[:3, 0]
    rough = simulate_docking_trial(Td, start, current_world=tuple(1.0 * xd), seed=1)
    assert np.std(rough["heading_error_deg"]) > np.std(calm["heading_error_deg"]) + 2.0
    assert np.max(np.abs(rough["p_dock"][:, 0])) > 1.0 > np.max(np.abs(calm["p_dock"][:, 0]))
    # the lateral thrusters hit their limit at times (no magic cancellation); calm never
    assert np.any(np.abs(rough["n_rad_s"][:, 2:4]) > 99.0)
    assert not np.any(np.abs(calm["n_rad_s"]) > 99.0)
    assert rough["stop_reason"] == "reached" and abs(rough["final_lateral_m"]) > 0.5


def test_docking_deterministic_with_seed():
    Td = _dock()
    start = random_start(np.random.default_rng(5))
    cur = tuple(0.6 * Td[:3, 0])
    a = simulate_docking_trial(Td, start, current_world=cur, seed=7, max_time_s=20)
    b = simulate_docking_trial(Td, start, current_world=cur, seed=7, max_time_s=20)
    c = simulate_docking_trial(Td, start, current_world=cur, seed=8, max_time_s=20)
    assert np.array_equal(a["T_world_body"], b["T_world_body"])
    assert np.array_equal(a["thrust"], b["thrust"])
    assert not np.array_equal(a["T_world_body"], c["T_world_body"])


def test_random_start_ranges():
    rng = np.random.default_rng(0)
    for _ in range(50):
        s = random_start(rng)
        assert 6 <= s["range_m"] <= 12 and abs(s["lateral_m"]) <= 1.5
        assert abs(s["vertical_m"]) <= 0.5 and abs(s["heading_error_deg"]) <= 15
    s = random_start(rng, {"range_m": (3, 4), "lateral_m": 0.2})
    assert 3 <= s["range_m"] <= 4 and abs(s["lateral_m"]) <= 0.2


def test_large_dt_rejected_small_dt_finite():
    Td = _dock()
    start = {"range_m": 6.0, "lateral_m": 0.5, "vertical_m": 0.0, "heading_error_deg": 5.0}
    with pytest.raises(ValueError, match="dt"):
        simulate_docking_trial(Td, start, dt=0.5)
    bad = Td.copy()
    bad[:3, 0] *= -1.0  # left-handed dock frame
    with pytest.raises(ValueError, match="rotation"):
        simulate_docking_trial(bad, start)
    with pytest.raises(ValueError, match="dt"):
        step_response("depth", 1.0, 10.0, dt=0.2)
    r = simulate_docking_trial(Td, start, dt=DT_MAX, fps=10.0, max_time_s=40)
    assert np.all(np.isfinite(r["T_world_body"])) and r["stop_reason"] == "reached"
