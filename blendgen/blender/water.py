"""Reference-fidelity water: a Cycles participating medium in a mesh box.

The medium is a closed box whose top face is the water surface. A World volume
would also fill the sky and kill sunlight (docs/water.md); with a box, the sun lamp's
shadow rays leave the medium through the top face, so sunlight reaching a point
at depth ``h`` is attenuated by ``exp(-c h / sin(elevation))`` -- with 0 volume
bounces (our default: **single scattering**), the unscattered beam. The box has
no surface shader: its faces are invisible interfaces that only bound the volume.

Coefficients go straight into Blender 5's **Volume Coefficients** node
(``ShaderNodeVolumeCoefficients``) in 1/m per RGB channel:
``Absorption Coefficients = sigma_a``, ``Scatter Coefficients = sigma_s``,
``Emission Coefficients = 0``, phase ``HENYEY_GREENSTEIN`` (``Anisotropy = g``)
or ``FOURNIER_FORAND`` (``IOR = ff_ior``, ``Backscatter = ff_backscatter``).
Constant inputs make the volume homogeneous, so Cycles integrates it analytically
(no ray marching: the volume step rate does not apply).
"""

from __future__ import annotations

import bpy

from blendgen.blender.meshes import mesh_object

#: The box grows this much (m) beyond ``box_min``/``box_max`` on every side but the
#: top, so that pool walls and floor lie inside the water instead of coinciding
#: with the volume's boundary faces (coplanar faces flicker between inside/outside).
SIDE_PAD_M = 0.01

PHASES = {"hg": "HENYEY_GREENSTEIN", "ff": "FOURNIER_FORAND"}


def _inp(node, name: str):
    """Input socket by name, also when hidden for the current phase (``inputs[name]``
    only finds available sockets)."""
    return next(s for s in node.inputs if s.name == name)


def volume_material(desc: dict, name: str = "water_medium") -> bpy.types.Material:
    """Material whose Volume output is a Volume Coefficients node set from ``desc``."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    vol = nt.nodes.new("ShaderNodeVolumeCoefficients")
    phase = desc.get("phase", "hg")
    if phase not in PHASES:
        raise ValueError(f"water phase must be one of {sorted(PHASES)}, got {phase!r}")
    vol.phase = PHASES[phase]
    _inp(vol, "Absorption Coefficients").default_value = tuple(float(x) for x in desc["sigma_a"])
    _inp(vol, "Scatter Coefficients").default_value = tuple(float(x) for x in desc["sigma_s"])
    _inp(vol, "Emission Coefficients").default_value = (0.0, 0.0, 0.0)
    _inp(vol, "Anisotropy").default_value = float(desc.get("g", 0.0))
    _inp(vol, "IOR").default_value = float(desc.get("ff_ior", 1.1))
    _inp(vol, "Backscatter").default_value = float(desc.get("ff_backscatter", 0.0183))
    nt.links.new(vol.outputs["Volume"], out.inputs["Volume"])
    return mat


def coefficients_of(mat: bpy.types.Material) -> dict:
    """Read back what the medium material holds (for tests of the mapping)."""
    vol = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeVolumeCoefficients")
    inv = {v: k for k, v in PHASES.items()}
    return {
        "sigma_a": list(_inp(vol, "Absorption Coefficients").default_value),
        "sigma_s": list(_inp(vol, "Scatter Coefficients").default_value),
        "emission": list(_inp(vol, "Emission Coefficients").default_value),
        "phase": inv.get(vol.phase, vol.phase),
        "g": _inp(vol, "Anisotropy").default_value,
        "ff_ior": _inp(vol, "IOR").default_value,
        "ff_backscatter": _inp(vol, "Backscatter").default_value,
        "linked_to": [lk.to_socket.name for lk in vol.outputs["Volume"].links],
    }


def add_water_volume(desc: dict, pad: float = SIDE_PAD_M) -> bpy.types.Object:
    """The water box from a ``plan.water_volume`` description; returns the object.

    ``desc``: ``sigma_a``, ``sigma_s`` (3 lists, 1/m), ``phase`` ('hg'|'ff'), ``g``,
    ``ff_ior``, ``ff_backscatter``, ``box_min``, ``box_max`` (world m; the top face
    ``z = box_max[2]`` is the surface). Object index 0: the medium is not an object
    of the index pass (a camera ray's first *surface* hit still sets it)."""

    (x0, y0, z0), (x1, y1, z1) = desc["box_min"], desc["box_max"]
    x0, y0, z0, x1, y1 = x0 - pad, y0 - pad, z0 - pad, x1 + pad, y1 + pad
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0), (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    obj = mesh_object("water_volume", v, f, index=0)
    obj.data.materials.append(volume_material(desc))
    return obj


def reference_settings(scene: bpy.types.Scene, volume_bounces: int = 0) -> None:
    """Cycles volume settings of the reference fidelity.

    ``volume_bounces = 0`` (default) is single scattering: each camera-ray scatter
    point is lit directly by the sun (next-event estimation through the medium);
    multiple scattering (bounces 8-64) raises the veiling light 1.5-7x (docs/water.md).
    Homogeneous media are integrated analytically, so the step rate only matters
    for heterogeneous ones; it is left at Cycles' default (1)."""
    cy = scene.cycles
    cy.volume_bounces = int(volume_bounces)
    cy.max_bounces = max(int(cy.max_bounces), int(volume_bounces))
    cy.volume_step_rate = 1.0
