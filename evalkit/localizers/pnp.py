"""Pose of a planar point set from its image (OpenCV 4.11), shared by the localizers.

Conventions (datasets_spec/FORMAT.md, docs/conventions.md): metres; camera frame OpenCV (+x right, +y down,
+z forward); pixel centres at integer coordinates; ``T_a_b`` maps points from b to a.
Only named PnP flags are used (``SOLVEPNP_IPPE``, ``SOLVEPNP_IPPE_SQUARE``), never integers.

A planar target has two IPPE solutions (the "flip" ambiguity). We keep the solutions
that put every target point in front of the camera and whose target normal (+z of the
target frame) faces the camera, pick the one with the lower reprojection error, and
refine it with ``solvePnPRefineLM``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class PlanarPose:
    """A solved pose. ``T_cam_target`` (4,4) maps target-frame points (m) into the camera
    frame; ``reproj_err_px`` is the RMS reprojection error (px) over ``n_points`` points;
    ``alt_reproj_err_px`` the RMS error of the rejected IPPE solution (inf if none)."""

    T_cam_target: np.ndarray
    reproj_err_px: float
    n_points: int
    alt_reproj_err_px: float


def camera_matrices(camera: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """``camera["K"]`` -> K (3,3) float64; ``camera["dist"]`` (or ``"distortion"``) ->
    OpenCV distortion coefficients (N,) float64 or None. Raises ValueError if K is unusable."""
    K = np.asarray(camera["K"], dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"invalid camera matrix K: {K.tolist()}")
    dist = camera.get("dist", camera.get("distortion"))
    if dist is not None:
        dist = np.asarray(dist, dtype=np.float64).reshape(-1)
        if dist.size == 0 or not np.any(dist):
            dist = None
    return K, dist


def T_from_rvec_tvec(rvec, tvec) -> np.ndarray:
    """Rodrigues rotation vector (3,) and translation (3,) in m -> 4x4 transform."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, np.float64).reshape(3)
    return T


def invert_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def distance_to_dock_plane(T_cam_dock: np.ndarray) -> float:
    """Distance (m) from the camera centre to the dock's marker plane (dock z = 0):
    |z of the camera centre in the dock frame| = |r3 . t| with T_cam_dock = [R | t]."""
    T = np.asarray(T_cam_dock, np.float64)
    return float(abs(T[:3, 2] @ T[:3, 3]))


def reprojection_rms(obj_pts, img_pts, rvec, tvec, K, dist) -> float:
    """RMS distance (px) between img_pts (N,2) and obj_pts (N,3, target frame, m) projected."""
    proj, _ = cv2.projectPoints(
        np.asarray(obj_pts, np.float64).reshape(-1, 1, 3),
        np.asarray(rvec, np.float64).reshape(3, 1),
        np.asarray(tvec, np.float64).reshape(3, 1),
        K,
        dist,
    )
    d = proj.reshape(-1, 2) - np.asarray(img_pts, np.float64).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def pose_is_plausible(T_cam_target: np.ndarray, obj_pts: np.ndarray, min_z_m: float = 1e-3) -> bool:
    """True when T (4,4) is finite, every target point (N,3) lies at z > min_z_m in the
    camera, and the target's +z normal faces the camera (n . (c - p) > 0)."""
    if not np.all(np.isfinite(T_cam_target)):
        return False
    R, t = T_cam_target[:3, :3], T_cam_target[:3, 3]
    p_cam = obj_pts @ R.T + t
    if np.any(p_cam[:, 2] <= min_z_m):
        return False
    normal_cam = R[:, 2]
    centre_cam = p_cam.mean(axis=0)
    return bool(normal_cam @ (-centre_cam) > 0.0)


# OpenCV's IPPE converts its rotations to vectors with its own rot2vec, which breaks down
# near a rotation of pi (sin(theta) -> 0; NaN or wrong poses). A camera facing the target
# sees R_cam_target ~ diag(1, -1, -1) (pi about x), and pi about z shows up after an
# in-plane half turn. We therefore solve in a pre-rotated target frame p = G p' with
# G = diag(1,-1,-1) Rz(k 90deg) (keeps the plane z = 0 and maps the square's corners onto
# themselves), k chosen from a homography estimate so that R_cam_target G ~ identity.
_FLIP = np.diag([1.0, -1.0, -1.0])
_G_CANDIDATES = [
    _FLIP @ np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]).round(12)
    for a in (0.0, np.pi / 2, np.pi, 3 * np.pi / 2)
]


