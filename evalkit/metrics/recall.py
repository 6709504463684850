"""Pose-level recall of the dock, BOP style: MSSD / MSPD errors with the marker models and ``AR_dock``.

``AR_dock`` is dockbench's own number, **not** the BOP Challenge's average recall: it uses the
MSSD and MSPD of the BOP Challenge 2019+ (Hodan et al., "BOP Challenge 2020 on 6D object
localization", section 2.2) with the whole dock as one object and without VSD, per trajectory.
The BOP19 AR as the BOP toolkit computes it (every marker its own object, VSD + MSSD + MSPD
pooled over the targets of a BOP export) is :func:`evalkit.reports.bop_score.bop19_scores`
(``dockbench export-bop --results``). Here:

* the **dock model** is the vertices of every marker's model (:func:`marker_model`: a
  plate :data:`MODEL_THICKNESS_M` deep for printed markers, a small cube per LED for
  LED arrays; the same meshes ``export-bop`` writes) expressed in the dock frame;
* ``MSSD = max_x |T_est x - T_true x|`` (m) over the model vertices ``x``;
* ``MSPD = max_x |proj(T_est x) - proj(T_true x)|`` (px), pinhole ``K`` (BOP ignores
  distortion too);
* ``AR_dock_MSSD`` = mean over thresholds ``0.05, 0.10, ..., 0.50 x`` the dock model's diameter
  of the fraction of *targets* whose MSSD is below the threshold; ``AR_dock_MSPD`` the same
  with ``5, 10, ..., 50 px x width/640``; ``AR_dock = (AR_dock_MSSD + AR_dock_MSPD) / 2``.

Targets are the counted frames (``0 <= d_true <= d_max``) with a marker in view; a
target without a detected pose is a miss. Marker symmetries are not modelled: the
coded markers (ArUco, QR, LED layouts with a reference LED) have none. A localizer
that never returns a pose has no AR_dock (NaN), not 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from evalkit.metrics import core

MODEL_THICKNESS_M = 0.005
MSSD_FRACTIONS = np.round(np.arange(1, 11) * 0.05, 2)
MSPD_PX_AT_640 = np.arange(1, 11) * 5.0
RECALL_COLUMNS = ["AR_dock_MSSD", "AR_dock_MSPD", "AR_dock"]


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def marker_points(marker: dict) -> np.ndarray:
    """Keypoints of a marker in its own frame (m), ``(N, 3)`` (manifest keypoints are in the dock frame)."""
    kp = np.asarray(marker.get("keypoints") or [], dtype=float).reshape(-1, 3)
    T_marker_dock = _inv(np.asarray(marker.get("T_dock_marker", np.eye(4)), dtype=float))
    return kp @ T_marker_dock[:3, :3].T + T_marker_dock[:3, 3]


def _outward(faces: np.ndarray) -> np.ndarray:
    """``faces`` of a unit :func:`_box` with each triangle wound counter-clockwise seen
    from outside (normal away from the centre), as renderers expect."""
    v = _box(0.0, 0.0, 1.0, 1.0, 0.0, 1.0)
    out = faces.copy()
    for i, (a, b, c) in enumerate(faces):
        normal = np.cross(v[b] - v[a], v[c] - v[a])
        if normal @ (v[[a, b, c]].mean(axis=0) - 0.5) < 0:
            out[i] = (a, c, b)
    return out


def _box(x0: float, y0: float, x1: float, y1: float, z0: float, z1: float) -> np.ndarray:
    """8 vertices: the face at ``z1`` TL, TR, BR, BL, then the same at ``z0``."""
    face = np.array([[x0, y1], [x1, y1], [x1, y0], [x0, y0]])
    return np.vstack([np.c_[face, np.full(4, z1)], np.c_[face, np.full(4, z0)]])


BOX_FACES = _outward(
    np.array(
        [
            [0, 1, 2],
            [0, 2, 3],
            [4, 5, 6],
            [4, 6, 7],
            [0, 4, 5],
            [0, 5, 1],
            [1, 5, 6],
            [1, 6, 2],
            [2, 6, 7],
            [2, 7, 3],
            [3, 7, 4],
            [3, 4, 0],
        ]
    )
)


def is_led_array(marker: dict) -> bool:
    """LED arrays are modelled LED by LED; every other marker as one plate."""
    return str(marker.get("kind", "")).startswith("led") and float(marker.get("led_radius_m") or 0) > 0


def marker_model(marker: dict, thickness_m: float = MODEL_THICKNESS_M) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh of a marker in its own frame: ``(vertices (8k, 3) m, faces (12k, 3))``,
    ``k`` boxes of 8 vertices each.

    * planar markers: one box, the keypoints' bounding rectangle in ``z = 0`` (or a
      ``size_m`` square without keypoints), ``thickness_m`` deep behind the face (-z);
    * LED arrays: one cube of side ``2 led_radius_m`` around each LED (keypoint), so the
      model is the lit geometry a camera sees, not the empty rectangle between the LEDs.
    """
    pts = marker_points(marker)
    if is_led_array(marker) and len(pts):
        r = float(marker["led_radius_m"])
        boxes = [_box(x - r, y - r, x + r, y + r, z - r, z + r) for x, y, z in pts]
    else:
        if len(pts) == 0:
            s = float(marker.get("size_m", 0.1)) / 2
            pts = np.array([[-s, -s, 0], [s, s, 0]])
        boxes = [_box(pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max(), -thickness_m, 0.0)]
    faces = np.vstack([BOX_FACES + 8 * i for i in range(len(boxes))])
    return np.vstack(boxes), faces


