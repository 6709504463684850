#!/usr/bin/env python3
"""Example external localizer for dockbench (JSON-lines protocol 1), ArUco + IPPE_SQUARE.

Self-contained: it needs only numpy and OpenCV (with cv2.aruco), not dockbench, to
show that a localizer in another code base -- or another language -- plugs in as

    dockbench evaluate DATASET -l "exec:python examples/external_localizer.py" -o OUT

Protocol (datasets_spec/LOCALIZER_PROTOCOL.md): read one JSON request per stdin
line, write exactly one JSON reply per line to stdout (flushed), log to stderr only.
"""

import json
import sys

import cv2
import numpy as np

PROTOCOL = 1


class ArucoState:
    """What a reset establishes: camera matrices, the marker, a detector."""

    def __init__(self, camera, params):
        self.K = np.asarray(camera["K"], float)
        dist = camera.get("dist")
        self.dist = None if dist is None else np.asarray(dist, float)
        wanted = params.get("marker_id")
        self.marker = next(
            (
                m
                for m in camera.get("markers", [])
                if m.get("kind") in ("aruco", "apriltag") and (wanted is None or str(m["id"]) == str(wanted))
            ),
            None,
        )
        self.detector = None
        if self.marker is not None:
            d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.marker["dictionary"]))
            self.detector = cv2.aruco.ArucoDetector(d, cv2.aruco.DetectorParameters())

    def localize(self, path):
        """Reply dict for the image at ``path``."""
        if self.detector is None:
            return {"ok": False}
        gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if gray is None:
            return {"ok": False, "error": f"cannot read {path}"}
        corners, ids, _ = self.detector.detectMarkers(gray)
        if ids is None:
            return {"ok": False}
        m = self.marker
        for c, i in zip(corners, ids.ravel()):
            if int(i) != int(m["marker_id"]):
                continue
            h = m["size_m"] / 2.0
            obj = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], float)
            img = cv2.cornerSubPix(
                gray,
                c.reshape(4, 1, 2).astype(np.float32),
                (3, 3),
                (-1, -1),
                (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 0.01),
            ).reshape(4, 2)
            # IPPE_SQUARE gives two poses (planar flip ambiguity): keep the better-fitting one
            n, rvecs, tvecs, errs = cv2.solvePnPGeneric(
                obj, img.astype(float), self.K, self.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
            )
            if n == 0:
                continue
            best = int(np.argmin(np.ravel(errs)))
            rvec, tvec = cv2.solvePnPRefineLM(obj, img.astype(float), self.K, self.dist, rvecs[best], tvecs[best])
            T_cam_marker = np.eye(4)
            T_cam_marker[:3, :3] = cv2.Rodrigues(rvec)[0]
            T_cam_marker[:3, 3] = tvec.ravel()
            T_cam_dock = T_cam_marker @ np.linalg.inv(np.asarray(m["T_dock_marker"], float))
            # distance from the camera centre to the dock plane (dock z = 0)
            n, p = T_cam_dock[:3, 2], T_cam_dock[:3, 3]
            return {
                "ok": True,
                "distance": float(abs(n @ p)),
                "T_cam_dock": T_cam_dock.tolist(),
                "marker_id": str(m["id"]),
                "confidence": 1.0,
            }
        return {"ok": False}


def main():
    state = None
    for line in sys.stdin:
        if not line.strip():
            continue
        req = json.loads(line)
        if req.get("type") == "reset":
            if req.get("protocol") != PROTOCOL:
                reply = {"ok": False, "error": f"protocol {req.get('protocol')} not supported"}
            else:
                state = ArucoState(req["camera"], req.get("params") or {})
                reply = {"ok": True, "protocol": PROTOCOL, "name": "example-aruco"}
        elif req.get("type") == "frame" and state is not None:
            reply = {"index": req["index"], **state.localize(req["image"])}
        else:
            reply = {"ok": False, "error": f"unexpected request {req.get('type')!r}"}
        sys.stdout.write(json.dumps(reply) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
