"""Synthetic marker images drawn with OpenCV only (test helper, no Blender).

Pixel convention (OpenCV, FORMAT.md): pixel (u, v) has its centre at integer (u, v)
and covers [u-0.5, u+0.5] x [v-0.5, v+0.5].

Anti-aliasing: everything is drawn at ``ss`` times the resolution and box-filtered
down with INTER_AREA. A high-res pixel i covers low-res [i/ss - 0.5, (i+1)/ss - 0.5],
so its centre is at u = (i + 0.5)/ss - 0.5, i.e. u_hi = ss*u + (ss-1)/2: the high-res
camera is K_hi = [[ss fx, 0, ss cx + (ss-1)/2], [0, ss fy, ss cy + (ss-1)/2], [0, 0, 1]].
Averaging the ss x ss block of pixel u gives back centre u exactly.

Square markers: the texture has one pixel per code cell (M x M cells, quiet zone
included), like blendgen's textures. Texture pixel (a, b) covers texture coordinates
[a-0.5, a+0.5] x [b-0.5, b+0.5], so the texture spans [-0.5, M-0.5]^2 and its corners
(-0.5,-0.5), (M-0.5,-0.5), (M-0.5,M-0.5), (-0.5,M-0.5) are the plate corners TL, TR, BR, BL
at (-P/2, P/2), (P/2, P/2), (P/2, -P/2), (-P/2, -P/2) in the marker frame, with
P = size_m * M / n_code (size_m spans the code without quiet zone). The plate-to-image
map is a homography, so warping with the homography of these 4 corner pairs
(INTER_NEAREST, as Blender samples the texture) puts the code corners exactly at the
projected keypoints.

LEDs: anti-aliased filled circles (sub-pixel centres via ``shift``), a coloured halo of
radius ``halo_scale * f r / Z`` and a white core of radius ``f r / Z``.
"""

from __future__ import annotations

import cv2
import numpy as np

QR_QUIET_MODULES = 4  # ISO/IEC 18004, blendgen's default
ARUCO_QUIET_CELLS = 1
SHIFT = 4  # cv2 drawing fixed-point bits: 1/16 px