def _homography_rotation(obj: np.ndarray, img: np.ndarray, K, dist) -> np.ndarray | None:
    """Rough R_cam_target (3,3) from the plane homography of z = 0 points, or None."""
    try:
        norm = cv2.undistortPoints(img.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
        Hm, _ = cv2.findHomography(obj[:, :2], norm, 0)
    except cv2.error:
        return None
    if Hm is None or not np.all(np.isfinite(Hm)):
        return None
    h1, h2, h3 = Hm[:, 0], Hm[:, 1], Hm[:, 2]
    scale = np.linalg.norm(h1) + np.linalg.norm(h2)
    if not scale > 0:
        return None
    lam = 2.0 / scale * (1.0 if h3[2] >= 0 else -1.0)
    M = np.column_stack([lam * h1, lam * h2, np.cross(lam * h1, lam * h2)])
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def _pre_rotation(obj: np.ndarray, img: np.ndarray, K, dist) -> np.ndarray:
    """G (3,3) among _G_CANDIDATES that brings the expected R_cam_target G nearest identity."""
    R0 = _homography_rotation(obj, img, K, dist)
    if R0 is None:
        return _G_CANDIDATES[0]
    return max(_G_CANDIDATES, key=lambda G: float(np.trace(R0 @ G)))


def _T_of(rv, tv, G: np.ndarray) -> np.ndarray:
    """T_cam_target from a pose (rv, tv) solved for the pre-rotated frame p = G p'."""
    T = T_from_rvec_tvec(rv, tv)
    T[:3, :3] = T[:3, :3] @ G.T
    return T


def solve_planar(obj_pts, img_pts, K, dist=None, square: bool = False, refine: bool = True) -> PlanarPose | None:
    """Pose of a planar target from N >= 4 correspondences.

    obj_pts: (N,3) target-frame points in metres, all with z = 0 (for ``square=True``
    the IPPE_SQUARE corners (-s/2,s/2,0), (s/2,s/2,0), (s/2,-s/2,0), (-s/2,-s/2,0), in that order).
    img_pts: (N,2) pixel coordinates (distorted if ``dist`` is given). K: (3,3).
    dist: OpenCV distortion coefficients or None. Returns None when the input is not finite,
    OpenCV fails, or no solution is in front of the camera and facing it.
    """
    obj = np.asarray(obj_pts, np.float64).reshape(-1, 3)
    img = np.asarray(img_pts, np.float64).reshape(-1, 2)
    n = obj.shape[0]
    if n < 4 or img.shape[0] != n or not (np.all(np.isfinite(obj)) and np.all(np.isfinite(img))):
        return None
    if np.max(np.abs(img)) > 1e7 or np.max(np.abs(obj[:, 2])) > 1e-9 * max(1.0, np.max(np.abs(obj))):
        return None
    G = _pre_rotation(obj, img, K, dist)
    obj_f = obj @ G  # p' = G^T p, row-wise
    order = list(range(n))
    if square:  # IPPE_SQUARE wants its canonical corner order in the solved frame
        canon = np.array([[-1, 1], [1, 1], [1, -1], [-1, -1]], float)
        order = [int(np.argmin(np.abs(np.sign(obj_f[:, :2].round(12)) - c).sum(axis=1))) for c in canon]
        if n != 4 or sorted(order) != [0, 1, 2, 3]:
            return None
    obj_f = np.ascontiguousarray(obj_f[order])
    img_f = np.ascontiguousarray(img[order])
    # IPPE also returns NaN for some exactly fronto-parallel views: SQPnP is the fallback.
    for flag in (cv2.SOLVEPNP_IPPE_SQUARE if square else cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_SQPNP):
        cands = _candidates(obj_f, img_f, K, dist, flag, G, obj)
        if cands:
            break
    else:
        return None
    cands.sort(key=lambda c: c[0])
    err, rv, tv = cands[0]
    alt = cands[1][0] if len(cands) > 1 else float("inf")
    if refine:
        rv, tv, err = _refine_lm(obj_f, img_f, K, dist, rv, tv, err, G, obj)
    T = _T_of(rv, tv, G)
    if not (np.isfinite(err) and pose_is_plausible(T, obj)):
        return None
    return PlanarPose(T, float(err), n, float(alt))


def _candidates(obj_f, img_f, K, dist, flag, G, obj) -> list:
    """Plausible solutions [(rms_px, rvec, tvec)] of solvePnPGeneric with ``flag``."""
    try:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj_f, img_f, K, dist, flags=flag)
    except cv2.error:
        return []
    out = []
    for rv, tv in zip(rvecs, tvecs):
        if np.all(np.isfinite(rv)) and np.all(np.isfinite(tv)) and pose_is_plausible(_T_of(rv, tv, G), obj):
            out.append((reprojection_rms(obj_f, img_f, rv, tv, K, dist), rv, tv))
    return out


def _refine_lm(obj_f, img_f, K, dist, rv, tv, err, G, obj):
    """solvePnPRefineLM from (rv, tv) (pose of the pre-rotated frame, see _pre_rotation);
    keeps the input when the refinement fails, gets worse or becomes implausible."""
    rv2, tv2 = rv.copy().reshape(3, 1), tv.copy().reshape(3, 1)
    try:
        rv2, tv2 = cv2.solvePnPRefineLM(obj_f, img_f, K, dist, rv2, tv2)
    except cv2.error:
        return rv, tv, err
    if not (np.all(np.isfinite(rv2)) and np.all(np.isfinite(tv2))):
        return rv, tv, err
    err2 = reprojection_rms(obj_f, img_f, rv2, tv2, K, dist)
    if not (err2 <= err + 1e-9) or not pose_is_plausible(_T_of(rv2, tv2, G), obj):
        return rv, tv, err
    return rv2, tv2, err2


def estimate_dict(T_cam_dock: np.ndarray, marker_id: str, pose: PlanarPose) -> dict | None:
    """The localizer result dict (distance m, T_cam_dock 4x4, marker_id, n_points,
    reproj_err_px), or None if the pose is not finite or the distance is not > 0."""
    T = np.asarray(T_cam_dock, np.float64)
    d = distance_to_dock_plane(T)
    if not (np.all(np.isfinite(T)) and np.isfinite(d) and d > 0.0):
        return None
    return {
        "distance": d,
        "T_cam_dock": T,
        "marker_id": str(marker_id),
        "n_points": int(pose.n_points),
        "reproj_err_px": float(pose.reproj_err_px),
    }
