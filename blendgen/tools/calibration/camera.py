"""Camera calibration check (the article's Table 4): Zhang's method on rendered chessboards.

For each resolution and trial a seeded set of board poses is drawn (tilt up to
``max_tilt_deg``, projected plate area ``fill`` of the image, whole plate inside
the image, checked by projecting its corners with the ground-truth K), rendered by
one Blender worker (:mod:`blendgen.blender.calibration_scene`), detected with
``cv2.findChessboardCorners``, refined with ``cv2.cornerSubPix`` on sRGB-decoded
linear intensity, and calibrated with ``cv2.calibrateCamera``. The table reports
the relative error of fx, fy, cx, cy against K, mean over trials, and the RMS
reprojection error.

Board frame = world frame: the plate lies in z = 0 facing +z, +x right, +y up;
texture row 0 is the top (+y) edge. Inner corners are ordered row by row from
the top-left, as OpenCV orders them for an upright board.

Pure Python (numpy; OpenCV imported on use): Blender runs only in the worker subprocess.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import Field, ValidationError

from blendgen.config.bundled import bundled_file
from blendgen.config.models import ConfigError, Strict, _read_yaml, format_validation_error
from blendgen.geometry import axis_angle_to_R, intrinsics_from_hfov, invert_T, make_T, project, rot_z, transform_points
from blendgen.pipeline import executor as ex

DEFAULT_CONFIG = bundled_file("configs", "calibration.yaml")
PARAMS = ("fx", "fy", "cx", "cy")


# ----------------------------------------------------------------------------- config


class Board(Strict):
    """Chessboard: ``cols`` x ``rows`` inner corners, squares ``square_m`` wide, a white
    border ``border_squares`` squares wide; cell radiances (linear) ``black``, ``white``."""

    cols: int = Field(9, ge=3, le=40)
    rows: int = Field(6, ge=3, le=40)
    square_m: float = Field(0.05, gt=0.001, le=1.0)
    border_squares: int = Field(1, ge=1, le=5)
    black: float = Field(0.04, ge=0.0, le=1.0)
    white: float = Field(0.85, ge=0.0, le=1.0)


class Poses(Strict):
    """Pose sampler: board tilt (deg), projected plate area / image area, margin (px)."""

    max_tilt_deg: float = Field(45.0, ge=0.0, le=70.0)
    fill_min: float = Field(0.2, gt=0.0, lt=1.0)
    fill_max: float = Field(0.7, gt=0.0, lt=1.0)
    margin_px: float = Field(4.0, ge=0.0, le=100.0)


class CalibrationConfig(Strict):
    resolutions: list[tuple[int, int]] = [(1920, 1080), (1280, 720), (640, 480)]
    trials: int = Field(5, ge=1, le=100)
    poses_per_trial: int = Field(15, ge=4, le=500)
    hfov_deg: float = Field(60.0, gt=1.0, lt=179.0)
    samples: int = Field(16, ge=1, le=4096)
    seed: int = Field(0, ge=0)
    fix_distortion: bool = False  # False: OpenCV's default model (k1, k2, p1, p2, k3 estimated)
    board: Board = Board()
    poses: Poses = Poses()


def load_config(path: str | Path) -> CalibrationConfig:
    path = Path(path)
    raw = _read_yaml(path)
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: the config must be a YAML mapping, got {type(raw).__name__}")
    try:
        cfg = CalibrationConfig.model_validate(raw)
    except ValidationError as e:
        raise ConfigError(format_validation_error(path, e)) from None
    if cfg.poses.fill_min > cfg.poses.fill_max:
        raise ConfigError(f"{path}: poses: fill_min {cfg.poses.fill_min} > fill_max {cfg.poses.fill_max}")
    for w, h in cfg.resolutions:
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise ConfigError(f"{path}: resolutions: {w}x{h} outside 16..8192 px")
    return cfg


# ----------------------------------------------------------------------------- board


@dataclass(frozen=True)
class ChessBoard:
    cols: int
    rows: int
    square_m: float
    border: int = 1

    @classmethod
    def from_config(cls, b: Board) -> ChessBoard:
        return cls(b.cols, b.rows, b.square_m, b.border_squares)

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's patternSize: (corners per row, corners per column)."""
        return self.cols, self.rows

    @property
    def cells_shape(self) -> tuple[int, int]:
        """Texture (rows, cols) in cells: squares plus the white border."""
        return self.rows + 1 + 2 * self.border, self.cols + 1 + 2 * self.border

    @property
    def plate_size_m(self) -> tuple[float, float]:
        """Physical plate (width, height), metres."""
        r, c = self.cells_shape
        return c * self.square_m, r * self.square_m

    def cells(self) -> np.ndarray:
        """uint8 texture (rows, cols), one pixel per square: 0 black, 255 white; the
        top-left square is black, the border is white."""
        r, c = self.cells_shape
        img = np.full((r, c), 255, np.uint8)
        ii, jj = np.mgrid[0 : self.rows + 1, 0 : self.cols + 1]
        img[self.border : self.border + self.rows + 1, self.border : self.border + self.cols + 1] = np.where(
            (ii + jj) % 2 == 0, 0, 255
        ).astype(np.uint8)
        return img

    def corners(self) -> np.ndarray:
        """Inner corners (rows*cols, 3) in the board frame, row by row from the top-left."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        x = (i - (self.cols - 1) / 2.0) * self.square_m
        y = ((self.rows - 1) / 2.0 - j) * self.square_m
        return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])

    def outline(self) -> np.ndarray:
        """Plate corners (4,3) TL, TR, BR, BL in the board frame."""
        w, h = (s / 2 for s in self.plate_size_m)
        return np.array([[-w, h, 0.0], [w, h, 0.0], [w, -h, 0.0], [-w, -h, 0.0]])


# ----------------------------------------------------------------------------- poses


def polygon_area(uv: np.ndarray) -> float:
    x, y = uv[:, 0], uv[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def board_in_view(
    K: np.ndarray, T_cam_board: np.ndarray, board: ChessBoard, width: int, height: int, margin_px: float = 0.0
) -> bool:
    """True when the whole plate projects inside the image, ``margin_px`` from its edges
    (pixel centres at integers: the image spans [-0.5, W - 0.5])."""
    P = transform_points(T_cam_board, board.outline())
    if np.any(P[:, 2] <= 0):
        return False
    uv = project(K, P)
    lo = -0.5 + margin_px
    return bool(
        np.all(uv[:, 0] >= lo)
        and np.all(uv[:, 0] <= width - 0.5 - margin_px)
        and np.all(uv[:, 1] >= lo)
        and np.all(uv[:, 1] <= height - 0.5 - margin_px)
    )


def board_fill(K: np.ndarray, T_cam_board: np.ndarray, board: ChessBoard, width: int, height: int) -> float:
    """Projected plate area / image area."""
    uv = project(K, transform_points(T_cam_board, board.outline()))
    return polygon_area(uv) / (width * height)


def board_tilt_deg(T_cam_board: np.ndarray) -> float:
    """Angle (deg) between the plate normal and the line of sight to its centre."""
    n = T_cam_board[:3, 2]
    t = T_cam_board[:3, 3]
    return math.degrees(math.acos(np.clip(-n @ t / np.linalg.norm(t), -1.0, 1.0)))


def sample_pose(
    rng: np.random.Generator,
    K: np.ndarray,
    board: ChessBoard,
    width: int,
    height: int,
    poses: Poses,
    max_tries: int = 500,
) -> np.ndarray:
    """One random T_cam_board (4x4): tilt <= max_tilt_deg (from facing the camera),
    any roll, projected plate area in [fill_min, fill_max] of the image, the whole
    plate inside the image with ``margin_px``. Rejection sampling."""
    Kinv = np.linalg.inv(K)
    R_facing = np.diag([1.0, -1.0, -1.0])  # board +x -> image right, +y -> image up, +z -> camera
    outline = board.outline()
    for _ in range(max_tries):
        tilt = math.radians(rng.uniform(0.0, poses.max_tilt_deg))
        az = rng.uniform(0.0, 2 * math.pi)
        roll = rng.uniform(-math.pi, math.pi)
        fill = rng.uniform(poses.fill_min, poses.fill_max)
        u0, v0 = rng.uniform(0.15, 0.85) * width, rng.uniform(0.15, 0.85) * height
        ray = Kinv @ np.array([u0, v0, 1.0])
        ray /= np.linalg.norm(ray)
        # tilt about an axis perpendicular to the line of sight, measured from facing it
        R_face_ray = _look_along(ray)
        R = R_face_ray @ axis_angle_to_R([math.cos(az), math.sin(az), 0.0], tilt) @ rot_z(roll) @ R_facing
        d = 1.0
        for _ in range(8):  # projected area ~ 1/d^2
            T = make_T(R, d * ray)
            P = transform_points(T, outline)
            if np.any(P[:, 2] <= 1e-3):
                d *= 2.0
                continue
            a = polygon_area(project(K, P)) / (width * height)
            d *= math.sqrt(a / fill)
        T = make_T(R, d * ray)
        if not board_in_view(K, T, board, width, height, poses.margin_px):
            continue
        if not (poses.fill_min <= board_fill(K, T, board, width, height) <= poses.fill_max):
            continue
        return T
    raise RuntimeError(
        f"no board pose found in {max_tries} tries for {width}x{height}: "
        f"loosen poses.fill_max / max_tilt_deg / margin_px"
    )


def _look_along(ray: np.ndarray) -> np.ndarray:
    """Rotation taking the camera's +z onto ``ray`` (unit), minimal angle."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, ray)
    s = np.linalg.norm(axis)
    if s < 1e-12:
        return np.eye(3)
    return axis_angle_to_R(axis, math.atan2(s, float(z @ ray)))


