"""The renderer interface the frame loop drives (:mod:`blendgen.pipeline.frameloop`).

A renderer is built once per job from the job's scene, camera and render settings and then
renders one frame at a time, returning the clean passes as numpy arrays, never files: ``rgb``
(H,W,3) float32 linear radiance, ``depth_z`` (H,W) float32 planar depth (m), ``index`` (H,W)
uint8 object index, plus ``albedo``/``normal``/``sun`` when the render settings ask for them.
Everything after the render (water, particles, sensor, ground truth, writing) is the
pipeline's. The implementation is Blender's (:mod:`blendgen.blender.renderer`, imported only
when a renderer is built, i.e. in a render worker process).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from blendgen.render_spec import FramePlan, RenderScene, RenderSettings


class Renderer(Protocol):
    def render(self, frame: FramePlan | dict, particles: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Clean passes of one planned frame (``T_world_cam`` 4x4, ``index``, ``t`` s, ROI boxes);
        ``particles`` (N,3) m world: where the real-geometry particles are at this frame."""

    def add_particles(self, positions: np.ndarray, radii: np.ndarray, object_index: int, color) -> None:
        """Real-geometry particles (validation mode): spheres (N,3) m, radii (N,) m."""

    def close(self) -> None:
        """Release per-job scratch (the built scene may be kept for the next job)."""


def load() -> None:
    """Import the renderer (Blender: seconds, once per process) before a job's clock starts, so
    its ``scene_build`` time is the build alone."""
    from blendgen.blender import renderer

    renderer.load()


def build(scene: RenderScene, camera: dict, render: RenderSettings, cache: dict | None = None) -> Renderer:
    """The renderer of one job (Blender; ``cache``: a persistent worker's dict that keeps the
    built scene while consecutive jobs share it)."""
    from blendgen.blender import renderer

    return renderer.build(scene, camera, render, cache)
