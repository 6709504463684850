"""Upper bound on ArUco acquisition range: the dock's tag (DICT_4X4_50 id 7, 0.12 m incl. 1-cell border)
imaged head-on by a pinhole camera (hfov 60 deg) at distance d, clean image (no water, no noise),
pixel integration by 8x supersampling + area averaging; OpenCV ArucoDetector with default parameters."""

import cv2
import numpy as np

d_ = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
det = cv2.aruco.ArucoDetector(d_, cv2.aruco.DetectorParameters())
tag = cv2.aruco.generateImageMarker(d_, 7, 600, borderBits=1)  # 6x6 cells, 100 px per cell
SS = 8


def detects(W, H, d, size=0.12, bg=128, shift=(0.37, 0.21)):
    f = (W / 2) / np.tan(np.radians(30))
    side = size * f / d * SS  # tag side in supersampled px
    Ws, Hs = W * SS, H * SS
    cx, cy = Ws / 2 + shift[0] * SS, Hs / 2 + shift[1] * SS
    src = np.float32([[0, 0], [600, 0], [600, 600], [0, 600]])
    dst = np.float32(
        [
            [cx - side / 2, cy - side / 2],
            [cx + side / 2, cy - side / 2],
            [cx + side / 2, cy + side / 2],
            [cx - side / 2, cy + side / 2],
        ]
    )
    M = cv2.getPerspectiveTransform(src, dst)
    # quiet zone: a white board around the tag (as on the dock face, 1 cell wide) on a mid-grey background
    img = np.full((Hs, Ws), bg, np.uint8)
    q = side / 6
    cv2.rectangle(
        img, (int(cx - side / 2 - q), int(cy - side / 2 - q)), (int(cx + side / 2 + q), int(cy + side / 2 + q)), 255, -1
    )
    warped = cv2.warpPerspective(tag, M, (Ws, Hs), flags=cv2.INTER_AREA, borderValue=0)
    mask = cv2.warpPerspective(np.full_like(tag, 255), M, (Ws, Hs), flags=cv2.INTER_NEAREST, borderValue=0) > 0
    img[mask] = warped[mask]
    small = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
    _, ids, _ = det.detectMarkers(small)
    return ids is not None and 7 in ids.reshape(-1)


for W, H in ((320, 240), (640, 480), (1280, 960)):
    f = (W / 2) / np.tan(np.radians(30))
    ds = np.round(np.arange(1.0, 14.01, 0.25), 2)
    ok = [d for d in ds if detects(W, H, d)]
    far = max(ok) if ok else float("nan")
    print(
        f"{W}x{H}: f = {f:.0f} px; farthest detection {far:.2f} m "
        f"(tag {0.12 * f / far:.1f} px, {0.02 * f / far:.2f} px per cell); "
        f"at 6 m the tag is {0.12 * f / 6:.1f} px ({0.02 * f / 6:.2f} px/cell), at 12 m {0.12 * f / 12:.1f} px"
    )
