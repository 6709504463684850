"""The only part of dockbench that imports bpy: scene, materials, water, lights, render, worker."""
