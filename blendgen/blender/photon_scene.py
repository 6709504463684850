"""The photon scene of the reference's caustics (``caustic_sun``): a second Blender scene that
shares the dataset's glass surface, an orthographic "sun" camera in the air whose depth of
field is the sun's disc, and recorder planes that read where each refracted sun ray lands."""

from __future__ import annotations

import math
from dataclasses import dataclass

import bpy
import mathutils
import numpy as np

from blendgen.blender import render as rnd
from blendgen.blender.materials import _fresh
from blendgen.physics.surface import optics as sf
from blendgen.physics.surface.caustic_beam import OFFSET


@dataclass
class Recorder:
    """One receiver polygon in the photon scene: origin ``o`` and in-plane axes ``eu``, ``ev`` (3,)."""

    o: np.ndarray
    eu: np.ndarray
    ev: np.ndarray


def recorder_material(k: int) -> bpy.types.Material:
    """Emission ``(x + OFFSET, y + OFFSET, k + 1)`` of the object coordinates, not a light
    (a photon recorder: a refracted sun ray that reaches it with weight 1 reads its position)."""
    mat, nt = _fresh(f"photon_recorder_{k}")
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Object"], sep.inputs["Vector"])
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    for i, axis in enumerate("XY"):
        add = nt.nodes.new("ShaderNodeMath")
        add.operation = "ADD"
        add.inputs[1].default_value = OFFSET
        nt.links.new(sep.outputs[axis], add.inputs[0])
        nt.links.new(add.outputs["Value"], comb.inputs[i])
    comb.inputs["Z"].default_value = float(k + 1)
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1.0
    nt.links.new(comb.outputs["Vector"], em.inputs["Color"])
    nt.links.new(em.outputs["Emission"], nt.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    mat.cycles.emission_sampling = "NONE"
    return mat


def add_recorders(photons: bpy.types.Scene, sources) -> list[Recorder]:
    """A recorder plane in ``photons`` for every polygon of the ``sources`` mesh objects."""
    out = []
    for obj in sources:
        M = np.array(obj.matrix_world)
        for poly in obj.data.polygons:
            P = np.array([(M @ np.append(obj.data.vertices[i].co, 1.0))[:3] for i in poly.vertices])
            n = np.cross(P[1] - P[0], P[2] - P[0])
            eu = (P[1] - P[0]) / np.linalg.norm(P[1] - P[0])
            ev = np.cross(n / np.linalg.norm(n), eu)
            local = [((p - P[0]) @ eu, (p - P[0]) @ ev, 0.0) for p in P]
            me = bpy.data.meshes.new(f"photon_recorder_{len(out)}")
            me.from_pydata(local, [], [tuple(range(len(local)))])
            rec = bpy.data.objects.new(me.name, me)
            rec.matrix_world = mathutils.Matrix([[*eu, 0], [*ev, 0], [*np.cross(eu, ev), 0], [*P[0], 1]]).transposed()
            me.materials.append(recorder_material(len(out)))
            rec.visible_camera = False
            photons.collection.objects.link(rec)
            out.append(Recorder(P[0], eu, ev))
    return out


def photon_scene(surface_obj: bpy.types.Object, threads: int) -> bpy.types.Scene:
    """A second scene sharing the dataset's glass surface: black sky, Cycles with refractive
    caustics, one sample per pixel, no clamping (photon weights are not fireflies)."""
    ps = bpy.data.scenes.new("photons")
    ps.world = bpy.data.worlds.new("photons_black")
    from blendgen.blender import materials

    materials.world_color(ps.world, [0.0, 0.0, 0.0])
    ps.collection.objects.link(surface_obj)
    rnd.setup_cycles(ps, {"samples": 1, "specular_bounces": 8, "max_bounces": 8, "threads": threads})
    cy = ps.cycles
    cy.caustics_reflective = cy.caustics_refractive = True
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.blur_glossy = 0.0
    ps.view_layers[0].use_pass_z = ps.view_layers[0].use_pass_object_index = False
    ps.render.resolution_percentage = 100
    return ps


def add_absorber(ps: bpy.types.Scene, surface: dict) -> bpy.types.Object:
    """A black frame just above the surface around its rectangle (1 km wide): sun rays that
    miss the surface end there instead of entering the pool unrefracted over its rim."""
    (cx, cy), (hx, hy), z = surface["centre_xy"], surface["half_xy"], float(surface["z"]) + 2e-3
    far = 1000.0
    inner = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)]
    outer = [(cx - far, cy - far), (cx + far, cy - far), (cx + far, cy + far), (cx - far, cy + far)]
    verts = [(x, y, z) for x, y in inner + outer]
    faces = [(i, (i + 1) % 4, 4 + (i + 1) % 4, 4 + i) for i in range(4)]
    me = bpy.data.meshes.new("photon_absorber")
    me.from_pydata(verts, [], faces)
    mat, nt = _fresh("photon_absorber")
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 0.0
    nt.links.new(em.outputs["Emission"], nt.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    me.materials.append(mat)
    obj = bpy.data.objects.new("photon_absorber", me)
    ps.collection.objects.link(obj)
    return obj


SUN_APERTURE_M = 0.25  # lens radius of the sun camera (m): rays start up to this far off their pixel


def sun_disc_aperture(data: bpy.types.Camera) -> None:
    """The sun's disc as the orthographic camera's depth of field: Cycles starts each ray at a
    uniform point ``u`` of a lens of radius ``1 / (2 fstop)`` (orthographic) and aims it at its
    pixel's point ``focus_distance`` ahead, so its direction is uniform over a disc of angular
    radius ``atan(a / f)``: the sun's 0.265 deg with ``a`` = SUN_APERTURE_M. A uniform shift
    of every ray by ``u`` keeps the photons' density (the frame grows by ``2 a``)."""
    data.dof.use_dof = True
    data.dof.aperture_fstop = 1.0 / (2.0 * SUN_APERTURE_M)
    data.dof.aperture_blades = 0
    data.dof.focus_distance = SUN_APERTURE_M / math.tan(sf.SUN_RADIUS_RAD)


def sun_camera(ps: bpy.types.Scene, region: dict, air: np.ndarray, pitch_m: float) -> bpy.types.Object:
    """Orthographic camera before the surface's centre along the sun's rays in the air,
    framing the rectangle ``region`` (``centre_xy``, ``half_xy``, ``z``) of the surface, pixels
    ``pitch_m`` apart (one photon each per render; its resolution kept as ``cam["resolution"]``). It
    stands far enough upstream that its whole (tilted) image plane is above the surface: an
    orthographic ray starts on that plane, and one starting below the surface never meets it."""
    (cx, cy), (hx, hy), z = region["centre_xy"], region["half_xy"], float(region["z"])
    data = bpy.data.cameras.new("photon_sun")
    data.type = "ORTHO"
    cam = bpy.data.objects.new("photon_sun", data)
    ps.collection.objects.link(cam)
    ps.camera = cam
    base = mathutils.Vector(tuple(-air)).to_track_quat("Z", "Y").to_matrix()
    cam.rotation_euler = base.to_euler()
    sun_disc_aperture(data)
    R = np.array(base)
    corners = np.array([[a * hx, b * hy, 0.0] for a in (-1, 1) for b in (-1, 1)])
    extent = 2 * np.abs(corners @ R[:, :2]).max(axis=0) + 4 * pitch_m + 2 * SUN_APERTURE_M
    data.ortho_scale = float(extent.max())
    sin_a = math.hypot(air[0], air[1])
    upstream = 1.0 + 0.5 * data.ortho_scale * sin_a / -air[2]  # the plane's lowest corner 1 m up
    cam.location = (cx - upstream * air[0], cy - upstream * air[1], z - upstream * air[2])
    data.clip_start, data.clip_end = 0.01, upstream + 1000.0
    cam["resolution"] = [int(math.ceil(e / pitch_m)) for e in extent]
    return cam
