"""Mesh objects from vertex and face lists, linked into the current scene (bpy).

The lowest layer of the Blender side: scene.py, water.py and the oracle scenes build on it.
"""

from __future__ import annotations

import bpy


def _link(obj: bpy.types.Object) -> bpy.types.Object:
    bpy.context.scene.collection.objects.link(obj)
    return obj


def mesh_object(name: str, verts, faces, uvs=None, index: int = 0, smooth: bool = False) -> bpy.types.Object:
    """Object from vertices (N,3), faces (lists of indices) and optional per-loop UVs."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(f) for f in faces])
    if uvs is not None:
        layer = me.uv_layers.new(name="UVMap")
        for loop, uv in zip(layer.data, uvs):
            loop.uv = uv
    if smooth:
        me.shade_smooth()
    me.update()
    obj = _link(bpy.data.objects.new(name, me))
    obj.pass_index = index
    return obj
