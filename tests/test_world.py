"""The world around the dock (docs/light.md): Snell's window, caustics, their zero cost when off.

Oracles: the critical angle asin(1/1.333) = 48.6 deg; Fresnel reflectance at normal incidence
((n-1)/(n+1))^2; energy conservation (mean caustic irradiance = flat-surface value); the
analytic contrast of the caustic model; monotone fall of contrast with depth in turbid water."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.config.models import Experiment, Water
from blendgen.physics.surface import optics as sf
from blendgen.pipeline import compose, plan
from blendgen.pipeline.plan import SequencePost, WorldPost

W, H = 161, 161
F = (W - 1) / 2 / math.tan(math.radians(75))  # 150 deg field of view: sees the whole window
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1]])


def _looking_up(cam_z: float) -> np.ndarray:
    """OpenCV camera at (0, 0, cam_z) looking straight up: z_cam = +z_world, y_cam = -y_world."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, 1.0])
    T[2, 3] = cam_z
    return T


def _post(world: WorldPost | None, water: Water | None = None) -> SequencePost:
    water = Water(preset="jerlov_IB") if water is None else water
    return SequencePost(
        seed=0,
        fps=10,
        image_formation="physical",
        water=water,
        light_depth_m=3.0,
        surface_z_m=0.0,
        irradiance_w_m2=3.0,
        world=world,
    )


def _world(surface=True, caustics=False, wind=0.0) -> WorldPost:
    return WorldPost(
        surface=surface,
        caustics=caustics,
        wind_mps=wind,
        wave_seed=7,
        sky_radiance=0.2,
        ambient_radiance=0.0,
        sun_travel_dir=[0.0, 0.0, -1.0],
    )


def _open_water_up(post, t=0.0):
    passes = {
        "rgb": np.zeros((H, W, 3), np.float32),
        "range_m": np.full((H, W), np.inf, np.float32),
        "index": np.zeros((H, W), np.uint8),
    }
    return compose.water_image(passes, compose.SequenceState.start(post), K, _looking_up(-3.0), [], t=t)


def _zenith_angle_deg() -> np.ndarray:
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    return np.degrees(np.arctan(np.hypot(u - K[0, 2], v - K[1, 2]) / F))


def test_fresnel_normal_incidence_and_total_internal_reflection():
    assert sf.fresnel_reflectance(1.0)[()] == pytest.approx(((1.333 - 1) / (1.333 + 1)) ** 2, rel=1e-4)
    assert sf.fresnel_reflectance(math.cos(math.radians(48.7)))[()] == 1.0
    assert math.degrees(sf.critical_angle_rad()) == pytest.approx(48.6, abs=0.05)