def sample_poses(
    seed: int, n: int, K: np.ndarray, board: ChessBoard, width: int, height: int, poses: Poses
) -> list[np.ndarray]:
    """``n`` seeded T_cam_board poses (see :func:`sample_pose`)."""
    rng = np.random.default_rng(seed)
    return [sample_pose(rng, K, board, width, height, poses) for _ in range(n)]


def trial_seed(base: int, width: int, height: int, trial: int) -> int:
    """Independent, reproducible seed per (resolution, trial)."""
    return int(np.random.SeedSequence([base, width, height, trial]).generate_state(1)[0])


# ----------------------------------------------------------------------------- detection + Zhang


def subpix_half_window(corners: np.ndarray, board: ChessBoard) -> int:
    """cornerSubPix half-window: 0.4 of the shortest corner spacing, 2..15 px, so the
    window never reaches a neighbouring corner."""
    c = corners.reshape(board.rows, board.cols, 2)
    dx = np.linalg.norm(np.diff(c, axis=1), axis=2).min()
    dy = np.linalg.norm(np.diff(c, axis=0), axis=2).min()
    return int(np.clip(math.floor(0.4 * min(dx, dy)), 2, 15))


def detect_corners(gray: np.ndarray, board: ChessBoard) -> np.ndarray | None:
    """Inner corners (N,2) of an 8-bit sRGB grey image, refined on linear intensity
    (on gamma-encoded pixels cornerSubPix is biased ~0.3 px), or None if not found."""
    import cv2

    from evalkit.localizers.square import linear_gray

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, c = cv2.findChessboardCorners(gray, board.pattern_size, flags=flags)
    if not ok or c is None:
        return None
    win = subpix_half_window(c.reshape(-1, 2), board)
    c = c.astype(np.float32).reshape(-1, 1, 2).copy()
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    cv2.cornerSubPix(linear_gray(gray), c, (win, win), (-1, -1), crit)
    return c.reshape(-1, 2).astype(np.float64)


