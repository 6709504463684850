"""Water-independent parts of a frame made once and shared by its conditions (FrameShare.memo).

Oracle: every condition's image made with the frame's shared parts equals the image made from
scratch for that condition alone (to 1e-4 relative, 40x below one 8-bit step: a deposit made on
a wider margin sums the same rays with other float rounding), whatever the order of the
waters (a wider deposit margin made first, a narrower one cut from it, and the reverse), and
conditions that differ in the surface's height (other caustic and surface geometry) do not
take each other's parts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blendgen.config.models import Water
from blendgen.physics.surface import caustic_map as cmap
from blendgen.physics.surface import optics as sf
from blendgen.pipeline import compose
from blendgen.pipeline.frameshare import FrameShare
from blendgen.pipeline.plan import SequencePost, WorldPost

WATERS = ("jerlov_I", "jerlov_IB", "jerlov_II", "jerlov_III")


def _post(preset: str, surface_z_m: float = 0.0) -> SequencePost:
    world = WorldPost(
        surface=True,
        caustics=True,
        wind_mps=1.5,
        wave_seed=11,
        sky_radiance=0.2,
        ambient_radiance=0.05,
        sun_travel_dir=[0.5, 0.0, -math.sqrt(0.75)],
        sun_irradiance=3.0,
    )
    return SequencePost(
        seed=0,
        fps=10,
        image_formation="physical",
        water=Water(preset=preset),
        light_depth_m=2.0,
        surface_z_m=surface_z_m,
        irradiance_w_m2=3.0,
        world=world,
    )


def _pool_frame():
    """160x120 camera 2 m deep pitched 15 deg up along +x: the surface above (Snell's window and
    total reflection), a floor/wall 3-9 m away below with an albedo pass (sunlight to focus)."""
    w, h = 160, 120
    f = w / 2 / math.tan(math.radians(40))
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    a = math.radians(15)
    pitch = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
    T = np.eye(4)
    T[:3, :3] = pitch @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    T[2, 3] = -2.0
    rng = np.full((h, w), np.inf, np.float32)
    rng[h // 2 :] = np.linspace(3, 9, w, dtype=np.float32)[None, :]
    u, v = np.meshgrid(np.linspace(0, 1, w, dtype=np.float32), np.linspace(0, 1, h, dtype=np.float32))
    rgb = np.dstack([0.1 + 0.4 * u, 0.3 + 0.2 * np.sin(12 * u) * v, 0.2 + 0.3 * v]).astype(np.float32)
    passes = {"rgb": rgb, "range_m": rng, "index": np.ones((h, w), np.uint8), "albedo": np.full_like(rgb, 0.5)}
    return passes, K, T


@pytest.mark.parametrize("order", [WATERS, WATERS[::-1]])
def test_shared_parts_give_each_waters_own_image(order):
    passes, K, T = _pool_frame()
    share = FrameShare()
    share.begin(passes)
    for z in (0.0, 0.5):  # a second surface height shares the frame's memo: its own geometry
        for preset in order:
            post = _post(preset, z)
            shared = compose.water_image(
                passes, compose.SequenceState.start(post), K, T, [], t=0.4, memo=share.memo(passes)
            )
            alone = compose.water_image(passes, compose.SequenceState.start(post), K, T, [], t=0.4)
            np.testing.assert_allclose(shared, alone, rtol=1e-4, atol=1e-7, err_msg=f"{preset} z={z}")
    assert sum(k[0] == "caustics" for k in share.memo(passes) if isinstance(k, tuple)) == 2
    assert share.memo({**passes}) == {}  # other passes (particles): nothing shared


def test_caustic_factor_per_water_equals_a_fresh_map_per_water():
    """FrameCaustics.factor for clear, turbid and clear again (deposits kept, cut to a narrower
    margin, the sharp map reused) against frame_factor made afresh for each water; a wall's
    beam paths over two octaves so several groups and both scattered paths are used."""
    waves = sf.waves_for(3, 1.5)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 1.2, 4000), rng.uniform(0, 0.8, 4000)
    path = 0.6 + 3.0 * x / 1.2
    foot = rng.choice([0.01, 0.02, 0.04], 4000)
    D = sf.sun_deflection([0.5, 0.0, -math.sqrt(0.75)])
    fc = cmap.FrameCaustics(waves, x, y, path, foot, 0.3, D)
    waters = [(0.002, 0.0), (0.06, 0.88), (0.38, 0.914), (0.06, 0.95), (0.002, 0.0), (1.2, 0.92)]
    deposits = {"shared": 0, "fresh": 0}
    real = cmap._deposit
    for b, g in waters:
        cmap._deposit = lambda *a, **k: deposits.__setitem__("shared", deposits["shared"] + 1) or real(*a, **k)
        got = fc.factor(b, g)
        cmap._deposit = lambda *a, **k: deposits.__setitem__("fresh", deposits["fresh"] + 1) or real(*a, **k)
        want = cmap.frame_factor(waves, x, y, path, foot, 0.3, D, b, g)
        cmap._deposit = real
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6, err_msg=f"b={b} g={g}")
        assert np.std(want) > 0.005  # a real pattern, not the flat 1
    assert deposits["shared"] < deposits["fresh"] / 2, deposits


def _with_particles(passes: dict) -> tuple[dict, np.ndarray]:
    """The frame with a sun pass (the render's sun light group), and the same frame with a block
    of near particles (0.6 m away, grey, no sunlight) over the floor and the surface above it, as
    add_particles composites them; and the occluder mask."""
    h, w = passes["range_m"].shape
    passes = {**passes, "sun": (0.6 * passes["rgb"]).astype(np.float32)}
    hidden = np.zeros((h, w), bool)
    hidden[h // 2 - 10 : h // 2 + 25, w // 3 : w // 3 + 30] = True
    rgb = np.where(hidden[..., None], np.float32(0.3), passes["rgb"]).astype(np.float32)
    rng = np.where(hidden, np.float32(0.6), passes["range_m"]).astype(np.float32)
    return passes, {**passes, "rgb": rgb, "range_m": rng}, hidden


def _counted(monkeypatch, name: str):
    """(calls, the real function): ``world_post.<name>`` patched to count its calls."""
    from blendgen.pipeline import world_post

    calls, real = [], getattr(world_post, name)
    monkeypatch.setattr(world_post, name, lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls, real


def _post_without(part: str):
    """Sequence post of a Jerlov preset with the world's ``part`` (surface or caustics) off."""

    def post(preset):
        p = _post(preset)
        return p.model_copy(update={"world": p.world.model_copy(update={part: False})})

    return post


def _particle_sequences(passes, seen, hidden, post, K, T):
    """Three sequences with particles (two waters, one twice) on one frame: (preset, image with
    the frame's shared parts, image from the sequence's own passes alone) each."""
    share = FrameShare()
    share.begin(passes)
    for preset in ("jerlov_IB", "jerlov_II", "jerlov_IB"):
        got = compose.water_image(
            seen, compose.SequenceState.start(post(preset)), K, T, [], occluded=hidden, t=0.4, memo=share.frame_memo()
        )
        own = compose.water_image(seen, compose.SequenceState.start(post(preset)), K, T, [], occluded=hidden, t=0.4)
        yield preset, got, own


def test_sequences_with_particles_take_the_frames_caustics_where_nothing_hides_the_surface(monkeypatch):
    """A sequence with particles focuses the sunlight with the caustic geometry of the frame's own
    passes (made once for the frame, whatever the number of such sequences): where no particle
    hides the floor its pixels are those of the frame without particles (particles in front of
    the camera do not move the floor's caustics; to the module's 1e-4), and the hidden pixels are
    exactly what its own passes give (no focusing on a particle). Surface off: it mixes the
    whole frame."""
    passes, K, T = _pool_frame()
    passes, seen, hidden = _with_particles(passes)
    calls, _ = _counted(monkeypatch, "caustic_geometry")
    post = _post_without("surface")
    for preset, got, own in _particle_sequences(passes, seen, hidden, post, K, T):
        clean = compose.water_image(passes, compose.SequenceState.start(post(preset)), K, T, [], t=0.4)
        np.testing.assert_array_equal(got[hidden], own[hidden])
        np.testing.assert_allclose(got[~hidden], clean[~hidden], rtol=1e-4, atol=1e-7)  # module docstring
        assert not np.allclose(got[hidden], clean[hidden])  # the particles are really there
    assert len(calls) == 1 + 3 + 3  # the frame's geometry once; each `own` and `clean` its own


def test_sequences_with_particles_take_the_frames_surface_where_nothing_is_in_front(monkeypatch):
    """The surface seen from below, in a sequence with particles: its geometry (wave slopes,
    Fresnel, sun disc, mirror march) is the frame's, made once for any number of such sequences,
    on the pixels where no particle is in front. Every pixel that does not mirror the scene
    (Snell's window, the particles, the scene below) is exactly what the sequence's own passes
    give; a mirrored pixel reads the sequence's colours at the frame's own march. Without the
    mask the particles in front of the surface would be painted over."""
    passes, K, T = _pool_frame()
    passes, seen, hidden = _with_particles(passes)
    calls, real = _counted(monkeypatch, "surface_geometry")
    post = _post_without("caustics")
    rays = compose._unit_rays(tuple(K.ravel()), 160, 120) @ T[:3, :3].T.astype(np.float32)
    depth = compose.surface_depth(passes["range_m"], K, T, 0.0)[0]
    geo = real(passes["range_m"], depth, post("jerlov_IB").world, rays, K, T, 0.0, 0.4)
    mirrored = np.zeros(hidden.size, bool)
    mirrored[geo.up[geo.idx]] = True
    mirrored = mirrored.reshape(hidden.shape)
    assert mirrored.any() and (hidden & ~np.isfinite(passes["range_m"])).any()  # both really in view
    calls.clear()
    for _, got, own in _particle_sequences(passes, seen, hidden, post, K, T):
        np.testing.assert_array_equal(got[~mirrored | hidden], own[~mirrored | hidden])
        assert np.isfinite(got).all()
    assert len(calls) == 1 + 3  # the frame's geometry once; each `own` its own
