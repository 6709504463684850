"""The only part of dockbench that imports bpy: scene, materials, water, lights, render, and the renderer adapter
(renderer.py) the pipeline's frame loop drives."""