def test_snells_window_half_angle_within_1_deg_looking_up():
    """Fast path, flat surface, open water, camera 3 m deep looking up: the bright disc's edge
    (radiance halfway between the zenith's and the totally reflected veil) sits at 48.6 +- 1 deg."""
    img = _open_water_up(_post(_world()))[..., 1]
    ang = _zenith_angle_deg()
    zen, far = float(img[H // 2, W // 2]), float(np.median(img[ang > 60]))
    assert zen > 2 * far > 0  # bright window over a veil, never black
    inside = ang[img > (zen + far) / 2]
    assert abs(inside.max() - 48.6) < 1.0


def test_outside_the_window_is_the_veil_not_black():
    """Open water: total internal reflection returns the veiling light at the camera's depth."""
    img = _open_water_up(_post(_world()))
    ref = _open_water_up(_post(None))  # without surface: the veil everywhere
    out = _zenith_angle_deg() > 55
    np.testing.assert_allclose(img[out], ref[out], rtol=1e-5)
    assert img[out].min() > 0


def test_rough_surface_moves_with_time():
    a = _open_water_up(_post(_world(wind=3.0)), t=0.0)
    b = _open_water_up(_post(_world(wind=3.0)), t=0.5)
    assert np.abs(a - b).max() > 0.01


def test_world_off_costs_nothing_and_changes_nothing(monkeypatch):
    """SequencePost.world None: the surface/caustic module is never entered."""
    from blendgen.pipeline import world_post

    def boom(*a, **k):
        raise AssertionError("world_post called while off")

    for name in (
        "add_surface",
        "surface_geometry",
        "shade_surface",
        "add_caustics",
        "caustic_geometry",
        "shade_caustics",
    ):
        monkeypatch.setattr(world_post, name, boom)
    _open_water_up(_post(None))
    with pytest.raises(AssertionError, match="while off"):  # the patch does catch the frame loop's calls
        _open_water_up(_post(_world(wind=3.0)))


def _floor_map(
    waves, depth_m: float, scattering: float = 0.0, size: int = 300, bin_m: float = 0.02, origin=(37.0, -20.0)
) -> np.ndarray:
    """The fast caustic map (caustic_map.light_map) of a floor ``depth_m`` below, zenith sun."""
    from blendgen.physics.surface import caustic_map

    patch = caustic_map.Patch(origin[0], origin[1], bin_m, (size, size))
    return caustic_map.light_map(waves, patch, depth_m, 1.7, None, scattering, 0.9)


def test_caustics_conserve_energy():
    """Mean irradiance = the flat surface's (2 %) before and far beyond the first focus;
    never negative."""
    waves = sf.WaveField.sample(3, 2.0)
    for h in (0.5, 2.0, 6.0, 15.0):
        m = _floor_map(waves, h, 0.05, size=400, bin_m=0.04)
        assert m.min() >= 0
        assert m.mean() == pytest.approx(1.0, abs=0.02), h


@pytest.mark.parametrize("b", [0.1, 0.3])
def test_caustic_contrast_falls_with_depth(b):
    """Beyond 1.5 x the first focal depth (``surface.focal_depth``, 3.5 m here; the Cycles photon
    map of ``bench caustics`` peaks near 1.4 x it), contrast (std of E/E0) falls monotonically
    with depth; at the same depth, more turbid water has lower contrast."""
    waves = sf.WaveField.sample(3, 1.0)
    hf = sf.focal_depth(waves)
    depths = [f * hf for f in (1.5, 2.0, 3.0, 4.0, 6.0)]
    cv = [float(_floor_map(waves, h, b, size=256, bin_m=0.04).std()) for h in depths]
    assert all(c1 > c2 for c1, c2 in zip(cv, cv[1:])), cv
    clearer = float(_floor_map(waves, depths[1], b / 3, size=256, bin_m=0.04).std())
    assert clearer > cv[1]


def test_caustics_rise_from_zero_at_the_surface():
    """At the surface there is no focusing yet: the pattern grows with depth at first."""
    waves = sf.WaveField.sample(3, 1.0)
    cv = [float(_floor_map(waves, h, size=200).std()) for h in (0.0, 0.2, 1.0)]
    assert cv[0] < 1e-6 < cv[1] < cv[2]


def test_flat_surface_has_no_caustics():
    flat = sf.WaveField.sample(3, 0.0, mss=0.0)
    np.testing.assert_allclose(_floor_map(flat, 4.0, 0.2, size=64), 1.0, atol=1e-5)


def test_caustics_move_the_floor_light_and_keep_its_mean():
    """Fast path: a sun-lit floor 4 m down gets a moving pattern, mean preserved (2 %)."""
    post = _post(_world(surface=False, caustics=True, wind=2.0), Water(preset="jerlov_IB"))
    T = _looking_up(-3.0)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down at the floor 1 m below
    passes = {"rgb": np.full((H, W, 3), 0.3, np.float32), "index": np.ones((H, W), np.uint8)}
    passes["depth_z"] = np.ones((H, W), np.float32)
    compose.add_range(passes, K)
    st = compose.SequenceState.start(post)
    a = compose.water_image(passes, st, K, T, [], t=0.0)
    b = compose.water_image(passes, st, K, T, [], t=0.3)
    off = compose.water_image(passes, compose.SequenceState.start(_post(None)), K, T, [])
    assert a.std() > 0.2 * off.mean() and np.abs(a - b).mean() > 0.01 * off.mean()
    assert a.mean() == pytest.approx(off.mean(), rel=0.05)


def test_caustics_leave_light_sources_alone():
    """An LED's own light is not sunlight: its pixels keep their radiance under caustics while
    the floor around them is patterned."""
    from blendgen.pipeline import world_post

    wp = _world(surface=False, caustics=True, wind=2.0)
    T = _looking_up(-3.0)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down at the floor 1 m below
    rays = np.einsum("ijk,lk->ijl", compose._unit_rays(tuple(K.ravel()), W, H), T[:3, :3].astype(np.float32))
    rng = (1.0 / -rays[..., 2]).astype(np.float32)
    rgb = np.full((H, W, 3), 0.3, np.float32)
    led = np.zeros((H, W), bool)
    led[60:100, 60:100] = True
    out = world_post.add_caustics(
        rgb, None, rng, np.full((H, W), 4.0, np.float32), wp, rays, K, T, 0.0, 0.0, emissive=led
    )
    np.testing.assert_array_equal(out[led], rgb[led])
    assert np.abs(out[~led] - 0.3).mean() > 0.01


def test_caustics_refocus_only_the_sunlight_a_pixel_holds():
    """A floor of albedo 0.5 in a sun of E = 3 W/m^2 from the zenith holds 0.5 E / pi of sunlight.
    Pixels that hold more (an LED's light spilled into them, a fill light) change by exactly as
    much as a plain sunlit pixel does: (M - 1) 0.5 E / pi, with M the focusing factor read from a
    sunlit twin of the frame; without the bound they changed in proportion to all their light.
    With the render's sun pass (the sun's light group) the change is (M - 1) times that pass,
    0 in its shadow."""
    from blendgen.pipeline import world_post

    wp = _world(surface=False, caustics=True, wind=2.0).model_copy(update={"sun_lamp_w_m2": 3.0})
    T = _looking_up(-3.0)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down at the floor 1 m below
    rays = np.einsum("ijk,lk->ijl", compose._unit_rays(tuple(K.ravel()), W, H), T[:3, :3].astype(np.float32))
    rng = (1.0 / -rays[..., 2]).astype(np.float32)
    albedo = np.full((H, W, 3), 0.5, np.float32)
    sun = np.float32(0.5 * 3.0 / math.pi)  # the floor faces the sun: cos(i) = 1
    depth = np.full((H, W), 4.0, np.float32)
    plain = world_post.add_caustics(np.full((H, W, 3), sun, np.float32), albedo, rng, depth, wp, rays, K, T, 0.0, 0.0)
    m_minus_1 = plain / sun - 1
    assert np.abs(m_minus_1).mean() > 0.05  # a pattern to refocus
    spill = np.full((H, W, 3), sun, np.float32)
    spill[40:120, 40:120] += np.float32(2.0)  # light that is not the sun's
    out = world_post.add_caustics(spill, albedo, rng, depth, wp, rays, K, T, 0.0, 0.0)
    np.testing.assert_allclose(out - spill, m_minus_1 * sun, atol=1e-5)
    unbounded = world_post.add_caustics(
        spill, albedo, rng, depth, wp.model_copy(update={"sun_lamp_w_m2": 0.0}), rays, K, T, 0.0, 0.0
    )
    assert np.abs(unbounded - spill - m_minus_1 * sun)[40:120, 40:120].max() > 0.1
    shade = np.ones((H, W, 1), np.float32)
    shade[:, :60] = 0.0  # the render's sun pass: a shadow on the left
    with_pass = world_post.add_caustics(spill, albedo, rng, depth, wp, rays, K, T, 0.0, 0.0, sun_pass=sun * shade)
    np.testing.assert_allclose(with_pass - spill, m_minus_1 * sun * shade, atol=1e-5)


def test_world_defaults_on_in_physical_off_in_article_and_recorded():
    traj = [{"kind": "linear", "id": "a"}]
    phys = Experiment.model_validate({"name": "w", "image_formation": "physical", "trajectories": traj})
    art = Experiment.model_validate({"name": "w", "image_formation": "article", "trajectories": traj})
    assert plan.world_post(phys) is not None and plan.world_post(art) is None
    assert plan.world_look(phys)["textures"] and not plan.world_look(art)["textures"]


def _reference_up(tmp_path, depth=3.0, size=97, samples=16) -> np.ndarray:
    import json
    import subprocess
    import sys

    spec = {"depth_m": depth, "hfov_deg": 150, "size": size, "samples": samples, "sky_radiance": 0.2, "water": None}
    p, out = tmp_path / "spec.json", tmp_path / "up.npy"
    p.write_text(json.dumps(spec))
    subprocess.run(
        [sys.executable, "-m", "blendgen.blender.testing.surface_oracle", str(p), str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return np.load(out)


def test_reference_snells_window_half_angle_and_radiance(tmp_path):
    """Cycles, glass surface IOR 1.333 seen from 3 m below (no medium): the window's edge at
    48.6 +- 1 deg; inside, the radiance T(theta) n^2 L_sky of the fast formula within 5 %
    (ring means over 0-40 deg)."""
    img = _reference_up(tmp_path)[..., 1]
    n = img.shape[0]
    f = (n - 1) / 2 / math.tan(math.radians(75))
    u, v = np.meshgrid(np.arange(n), np.arange(n))
    ang = np.degrees(np.arctan(np.hypot(u - (n - 1) / 2, v - (n - 1) / 2) / f))
    centre = float(img[ang < 20].mean())
    assert abs(ang[img > centre / 2].max() - 48.6) < 1.0
    assert float(img[ang > 50].max()) == 0.0  # total internal reflection of a black pool
    for lo in (0, 20, 30):
        ring = (ang >= lo) & (ang < lo + 10)
        fast = sf.window_radiance(np.cos(np.radians(ang[ring])), [0.2] * 3, [0.0] * 3)[:, 1].mean()
        assert float(img[ring].mean()) == pytest.approx(float(fast), rel=0.05)


def _albedo(tmp_path, seed: int) -> np.ndarray:
    import json
    import subprocess
    import sys

    p, out = tmp_path / f"a{seed}.json", tmp_path / f"a{seed}.npy"
    p.write_text(json.dumps({"kind": "albedo", "size": 96, "height_m": 1.5, "seed": seed}))
    subprocess.run(
        [sys.executable, "-m", "blendgen.blender.testing.surface_oracle", str(p), str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return np.load(out)


def test_albedo_pass_carries_the_tile_texture(tmp_path):
    """The ambient term's albedo is textured: grout lines darker than tiles (the floor colour
    0.5-0.55 x 0.55 in grout), mean near the configured colour, and the seed changes it."""
    a = _albedo(tmp_path, 0)[..., 1]
    assert np.percentile(a, 2) < 0.75 * np.median(a)  # grout and grime
    assert 0.35 < float(np.median(a)) < 0.65  # tiles near the floor colour 0.55
    # 1.5 m above the floor, hfov 40 deg: ~1.1 m wide, 0.25 m tiles -> grout columns repeat
    # every ~22 px; mean albedo per column dips at the grout
    col = a.mean(axis=0)
    assert col.max() - col.min() > 0.05
    b = _albedo(tmp_path, 1)[..., 1]
    assert np.abs(a - b).mean() > 0.01


def test_pool_rim_above_a_moved_surface_shows_the_surface():
    """A depth condition lowers the surface below the pool rim: rays that meet the rim above
    the water meet the surface first (fast path), and get the window or its reflection."""
    post = _post(_world()).model_copy(update={"surface_z_m": -1.0})
    passes = {
        "rgb": np.full((H, W, 3), 0.5, np.float32),
        "range_m": np.full((H, W), 5.0, np.float32),
        "index": np.ones((H, W), np.uint8),
    }  # a "wall" 5 m away along every ray
    img = compose.water_image(passes, compose.SequenceState.start(post), K, _looking_up(-3.0), [])
    ang = _zenith_angle_deg()
    # the surface is 2 m up: rays within acos(2/5) = 66 deg of the zenith meet it before the wall
    inside, beyond = ang < 60, ang > 70
    ref = _open_water_up(post)
    # inside Snell's window the sky dominates; its few % of Fresnel reflection show the scene
    # below, which here (a wall in the frame) is the mirror fill, not open water's dark veil
    window = ang < 40
    np.testing.assert_allclose(img[window], ref[window], rtol=0.05)
    assert not np.allclose(img[inside & ~window], img[beyond].mean(axis=0), rtol=0.05)  # surface, not wall
    assert not np.allclose(img[beyond], ref[beyond])


def test_reference_jobs_carry_the_refracting_surface_and_specular_bounces():
    traj = [{"kind": "linear", "id": "a"}]
    exp = Experiment.model_validate(
        {"name": "w", "image_formation": "physical", "trajectories": traj, "render": {"fidelity": "reference"}}
    )
    post = plan.condition_post(exp, exp.conditions[0], 0)
    surf = plan.water_surface(exp, post)
    assert surf["z"] == post.surface_z_m and surf["half_xy"] == [7.5, 2.5]
    assert plan.render_settings(exp, 1)["specular_bounces"] == 2
    off = exp.model_copy(
        update={
            "scene": exp.scene.model_copy(
                update={"world": exp.scene.world.model_copy(update={"surface": False, "caustics": False})}
            )
        }
    )
    assert plan.water_surface(off, plan.condition_post(off, off.conditions[0], 0)) is None
    assert plan.render_settings(off, 1)["specular_bounces"] == 0


def test_article_mode_refuses_an_explicit_surface():
    from blendgen.config.models import ConfigError

    traj = [{"kind": "linear", "id": "a"}]
    exp = Experiment.model_validate(
        {"name": "w", "image_formation": "article", "trajectories": traj, "scene": {"world": {"caustics": True}}}
    )
    with pytest.raises(ConfigError, match="scene.world"):
        plan.world_post(exp)


@pytest.mark.parametrize("zenith_air, azimuth", [(0.0, 0.0), (41.8, 180.0), (75.0, -120.0), (89.0, 33.0)])
def test_sun_in_air_inverts_the_refraction(zenith_air, azimuth):
    """Snell's law both ways: the in-water beam of a sun in the sky gives that sun back, and
    its horizontal part shrinks by exactly n (sin_t = sin_i / n)."""
    z, a = math.radians(zenith_air), math.radians(azimuth)
    air = np.array([math.sin(z) * math.cos(a), math.sin(z) * math.sin(a), -math.cos(z)])
    water = sf.refracted_sun(air)
    assert np.hypot(*water[:2]) == pytest.approx(math.sin(z) / sf.N_WATER, abs=1e-12)
    np.testing.assert_allclose(sf.sun_in_air(water), air, atol=1e-12)


def test_a_sun_outside_snells_cone_is_refused_with_a_surface(tmp_path):
    """``sun_elevation_deg`` is the in-water direction: at 40 deg (zenith 50 > 48.6) no sun
    in the sky sends it, so a scene with a surface is refused; without one it stays allowed."""
    from blendgen.config.models import ConfigError

    traj = [{"kind": "linear", "id": "a", "start_range_m": 4.0, "end_range_m": 3.0}]
    exp = Experiment.model_validate(
        {"name": "w", "image_formation": "physical", "trajectories": traj, "scene": {"sun_elevation_deg": 40.0}}
    )
    with pytest.raises(ConfigError, match=r"scene.sun_elevation_deg: 40 .*41.4"):
        plan.world_post(exp)
    off = Experiment.model_validate(
        {
            "name": "w",
            "image_formation": "physical",
            "trajectories": traj,
            "scene": {"sun_elevation_deg": 40.0, "world": {"surface": False, "caustics": False}},
        }
    )
    assert plan.world_post(off) is None
    from blendgen.pipeline.generate import generate

    with pytest.raises(ConfigError, match="sun_elevation_deg"):
        generate(exp, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()  # refused before anything is written
    ok = exp.model_copy(update={"scene": exp.scene.model_copy(update={"sun_elevation_deg": 60.0})})
    np.testing.assert_allclose(
        sf.refracted_sun(plan.world_post(ok).sun_travel_dir), plan._sun_dir(60.0, ok.scene.sun_azimuth_deg), atol=1e-12
    )


def test_total_internal_reflection_mirrors_the_pool():
    """Flat surface 1 m above a horizontal camera, a wall 5 m ahead whose radiance encodes its
    depth, clear beam (c = 0): a totally reflected pixel of ray d shows the wall where the
    mirrored ray from the surface point meets it, parallax included (depth 5 d_z / d_x - 1),
    not what the camera sees in the mirrored direction from its own position (depth
    5 d_z / d_x + 1), and never the veil."""
    water = Water(preset="jerlov_IB", sigma_a=0.0, sigma_s=0.0, B_inf=0.0)
    post = _post(_world(), water)
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # looking along +x
    T[2, 3] = -1.0  # 1 m below the surface z = 0
    h, w = 121, 81
    k = np.array([[60.0, 0, (w - 1) / 2], [0, 60.0, (h - 1) / 2], [0, 0, 1]])
    rays = np.einsum("ijk,lk->ijl", compose._unit_rays(tuple(k.ravel()), w, h), T[:3, :3].astype(np.float32))
    to_wall = 5.0 / rays[..., 0]
    z_wall = -1.0 + to_wall * rays[..., 2]
    wall = z_wall < 0  # below the surface: the wall is seen
    height = np.where(wall, -z_wall, 0.0).astype(np.float32)  # radiance = depth of the wall point
    passes = {
        "rgb": np.repeat(0.1 + 0.1 * height[..., None], 3, axis=2),
        "range_m": np.where(wall, to_wall, np.inf).astype(np.float32),
        "index": np.ones((h, w), np.uint8),
    }
    img = compose.water_image(passes, compose.SequenceState.start(post), k, T, [])
    dx, dy, dz = rays[..., 0].astype(float), rays[..., 1].astype(float), rays[..., 2].astype(float)
    el = np.arcsin(np.clip(dz, -1, 1))
    tir = ~wall & (dz > 0.05) & (el < np.radians(90 - 48.6) - 0.02)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_wall = (5.0 - dx / dz) / dx  # from the surface point to the wall
        depth_hit = 5.0 * dz / dx - 1.0  # below the surface where it lands
        y_hit = dy / dz + s_wall * dy
        u = k[0, 2] + k[0, 0] * -y_hit / 5.0  # that wall point in the image
        v = k[1, 2] + k[1, 1] * (depth_hit - 1.0) / 5.0
    seen = tir & (u > 1) & (u < w - 2) & (v > 1) & (v < h - 2)
    assert seen.sum() > 50
    # the camera's own view of that wall point (same depth light, c = 0: no path loss)
    want = img[np.rint(v[seen]).astype(int), np.rint(u[seen]).astype(int), 0]
    got = img[seen][:, 0]
    column = img[:, w // 2, 0]
    px = np.median(np.abs(np.diff(column))[wall[1:, w // 2] & wall[:-1, w // 2]])  # radiance per px of wall
    assert np.abs(got - want).max() < 5 * px  # one ray per 2 x 2 block (magnified near grazing)
    assert np.median(np.abs(got - want)) < 1.5 * px
    old = column[np.clip(np.rint(k[1, 2] + k[1, 1] * dz[seen] / dx[seen]), 0, h - 1).astype(int)]
    assert np.abs(old - want).mean() > 10 * px  # the lookup that ignored the parallax
    assert img[tir].min() > 0.05  # never the (zero) veil where the wall is seen


def test_pixel_footprint_on_floor_and_wall():
    """Face-on floor: the footprint is r px (analytic, 1 %); seen at 60 deg from its normal,
    r px / cos 60; moved up a 30-deg beam onto the surface plane, a floor's stays and a wall's
    shrinks by sqrt(|n . beam| / |beam_z|) (sqrt(tan 30 deg))."""
    from blendgen.pipeline import world_post

    def plane(normal, dist, axis):
        """Rays of a 9x9 pinhole (0.2 mrad/px) along ``axis`` hitting the plane n.x = -dist."""
        rays = np.zeros((9, 9, 3), np.float32)
        u, v = np.meshgrid(np.linspace(-0.0008, 0.0008, 9), np.linspace(-0.0008, 0.0008, 9))
        e1 = np.cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        rays[:] = np.asarray(axis, np.float32) + u[..., None] * e1 + v[..., None] * e2
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        rng = (-dist / np.einsum("ijk,k->ij", rays, normal)).astype(np.float32)
        return rays, rng

    floor = np.array([0.0, 0.0, 1.0])
    for dist in (1.0, 30.0):
        rays, rng = plane(floor, dist, np.array([0.0, 0.0, -1.0]))
        n = world_post.facing_normals(rays, rng)
        np.testing.assert_allclose(n[4, 4], floor, atol=1e-4)
        f = world_post.footprint_m(rays, rng, n, 2e-4)[4, 4]
        assert f == pytest.approx(dist * 2e-4, rel=0.01)
    slant = np.array([math.sin(math.radians(60)), 0.0, -math.cos(math.radians(60))])
    rays, rng = plane(floor, 2.0, slant)
    n = world_post.facing_normals(rays, rng)
    assert world_post.footprint_m(rays, rng, n, 2e-4)[4, 4] == pytest.approx(4.0 * 2e-4 / 0.5, rel=0.01)
    beam = np.array([math.sin(math.radians(30)), 0.0, -math.cos(math.radians(30))])
    assert world_post.footprint_m(rays, rng, n, 2e-4, beam)[4, 4] == pytest.approx(4.0 * 2e-4 / 0.5, rel=0.01)
    wall = np.array([-1.0, 0.0, 0.0])  # faces the sun travelling along +x
    rays, rng = plane(wall, 2.0, np.array([1.0, 0.0, 0.0]))
    n = world_post.facing_normals(rays, rng)
    expect = 2.0 * 2e-4 * math.sqrt(math.tan(math.radians(30)))
    assert world_post.footprint_m(rays, rng, n, 2e-4, beam)[4, 4] == pytest.approx(expect, rel=0.01)


def _pool_view(world: WorldPost, t=0.3):
    """640x480 camera 3 m deep, pitched 15 deg up along +x: surface above (most of it totally
    reflecting the pool), a smoothly shaded floor/wall 4-12 m away below; linear image."""
    w, h = 640, 480
    f = w / 2 / math.tan(math.radians(40))
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    a = math.radians(15)
    pitch = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
    T = np.eye(4)
    T[:3, :3] = pitch @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    T[2, 3] = -3.0
    rng = np.full((h, w), np.inf, np.float32)
    rng[h // 2 :] = np.linspace(4, 12, w, dtype=np.float32)[None, :]
    u, v = np.meshgrid(np.linspace(0, 1, w, dtype=np.float32), np.linspace(0, 1, h, dtype=np.float32))
    rgb = np.dstack([0.1 + 0.4 * u, 0.3 + 0.2 * np.sin(12 * u) * v, 0.2 + 0.3 * v])  # smooth pool scene
    passes = {"rgb": rgb, "range_m": rng, "index": np.ones((h, w), np.uint8), "albedo": np.full_like(rgb, 0.5)}
    return compose.water_image(passes, compose.SequenceState.start(_post(world)), k, T, [], t=t)


def test_half_resolution_slopes_change_the_image_by_few_dn(monkeypatch):
    """The surface's wave slopes on every second pixel (interpolated) against every pixel, rough
    surface (3 m/s): after the 8-bit sRGB encode the mean change is < 0.3 DN, 99 % of pixels
    move <= 4 DN and < 0.5 % more than 10 DN (pixels at the window's edge, where a slope
    difference flips refraction into total reflection)."""
    from blendgen.physics.camera import sensor
    from blendgen.pipeline import world_post

    world = _world(wind=3.0)
    half = _pool_view(world)
    monkeypatch.setattr(world_post, "SLOPE_STRIDE", 1)
    full = _pool_view(world)
    scale = 1.0 / float(np.percentile(full, 99.5))
    d = np.abs(sensor.to_uint8(half * scale).astype(int) - sensor.to_uint8(full * scale).astype(int))
    assert d.mean() < 0.3 and np.percentile(d, 99) <= 4 and (d > 10).mean() < 0.005, (d.mean(), d.max())
    assert np.abs(half - full).max() > 0  # the stride is really in use


def test_scattered_transfer_limits():
    """Small-angle transfer function of the scattered light: long waves keep their pattern
    (-> 1), short ones lose it (-> 0); more forward scattering keeps more; isotropic scattering
    keeps none; in the single-scattering limit it is (1 - exp(-a k h)) / (a k h) (analytic, 1e-3)."""
    from blendgen.physics.surface.caustic_map import scattered_transfer

    k = np.array([1e-4, 1.0, 10.0, 1e4])
    m = scattered_transfer(k, 2.0, 0.3, 0.9)
    assert m[0] == pytest.approx(1.0, abs=1e-3) and m[-1] < 1e-3 and np.all(np.diff(m) < 0)
    assert np.all(scattered_transfer(k, 2.0, 0.3, 0.95)[1:3] > m[1:3])
    assert not scattered_transfer(k, 2.0, 0.3, 0.0)[1:].any()
    a = (1 - 0.9) / math.sqrt(0.9)
    single = scattered_transfer(np.array([10.0]), 2.0, 1e-5, 0.9)[0]
    assert single == pytest.approx((1 - math.exp(-a * 10 * 2)) / (a * 10 * 2), rel=1e-3)


def _sun_disc_fast(to_sun, tilt_deg: float, size: int, hfov_deg: float) -> np.ndarray:
    """Fast path: flat surface, black sky and pool, the sun (3 W/m^2) seen from 2 m below by
    a narrow camera tilted ``tilt_deg`` from the zenith towards +x; linear (H, W) radiance."""
    from blendgen.pipeline import world_post
    from blendgen.pipeline.compose import _unit_rays

    f = size / 2 / math.tan(math.radians(hfov_deg / 2))
    k = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]])
    a = math.radians(tilt_deg)
    T = np.eye(4)
    T[:3, :3] = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]) @ np.diag(
        [1.0, -1.0, 1.0]
    )
    T[2, 3] = -2.0
    rays = np.einsum("ijk,lk->ijl", _unit_rays(tuple(k.ravel()), size, size), T[:3, :3].astype(np.float32))
    wp = WorldPost(
        surface=True,
        caustics=False,
        wind_mps=0.0,
        wave_seed=0,
        sky_radiance=0.0,
        ambient_radiance=0.0,
        sun_travel_dir=[-v for v in to_sun],
        sun_irradiance=3.0,
    )
    rgb, _, _ = world_post.add_surface(
        np.zeros((size, size, 3), np.float32),
        np.full((size, size), np.inf, np.float32),
        0.0,
        wp,
        rays,
        k,
        T,
        0.0,
        0.0,
        np.zeros(3, np.float32),
    )
    return rgb[..., 1]


@pytest.mark.blender
@pytest.mark.parametrize("zenith_deg", [0.0, 40.0])
def test_sun_disc_in_snells_window_fast_vs_reference(tmp_path, zenith_deg):
    """The sun seen through a flat surface from below, camera aimed at its refracted image
    (zenith asin(sin z / n)): the disc's power sum(L) Omega_px equals the analytic
    T(theta) E cos(z) / cos(z_w) (radiance n^2 L over a solid angle shrunk by n^2 cos z_w / cos z)
    within 3 % in the fast path and 5 % in Cycles (disc in the world for transmission rays);
    fast and reference centroids within 0.5 px, half-maximum areas within 15 %."""
    import json
    import subprocess
    import sys

    z = math.radians(zenith_deg)
    zw = math.asin(math.sin(z) / sf.N_WATER)
    to_sun = [math.sin(z), 0.0, math.cos(z)]
    size, hfov = 48, 1.6
    spec = {
        "depth_m": 2.0,
        "hfov_deg": hfov,
        "size": size,
        "samples": 16,
        "sky_radiance": 0.0,
        "water": None,
        "tilt_deg": math.degrees(zw),
        "sun": {"to_sun": to_sun, "irradiance": 3.0},
    }
    p, out = tmp_path / "spec.json", tmp_path / "sun.npy"
    p.write_text(json.dumps(spec))
    subprocess.run(
        [sys.executable, "-m", "blendgen.blender.testing.surface_oracle", str(p), str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    ref = np.load(out)[..., 1]
    fast = _sun_disc_fast(to_sun, math.degrees(zw), size, hfov)
    omega_px = (math.tan(math.radians(hfov / 2)) / (size / 2)) ** 2
    expect = (1 - float(sf.fresnel_reflectance(math.cos(zw)))) * 3.0 * math.cos(z) / math.cos(zw)
    assert fast.sum() * omega_px == pytest.approx(expect, rel=0.03)
    assert ref.sum() * omega_px == pytest.approx(expect, rel=0.05)
    v, u = np.mgrid[:size, :size]
    for img in (fast, ref):
        assert abs((img * u).sum() / img.sum() - (size - 1) / 2) < 0.5
        assert abs((img * v).sum() / img.sum() - (size - 1) / 2) < 0.5
    assert (fast > fast.max() / 2).sum() == pytest.approx((ref > ref.max() / 2).sum(), rel=0.15)


@pytest.mark.blender
def test_rough_window_edge_same_waves_fast_and_reference(tmp_path):
    """Wind 2 m/s, camera 3 m down tilted 20 deg: the ragged edge of Snell's window (zenith
    40-58 deg) is the same pattern in both fidelities (correlation > 0.9: the reference's
    waves are not mirrored, as Cycles' back-face bump made them) and ring means agree (5 %;
    15 % on the edge, 48-52 deg, at this 128 px size, where the half-grid slopes show)."""
    import json
    import subprocess
    import sys

    from blendgen.pipeline import world_post
    from blendgen.pipeline.compose import _unit_rays

    size, hfov, tilt = 128, 110.0, 20.0
    spec = {
        "depth_m": 3.0,
        "hfov_deg": hfov,
        "size": size,
        "samples": 16,
        "sky_radiance": 0.2,
        "water": None,
        "tilt_deg": tilt,
        "wind_mps": 2.0,
        "wave_seed": 7,
    }
    p, out = tmp_path / "spec.json", tmp_path / "up.npy"
    p.write_text(json.dumps(spec))
    subprocess.run(
        [sys.executable, "-m", "blendgen.blender.testing.surface_oracle", str(p), str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    ref = np.load(out)[..., 1]
    f = size / 2 / math.tan(math.radians(hfov / 2))
    k = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]])
    a = math.radians(tilt)
    T = np.eye(4)
    T[:3, :3] = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]) @ np.diag(
        [1.0, -1.0, 1.0]
    )
    T[2, 3] = -3.0
    rays = np.einsum("ijk,lk->ijl", _unit_rays(tuple(k.ravel()), size, size), T[:3, :3].astype(np.float32))
    wp = WorldPost(
        surface=True,
        caustics=False,
        wind_mps=2.0,
        wave_seed=7,
        sky_radiance=0.2,
        ambient_radiance=0.0,
        sun_travel_dir=[0.0, 0.0, -1.0],
    )
    fast = world_post.add_surface(
        np.zeros((size, size, 3), np.float32),
        np.full((size, size), np.inf, np.float32),
        0.0,
        wp,
        rays,
        k,
        T,
        0.0,
        0.0,
        np.zeros(3, np.float32),
    )[0][..., 1]
    zen = np.degrees(np.arccos(np.clip(rays[..., 2], -1, 1)))
    band = (zen > 40) & (zen < 58)
    assert np.corrcoef(ref[band], fast[band])[0, 1] > 0.9
    for lo, hi, tol in ((0, 40, 0.05), (40, 48, 0.05), (48, 52, 0.15)):  # 48-52: the edge itself,
        ring = (zen >= lo) & (zen < hi)  # slopes on the half grid
        assert float(fast[ring].mean()) == pytest.approx(float(ref[ring].mean()), rel=tol), (lo, hi)


def test_sun_glint_follows_the_surface_and_its_switch():
    """scene.world.sun_glint null: the sun's disc (irradiance scene.sun_strength) in physical
    mode with the surface; false, or the surface off: 0 (the glint code is not entered);
    the reference's surface job carries the disc only then."""
    traj = [{"kind": "linear", "id": "a"}]

    def post(world):
        exp = Experiment.model_validate(
            {
                "name": "w",
                "image_formation": "physical",
                "trajectories": traj,
                "scene": {"sun_strength": 5.0, "world": world},
            }
        )
        return exp, plan.condition_post(exp, exp.conditions[0], 0)

    exp, on = post({})
    assert on.world.sun_irradiance == 5.0 and plan.water_surface(exp, on)["sun"]["irradiance"] == 5.0
    for world in ({"sun_glint": False}, {"surface": False}):
        exp, off = post(world)
        assert off.world.sun_irradiance == 0.0
        assert plan.water_surface(exp, off) is None or plan.water_surface(exp, off)["sun"] is None


def test_no_sun_disc_when_its_irradiance_is_zero(monkeypatch):
    """sun_irradiance 0: surface.sun_disc_radiance is never called."""

    def boom(*a, **k):
        raise AssertionError("sun disc computed while off")

    monkeypatch.setattr(sf, "sun_disc_radiance", boom)
    _open_water_up(_post(_world()))


def _land(d_air, slope, depth, n=sf.N_WATER):
    """Exact: where the sun ray refracted at the origin, under a surface of slope (sx, sy),
    reaches the depth (vector Snell's law, no small-slope step)."""
    N = np.array([-slope[0], -slope[1], 1.0])
    N /= np.linalg.norm(N)
    d = np.asarray(d_air, float) / np.linalg.norm(d_air)
    ci = -N @ d
    ct = math.sqrt(1 - (1 - ci * ci) / n**2)
    t = d / n + (ci / n - ct) * N
    return t[:2] * depth / -t[2]


@pytest.mark.parametrize("zenith_deg, azimuth_deg", [(0.0, 0.0), (40.0, 30.0), (60.0, -120.0)])
def test_sun_deflection_is_the_derivative_of_snells_law(zenith_deg, azimuth_deg):
    """The landing point's shift per unit slope, by central differences of exact vector
    refraction, equals slant path x sun_deflection (both columns; 1e-4 relative)."""
    z, a = math.radians(zenith_deg), math.radians(azimuth_deg)
    d_air = [math.sin(z) * math.cos(a), math.sin(z) * math.sin(a), -math.cos(z)]
    depth, eps = 3.0, 1e-5
    slant = depth / -sf.refracted_sun(d_air)[2]
    J = np.column_stack([(_land(d_air, e * eps, depth) - _land(d_air, -e * eps, depth)) / (2 * eps) for e in np.eye(2)])
    np.testing.assert_allclose(J, slant * sf.sun_deflection(d_air), rtol=1e-4, atol=1e-7)
    if zenith_deg == 0.0:
        np.testing.assert_allclose(sf.sun_deflection(d_air), (1 - 1 / sf.N_WATER) * np.eye(2), atol=1e-12)


def _dock_before_wall(sun_travel: np.ndarray):
    """(range, depth, rays, K, T, on the dock's face, in the dock's sun shadow) of a 60 deg
    camera 1.8 m deep looking +x at a wall at x = 3 m, a 1 x 0.4 m dock plate 0.15-0.25 m in front of it:
    ray-cast, the shadow by a ray from each point back up the refracted sun."""
    lo, hi = np.array([2.75, -0.5, -1.6]), np.array([2.85, 0.5, -1.2])
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # x right = -y, z forward = +x
    T[:3, 3] = [0.0, 0.0, -1.8]
    f = (W - 1) / 2 / math.tan(math.radians(30))
    K60 = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    rays = np.einsum("ijk,lk->ijl", compose._unit_rays(tuple(K60.ravel()), W, H), T[:3, :3].astype(np.float32))
    d, o = rays.astype(np.float64), T[:3, 3]

    def box_hit(origin, direction):
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (lo - origin) / direction, (hi - origin) / direction
        t0, t1 = np.minimum(a, b).max(-1), np.maximum(a, b).min(-1)
        return np.where((t0 > 1e-6) & (t0 <= t1), t0, np.inf)

    t_wall = (3.0 - o[0]) / d[..., 0]
    t_dock = box_hit(o, d)
    rng = np.minimum(t_wall, t_dock)
    p = o + rng[..., None] * d
    face = t_dock < t_wall
    shadow = ~face & np.isfinite(box_hit(p, np.broadcast_to(-sun_travel, p.shape)))
    return rng.astype(np.float32), (-p[..., 2]).astype(np.float32), rays, K60, T, face, shadow


def test_points_in_the_suns_shadow_do_not_change_the_caustics_of_the_surface_that_casts_it():
    """The wall behind a dock, in the dock's sun shadow, crosses the surface where the dock's
    face does; it has no sunlight to focus. The dock face's caustics are the same with that
    shadow in the frame (sun pass 0 there) as with those pixels left out of the caustics. Fails
    when shadowed points join the face's bins: their longer beam paths moved the face's pattern
    (by up to 0.34 of a pixel's 0.3)."""
    from blendgen.pipeline import world_post

    wp = _world(surface=False, caustics=True, wind=2.0).model_copy(
        update={"sun_travel_dir": sf.sun_in_air(np.array([0.5, 0.0, -0.866])).tolist(), "sun_lamp_w_m2": 3.0}
    )
    sun = sf.refracted_sun(wp.sun_travel_dir)
    rng, depth, rays, K60, T, face, shadow = _dock_before_wall(sun)
    assert shadow.sum() > 500 and face.sum() > 500
    rgb = np.full((H, W, 3), 0.3, np.float32)
    sun_pass = np.where(shadow[..., None], 0.0, 0.2).astype(np.float32) * np.ones(3, np.float32)
    args = (rgb, None, rng, depth, wp, rays, K60, T, 0.4, 0.05, 0.9)
    whole = world_post.add_caustics(*args, sun_pass=sun_pass)
    alone = world_post.add_caustics(*args, emissive=shadow, sun_pass=sun_pass)  # the shadow left out
    assert np.abs(whole[face] - 0.3).max() > 0.05  # a pattern on the face
    np.testing.assert_array_equal(whole[face], alone[face])
    np.testing.assert_array_equal(whole[shadow], rgb[shadow])
