"""Rigid transforms, camera intrinsics and Blender <-> OpenCV conventions.

Conventions (docs/conventions.md, *must*):
- metres and radians; poses are 4x4 float64 homogeneous matrices named ``T_a_b``:
  the pose of frame b expressed in frame a, mapping points from b into a.
- The camera frame is OpenCV's: +x right, +y down, +z forward (optical axis).
  Blender's camera looks down its local -Z with +Y up, so
  ``R_cv_from_blendercam = diag(1, -1, -1)``.
- Pixel centres sit at integer coordinates (OpenCV). Blender's raster origin is a
  pixel corner, hence the half-pixel in ``cx, cy``.
- World frame: Blender's world (+z up, metres). The water surface is z = 0 in the
  pool templates, so a point at water depth h has z = -h.

rot_x/y/z and rpy_to_R stay closed-form (they sit in the vehicle model's RK4 inner loop, where
scipy's per-call overhead would double its cost); every other rotation goes through scipy.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from datasets_spec.geometry import (  # noqa: F401  (the format's transforms, re-exported for blendgen)
    axis_angle_to_R,
    check_K,
    check_T,
    invert_T,
    make_T,
    rotation_angle,
)

# Rotation taking Blender-camera-frame vectors to OpenCV-camera-frame vectors.
R_CV_FROM_BLENDERCAM = np.diag([1.0, -1.0, -1.0])
T_CV_FROM_BLENDERCAM = np.diag([1.0, -1.0, -1.0, 1.0])


def rot_x(a: float) -> np.ndarray:
    """Rotation about +x by angle a (rad), 3x3."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=float)


def rot_y(a: float) -> np.ndarray:
    """Rotation about +y by angle a (rad), 3x3."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=float)


def rot_z(a: float) -> np.ndarray:
    """Rotation about +z by angle a (rad), 3x3."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=float)


def rpy_to_R(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """ZYX Euler (yaw about z, then pitch about y, then roll about x), rad -> 3x3."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def R_to_rpy(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rpy_to_R`: (roll, pitch, yaw) in rad, pitch in [-pi/2, pi/2]."""
    yaw, pitch, roll = Rotation.from_matrix(np.asarray(R, float)).as_euler("ZYX")
    return float(roll), float(pitch), float(yaw)


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD projection, det = +1) to a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def look_at_R(forward, up_hint=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation whose columns are the OpenCV camera axes (x right, y down, z forward)
    expressed in the world, for a camera looking along ``forward`` (3,) with the
    world's ``up_hint`` pointing image-up. Returns R_world_cam (3x3)."""
    z = np.asarray(forward, float)
    z = z / np.linalg.norm(z)
    up = np.asarray(up_hint, float)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along up: pick any right vector
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def intrinsics_from_hfov(
    width: int, height: int, hfov_rad: float, shift_x: float = 0.0, shift_y: float = 0.0
) -> np.ndarray:
    """K (3x3) that Blender renders for a perspective camera with horizontal sensor fit.

    ``fx = (W/2) / tan(hfov/2)`` (equivalently lens_mm * W / sensor_width_mm),
    ``fy = fx`` (square pixels), ``cx = W/2 - shift_x*W - 0.5``,
    ``cy = H/2 + shift_y*W - 0.5`` (shifts in Blender's units of the sensor width;
    -0.5 moves Blender's corner-origin raster to OpenCV's integer pixel centres).
    """
    if not (0.0 < hfov_rad < math.pi):
        raise ValueError(f"hfov must be in (0, 180) deg, got {math.degrees(hfov_rad)}")
    fx = (width / 2.0) / math.tan(hfov_rad / 2.0)
    cx = width / 2.0 - shift_x * width - 0.5
    cy = height / 2.0 + shift_y * width - 0.5
    return np.array([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]])


def hfov_from_K(K: np.ndarray, width: int) -> float:
    """Horizontal field of view (rad) of K for an image ``width`` pixels wide."""
    return 2.0 * math.atan((width / 2.0) / K[0, 0])


def vfov_from_K(K: np.ndarray, height: int) -> float:
    """Vertical field of view (rad) of K for an image ``height`` pixels tall."""
    return 2.0 * math.atan((height / 2.0) / K[1, 1])


def transform_points(T: np.ndarray, pts) -> np.ndarray:
    """Apply a 4x4 transform to points (N,3) -> (N,3)."""
    P = np.asarray(pts, float).reshape(-1, 3)
    return P @ T[:3, :3].T + T[:3, 3]


def project(K: np.ndarray, pts_cam) -> np.ndarray:
    """Pinhole projection of camera-frame points (N,3) to pixels (N,2).

    Points with z <= 0 project to NaN (behind the camera)."""
    P = np.asarray(pts_cam, float).reshape(-1, 3)
    z = P[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * P[:, 0] / z + K[0, 1] * P[:, 1] / z + K[0, 2]
        v = K[1, 1] * P[:, 1] / z + K[1, 2]
    uv = np.column_stack([u, v])
    uv[z <= 0] = np.nan
    return uv


def unproject(K: np.ndarray, uv, z) -> np.ndarray:
    """Inverse of :func:`project`: pixels (N,2) and planar depth z (N,) -> points (N,3)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    z = np.asarray(z, float).reshape(-1)
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.column_stack([x * z, y * z, z])


def ray_norm_grid(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Per-pixel ||((u-cx)/fx, (v-cy)/fy, 1)|| (H,W) float32: planar depth -> range factor."""
    u = (np.arange(width, dtype=np.float64) - K[0, 2]) / K[0, 0]
    v = (np.arange(height, dtype=np.float64) - K[1, 2]) / K[1, 1]
    return np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2).astype(np.float32)


def planar_depth_to_range(depth_z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Cycles' planar Depth pass (H,W) in metres -> range along each pixel ray (H,W)."""
    h, w = depth_z.shape
    return depth_z * ray_norm_grid(K, w, h)


def blender_matrix_world_from_T_world_cam(T_world_cam: np.ndarray) -> np.ndarray:
    """Blender camera object's matrix_world (4x4) for an OpenCV-frame camera pose."""
    return T_world_cam @ T_CV_FROM_BLENDERCAM


def T_world_cam_from_blender_matrix_world(M: np.ndarray) -> np.ndarray:
    """OpenCV-frame camera pose from a Blender camera's matrix_world (4x4)."""
    return np.asarray(M, float) @ T_CV_FROM_BLENDERCAM


def point_plane_distance(p, plane_point, plane_normal) -> float:
    """Unsigned distance (m) from point p (3,) to the plane through plane_point with normal."""
    n = np.asarray(plane_normal, float)
    n = n / np.linalg.norm(n)
    return float(abs(np.dot(np.asarray(p, float) - np.asarray(plane_point, float), n)))
