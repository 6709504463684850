"""Upper bound on QR acquisition range: the dock's code ("DOCK-01", 0.15 m without its quiet zone,
segno's smallest version at level M) imaged head-on by a pinhole camera (hfov 60 deg) at distance d,
clean image (no water, no noise), pixel integration by 8x supersampling + area averaging; decoded by
the `qr` localizer's zxing-cpp reader (LocalAverage binarizer). Same method as closed_loop_aruco_range.py."""

import cv2
import numpy as np

from blendgen.markers import qr_texture
from evalkit.localizers.qr import zxing_reader

tex = qr_texture("DOCK-01", 0.15)
read = zxing_reader()
SS = 8


def decodes(W, H, d, bg=128, shift=(0.37, 0.21)):
    f = (W / 2) / np.tan(np.radians(30))
    cells = tex.cells  # quiet zone included; tex.plane_size_m is its side
    side = tex.plane_size_m * f / d * SS
    Ws, Hs = W * SS, H * SS
    cx, cy = Ws / 2 + shift[0] * SS, Hs / 2 + shift[1] * SS
    img = np.full((Hs, Ws), bg, np.uint8)
    n = cells.shape[0]
    src = np.float32([[0, 0], [n, 0], [n, n], [0, n]])
    dst = np.float32(
        [
            [cx - side / 2, cy - side / 2],
            [cx + side / 2, cy - side / 2],
            [cx + side / 2, cy + side / 2],
            [cx - side / 2, cy + side / 2],
        ]
    )
    M = cv2.getPerspectiveTransform(src, dst)
    warped = cv2.warpPerspective(cells, M, (Ws, Hs), flags=cv2.INTER_NEAREST, borderValue=0)
    mask = cv2.warpPerspective(np.full_like(cells, 255), M, (Ws, Hs), flags=cv2.INTER_NEAREST, borderValue=0) > 0
    img[mask] = warped[mask]
    small = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
    return any(p == "DOCK-01" for p, _ in read(small))


modules = np.array(qr_texture("DOCK-01", 0.15, quiet_modules=0).cells).shape[0]
for W, H in ((320, 240), (640, 480), (1280, 960)):
    f = (W / 2) / np.tan(np.radians(30))
    ds = np.round(np.arange(0.5, 8.01, 0.1), 2)
    ok = [d for d in ds if decodes(W, H, d)]
    far = max(ok) if ok else float("nan")
    print(
        f"{W}x{H}: f = {f:.0f} px; {modules} modules; farthest decode {far:.2f} m "
        f"(code {0.15 * f / far:.1f} px, {0.15 / modules * f / far:.2f} px per module); "
        f"at 6 m the code is {0.15 * f / 6:.1f} px ({0.15 / modules * f / 6:.2f} px/module)"
    )