def order_like(detected: np.ndarray, truth_uv: np.ndarray) -> tuple[np.ndarray, float]:
    """Detected corners in the board's order (OpenCV may start from either end of a
    non-square board): the ordering, as found or reversed, nearer the projection of
    the true corners. Returns (corners, mean distance to truth in px). Only the order
    is taken from the truth; Zhang's method never sees the true pose."""
    best = None
    for cand in (detected, detected[::-1]):
        e = float(np.mean(np.linalg.norm(cand - truth_uv, axis=1)))
        if best is None or e < best[1]:
            best = (cand, e)
    return best


@dataclass
class TrialResult:
    width: int
    height: int
    trial: int
    n_views: int
    K_true: np.ndarray
    K_est: np.ndarray | None
    dist: np.ndarray | None
    rms_px: float
    corner_err_px: float  # mean |detected - true projection| over all used corners

    def rel_err_pct(self) -> dict[str, float]:
        if self.K_est is None:
            return {p: float("nan") for p in PARAMS}
        idx = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
        return {p: 100.0 * abs(self.K_est[i] - self.K_true[i]) / self.K_true[i] for p, i in idx.items()}


def calibrate(
    image_paths: list[Path],
    T_cam_boards: list[np.ndarray],
    board: ChessBoard,
    K_true: np.ndarray,
    width: int,
    height: int,
    trial: int = 0,
    fix_distortion: bool = False,
) -> TrialResult:
    """Detect, refine and run cv2.calibrateCamera on one trial's images."""
    import cv2

    obj = board.corners().astype(np.float32)
    objpts, imgpts, errs = [], [], []
    for path, T in zip(image_paths, T_cam_boards):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise RuntimeError(f"cannot read {path}")
        c = detect_corners(gray, board)
        if c is None:
            continue
        truth = project(K_true, transform_points(np.asarray(T, float), obj))
        c, e = order_like(c, truth)
        if e > 2.0:  # a mis-ordered or wrong detection: drop the view
            continue
        objpts.append(obj.copy())
        imgpts.append(c.astype(np.float32).reshape(-1, 1, 2))
        errs.append(e)
    if len(objpts) < 3:
        return TrialResult(width, height, trial, len(objpts), K_true, None, None, float("nan"), float("nan"))
    flags = 0
    if fix_distortion:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, dist, _, _ = cv2.calibrateCamera(objpts, imgpts, (width, height), None, None, flags=flags, criteria=crit)
    return TrialResult(width, height, trial, len(objpts), K_true, K, dist.ravel(), float(rms), float(np.mean(errs)))


