"""Rigid transforms and intrinsics as the format defines them (FORMAT.md), shared by both halves.

Poses are 4x4 homogeneous ``T_a_b`` (pose of frame b in frame a; maps points from b to a),
metres and radians; K is the 3x3 OpenCV pinhole matrix with pixel centres at integers.
Rotations go through :class:`scipy.spatial.transform.Rotation` (maintained, vectorised,
numerically careful near 0 and pi) rather than hand-written formulas.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

ORTHONORMAL_TOL = 1e-6


def check_T(T, name: str = "T") -> np.ndarray:
    """``T`` as a float (4, 4) rigid transform, or ValueError naming what is wrong.

    Checks: shape, finite entries, bottom row [0, 0, 0, 1], rotation orthonormal with det +1
    (within ``ORTHONORMAL_TOL``)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"{name}: shape {T.shape}, expected (4, 4)")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: non-finite entries")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=ORTHONORMAL_TOL):
        raise ValueError(f"{name}: bottom row {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=ORTHONORMAL_TOL) or np.linalg.det(R) <= 0:
        raise ValueError(f"{name}: rotation part is not orthonormal with det +1")
    return T


def check_K(K, name: str = "K") -> np.ndarray:
    """``K`` as a float (3, 3) pinhole matrix (fx, fy > 0, zero skew, last row [0, 0, 1]) or ValueError."""
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"{name}: shape {K.shape}, expected (3, 3)")
    if not np.all(np.isfinite(K)):
        raise ValueError(f"{name}: non-finite entries")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{name}: focal lengths must be > 0 px, got fx={K[0, 0]}, fy={K[1, 1]}")
    if K[1, 0] != 0 or K[0, 1] != 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise ValueError(f"{name}: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    return K


def make_T(R, t) -> np.ndarray:
    """Homogeneous (4, 4) from a (3, 3) rotation and a translation (3,), metres."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert_T(T) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform (R^T, -R^T t; not a general matrix inverse)."""
    T = np.asarray(T, dtype=float)
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def rotation_angle(R) -> float:
    """Angle (rad, [0, pi]) of a (3, 3) rotation matrix."""
    return float(Rotation.from_matrix(np.asarray(R, dtype=float)).magnitude())


def relative_rotation_angles(R_a, R_b) -> np.ndarray:
    """Angles (rad, (N,)) of R_a[i]^T R_b[i] for stacks (N, 3, 3): rotation error between poses."""
    rel = np.einsum("nji,njk->nik", np.asarray(R_a, float), np.asarray(R_b, float))
    return Rotation.from_matrix(rel).magnitude()


def axis_angle_to_R(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` (rad) about ``axis`` (3,), any non-zero length."""
    a = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(a / np.linalg.norm(a) * angle).as_matrix()
