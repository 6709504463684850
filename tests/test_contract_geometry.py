"""datasets_spec.geometry: the format's rigid transforms and their validators."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from datasets_spec.geometry import (
    axis_angle_to_R,
    check_K,
    check_T,
    invert_T,
    make_T,
    relative_rotation_angles,
    rotation_angle,
)

angles = st.floats(0.0, math.pi, allow_nan=False)
axes = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda a: np.linalg.norm(a) > 1e-3)


@settings(max_examples=200, deadline=None)
@given(axes, angles, st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3))
def test_rigid_transform_round_trip(axis, angle, t):
    T = check_T(make_T(axis_angle_to_R(axis, angle), t))
    assert np.allclose(invert_T(T) @ T, np.eye(4), atol=1e-9 * max(1.0, np.abs(t).max()))
    assert rotation_angle(T[:3, :3]) == pytest.approx(angle, abs=1e-7)


def test_rotation_angle_near_pi_and_zero():
    """The angle of a half-turn and of a micro-rotation, where acos((tr-1)/2) loses digits."""
    assert rotation_angle(axis_angle_to_R([1, 2, 3], math.pi)) == pytest.approx(math.pi, abs=1e-9)
    assert rotation_angle(axis_angle_to_R([0, 0, 1], 1e-9)) == pytest.approx(1e-9, rel=1e-6)
    R = Rotation.random(50, random_state=1).as_matrix()
    assert np.allclose(relative_rotation_angles(R, R), 0.0, atol=1e-7)


@pytest.mark.parametrize(
    "bad, why",
    [
        (np.eye(3), "shape"),
        (np.full((4, 4), np.nan), "non-finite"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "det"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), "orthonormal"),
        (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "bottom row"),
    ],
)
def test_check_T_names_the_fault(bad, why):
    with pytest.raises(ValueError, match=why.split()[0]):
        check_T(bad, "T_cam_dock")


@pytest.mark.parametrize(
    "bad, why",
    [
        (np.eye(4), "shape"),
        ([[500, 0, 320], [0, -500, 240], [0, 0, 1]], "focal"),
        ([[500, 0, 320], [0, 500, np.inf], [0, 0, 1]], "non-finite"),
        ([[500, 3, 320], [0, 500, 240], [0, 0, 1]], "expected"),
    ],
)
def test_check_K_names_the_fault(bad, why):
    with pytest.raises(ValueError, match=why):
        check_K(bad)
    assert check_K([[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]]).shape == (3, 3)