@dataclass(frozen=True)
class DockModel:
    """Vertices of all marker models in the dock frame and the camera that sees them.

    ``points``: ``(N, 3)`` m; ``diameter_m``: largest vertex distance (m);
    ``K``: 3x3 intrinsics (px); ``width``: image width (px)."""

    points: np.ndarray
    diameter_m: float
    K: np.ndarray
    width: int

    @classmethod
    def from_markers(cls, markers: list[dict], K, width: int) -> DockModel | None:
        """The model of a dataset's markers; None if there are none."""
        parts = []
        for m in markers:
            T = np.asarray(m.get("T_dock_marker", np.eye(4)), dtype=float)
            vertices, _ = marker_model(m)
            parts.append(vertices @ T[:3, :3].T + T[:3, 3])
        if not parts:
            return None
        pts = np.vstack(parts)
        diam = float(np.max(np.linalg.norm(pts[:, None] - pts[None], axis=2)))
        return cls(pts, diam, np.asarray(K, dtype=float), int(width))

    def mssd_thresholds(self) -> np.ndarray:
        """MSSD thresholds (m)."""
        return MSSD_FRACTIONS * self.diameter_m

    def mspd_thresholds(self) -> np.ndarray:
        """MSPD thresholds (px)."""
        return MSPD_PX_AT_640 * self.width / 640.0


def _project(pts_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``(F, N, 3)`` camera points -> ``(F, N, 2)`` pixels; NaN behind the camera."""
    z = pts_cam[..., 2:3]
    uv = np.einsum("ij,fnj->fni", K[:2, :2], pts_cam[..., :2] / np.where(z > 1e-9, z, np.nan))
    return uv + K[:2, 2]


def mssd_mspd(df: pd.DataFrame, model: DockModel) -> pd.DataFrame:
    """Per-frame ``mssd_m`` (m) and ``mspd_px`` (px); NaN without a detected estimated pose.

    A vertex behind the camera in either pose makes MSPD infinite (a miss)."""
    out = pd.DataFrame(np.nan, index=df.index, columns=["mssd_m", "mspd_px"])
    if core.EST_POSE not in df.columns or core.TRUE_POSE not in df.columns or df.empty:
        return out
    est, true = core.as_matrices(df[core.EST_POSE]), core.as_matrices(df[core.TRUE_POSE])
    ok = core.detected_mask(df).to_numpy() & np.isfinite(est).all(axis=(1, 2)) & np.isfinite(true).all(axis=(1, 2))
    if not ok.any():
        return out
    p = model.points
    pe = np.einsum("fij,nj->fni", est[ok, :3, :3], p) + est[ok, None, :3, 3]
    pt = np.einsum("fij,nj->fni", true[ok, :3, :3], p) + true[ok, None, :3, 3]
    out.loc[ok, "mssd_m"] = np.linalg.norm(pe - pt, axis=2).max(axis=1)
    d_px = np.linalg.norm(_project(pe, model.K) - _project(pt, model.K), axis=2)
    out.loc[ok, "mspd_px"] = np.where(np.isnan(d_px).any(axis=1), np.inf, np.nanmax(d_px, axis=1))
    return out


def average_recall(errors: np.ndarray, thresholds: np.ndarray) -> float:
    """Mean over ``thresholds`` of the fraction of ``errors`` below it (NaN error = miss);
    NaN for no target."""
    e = np.asarray(errors, dtype=float)
    if e.size == 0:
        return float("nan")
    e = np.where(np.isnan(e), np.inf, e)
    return float(np.mean([(e < t).mean() for t in thresholds]))


def recall_table(frames: pd.DataFrame, model: DockModel | None, d_max: float = core.D_MAX_M) -> pd.DataFrame:
    """Per (localizer, trajectory, condition): :data:`RECALL_COLUMNS` and ``n_targets``.

    ``frames`` needs ``mssd_m``/``mspd_px`` (:func:`mssd_mspd`). NaN ARs when there is
    no model or the localizer returned no pose in the group."""
    group = core.GROUP
    targets = frames[core.counted_mask(frames["d_true"], d_max) & frames["in_view"].fillna(False).astype(bool)]
    rows = []
    for key, g in frames.groupby(group, sort=True, dropna=False):
        t = targets[(targets[group] == pd.Series(key, index=group)).all(axis=1)]
        row = dict(zip(group, key), n_targets=len(t))
        has_pose = model is not None and "mssd_m" in g.columns and g["mssd_m"].notna().any()
        if has_pose and model is not None:
            row["AR_dock_MSSD"] = average_recall(t["mssd_m"].to_numpy(), model.mssd_thresholds())
            row["AR_dock_MSPD"] = average_recall(t["mspd_px"].to_numpy(), model.mspd_thresholds())
            row["AR_dock"] = (row["AR_dock_MSSD"] + row["AR_dock_MSPD"]) / 2.0
        rows.append(row)
    return pd.DataFrame(rows, columns=group + ["n_targets"] + RECALL_COLUMNS)