# ----------------------------------------------------------------------------- rendering


def write_job(
    cfg: CalibrationConfig,
    board: ChessBoard,
    texture: Path,
    width: int,
    height: int,
    trial: int,
    out: Path,
    threads: int,
) -> tuple[Path, list[np.ndarray], list[Path]]:
    """Plan one (resolution, trial): sample its poses and write the worker's job file."""
    K = intrinsics_from_hfov(width, height, math.radians(cfg.hfov_deg))
    seed = trial_seed(cfg.seed, width, height, trial)
    Ts = sample_poses(seed, cfg.poses_per_trial, K, board, width, height, cfg.poses)
    d = out / "frames" / f"{width}x{height}" / f"trial{trial}"
    d.mkdir(parents=True, exist_ok=True)
    paths = [d / f"{i:03d}.png" for i in range(len(Ts))]
    job = {
        "board": {
            "texture": str(texture),
            "plate_size_m": list(board.plate_size_m),
            "black": cfg.board.black,
            "white": cfg.board.white,
        },
        "camera": {"width": width, "height": height, "hfov_rad": math.radians(cfg.hfov_deg)},
        "render": {"samples": cfg.samples, "threads": threads, "seed": seed % 2**31},
        "frames": [
            {"index": i, "T_world_cam": invert_T(T).tolist(), "path": str(p)} for i, (T, p) in enumerate(zip(Ts, paths))
        ],
        "progress": str(d / "frames.jsonl"),
        "log": str(d / "render.log"),
        "timing_out": str(d / "timing.json"),
    }
    jf = d / "job.json"
    jf.write_text(json.dumps(job))
    return jf, Ts, paths


def with_overrides(
    cfg: CalibrationConfig, size: tuple[int, int] | None = None, trials: int | None = None
) -> CalibrationConfig:
    """``cfg`` with one resolution ``size`` (px) instead of the config's list and/or ``trials``."""
    update = {}
    if size is not None:
        update["resolutions"] = [tuple(int(v) for v in size)]
    if trials is not None:
        update["trials"] = int(trials)
    return cfg.model_copy(update=update)


