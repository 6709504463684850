"""Small obstacles as real 3D geometry (validation of the image-space particle model).

One object holds a point cloud (world positions, a per-point ``radius`` attribute);
a geometry-nodes modifier instances a smooth-shaded icosphere of radius 1 (subdivision 4:
2562 vertices, shared by every instance) on every point, scaled by ``radius``. Moving the particles between frames
rewrites the point positions only.
Particles are grey diffuse spheres of the config's albedo lit by the scene's lights (the
fast path's Lambertian-sphere part; its forward lobe has no counterpart here),
and every instance carries the object's pass index, so the object-index pass shows
exactly which pixels real geometry hides.
"""

from __future__ import annotations

import bpy
import numpy as np

from blendgen.blender import materials

SUBDIVISIONS = 4  # facets ~4 deg: smooth silhouettes and shading, not gravel


def _node_group(material: bpy.types.Material) -> bpy.types.NodeTree:
    ng = bpy.data.node_groups.new("dockbench_particles", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    n = ng.nodes
    gin, gout = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    sphere = n.new("GeometryNodeMeshIcoSphere")
    sphere.inputs["Radius"].default_value = 1.0
    sphere.inputs["Subdivisions"].default_value = SUBDIVISIONS
    smooth = n.new("GeometryNodeSetShadeSmooth")
    radius = n.new("GeometryNodeInputNamedAttribute")
    radius.data_type = "FLOAT"
    radius.inputs["Name"].default_value = "radius"
    inst = n.new("GeometryNodeInstanceOnPoints")
    mat = n.new("GeometryNodeSetMaterial")
    mat.inputs["Material"].default_value = material
    ln = ng.links
    ln.new(gin.outputs[0], inst.inputs["Points"])
    ln.new(sphere.outputs["Mesh"], smooth.inputs["Geometry"])
    ln.new(smooth.outputs["Geometry"], inst.inputs["Instance"])
    ln.new(radius.outputs["Attribute"], inst.inputs["Scale"])
    ln.new(inst.outputs["Instances"], mat.inputs["Geometry"])
    ln.new(mat.outputs["Geometry"], gout.inputs[0])
    return ng


def add_particles(positions: np.ndarray, radii: np.ndarray, index: int, color=(0.6, 0.65, 0.6)) -> bpy.types.Object:
    """Point-cloud object instancing spheres: positions (N,3) world m, radii (N,) m."""
    me = bpy.data.meshes.new("particles")
    me.vertices.add(len(positions))
    me.vertices.foreach_set("co", np.asarray(positions, np.float32).ravel())
    attr = me.attributes.new("radius", "FLOAT", "POINT")
    attr.data.foreach_set("value", np.asarray(radii, np.float32))
    me.update()
    obj = bpy.data.objects.new("particles", me)
    bpy.context.scene.collection.objects.link(obj)
    obj.pass_index = int(index)
    mod = obj.modifiers.new("particles", "NODES")
    mod.node_group = _node_group(materials.diffuse("particle", color))
    return obj


def move_particles(obj: bpy.types.Object, positions: np.ndarray) -> None:
    """New world positions (N,3) for the same particles (drift between frames)."""
    me = obj.data
    me.vertices.foreach_set("co", np.asarray(positions, np.float32).ravel())
    me.update()
