"""Thruster authority against hand calculations of drag vs thrust (no simulation)."""

import math

import pytest

from blendgen.vehicle import authority
from blendgen.vehicle.dynamics import VehicleParams

RHO = 1025.0
P = VehicleParams()
# hand numbers for the default vehicle (dynamics.VehicleParams, thrusters.default_thrusters)
D_SWAY_LIN = (30.48 + 35.5) / 5.0  # (m + Y_vdot) / T_sway, N/(m/s)
D_SWAY_QUAD = 131.0  # N/(m/s)^2
LAT_FWD = RHO * 0.0125 * 0.13**4 * 100.0**2  # one lateral tunnel thruster at n_max, N
LAT_REV = 0.7 * LAT_FWD


def test_sway_drag_at_one_metre_per_second_against_hand_calculation():
    tau = authority.required_force_frd(P, RHO, [0.0, 1.0, 0.0])
    assert tau[1] == pytest.approx(D_SWAY_LIN + D_SWAY_QUAD, rel=1e-9)  # 144.2 N
    assert tau[2] == pytest.approx(-P.net_weight(RHO), rel=1e-9)  # hover: push up (FRD -z)


def test_lateral_flow_one_metre_per_second_is_beyond_the_lateral_pair():
    # flow pushing the vehicle to its left: the lateral pair must push right = reverse thrust
    h = authority.hold([0.0, 1.0, 0.0], RHO)  # vehicle moves right through the water (FRD +y)
    need = D_SWAY_LIN + D_SWAY_QUAD
    assert h.thrust_N["lateral"] == pytest.approx(-need / 2, rel=1e-6)
    assert h.utilisation == pytest.approx(need / 2 / LAT_REV, rel=1e-6)  # 2.81
    assert not h.holds and h.limiting_group == "lateral"


def test_largest_holdable_lateral_speed_solves_the_drag_quadratic():
    # d v + d_q v^2 = 2 T_rev  ->  v = (-d + sqrt(d^2 + 8 d_q T_rev)) / (2 d_q)
    v_left = (-D_SWAY_LIN + math.sqrt(D_SWAY_LIN**2 + 8 * D_SWAY_QUAD * LAT_REV)) / (2 * D_SWAY_QUAD)
    v_right = (-D_SWAY_LIN + math.sqrt(D_SWAY_LIN**2 + 8 * D_SWAY_QUAD * LAT_FWD)) / (2 * D_SWAY_QUAD)
    assert authority.max_holdable_speed((0, 1, 0), RHO) == pytest.approx(v_left, abs=2e-4)  # 0.577
    assert authority.max_holdable_speed((0, -1, 0), RHO) == pytest.approx(v_right, abs=2e-4)  # 0.699


def test_station_keeping_rows_flag_exactly_the_unholdable_flows():
    rows = {(r["flow"], r["speed_mps"]): r for r in authority.station_keeping_authority((0.5, 1.0), RHO)}
    assert rows[("left", 0.5)]["holds"] and not rows[("left", 1.0)]["holds"]
    assert rows[("forward", 1.0)]["holds"]  # 4.8 N of surge drag vs 17.9 N reverse
    for r in rows.values():
        assert r["holds"] == (r["speed_mps"] <= r["max_speed_mps"])


def test_docking_authority_uses_the_crab_angle_within_the_heading_limit():
    # approach along world +x, current toward world +y (the vehicle's left) at 0.5 m/s: crab to the right
    res = authority.docking_authority((0.0, 0.5, 0.0), (1.0, 0.0, 0.0), 0.2, 15.0, RHO)
    assert res["holds"] and res["heading_offset_deg"] < 0
    # hand: nose 15 deg right, the body moves through the water to its right at 0.5 cos15 - 0.2 sin15
    b = math.radians(abs(res["heading_offset_deg"]))
    assert b == pytest.approx(math.radians(15.0))
    v = 0.5 * math.cos(b) - 0.2 * math.sin(b)
    assert res["utilisation"] == pytest.approx((D_SWAY_LIN * v + D_SWAY_QUAD * v * v) / 2 / LAT_REV, rel=1e-6)
    assert not authority.docking_authority((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), 0.2, 15.0, RHO)["holds"]
    # a wider heading limit lets it crab further into the flow and hold more current
    c15 = authority.max_docking_current((0, 1, 0), (1, 0, 0), 0.2, 15.0, RHO)
    c45 = authority.max_docking_current((0, 1, 0), (1, 0, 0), 0.2, 45.0, RHO)
    assert 0.577 < c15 < c45


def test_authority_command_judges_the_current_ladder_and_refuses_bad_input():
    from click.testing import CliRunner

    from cli import main

    r = CliRunner().invoke(main, ["authority", "--speed", "1.0", "--experiment", "current"])
    assert r.exit_code == 0, r.output
    lines = {ln.split("|")[1].strip(): ln for ln in r.output.splitlines() if ln.startswith("| current_")}
    assert "within" in lines["current_0.5"] and "beyond the vehicle's authority" in lines["current_1.0"]
    bad = CliRunner().invoke(main, ["authority", "--experiment", "no_such_experiment"])
    assert bad.exit_code == 2 and len(bad.output.strip().splitlines()) == 1
    neg = CliRunner().invoke(main, ["authority", "--speed", "-1"])
    assert neg.exit_code == 2
