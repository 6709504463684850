"""Warm render server: ``python -m blendgen.blender.serve LOG_FILE``.

One Blender process builds the scene once and then renders one camera frame per request,
for closed-loop runs where the next pose depends on the last image. It speaks JSON lines:
requests on stdin, one reply line per request on the original stdout (Blender's own chatter
goes to ``LOG_FILE``):

- ``{"cmd": "init", "scene": ..., "camera": ..., "render": ...}`` (the same scene, camera and
  render records a dataset job file holds) ->
  ``{"ok": true, "scene_build_s": s}``;
- ``{"cmd": "render", "T_world_cam": 4x4, "roi": [x0, y0, x1, y1] | null, "rois": [[x0, y0, x1, y1], ...],
  "out": path}`` (``rois``, per-marker boxes, optional and winning over ``roi``, as in a dataset frame) ->
  the clean passes written to ``path`` as a raw pass file (:mod:`blendgen.passfile`: ``rgb``
  (H,W,3) float32 linear, ``depth_z`` (H,W) float32 planar depth m, ``index`` (H,W) uint8, plus
  ``albedo``/``sun``/``normal`` when the render settings ask for them), reply
  ``{"ok": true, "ms": render + read time}``;
- ``{"cmd": "quit"}`` or end of input -> exit 0.

A failing request replies ``{"ok": false, "error": "..."}`` and the server keeps serving.
The frame is rendered exactly as a dataset job renders it (``renderer.BlenderRenderer.render``);
the image-space stages (water, particles, sensor) run in the client with the dataset frame
loop's stage functions (``blendgen.pipeline.frameloop``).
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback

from blendgen import passfile


class _Server:
    def __init__(self):
        self.renderer = None

    def init(self, req: dict) -> dict:
        from blendgen.blender.renderer import build

        t0 = time.perf_counter()
        self.renderer = build(req["scene"], req["camera"], req["render"])
        return {"ok": True, "scene_build_s": time.perf_counter() - t0}

    def render(self, req: dict) -> dict:
        if self.renderer is None:
            raise RuntimeError("render before init")
        t0 = time.perf_counter()
        frame = {"T_world_cam": req["T_world_cam"], "roi": req.get("roi")}
        if req.get("rois") is not None:
            frame["rois"] = req["rois"]
        passfile.write_passes(req["out"], self.renderer.render(frame))
        return {"ok": True, "ms": 1e3 * (time.perf_counter() - t0)}

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()


def serve(requests, reply) -> int:
    """Answer each JSON request line of ``requests`` with ``reply(dict)`` until quit/EOF."""
    srv = _Server()
    try:
        for line in requests:
            if not line.strip():
                continue
            try:
                req = json.loads(line)
                cmd = req.get("cmd")
                if cmd == "quit":
                    break
                if cmd not in ("init", "render"):
                    raise ValueError(f"unknown cmd {cmd!r}; expected init, render or quit")
                reply(getattr(srv, cmd)(req))
            except Exception as e:  # noqa: BLE001 - one bad request must not stop the server
                traceback.print_exc(file=sys.stderr)
                reply({"ok": False, "error": f"{type(e).__name__}: {e}"})
    finally:
        srv.close()
    return 0


def main(argv: list[str]) -> int:
    from blendgen.workerio import log_to, reply_channel

    reply = reply_channel()
    log_to(argv[1] if len(argv) > 1 else os.devnull)
    return serve(sys.stdin, reply)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
