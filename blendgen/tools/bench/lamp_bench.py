"""Fast lamp model vs the Cycles reference (``dockbench bench lamp``).

Each case renders :mod:`blendgen.blender.lamp_scene` (camera + config lamps in a water box,
optionally facing a grey card) in a subprocess and evaluates
:mod:`blendgen.physics.light.lamp_water` on the same geometry (camera frame, pinhole K of the
render). Two comparisons:

- **card**: a grey card (albedo 0.5) at several distances in clear and turbid water; the
  card's centre radiance minus the same scene with a black card (the veil) against
  ``rho/pi I0 / d^2 exp(-c d) exp(-c d)`` (inverse square x attenuation both ways);
- **veil**: no surface at all; the image is the lamps' backscatter, fast vs reference,
  reported as the ratio of the mean veil (per channel) and the per-pixel relative error
  over the pixels holding 90 % of the reference's veil energy.
"""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from blendgen.geometry import intrinsics_from_hfov
from blendgen.physics.light import lamp_water
from blendgen.physics.light.sources import lamp_lights
from blendgen.physics.water import optics

#: The evidence lamp: 0.3 m below the camera, aimed 5 deg down, a 30 deg cone with a
#: 5 deg soft edge, 20 W of radiant flux (a typical AUV LED lamp: 2000-3000 lm at ~100 lm/W
#: of white LED radiometric efficiency ~ 20-30 W optical).
DEMO_LAMP = {
    "id": "lamp",
    "offset_m": [0.0, 0.3, 0.0],
    "yaw_deg": 0.0,
    "pitch_deg": 5.0,
    "half_angle_deg": 30.0,
    "edge_deg": 5.0,
    "power_w": 20.0,
    "color": [1.0, 1.0, 1.0],
}


def _ns(d: dict):
    from types import SimpleNamespace

    return SimpleNamespace(**d)


def water_dict(w: optics.WaterOptics) -> dict | None:
    """The lamp scene's medium (``plan.water_volume`` keys without the box), None if clear."""
    if w.is_clear:
        return None
    return {
        "sigma_a": list(map(float, w.sigma_a)),
        "sigma_s": list(map(float, w.sigma_s)),
        "phase": w.phase,
        "g": float(w.g),
        "ff_ior": float(w.ff_ior),
        "ff_backscatter": float(w.ff_backscatter),
    }


ON_RENDER = None  # callable(message) told before each Cycles render (the CLI's progress line), or None
_RENDERS = [0]


def reference(spec: dict, work: Path) -> np.ndarray:
    """Render one lamp scene (subprocess, nice 10); returns linear RGB (H, W, 3)."""
    work.mkdir(parents=True, exist_ok=True)
    key = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]
    sp, out = work / f"lamp_{key}.json", work / f"lamp_{key}.npy"
    if not out.exists():
        _RENDERS[0] += 1
        if ON_RENDER is not None:
            ON_RENDER(
                f"Cycles render {_RENDERS[0]} ({spec.get('width')}x{spec.get('height')}, "
                f"{spec.get('samples')} spp, {spec.get('volume_bounces')} volume bounces)"
            )
        sp.write_text(json.dumps(spec))
        res = subprocess.run(
            ["nice", "-n", "10", sys.executable, "-m", "blendgen.blender.lamp_scene", str(sp), str(out)],
            capture_output=True,
            text=True,
            timeout=3600,
        )
        if res.returncode != 0:
            raise RuntimeError(res.stderr[-2000:])
    return np.load(out)


def camera(spec: dict) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3), unit rays (H, W, 3)) of a lamp-scene spec's pinhole."""
    from blendgen.pipeline.compose import _unit_rays

    w, h = int(spec["width"]), int(spec["height"])
    K = intrinsics_from_hfov(w, h, math.radians(spec["hfov_deg"]))
    return K, _unit_rays(tuple(K.ravel()), w, h)


