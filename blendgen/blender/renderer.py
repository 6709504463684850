"""The Blender renderer: a built scene that renders one frame's clean passes per call.

``build(scene, camera, render)`` builds the Blender scene of a job (or reuses the one a
persistent worker kept, ``cache``); ``BlenderRenderer.render(frame)`` places the camera at the
frame's pose and returns its clean passes as numpy arrays (``rgb`` (H,W,3) float32 linear,
``depth_z`` (H,W) float32 planar depth in m, ``index`` (H,W) uint8, plus ``albedo``/``normal``/
``sun`` when the render settings ask for them). What is done with the passes (water, particles,
sensor, ground truth, files) is the caller's (:mod:`blendgen.pipeline.frameloop`): this module
imports nothing from the pipeline.
"""

from __future__ import annotations

import json
import os

from blendgen.render_spec import FramePlan, RenderScene, RenderSettings


def photon_seed(render: RenderSettings, frame: dict) -> int:
    """The caustic photons' seed of one frame: the render seed and the frame index."""
    return (render.seed * 7919 + int(frame["index"])) % (1 << 20)


def scene_key(scene: dict, camera: dict, render: dict) -> str | None:
    """What the built Blender scene depends on (plain scene, camera, Cycles settings), or
    None when the job changes the scene while it renders (real-geometry particles)."""
    if scene.get("particles"):
        return None
    return json.dumps([scene, camera, render], sort_keys=True)


class _Particles:
    """Real-geometry particles (validation mode): one Blender object moved every frame."""

    def __init__(self, obj):
        self.obj = obj

    def move(self, positions) -> None:
        from blendgen.blender import particles

        particles.move_particles(self.obj, positions)


class BlenderRenderer:
    """One built scene (``build``); ``render(frame)`` -> clean passes of that frame."""

    def __init__(self, sc, cam, caustics, scene: RenderScene, render: RenderSettings, width: int, height: int):
        from blendgen.blender import render as rnd

        self.sc, self.cam, self.caustics = sc, cam, caustics
        self.scene, self.settings, self.size = scene, render, (width, height)
        self.cycles = render.model_dump(mode="json")  # plain data for blender/render.py
        self.exr = os.path.join(rnd.scratch_dir(), f"dockbench-{os.getpid()}.exr")
        self.particles: _Particles | None = None

    def add_particles(self, positions, radii, object_index: int, color) -> None:
        """Spheres at ``positions`` (N,3) m world, ``radii`` (N,) m, moved by ``render(frame, particles=...)``."""
        from blendgen.blender import particles

        self.particles = _Particles(particles.add_particles(positions, radii, object_index, color=color))

    def render(self, frame: FramePlan | dict, particles=None) -> dict:
        """The clean passes of ``frame`` (a planned frame; the closed loop's: ``T_world_cam`` and
        ``roi`` only); ``particles`` (N,3) the real-geometry particles' positions at this frame
        (with :meth:`add_particles`)."""
        from blendgen.blender import render as rnd

        fr = frame.plain() if isinstance(frame, FramePlan) else frame
        if self.particles is not None and particles is not None:
            self.particles.move(particles)
        if self.scene.water_surface is not None:
            from blendgen.blender.world import set_wave_time

            set_wave_time(fr.get("t", 0.0))
        if self.caustics is not None:
            self.caustics.update(photon_seed(self.settings, fr))
        return rnd.render_roi_frame(self.sc, self.cam, fr, self.cycles, *self.size, self.exr)

    def close(self) -> None:
        """Remove the scratch EXR (the built scene stays for the next job of a persistent worker)."""
        if os.path.exists(self.exr):
            os.remove(self.exr)


def load() -> None:
    """Import Blender (bpy, seconds; once per process)."""
    from blendgen.blender import lamps, render, scene  # noqa: F401


def build(
    scene: RenderScene | dict, camera: dict, render: RenderSettings | dict, cache: dict | None = None
) -> BlenderRenderer:
    """The renderer of one job: the Blender scene of ``scene`` seen by ``camera`` with the Cycles
    settings ``render`` (records or their plain data, validated here: a wrong key fails before
    anything is built), taken from ``cache`` when the last job built the same one (persistent
    worker), else built from factory settings (nothing kept from earlier jobs)."""
    from blendgen.blender import lamps
    from blendgen.blender import render as rnd
    from blendgen.blender import scene as scn

    scene, render = RenderScene.model_validate(scene), RenderSettings.model_validate(render)
    plain, cycles = scene.model_dump(mode="json"), render.model_dump(mode="json")  # what the builders read
    key = scene_key(plain, camera, cycles)
    if cache is not None and key is not None and cache.get("key") == key:
        sc, cam, caustics = cache["sc"], cache["cam"], cache["caustics"]
    else:
        sc = scn.build(plain)  # read_factory_settings: nothing kept
        cam = rnd.setup_camera(sc, camera)
        lamps.add_lamps(cam, plain.get("lamps") or [])  # reference fidelity only
        rnd.setup_cycles(sc, cycles)
        caustics = None
        if scene.water_surface is not None and scene.water_surface.caustics is not None:  # reference: the sun
            from blendgen.blender.caustic_sun import CausticSun  # as a caustic spot

            caustics = CausticSun(sc, plain, render.threads)
        if cache is not None:
            cache.update(key=key, sc=sc, cam=cam, caustics=caustics)
    return BlenderRenderer(sc, cam, caustics, scene, render, int(camera["width"]), int(camera["height"]))