def linear_to_srgb(c) -> np.ndarray:
    """Linear RGB in [0,1] -> sRGB in [0,1]."""
    c = np.clip(np.asarray(c, float), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def qr_cells(payload: str, error: str = "m", quiet: int = QR_QUIET_MODULES) -> tuple[np.ndarray, int]:
    """QR cells (uint8, 0 dark / 255 light) with the quiet zone, and the code's module count."""
    import segno

    code = np.array(segno.make_qr(payload, error=error.lower(), boost_error=False).matrix, dtype=np.uint8)
    cells = np.where(code > 0, 0, 255).astype(np.uint8)
    return np.pad(cells, quiet, constant_values=255), code.shape[0]


def aruco_cells(dictionary: str, marker_id: int) -> tuple[np.ndarray, int]:
    """ArUco/AprilTag cells with a one-cell white quiet zone, and the cells of the black square."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = d.markerSize + 2
    img = cv2.aruco.generateImageMarker(d, int(marker_id), n, borderBits=1)
    return np.pad(img, ARUCO_QUIET_CELLS, constant_values=255), n


def camera_dict(K, width, height, markers, dist=None) -> dict:
    """The ``camera`` dict a localizer's reset() receives."""
    return {"width": width, "height": height, "K": np.asarray(K).tolist(), "dist": dist, "markers": markers}


def k_from_hfov(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K with pixel centres at integers (cx = W/2 - 0.5)."""
    f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return np.array([[f, 0, width / 2.0 - 0.5], [0, f, height / 2.0 - 0.5], [0, 0, 1.0]])


def project(K, T_cam_x, pts) -> tuple[np.ndarray, np.ndarray]:
    """Frame-x points (N,3) -> pixels (N,2) and camera depths z (N,)."""
    P = np.asarray(pts, float) @ T_cam_x[:3, :3].T + T_cam_x[:3, 3]
    return (P @ np.asarray(K).T)[:, :2] / P[:, 2:3], P[:, 2]


def _draw_square(img, K_hi, T_cam_dock, marker, plate_grey):
    if marker["kind"] == "qr":
        cells, n_code = qr_cells(
            marker["payload"], marker.get("error_correction", "m"), marker.get("quiet_zone_modules", QR_QUIET_MODULES)
        )
    else:
        cells, n_code = aruco_cells(marker["dictionary"], marker["marker_id"])
    M = cells.shape[0]
    h = marker["size_m"] * M / n_code / 2.0
    plate = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    T_cam_marker = T_cam_dock @ np.asarray(marker["T_dock_marker"], float)
    uv, z = project(K_hi, T_cam_marker, plate)
    if np.any(z <= 0.01):
        return
    src = np.array([[-0.5, -0.5], [M - 0.5, -0.5], [M - 0.5, M - 0.5], [-0.5, M - 0.5]], np.float32)
    H = cv2.getPerspectiveTransform(src, uv.astype(np.float32))
    lo, hi = plate_grey
    tex = (lo + (hi - lo) * (cells.astype(np.float32) / 255.0)).astype(np.uint8)
    tex = np.repeat(tex[:, :, None], 3, axis=2)
    cv2.warpPerspective(
        tex, H, (img.shape[1], img.shape[0]), dst=img, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_TRANSPARENT
    )


def _draw_leds(img, K_hi, T_cam_dock, marker, halo_scale, halo_gain):
    uv, z = project(K_hi, T_cam_dock, marker["keypoints"])
    f = K_hi[0, 0]
    for (u, v), zz, col in zip(uv, z, marker["colors"]):
        if zz <= 0.01:
            continue
        r = f * marker["led_radius_m"] / zz
        c = linear_to_srgb(col)
        halo = tuple(float(x) for x in 255.0 * halo_gain * c / max(c.max(), 1e-6))
        centre = (int(round(u * (1 << SHIFT))), int(round(v * (1 << SHIFT))))
        for radius, colour in ((halo_scale * r, halo), (r, (255.0, 255.0, 255.0))):
            cv2.circle(img, centre, max(1, int(round(radius * (1 << SHIFT)))), colour, -1, cv2.LINE_AA, SHIFT)


def box_downsample_linear(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Average ss x ss blocks in *linear* light, as a sensor integrates radiance over its
    pixel (averaging sRGB codes would darken edges and bias corners inward)."""
    from blendgen.physics.camera.sensor import srgb_decode, to_uint8

    lin = cv2.resize(srgb_decode(img), (width, height), interpolation=cv2.INTER_AREA)
    return to_uint8(lin)


def render(
    K,
    T_cam_dock,
    markers,
    width=640,
    height=480,
    ss=4,
    background=(10, 40, 70),
    plate_grey=(25, 230),
    noise_std=0.0,
    seed=0,
    halo_scale=1.8,
    halo_gain=0.9,
) -> np.ndarray:
    """RGB uint8 (H,W,3) image of ``markers`` (manifest dicts) seen with intrinsics K (3,3)
    from a camera with dock pose ``T_cam_dock`` (4,4); optional Gaussian noise (8-bit std)."""
    K = np.asarray(K, float)
    K_hi = K.copy()
    K_hi[:2, :] *= ss
    K_hi[0, 2] += (ss - 1) / 2.0
    K_hi[1, 2] += (ss - 1) / 2.0
    img = np.empty((height * ss, width * ss, 3), np.uint8)
    img[:] = background
    T = np.asarray(T_cam_dock, float)
    for m in markers:
        if m["kind"] == "led_array":
            _draw_leds(img, K_hi, T, m, halo_scale, halo_gain)
        else:
            _draw_square(img, K_hi, T, m, plate_grey)
    out = box_downsample_linear(img, width, height)
    if noise_std > 0:
        rng = np.random.default_rng(seed)
        out = np.clip(out + rng.normal(0.0, noise_std, out.shape), 0, 255).astype(np.uint8)
    return out


def pose_looking_at_dock(
    distance_m: float, yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0, offset=(0.0, 0.0)
) -> np.ndarray:
    """T_cam_dock for a camera at ``distance_m`` from the dock plane, displaced by viewing
    angles yaw (about dock +y) and pitch (about dock +x), looking at the dock point
    ``offset`` (x, y) with the image up = dock +y, then rolled about its optical axis."""
    yaw, pitch, roll = np.radians([yaw_deg, pitch_deg, roll_deg])
    target = np.array([offset[0], offset[1], 0.0])
    direction = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    centre = target + direction * distance_m / direction[2]
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, np.array([0.0, 1.0, 0.0]))  # image +x = dock +x when facing the dock
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_dock_cam = np.column_stack([x, y, z])
    c, s = np.cos(roll), np.sin(roll)
    R_dock_cam = R_dock_cam @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    T_dock_cam = np.eye(4)
    T_dock_cam[:3, :3] = R_dock_cam
    T_dock_cam[:3, 3] = centre
    R = R_dock_cam.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ centre
    return T
