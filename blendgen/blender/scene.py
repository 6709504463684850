"""Build the docking scene in Blender from a plain scene description (dict).

The description is produced by :mod:`blendgen.pipeline.plan` (pure Python) and holds only
numbers, colours and file paths; see ``plan.scene_description``. Everything here
is in world coordinates (metres, +z up, water surface z = 0).
"""

from __future__ import annotations

import math

import bpy
import numpy as np
from mathutils import Matrix

from blendgen.blender import materials, world
from blendgen.blender.meshes import _link, mesh_object  # noqa: F401  (scene builders use both)


def reset() -> bpy.types.Scene:
    """Empty factory scene (no default cube, camera or light)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def set_matrix(obj: bpy.types.Object, T) -> None:
    """Place an object by a 4x4 world transform (row-major; a bare nested list would be
    read as columns by bpy, so build the Matrix from rows explicitly)."""
    obj.matrix_world = Matrix(np.asarray(T, float).tolist())


def add_pool(pool: dict, index: int, look: dict | None = None) -> None:
    """Open-top box: floor and four walls, normals facing inward; tiled when ``look`` says
    so (``blender/world.py``), else flat colours."""
    L, W, D = pool["length_m"] / 2, pool["width_m"] / 2, pool["depth_m"]
    v = [(-L, -W, -D), (L, -W, -D), (L, W, -D), (-L, W, -D), (-L, -W, 0), (L, -W, 0), (L, W, 0), (-L, W, 0)]
    floor = mesh_object("pool_floor", v, [(0, 1, 2, 3)], index=index)
    walls = mesh_object("pool_walls", v, [(0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0)], index=index)
    if look and look.get("textures"):
        floor.data.materials.append(world.tiles("floor", pool["floor_color"], look, "xy"))
        walls.data.materials.append(world.tiles("walls", pool["wall_color"], look, "wall"))
        return
    floor.data.materials.append(materials.diffuse("floor", pool["floor_color"]))
    walls.data.materials.append(materials.diffuse("walls", pool["wall_color"]))


def box_verts(sx: float, sy: float, sz: float, z0: float = 0.0):
    """Axis-aligned box centred in x,y, spanning z in [z0 - sz, z0]; outward faces."""
    x, y = sx / 2, sy / 2
    v = [
        (-x, -y, z0 - sz),
        (x, -y, z0 - sz),
        (x, y, z0 - sz),
        (-x, y, z0 - sz),
        (-x, -y, z0),
        (x, -y, z0),
        (x, y, z0),
        (-x, y, z0),
    ]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    return v, f


def add_dock(dock: dict, index: int, look: dict | None = None) -> None:
    """Dock body: a box whose front face lies 2 mm behind the marker plane (dock z = 0);
    with textures, painted with dirt and held by an aluminium frame (``blender/world.py``)."""
    sx, sy, sz = dock["body_size_m"]
    v, f = box_verts(sx, sy, sz, z0=-0.002)
    obj = mesh_object("dock_body", v, f, index=index)
    set_matrix(obj, dock["T_world_dock"])
    if look and look.get("textures"):
        obj.data.materials.append(world.painted("dock_face", dock["face_color"], look))
        dock_frame(dock, index, look)
        return
    obj.data.materials.append(materials.diffuse("dock_face", dock["face_color"]))


def add_square_marker(m: dict, T_world_marker) -> None:
    """Textured plate in the marker plane; its texture cells are sampled nearest."""
    h = m["plate_size_m"] / 2
    v = [(-h, h, 0), (h, h, 0), (h, -h, 0), (-h, -h, 0)]
    uvs = [(0, 1), (1, 1), (1, 0), (0, 0)]
    obj = mesh_object(
        f"marker_{m['id']}", v, [(0, 3, 2, 1)], uvs=[uvs[i] for i in (0, 3, 2, 1)], index=m["object_index"]
    )
    obj.data.materials.append(materials.printed_texture(f"tex_{m['id']}", m["texture"]))
    set_matrix(obj, T_world_marker)


def uv_sphere(radius: float, segments: int = 24, rings: int = 12):
    """Vertices and quads/triangles of a UV sphere centred at the origin."""
    verts = [(0.0, 0.0, radius)]
    for i in range(1, rings):
        th = math.pi * i / rings
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts.append(
                (radius * math.sin(th) * math.cos(ph), radius * math.sin(th) * math.sin(ph), radius * math.cos(th))
            )
    verts.append((0.0, 0.0, -radius))
    faces, last = [], len(verts) - 1
    ring = lambda i, j: 1 + (i - 1) * segments + (j % segments)  # noqa: E731
    for j in range(segments):
        faces.append((0, ring(1, j), ring(1, j + 1)))
        faces.append((last, ring(rings - 1, j + 1), ring(rings - 1, j)))
    for i in range(1, rings - 1):
        for j in range(segments):
            faces.append((ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)))
    return verts, faces


def camera_only(obj: bpy.types.Object) -> None:
    """Seen by the camera, invisible to every other ray: an LED that lights nothing
    (no BSDF-sampled sparkle on the face at a few samples per pixel)."""
    obj.visible_diffuse = obj.visible_glossy = obj.visible_transmission = False
    obj.visible_volume_scatter = obj.visible_shadow = False


def disc(radius: float, segments: int = 48):
    """Flat disc in the local z = 0 plane facing +z, area-matched to the circle."""
    r = radius * math.sqrt(2 * math.pi / (segments * math.sin(2 * math.pi / segments)))
    verts = [
        (r * math.cos(2 * math.pi * k / segments), r * math.sin(2 * math.pi * k / segments), 0.0)
        for k in range(segments)
    ]
    return verts, [tuple(range(segments))]


def add_led_array(m: dict, T_world_dock, lights_scene: bool = False) -> None:
    """One flat emitting disc of radius ``led_radius_m`` per LED, centred on its keypoint
    in the marker plane, facing out of the dock: its image centroid is the projected
    keypoint (a dome would shift it under oblique views). Radiance ``m["radiance"]``
    (``physics/light/leds.py``: intensity / (pi r^2)). ``lights_scene`` (reference fidelity):
    the discs are lights (sampled, seen by scatter rays: they light the water and the
    surfaces in front of them); else camera-only (fast fidelity adds their light itself)."""
    v, f = disc(m["led_radius_m"])
    T = np.asarray(T_world_dock, float)
    for i, (kp, rad) in enumerate(zip(m["keypoints"], m["radiance"])):
        obj = mesh_object(f"led_{m['id']}_{i}", v, f, index=m["object_index"])
        obj.data.materials.append(materials.emission(f"led_{m['id']}_{i}", rad, 1.0, sampled=lights_scene))
        if not lights_scene:
            camera_only(obj)
        set_matrix(obj, T @ np.vstack([np.column_stack([np.eye(3), kp]), [0, 0, 0, 1]]))


def add_obstacle(o: dict) -> None:
    """Large fixed obstacle (box, cylinder or rock) at its world pose."""
    sx, sy, sz = o["size_m"]
    if o["kind"] == "box":
        v, f = box_verts(sx, sy, sz, z0=sz / 2)
    elif o["kind"] == "cylinder":
        n = 32
        ang = [2 * math.pi * k / n for k in range(n)]
        v = [(sx / 2 * math.cos(a), sy / 2 * math.sin(a), z) for z in (-sz / 2, sz / 2) for a in ang]
        f = [tuple(range(n - 1, -1, -1)), tuple(range(n, 2 * n))]
        f += [(k, (k + 1) % n, n + (k + 1) % n, n + k) for k in range(n)]
    else:  # rock: a lumpy sphere, deterministic from its pose
        v, f = uv_sphere(0.5, 16, 8)
        rng = np.random.default_rng(abs(hash(tuple(np.round(o["T_world"][0], 3)))) % 2**32)
        v = [tuple(np.array(p) * (1 + 0.15 * rng.standard_normal()) * (sx, sy, sz)) for p in v]
    obj = mesh_object(f"obstacle_{o['object_index']}", v, f, index=o["object_index"])
    obj.data.materials.append(materials.diffuse(f"obstacle_{o['object_index']}", o["color"]))
    set_matrix(obj, o["T_world"])


def add_sun(name: str, travel_dir, strength: float, shadows: bool = True, lightgroup: str = "") -> None:
    """Directional light travelling along ``travel_dir`` (world, unit) with irradiance ``strength``;
    ``lightgroup``: its Cycles light group (its own pass when the view layer has the group)."""
    light = bpy.data.lights.new(name, type="SUN")
    light.energy = float(strength)
    light.angle = 0.0
    light.use_shadow = bool(shadows)
    obj = _link(bpy.data.objects.new(name, light))
    obj.lightgroup = lightgroup
    d = -np.asarray(travel_dir, float)
    d /= np.linalg.norm(d)
    obj.rotation_euler = (0.0, math.acos(np.clip(d[2], -1, 1)), math.atan2(d[1], d[0]))


def dock_frame(dock: dict, index: int, look: dict):
    """Aluminium frame behind the marker plane: four corner posts along the body's depth and a
    rim around its face, all outside the body's footprint and behind the face (dock z <
    -2 mm), so no marker is ever covered. Returns the object."""
    sx, sy, sz = dock["body_size_m"]
    t = 0.04
    verts, faces = [], []

    def bar(cx, cy, lx, ly, lz, z0):
        v, f = box_verts(lx, ly, lz, z0=z0)
        base = len(verts)
        verts.extend((x + cx, y + cy, z) for x, y, z in v)
        faces.extend(tuple(i + base for i in q) for q in f)

    z_face = -0.003
    for ex in (-1, 1):
        for ey in (-1, 1):
            bar(ex * (sx + t) / 2, ey * (sy + t) / 2, t, t, sz, z_face)
    for ey in (-1, 1):
        bar(0.0, ey * (sy + t) / 2, sx + 2 * t, t, t, z_face)
    for ex in (-1, 1):
        bar(ex * (sx + t) / 2, 0.0, t, sy, t, z_face)
    obj = mesh_object("dock_frame", verts, faces, index=index)
    obj.data.materials.append(world.metal("dock_metal"))
    set_matrix(obj, dock["T_world_dock"])
    return obj


def add_seabed(look: dict, centre_xy, index: int, half: float = 60.0) -> None:
    """Open water: a sand plane ``seabed_depth_m`` below the surface around the dock, with a
    few seeded rocks (0.3-1.2 m) half buried in it."""
    z = -float(look["seabed_depth_m"])
    cx, cy = (float(c) for c in centre_xy)
    v = [(cx - half, cy - half, z), (cx + half, cy - half, z), (cx + half, cy + half, z), (cx - half, cy + half, z)]
    bed = mesh_object("seabed", v, [(0, 1, 2, 3)], index=index)
    bed.data.materials.append(world.sand("sand", look))
    rng = np.random.default_rng(look["texture_seed"] + 5)
    mat = world.rock("rock", look)
    for i in range(24):
        r = rng.uniform(0.3, 1.2)
        sv, sf = uv_sphere(1.0, 16, 8)
        scale = r * np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.35, 0.7)])
        pts = [tuple(np.array(p) * scale * (1 + 0.12 * rng.standard_normal())) for p in sv]
        obj = mesh_object(f"rock_{i}", pts, sf, index=index)
        obj.data.materials.append(mat)
        ang = rng.uniform(0, 2 * math.pi)
        T = np.eye(4)
        T[:2, :2] = [[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]]
        T[:3, 3] = (cx + rng.uniform(-25, 25), cy + rng.uniform(-25, 25), z)
        set_matrix(obj, T)


def build(desc: dict) -> bpy.types.Scene:
    """Whole scene from a description; returns the Blender scene."""
    scene = reset()
    env = bpy.data.worlds.new("water")
    scene.world = env
    sky = desc.get("sky")
    if sky:  # reference fidelity: the diffuse light field as a hidden environment
        materials.world_sky(env, sky["upper"], sky["lower"])
    else:
        materials.world_color(env, desc["world_color"])
    look = desc.get("world")
    if desc.get("pool"):
        add_pool(desc["pool"], desc["object_index"]["pool"], look)
    elif look and look.get("textures"):  # open water: a sand-and-rock seabed template
        add_seabed(look, np.asarray(desc["dock"]["T_world_dock"], float)[:2, 3], desc["object_index"]["pool"])
    add_dock(desc["dock"], desc["object_index"]["dock"], look)
    T_wd = np.asarray(desc["dock"]["T_world_dock"], float)
    for m in desc["markers"]:
        if m["kind"] == "led_array":
            add_led_array(m, T_wd, bool(desc.get("led_lights")))
        else:
            add_square_marker(m, T_wd @ np.asarray(m["T_dock_marker"], float))
    for o in desc.get("obstacles", []):
        add_obstacle(o)
    if desc.get("water_volume"):  # reference fidelity: the water is a participating medium
        from blendgen.blender import water

        water.add_water_volume(desc["water_volume"])
    if desc.get("water_surface"):  # reference fidelity: a refracting surface with the sky above
        world.add_water_surface(desc["water_surface"])
        world.world_sky_through_surface(env, desc["water_surface"]["sky_radiance"], desc["water_surface"].get("sun"))
    add_sun("sun", desc["sun"]["direction"], desc["sun"]["strength"], lightgroup="sun")
    if desc["fill"]["strength"] > 0:
        add_sun("fill", desc["fill"]["direction"], desc["fill"]["strength"], shadows=False)
    return scene
