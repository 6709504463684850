"""Reference caustics: sunlight traced forward through the Cycles water surface (a photon map).

Why not path tracing from the floor: the sun is a delta (0.53 deg) light and the surface a
specular interface, so a diffuse floor's BSDF rays almost never refract into the sun's disc
(probability ~ solid angle / pi ~ 2e-5 per sample), and next-event estimation cannot
cross a refracting surface; Cycles' MNEE shadow caustics need a mesh or area light with a
caster/receiver pair and gave black with a sun lamp. Instead we use the reciprocity of the
specular path: an **orthographic camera in the air plays the sun** (parallel rays, one per
pixel sample, each carrying the flux ``E_sun * pixel area``), Cycles refracts each ray
through the same glass surface as the reference fidelity
(:func:`blendgen.blender.world.add_water_surface`: IOR 1.333, Fresnel-weighted choice of
reflection/refraction, the 24 seeded waves as a bump normal), carries it through the water
volume (grey Henyey-Greenstein medium, absorption and multiple scattering by Cycles' own
volume sampling), and the floor **records where it lands**: its emission is its own
position ``(x + OFFSET, y + OFFSET, 1)`` (not sampled as a light: only rays that reach it
see it), so the pixel's value is ``w (x + OFFSET, y + OFFSET, 1)`` with ``w`` the path weight
(Fresnel choice, absorption, Russian roulette). Histogramming ``(R/B, G/B)`` weighted by ``B``
over the floor gives the irradiance map ``E / E_sun`` with every preimage summed, exact
Snell refraction (no small-slope approximation) and the scattered light included. The
sun's disc (angular radius 0.265 deg) is sampled by tilting the camera over a stratified
set of directions within it, one render each. Reflected rays leave to a black sky
(weight 0): Fresnel losses count.

``python -m blendgen.blender.caustic_reference SPEC.json OUT.npz``. SPEC keys: ``depth_m``,
``wave_seed``, ``wind_mps``, ``t`` (s), ``patch_m`` (side of the binned floor square, centred
at the origin), ``bins`` (rows along +y, columns along +x, both ascending), ``margin_m`` (camera footprint beyond
the patch, for light that
scatters in), ``size`` (pixels per render side), ``renders`` (sun directions),
``sun_radius_deg``, ``sun_zenith_deg`` (in air, heading +x; default 0), ``sigma_a``, ``sigma_s`` (grey, 1/m; 0 and
0: no medium), ``g``,
``volume_bounces``, ``seed``. OUT: ``E`` (bins, bins) irradiance over the sun's (above the
surface, normal to its rays), ``E2`` the per-bin sum of squared photon contributions (for
the shot-noise variance), ``photons`` the number of camera rays.
"""

from __future__ import annotations

import json
import math
import os
import sys

from blendgen.physics.surface.caustic_beam import OFFSET  # keeps the recorded positions positive


def _floor(depth: float, half: float):
    """Emitter at ``z = -depth`` whose colour is its own object position (+ OFFSET), B = 1."""
    from blendgen.blender.meshes import mesh_object
    from blendgen.blender.photon_scene import recorder_material

    v = [(-half, -half, -depth), (half, -half, -depth), (half, half, -depth), (-half, half, -depth)]
    obj = mesh_object("floor_recorder", v, [(0, 1, 2, 3)], index=1)
    obj.data.materials.append(recorder_material(0))
    obj.visible_camera = False
    return obj


def build(spec: dict):
    """The scene: black sky, wavy glass surface at z = 0, optional grey medium, recorder floor,
    orthographic camera 1 m above looking down. Returns (scene, camera object)."""
    import bpy

    from blendgen.blender import materials, water, world
    from blendgen.blender import render as rnd
    from blendgen.blender import scene as scn

    sc = scn.reset()
    wo = bpy.data.worlds.new("w")
    sc.world = wo
    materials.world_color(wo, [0.0, 0.0, 0.0])
    depth, big = float(spec["depth_m"]), float(spec["patch_m"]) / 2 + 4.0 * float(spec["depth_m"]) + 2.0
    world.add_water_surface(
        {
            "z": -1e-3,
            "centre_xy": [0.0, 0.0],
            "half_xy": [big, big],
            "wave_seed": int(spec["wave_seed"]),
            "wind_mps": float(spec["wind_mps"]),
        }
    )
    world.set_wave_time(float(spec.get("t", 0.0)))
    if float(spec["sigma_a"]) + float(spec["sigma_s"]) > 0:
        water.add_water_volume(
            {
                "sigma_a": [float(spec["sigma_a"])] * 3,
                "sigma_s": [float(spec["sigma_s"])] * 3,
                "phase": "hg",
                "g": float(spec.get("g", 0.9)),
                "box_min": [-big, -big, -depth],
                "box_max": [big, big, -2e-3],
            }
        )
    _floor(depth, big)
    data = bpy.data.cameras.new("sun")
    data.type = "ORTHO"
    data.ortho_scale = float(spec["patch_m"]) + 2 * float(spec["margin_m"])
    cam = bpy.data.objects.new("sun", data)
    sc.collection.objects.link(cam)
    sc.camera = cam
    cam.location = tuple(sun_camera_position(spec))
    n = int(spec["size"])
    sc.render.resolution_x = sc.render.resolution_y = n
    sc.render.resolution_percentage = 100
    vb = int(spec.get("volume_bounces", 0))
    rnd.setup_cycles(
        sc,
        {
            "samples": 1,
            "specular_bounces": 8,
            "volume_bounces": vb,
            "max_bounces": 8 + vb,
            "threads": int(spec.get("threads", 1)),
        },
    )
    cy = sc.cycles
    cy.caustics_reflective = cy.caustics_refractive = True
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0  # photon weights are not fireflies
    cy.blur_glossy = 0.0  # keep the glass sharp after a scatter
    return sc, cam