def run_calibration(cfg: CalibrationConfig, out: Path, progress: bool = True) -> list[TrialResult]:
    """Render and calibrate every (resolution, trial), with a progress bar (stderr) over the
    trials. Rendering of the next trial overlaps the detection and calibration of the previous one."""
    from evalkit.runner import progress_bar

    ex.require_render_stack()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    import cv2

    board = ChessBoard.from_config(cfg.board)
    texture = out / "chessboard.png"
    cv2.imwrite(str(texture), board.cells())
    threads = os.cpu_count() or 1
    t0 = time.perf_counter()
    todo = [(w, h, k) for w, h in cfg.resolutions for k in range(cfg.trials)]
    results: list[TrialResult] = []
    pending = None  # (job_file, Ts, paths, (w, h, k))

    def finish(item) -> None:
        jf, Ts, paths, (w, h, k) = item
        K = intrinsics_from_hfov(w, h, math.radians(cfg.hfov_deg))
        r = calibrate(paths, Ts, board, K, w, h, k, cfg.fix_distortion)
        results.append(r)
        if progress:
            e = r.rel_err_pct()
            print(
                f"calibrate: {w}x{h} trial {k}: {r.n_views}/{len(paths)} views, rms {r.rms_px:.3f} px, "
                + ", ".join(f"{p} {e[p]:.3f}%" for p in PARAMS)
                + f" ({time.perf_counter() - t0:.0f} s)",
                file=sys.stderr,
            )

    children = ex.Children()
    with (
        ThreadPoolExecutor(max_workers=1) as pool,
        progress_bar(len(todo), progress, "calibrate: render + Zhang, trials") as tick,
    ):
        try:
            for w, h, k in todo:
                jf, Ts, paths = write_job(cfg, board, texture, w, h, k, out, threads)
                rendering = pool.submit(ex.run_worker, jf, jf.parent / "render.log", children, ex.calibration_command)
                if pending is not None:  # calibrate the previous trial while this one renders
                    finish(pending)
                    tick(1)
                rendering.result()
                pending = (jf, Ts, paths, (w, h, k))
        except BaseException:
            children.kill()  # an interrupt or a failed render ends every worker
            raise
        if pending is not None:
            finish(pending)
            tick(1)
    return results


# ----------------------------------------------------------------------------- table


def summarize(results: list[TrialResult]) -> list[dict]:
    """One row per resolution: mean (and max) relative error % of fx, fy, cx, cy over
    trials, mean RMS reprojection error (px), mean corner error vs truth (px)."""
    rows = []
    for res in dict.fromkeys((r.width, r.height) for r in results):
        rs = [r for r in results if (r.width, r.height) == res]
        errs = [r.rel_err_pct() for r in rs]
        row = {"resolution": f"{res[0]}x{res[1]}", "trials": len(rs)}
        for p in PARAMS:
            v = np.array([e[p] for e in errs])
            row[f"{p}_err_pct"] = float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
            row[f"{p}_err_pct_max"] = float(np.nanmax(v)) if np.isfinite(v).any() else float("nan")
        rms = np.array([r.rms_px for r in rs])
        row["rms_px"] = float(np.nanmean(rms)) if np.isfinite(rms).any() else float("nan")
        row["corner_err_px"] = float(np.nanmean([r.corner_err_px for r in rs]))
        row["views"] = int(sum(r.n_views for r in rs))
        rows.append(row)
    return rows


def format_table(rows: list[dict]) -> str:
    head = (
        f"{'resolution':<11}"
        + "".join(f"{p + ' err %':>10}" for p in PARAMS)
        + f"{'RMS px':>9}{'corner px':>11}{'views':>7}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['resolution']:<11}"
            + "".join(f"{r[p + '_err_pct']:>10.4f}" for p in PARAMS)
            + f"{r['rms_px']:>9.3f}{r['corner_err_px']:>11.3f}{r['views']:>7d}"
        )
    return "\n".join(lines)


def write_csv(results: list[TrialResult], rows: list[dict], out: Path) -> tuple[Path, Path]:
    out = Path(out)
    per_trial = out / "calibration_trials.csv"
    with open(per_trial, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "resolution",
                "trial",
                "views",
                *(f"{p}_true" for p in PARAMS),
                *(f"{p}_est" for p in PARAMS),
                *(f"{p}_err_pct" for p in PARAMS),
                "rms_px",
                "corner_err_px",
                "dist_coeffs",
            ]
        )
        for r in results:
            t = [r.K_true[0, 0], r.K_true[1, 1], r.K_true[0, 2], r.K_true[1, 2]]
            e = [r.K_est[0, 0], r.K_est[1, 1], r.K_est[0, 2], r.K_est[1, 2]] if r.K_est is not None else [""] * 4
            rel = r.rel_err_pct()
            w.writerow(
                [
                    f"{r.width}x{r.height}",
                    r.trial,
                    r.n_views,
                    *t,
                    *e,
                    *(rel[p] for p in PARAMS),
                    r.rms_px,
                    r.corner_err_px,
                    " ".join(f"{x:.3e}" for x in r.dist) if r.dist is not None else "",
                ]
            )
    summary = out / "calibration.csv"
    with open(summary, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return summary, per_trial
