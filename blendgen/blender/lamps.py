"""The vehicle's lamps in the reference fidelity: Cycles spot lights parented to the camera.

A config lamp (``config.models.Lamp``: ``offset_m``, ``yaw_deg``, ``pitch_deg`` in the OpenCV
camera frame, ``half_angle_deg``, ``edge_deg``, ``power_w`` the radiant flux into the cone,
``color``) becomes one ``SPOT`` light that moves with the camera, so it lights the scene and
the water volume (the backscatter cone appears natively, with as many volume bounces as
the render uses).

Units (bpy 5.x ``SpotLight.energy``: "the energy this light would emit over its entire area
if it wasn't limited by the spot angle", W): a spot of energy ``E`` has the on-axis radiant
intensity of a point light of that power, ``E / (4 pi)`` W/sr (measured: see
``blendgen.tools.bench.lamp_bench``), so the config's cone flux ``P`` maps to
``E = 4 pi I0`` with ``I0 = P / (2 pi (1 - cos a))`` (``physics.light.sources.cone_intensity``).
The soft edge: Cycles' spot mask is ``smoothstep((cos t - cos a) / ((1 - cos a) blend))``
(kernel/light/spot.h), so ``blend = (cos(a - edge) - cos a) / (1 - cos a)`` puts the
full-intensity cone at ``a - edge`` exactly as ``physics.light.sources.PointLight.profile`` does.
"""

from __future__ import annotations

import math

import bpy
import numpy as np
from mathutils import Vector

from blendgen.physics.light.sources import blender_spot_blend, lamp_lights


def add_lamps(cam_obj: bpy.types.Object, lamps: list[dict]) -> list[bpy.types.Object]:
    """One spot light per config lamp (dicts of ``Lamp`` fields), children of ``cam_obj``."""
    out = []
    if not lamps:
        return out
    from types import SimpleNamespace

    for i, (_lamp, pl) in enumerate(zip(lamps, lamp_lights([SimpleNamespace(**d) for d in lamps]))):
        i0 = np.asarray(pl.intensity_w_sr, float)
        peak = float(i0.max())
        light = bpy.data.lights.new(f"lamp_{i}", type="SPOT")
        light.energy = 4.0 * math.pi * peak
        light.color = tuple(float(x) for x in i0 / peak) if peak > 0 else (0.0, 0.0, 0.0)
        light.spot_size = 2.0 * pl.half_angle_rad
        light.spot_blend = blender_spot_blend(pl.half_angle_rad, pl.edge_rad)
        light.shadow_soft_size = 0.0  # a point source (config: no lamp radius)
        if hasattr(light, "use_soft_falloff"):
            light.use_soft_falloff = False
        obj = bpy.data.objects.new(f"lamp_{i}", light)
        bpy.context.scene.collection.objects.link(obj)
        obj.parent = cam_obj
        # OpenCV camera frame -> Blender camera local frame: (x, -y, -z); a spot shines along -Z
        pos = np.asarray(pl.position_m, float) * [1.0, -1.0, -1.0]
        axis = np.asarray(pl.axis, float) * [1.0, -1.0, -1.0]
        obj.location = tuple(pos)
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = Vector(tuple(-axis)).to_track_quat("Z", "Y")
        out.append(obj)
    return out