def sun_travel(spec: dict):
    """The sun's travel direction in air (3,), zenith angle ``sun_zenith_deg`` (default 0),
    heading +x, and below a flat surface (``surface.refracted_sun``)."""
    import numpy as np

    from blendgen.physics.surface.optics import refracted_sun

    z = math.radians(float(spec.get("sun_zenith_deg", 0.0)))
    air = np.array([math.sin(z), 0.0, -math.cos(z)])
    return air, refracted_sun(air)


def sun_camera_position(spec: dict):
    """The orthographic "sun" camera 1 m before the surface along the beam, centred on the
    surface point whose refracted ray reaches the patch centre (h tan(theta_t) upstream)."""
    import numpy as np

    air, water = sun_travel(spec)
    upstream = float(spec["depth_m"]) * water[0] / -water[2]
    return np.array([-upstream, 0.0, 0.0]) - air


def sun_rotation(spec: dict, rx: float, ry: float):
    """Camera rotation: its -Z along the sun's travel in air, then tilted by (rx, ry) (rad)
    within the sun's disc."""
    import mathutils

    air, _ = sun_travel(spec)
    base = mathutils.Vector((-air[0], -air[1], -air[2])).to_track_quat("Z", "Y").to_matrix()
    return (base @ mathutils.Euler((rx, ry, 0.0)).to_matrix()).to_euler()


def sun_directions(count: int, radius_rad: float):
    """``count`` tilts (rx, ry) (rad) spread evenly over the sun's disc (golden-angle spiral)."""
    out = []
    for i in range(count):
        r = radius_rad * math.sqrt((i + 0.5) / count)
        a = i * math.pi * (3.0 - math.sqrt(5.0))
        out.append((r * math.cos(a), r * math.sin(a)))
    return out


def photon_map(spec: dict, out: str) -> None:
    """Render the sun's rays ``spec["renders"]`` times (one sun direction and seed each) and
    save the binned irradiance (module docstring)."""
    import numpy as np

    from blendgen.blender import render as rnd

    sc, cam = build(spec)
    n, nb = int(spec["size"]), int(spec["bins"])
    half = float(spec["patch_m"]) / 2
    edges = np.linspace(-half, half, nb + 1)
    E = np.zeros((nb, nb))
    E2 = np.zeros((nb, nb))
    tilts = sun_directions(int(spec["renders"]), math.radians(float(spec.get("sun_radius_deg", 0.265))))
    path = os.path.join(rnd.scratch_dir(), f"dockbench-caustic-{os.getpid()}.exr")
    try:
        for i, (rx, ry) in enumerate(tilts):
            cam.rotation_euler = sun_rotation(spec, rx, ry)
            sc.cycles.seed = int(spec.get("seed", 0)) * 1000 + i
            sc.render.filepath = path
            import bpy

            bpy.ops.render.render(write_still=True)
            rgb = rnd.read_passes(path)["rgb"].reshape(-1, 3).astype(np.float64)
            w = rgb[:, 2]
            ok = w > 0
            x, y = rgb[ok, 0] / w[ok] - OFFSET, rgb[ok, 1] / w[ok] - OFFSET
            # rows along y (ascending), columns along x
            E += np.histogram2d(y, x, bins=[edges, edges], weights=w[ok])[0]
            E2 += np.histogram2d(y, x, bins=[edges, edges], weights=w[ok] ** 2)[0]
    finally:
        if os.path.exists(path):
            os.remove(path)
    photons = n * n * len(tilts)
    per_photon = (float(spec["patch_m"]) + 2 * float(spec["margin_m"])) ** 2 / (n * n) / len(tilts)
    bin_area = (2 * half / nb) ** 2
    scale = per_photon / bin_area  # one photon of weight 1 in a bin: this E / E_sun
    np.savez(out, E=E * scale, E2=E2 * scale * scale, photons=photons, spec=json.dumps(spec))


if __name__ == "__main__":
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    photon_map(json.loads(open(sys.argv[1]).read()), sys.argv[2])