def _box_hit(rays: np.ndarray, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Slab test of unit rays (H, W, 3) from the origin against a box: (entry range (H, W), inf
    where missed; index (H, W) of the entry face's axis)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.asarray(lo, np.float64) / rays
        t2 = np.asarray(hi, np.float64) / rays
    tn, tf = np.fmin(t1, t2), np.fmax(t1, t2)
    t_in, t_out = tn.max(axis=-1), tf.min(axis=-1)
    hit = (t_out >= t_in) & (t_in > 0)
    return np.where(hit, t_in, np.inf), tn.argmax(axis=-1)


def scene_passes(spec: dict, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Analytic range (H, W), albedo (H, W, 3), normals (H, W, 3) and object id (H, W; 0 none,
    1 card, 2+ occluders) of a lamp-scene spec (card plane facing the camera, boxes)."""
    h, w = rays.shape[:2]
    rng = np.full((h, w), np.inf)
    alb = np.zeros((h, w))
    nrm = np.zeros((h, w, 3))
    obj = np.zeros((h, w), np.int32)
    card = spec.get("card")
    if card:
        rng = float(card["distance_m"]) / rays[..., 2].astype(np.float64)
        alb[:] = float(card["albedo"])
        nrm[:] = (0.0, 0.0, -1.0)
        obj[:] = 1
    for i, box in enumerate(spec.get("occluders") or []):
        t, axis = _box_hit(rays, box["min"], box["max"])
        near = t < rng
        rng[near], alb[near], obj[near] = t[near], float(box["albedo"]), 2 + i
        n = np.zeros((h, w, 3))
        np.put_along_axis(n, axis[..., None], -np.sign(np.take_along_axis(rays, axis[..., None], -1)), -1)
        nrm[near] = n[near]
    return (rng.astype(np.float32), np.repeat(alb[..., None], 3, -1).astype(np.float32), nrm.astype(np.float32), obj)


def fast(
    spec: dict,
    water: optics.WaterOptics,
    forward_kept: float | None = None,
    shadows: bool = True,
    veil_shadows: bool = True,
) -> np.ndarray:
    """The fast model's lamp image (H, W, 3) for a lamp-scene spec (card, boxes or none)."""
    import dataclasses

    K, rays = camera(spec)
    kw = {} if forward_kept is None else {"forward_kept": forward_kept}
    model = lamp_water.LampWater.build(lamp_lights([_ns(d) for d in spec["lamps"]]), water, shadows=shadows, **kw)
    model = dataclasses.replace(model, veil_shadows=veil_shadows)
    rng, albedo, normals, _ = scene_passes(spec, rays)
    return lamp_water.lamp_radiance(model, K, rays, rng, albedo, normals)


def geometric_shadow(spec: dict, rays: np.ndarray) -> np.ndarray:
    """(H, W) bool oracle: the card's pixels whose point's straight segment to the (first) lamp
    crosses an occluder box (slab test on the segment, independent of the range pass)."""
    rng, _, _, obj = scene_passes(spec, rays)
    X = rays.astype(np.float64) * np.where(obj == 1, rng, 0.0)[..., None]
    S = np.asarray(spec["lamps"][0]["offset_m"], np.float64)
    d = S - X
    out = np.zeros(rng.shape, bool)
    for box in spec.get("occluders") or []:
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (np.asarray(box["min"], np.float64) - X) / d
            t2 = (np.asarray(box["max"], np.float64) - X) / d
        t_in, t_out = np.fmin(t1, t2).max(axis=-1), np.fmax(t1, t2).min(axis=-1)
        out |= (obj == 1) & (t_out >= t_in) & (t_out > 0) & (t_in < 1)
    return out


def scene_spec(water, lamps, card=None, size=(96, 72), samples=64, bounces=0, hfov=60.0) -> dict:
    return {
        "water": water_dict(water),
        "lamps": lamps,
        "card": card,
        "hfov_deg": hfov,
        "width": size[0],
        "height": size[1],
        "samples": samples,
        "volume_bounces": bounces,
        "seed": 1,
    }


def card_law(lamp: dict, d: float, albedo: float, c: float) -> float:
    """Analytic radiance (one channel) of the grey card's centre pixel at distance ``d``: a
    lamp at ``offset_m`` aimed along the optical axis, ``rho/pi I0 cos(i) / d_l^2 exp(-c d_l)
    exp(-c d)`` with ``d_l`` the lamp-card distance (inside the cone's full-intensity core)."""
    d_l = math.hypot(d, math.hypot(lamp["offset_m"][0], lamp["offset_m"][1]))
    i0 = lamp["power_w"] / (2 * math.pi * (1 - math.cos(math.radians(lamp["half_angle_deg"]))))
    return albedo / math.pi * i0 * (d / d_l) / d_l**2 * math.exp(-c * (d_l + d))


def card_table(
    work: Path, waters=("clear", "mild", "moderate"), distances=(1.0, 2.0, 4.0), samples: int = 256
) -> pd.DataFrame:
    """Grey-card centre radiance (green) vs distance: reference, fast and the analytic law
    (card minus black card: the veil in front of the card cancels, same seed)."""
    lamp = {**DEMO_LAMP, "pitch_deg": 0.0}
    rows = []
    for name in waters:
        w = optics.get_preset(name)
        for d in distances:
            grey = scene_spec(w, [lamp], {"distance_m": d, "albedo": 0.5}, (32, 24), samples, hfov=10.0)
            black = {**grey, "card": {"distance_m": d, "albedo": 0.0}}
            centre = (slice(10, 14), slice(14, 18), 1)
            ref = reference(grey, work)[centre].mean() - reference(black, work)[centre].mean()
            fst = fast(grey, w, 0.0)[centre].mean() - fast(black, w, 0.0)[centre].mean()
            law = card_law(lamp, d, 0.5, float(w.c[1]))
            rows.append(
                {
                    "water": name,
                    "d_m": d,
                    "law": law,
                    "reference": ref,
                    "fast": fst,
                    "ref/law": ref / law,
                    "fast/law": fst / law,
                }
            )
    return pd.DataFrame(rows)


def veil_stats(fast_img: np.ndarray, ref_img: np.ndarray, blocks=(8, 6), outside=None) -> dict:
    """Green channel: mean ratio fast/reference, and the relative error of block means
    (``blocks`` (nx, ny) over the image: Monte Carlo noise of the multi-bounce reference
    averages out) over the blocks above the reference's 25th percentile (mean and max);
    with ``outside`` (H, W) bool, the pixels outside the lamp's single-scatter cone, the mean
    ratio there and inside."""
    import cv2

    f = cv2.resize(np.ascontiguousarray(fast_img[..., 1]), blocks, interpolation=cv2.INTER_AREA)
    r = cv2.resize(np.ascontiguousarray(ref_img[..., 1]), blocks, interpolation=cv2.INTER_AREA)
    top = r >= np.quantile(r, 0.25)
    err = np.abs(f - r)[top] / r[top]
    out = {
        "ref_mean": float(r.mean()),
        "fast_mean": float(f.mean()),
        "ratio": float(f.mean() / r.mean()),
        "block_err_mean": float(err.mean()),
        "block_err_max": float(err.max()),
    }
    if outside is not None and outside.any() and not outside.all():
        fg, rg = fast_img[..., 1], ref_img[..., 1]
        out["ratio_outside_cone"] = float(fg[outside].mean() / rg[outside].mean())
        out["ratio_inside_cone"] = float(fg[~outside].mean() / rg[~outside].mean())
    return out


def outside_cone(spec: dict, water: optics.WaterOptics) -> np.ndarray:
    """(H, W) bool: pixels whose single-scatter veil (F = 0, the sharp cone) is below 5 % of its
    mean, i.e. what only multiply scattered light reaches."""
    single = fast(spec, water, 0.0)[..., 1]
    return single < 0.05 * single.mean()


def veil_table(
    work: Path,
    waters=("mild", "moderate"),
    bounces=(0, 32),
    samples: int = 256,
    size=(96, 72),
    forward_kept: float | None = None,
) -> pd.DataFrame:
    """Backscatter veil with no surface: fast (single scatter; with bounces the F correction and
    the beam spread) vs Cycles."""
    rows = []
    for name in waters:
        w = optics.get_preset(name)
        for nb in bounces:
            spec = scene_spec(w, [DEMO_LAMP], None, size, samples, nb)
            ref = reference(spec, work)
            fk = 0.0 if nb == 0 else forward_kept
            rows.append(
                {
                    "water": name,
                    "volume_bounces": nb,
                    "F": lamp_water.FORWARD_KEPT if fk is None else fk,
                    **veil_stats(fast(spec, w, fk), ref, outside=outside_cone(spec, w) if nb else None),
                }
            )
    return pd.DataFrame(rows)


def lamp_experiment(
    width: int, height: int, samples: int, fidelity: str, depth_m: float, lamp: bool, sun_strength: float | None = None
):
    """The preview approach (camera 8, 5, 2 m from the dock) in clear/mild/moderate water at
    dock depth ``depth_m``, with or without :data:`DEMO_LAMP`; ``sun_strength`` (W/m^2) None
    keeps the template's daylight, a small value is dusk/night."""
    from blendgen.config.models import Condition, Lamp, Water
    from blendgen.tools.apps.preview import WATERS, preview_experiment

    exp = preview_experiment(width, height, samples, fidelity)
    exp.conditions = [Condition(label=w, water=Water(preset=w), dock_water_depth_m=depth_m) for w in WATERS]
    exp.vehicle.lamps = [Lamp(**DEMO_LAMP)] if lamp else []
    if sun_strength is not None:
        exp.scene.sun_strength = float(sun_strength)
    exp.name = f"lamp-{'on' if lamp else 'off'}-{fidelity}"
    return exp


def lamp_sheet(
    out: Path,
    width: int = 320,
    height: int = 240,
    samples: int = 4,
    fidelity: str = "fast",
    depth_m: float = 5.0,
    sun_strength: float | None = None,
) -> Path:
    """Contact sheet: rows clear/mild/moderate x lamp off/on, columns camera 8/5/2 m from the dock."""
    import shutil

    import cv2

    from blendgen.pipeline.generate import generate
    from blendgen.tools.apps.preview import VIEWS, WATERS
    from evalkit.dataset import Dataset

    rows = []
    for lamp in (False, True):
        work = out.parent / f"{out.stem}-{'on' if lamp else 'off'}"
        shutil.rmtree(work, ignore_errors=True)
        generate(
            lamp_experiment(width, height, samples, fidelity, depth_m, lamp, sun_strength),
            work,
            workers=1,
            progress=False,
        )
        ds = Dataset.open(work)
        frames = {s["condition"]: list(ds.iter_frames(s["id"])) for s in ds.sequences}
        for w in WATERS:
            imgs = [ds.load_image(f).copy() for f in frames[w][: len(VIEWS)]]
            for img, (_, vl) in zip(imgs, VIEWS):
                cv2.putText(
                    img,
                    f"{w}, lamp {'on' if lamp else 'off'}, {vl}",
                    (4, height - 6),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.4,
                    (255, 255, 255),
                    1,
                    cv2.LINE_AA,
                )
            rows.append((WATERS.index(w), lamp, np.hstack(imgs)))
    sheet = np.vstack([r[2] for r in sorted(rows, key=lambda r: (r[0], r[1]))])
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return out


#: The shadow scene: a lamp 0.2 m right of and 0.3 m below the camera (diagonal shadows),
#: a 40 x 10 x 5 cm slab 1 m ahead and a 5 cm post 1.8 m ahead, a grey wall at 3 m.
SHADOW_LAMP = {**DEMO_LAMP, "offset_m": [0.2, 0.3, 0.0]}
SHADOW_OCCLUDERS = [
    {"min": [-0.25, 0.0, 1.0], "max": [0.15, 0.1, 1.05], "albedo": 0.5},
    {"min": [0.3, -0.5, 1.8], "max": [0.35, 0.2, 1.85], "albedo": 0.5},
]


def shadow_spec(water, size=(320, 240), samples: int = 64, occluders=True) -> dict:
    """The shadow scene (:data:`SHADOW_LAMP`, :data:`SHADOW_OCCLUDERS`, wall at 3 m)."""
    spec = scene_spec(water, [SHADOW_LAMP], {"distance_m": 3.0, "albedo": 0.5}, size, samples, 0)
    return {**spec, "occluders": SHADOW_OCCLUDERS if occluders else []}


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def shadow_masks(img: np.ndarray, free: np.ndarray, obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(wall pixels well inside the lamp's cone, the shadowed ones: below half the radiance of the
    same scene without occluders), green channel."""
    g, f = img[..., 1], free[..., 1]
    wall = (obj == 1) & (f > 0.5 * np.percentile(f[obj == 1], 90))
    return wall, wall & (g < 0.5 * f)


def shadow_stats(fast_img, fast_free, ref_img, ref_free, obj, geo, fast_lit_veil=None) -> dict:
    """Shadowed-area IoU fast/reference/geometry and the shadow-to-lit radiance ratio of each
    (green; core: the geometric shadow eroded 2 px; lit: a 2-6 px ring around it on the wall)."""
    import cv2

    wall, sf = shadow_masks(fast_img, fast_free, obj)
    _, sr = shadow_masks(ref_img, ref_free, obj)
    geo = geo & wall
    k = np.ones((3, 3), np.uint8)
    g8 = geo.astype(np.uint8)
    core = cv2.erode(g8, k, iterations=2).astype(bool)
    ring = wall & cv2.dilate(g8, k, iterations=6).astype(bool) & ~cv2.dilate(g8, k, iterations=2).astype(bool)
    imgs = (("fast", fast_img), ("ref", ref_img), ("lit_veil", fast_img if fast_lit_veil is None else fast_lit_veil))
    ratio = {n: float(im[core, 1].mean() / im[ring, 1].mean()) for n, im in imgs}
    return {
        "iou_fast_ref": _iou(sf, sr),
        "iou_fast_geo": _iou(sf, geo),
        "iou_ref_geo": _iou(sr, geo),
        "shadow/lit_ref": ratio["ref"],
        "shadow/lit_fast": ratio["fast"],
        "shadow/lit_fast_lit_veil": ratio["lit_veil"],
        "lit_fast/ref": float(fast_img[ring, 1].mean() / ref_img[ring, 1].mean()),
    }


def shadow_table(work: Path, waters=("clear", "mild", "moderate"), size=(320, 240), samples: int = 64):
    """Lamp shadows, fast (screen-space test) vs Cycles (0 volume bounces, F = 0) vs geometry;
    ``shadow/lit_fast_lit_veil``: the fast ratio with the veil not shadowed (surfaces only)."""
    rows = []
    for name in waters:
        w = optics.get_preset(name)
        spec, free = shadow_spec(w, size, samples), shadow_spec(w, size, samples, occluders=False)
        _, rays = camera(spec)
        _, _, _, obj = scene_passes(spec, rays)
        st = shadow_stats(
            fast(spec, w, 0.0),
            fast(free, w, 0.0),
            reference(spec, work),
            reference(free, work),
            obj,
            geometric_shadow(spec, rays),
            fast(spec, w, 0.0, veil_shadows=False),
        )
        rows.append({"water": name, **st})
    return pd.DataFrame(rows)
