"""Fast vs reference water: calibration of the fast model and the fidelity benchmark.

Both commands render a fixed *held-in* set through the normal pipeline
(:func:`blendgen.pipeline.generate.generate`, Blender in worker subprocesses): the
quickstart pool, one straight approach with frames at ``frames`` distances from
10 m to 1 m, conditions clear / mild / moderate / jerlov_1C (coastal), dock at
1 m depth, sun 3 W/m^2 at 60 deg elevation.

* ``reference``: the water as a Cycles medium (single scattering, 0 volume
  bounces), ``ref_samples`` spp.
* ``fast``: surfaces only at a few spp, then :func:`blendgen.physics.water.optics.apply_water`.

Images are compared in **linear RGB** decoded from the 8-bit sRGB PNGs the
datasets store (quantisation adds ~1e-3 MAE near black), over the *marker region*:
the pixels of the marker objects (object-index pass of the reference) dilated by
3 px. A fast setting rendered at another resolution is compared with the
reference resized to its size (INTER_AREA).

Calibration (``dockbench calibrate-water``) fits per preset and channel the two
numbers of ``I_ref = a J exp(-c r) + B (1 - exp(-c r))`` by least squares over the
non-emissive dock and marker pixels (J: clean render, c: the preset's beam
attenuation), then stores ``Kd = -ln(a) / depth`` (effective depth light) and
``B_inf = B / (a E_sun)`` (per unit sun irradiance) in
``blendgen/data/water_calibration.json`` with the residuals before and after.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

from blendgen.config.bundled import bundled_file

CONDITIONS = ("clear", "mild", "moderate", "jerlov_1C")
LOCALIZERS = ("led", "qr")
D_FAR, D_NEAR = 10.0, 1.0


# --------------------------------------------------------------------------- experiments


def held_in_experiment(
    width: int,
    height: int,
    frames: int,
    conditions=CONDITIONS,
    *,
    fidelity: str = "fast",
    samples: int = 4,
    water_opts: dict | None = None,
    volume_bounces: int = 0,
    caustics: bool = False,
):
    """The held-in set: quickstart pool, one approach 10 m -> 1 m in ``frames`` frames
    (``volume_bounces``: the reference medium's multiple scattering; ``caustics``: both
    fidelities with caustics, the reference's from its photon-map spot)."""
    from blendgen.config.models import Condition, Water, load_experiment

    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    traj = exp.trajectories[0]
    lead = exp.camera.T_body_cam.xyz[0]  # the camera sits ahead of the body: d_true = range - lead
    traj.start_range_m, traj.end_range_m = D_FAR + lead, D_NEAR + lead
    traj.speed_mps = (D_FAR - D_NEAR) * exp.camera.fps / max(1, frames - 1)
    exp.trajectories = [traj]
    exp.camera.width, exp.camera.height = int(width), int(height)
    exp.render.fidelity = fidelity
    exp.render.samples = exp.render.reference_samples = int(samples)
    exp.render.volume_bounces = int(volume_bounces)
    exp.conditions = [Condition(label=c, water=Water(preset=c, **(water_opts or {}))) for c in conditions]
    # off by default: the veil and glow settings are compared without the caustic pattern,
    # whose detail differs between the fast map and the reference's photons (bench caustics)
    exp.scene.world.caustics = bool(caustics)
    exp.name = f"fidelity-{fidelity}" + ("-caustics" if caustics else "")
    return exp


def render(exp, out: Path, fresh: bool = False) -> tuple[Path, dict]:
    """Generate ``exp`` into ``out`` (reused when already complete and ``fresh`` is False).

    Returns (path, timing) with median seconds per stage and the wall time."""
    from blendgen.pipeline.generate import config_digest, generate, timing_summary

    stamp = out / ".work" / "config.sha256"
    done = (out / "manifest.json").exists() and stamp.exists() and stamp.read_text().strip() == config_digest(exp)
    if fresh or not done:
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        generate(exp, out, workers=1, progress=False)
        (out / ".work" / "wall_s").write_text(str(time.perf_counter() - t0))
    return out, {**timing_summary(out), "wall": float((out / ".work" / "wall_s").read_text())}


# --------------------------------------------------------------------------- images


def srgb_to_linear(img_u8: np.ndarray) -> np.ndarray:
    x = img_u8.astype(np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def load_frames(ds_path: Path) -> dict:
    """{(condition, frame index): {"rgb" linear, "index", "range", "d_true"}} of a dataset."""
    from datasets_spec.io import load_index, load_range
    from evalkit.dataset import Dataset

    ds = Dataset.open(ds_path)
    out = {}
    for seq in ds.sequences:
        for f in ds.iter_frames(seq["id"]):
            rec = {"rgb": srgb_to_linear(ds.load_image(f)), "d_true": f["d_true"]}
            if f.get("object_index"):
                rec["index"] = load_index(ds.frame_file(f, "object_index"))
            if f.get("depth"):
                rec["range"] = load_range(ds.frame_file(f, "depth"))
            out[(seq["condition"], f["index"])] = rec
    return out


def marker_region(index: np.ndarray, markers: list[dict], dilate_px: int = 3) -> np.ndarray:
    import cv2

    m = np.isin(index, [mk["object_index"] for mk in markers]).astype(np.uint8)
    if dilate_px > 0:
        m = cv2.dilate(m, np.ones((2 * dilate_px + 1,) * 2, np.uint8))
    return m.astype(bool)


def image_errors(fast: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(PSNR dB with peak 1, mean absolute error) over ``mask``, linear RGB."""
    import cv2

    if fast.shape[:2] != ref.shape[:2]:
        ref = cv2.resize(ref, (fast.shape[1], fast.shape[0]), interpolation=cv2.INTER_AREA)
        mask = cv2.resize(
            mask.astype(np.uint8), (fast.shape[1], fast.shape[0]), interpolation=cv2.INTER_NEAREST
        ).astype(bool)
    d = (fast - ref)[mask]
    if d.size == 0:
        return float("nan"), float("nan")
    mse = float(np.mean(d**2))
    return (10 * math.log10(1.0 / mse) if mse > 0 else float("inf")), float(np.mean(np.abs(d)))


# --------------------------------------------------------------------------- calibration


def fit_condition(
    samples: list[tuple[np.ndarray, np.ndarray, np.ndarray]], c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``(a, B)`` (3,) each of ``y = a J t + B (1 - t)``, t = exp(-c r).

    ``samples``: (y (N,3), J (N,3), r (N,)) per frame, already masked."""
    a, B = np.zeros(3), np.zeros(3)
    y = np.concatenate([s[0] for s in samples])
    J = np.concatenate([s[1] for s in samples])
    r = np.concatenate([s[2] for s in samples])
    for ch in range(3):
        t = np.exp(-c[ch] * r)
        X = np.column_stack([J[:, ch] * t, 1 - t])
        (a[ch], B[ch]), *_ = np.linalg.lstsq(X, y[:, ch], rcond=None)
    return a, np.maximum(B, 0.0)


def fit_mask(clean: dict, ref_rgb: np.ndarray, dock_ids: list[int], markers: list[dict]) -> np.ndarray:
    """Dock and marker pixels away from the LEDs: no LED pixel within 3 px (the box
    pixel filter bleeds their clipped glow into neighbours), nothing clipped."""
    import cv2

    from blendgen.pipeline.compose import emissive_mask

    led = cv2.dilate(emissive_mask(clean["index"], markers).astype(np.uint8), np.ones((7, 7), np.uint8))
    return (
        np.isin(clean["index"], dock_ids)
        & (led == 0)
        & np.isfinite(clean["range"])
        & (clean["rgb"].max(axis=2) < 0.98)
        & (ref_rgb.max(axis=2) < 0.98)
    )


def calibrate(
    ref_path: Path, clean_path: Path, light_depth_m: float, irradiance: float, sun_elevation_deg: float = 90.0
) -> dict:
    """Fit every turbid condition of the reference dataset; returns the calibration dict.
    ``irradiance`` is the sun's strength (W/m^2, normal to the beam) at ``sun_elevation_deg``."""
    from blendgen.config.models import Water
    from blendgen.physics.water import optics
    from evalkit.dataset import Dataset

    ref, clean = load_frames(ref_path), load_frames(clean_path)
    markers = Dataset.open(ref_path).markers
    from blendgen.pipeline.plan import INDEX_DOCK

    dock_ids = [INDEX_DOCK] + [m["object_index"] for m in markers]
    presets = {}
    for cond in sorted({k[0] for k in ref}):
        spec = Water(preset=cond)  # rendered bare: in physical mode the level's Jerlov type
        w0, key = optics.water_for_mode(spec, "physical"), optics.effective_preset(spec, "physical")
        if w0.is_clear:
            continue
        keys = sorted(k for k in ref if k[0] == cond)
        pix = []
        for k in keys:
            cl = clean[("clear", k[1])]
            m = fit_mask(cl, ref[k]["rgb"], dock_ids, markers)
            pix.append((ref[k]["rgb"][m], cl["rgb"][m], cl["range"][m]))
        a, B = fit_condition(pix, w0.c)
        a = np.clip(a, 1e-6, None)
        entry = {
            "B_inf": (B / (a * irradiance)).round(6).tolist(),
            "Kd": np.clip(-np.log(a) / max(light_depth_m, 1e-6), 0.0, 5.0).round(5).tolist(),
            "blur": False,
            "a": a.round(5).tolist(),
        }
        cal = {"presets": {key: entry}, "sun_elevation_deg": sun_elevation_deg}
        res = {}
        for label, use in (("uncalibrated", False), ("calibrated", True)):
            e_d = irradiance * math.sin(math.radians(sun_elevation_deg))
            w, fo = optics.fast_water(Water(preset=cond, calibrated=use), "physical", e_d, cal)
            err = []
            for _k, (y, J, r) in zip(keys, pix):
                pred = optics.apply_water(
                    J[None].astype(np.float64), r[None], None, w, light_depth_m, irradiance=fo["irradiance"]
                )[0]
                err.append(np.abs(pred - y))
            e = np.concatenate(err)
            res[label] = {
                "mae": float(e.mean()),
                "mae_rgb": e.mean(axis=0).round(5).tolist(),
                "rel_mae": float(e.mean() / max(np.concatenate([p[0] for p in pix]).mean(), 1e-12)),
            }
        entry["residual"] = res
        entry["n_pixels"] = int(sum(len(p[0]) for p in pix))
        presets[key] = entry
    return presets


def run_calibration(
    work: Path,
    data_path: Path,
    width: int,
    height: int,
    frames: int,
    ref_samples: int,
    conditions=CONDITIONS,
    echo=print,
) -> dict:
    """Render reference + clean sets, fit, write ``data_path``; returns the file's dict."""
    echo(f"reference: {len(conditions)} conditions x {frames} frames at {width}x{height}, {ref_samples} spp ...")
    ref_exp = held_in_experiment(width, height, frames, conditions, fidelity="reference", samples=ref_samples)
    ref_path, _ = render(ref_exp, work / f"reference-{width}x{height}-s{ref_samples}")
    echo("clean surfaces-only render at the same spp ...")
    clean_exp = held_in_experiment(width, height, frames, ("clear",), fidelity="fast", samples=ref_samples)
    clean_path, _ = render(clean_exp, work / f"clean-{width}x{height}-s{ref_samples}")
    from blendgen.vehicle.trajectories import dock_top_m

    depth = ref_exp.scene.dock.water_depth_m + dock_top_m(ref_exp.scene.dock)  # the face centre's depth
    E = ref_exp.scene.sun_strength
    presets = calibrate(ref_path, clean_path, depth, E, ref_exp.scene.sun_elevation_deg)
    data = {
        "version": 1,
        "method": (
            f"least squares of I_ref = a J exp(-c r) + B (1 - exp(-c r)) over dock+marker pixels; "
            f"reference: Cycles medium, 0 volume bounces (single scattering), {ref_samples} spp, "
            f"{width}x{height}, {frames} frames {D_FAR:g}-{D_NEAR:g} m, dock depth {depth:g} m, "
            f"sun {E:g} W/m^2 at {ref_exp.scene.sun_elevation_deg:g} deg; Kd = -ln(a)/depth, "
            "B_inf = B/(a E) per unit sun irradiance; blur off (no forward scatter at 0 bounces)"
        ),
        "sun_strength": E,
        "light_depth_m": depth,
        "sun_elevation_deg": ref_exp.scene.sun_elevation_deg,
        "presets": presets,
    }
    data_path.parent.mkdir(parents=True, exist_ok=True)
    data_path.write_text(json.dumps(data, indent=1) + "\n")
    return data


# --------------------------------------------------------------------------- bench


def default_ladder(width: int, height: int) -> list[dict]:
    """Fast settings compared with the reference. ``calibrated: False`` is the physical default
    (the calibrated veil model, :mod:`blendgen.physics.water.veil`); ``True`` the older per-condition
    fit to a 0-bounce reference (``calibrate-water``)."""
    half = (max(16, width // 2), max(16, height // 2))
    return [
        {"setting": "fast s1", "samples": 1, "size": (width, height), "blur": False, "calibrated": False},
        {"setting": "fast s4", "samples": 4, "size": (width, height), "blur": False, "calibrated": False},
        {"setting": "fast s16", "samples": 16, "size": (width, height), "blur": False, "calibrated": False},
        {"setting": "fast s4 blur", "samples": 4, "size": (width, height), "blur": True, "calibrated": False},
        {"setting": "fast s4 0-bounce fit", "samples": 4, "size": (width, height), "blur": False, "calibrated": True},
        {"setting": "fast s4 half-res", "samples": 4, "size": half, "blur": False, "calibrated": False},
    ]


def veil_residual_table(calibration: dict | None = None):
    """Fast veil model (today's code, stored kappa/K_v/eta) vs the stored Cycles references
    (``calibrate-veil``), per preset, camera depth, view elevation and channel: DataFrame with
    reference, fast, their relative difference and the old isotropic-equivalent estimate's."""
    import pandas as pd

    from blendgen.physics.water import optics
    from blendgen.tools.calibration import veil as vc

    cal = calibration if calibration is not None else optics.load_calibration()
    rows = []
    for name, e in sorted(((cal.get("veil") or {}).get("presets") or {}).items()):
        if name in vc.ALIASES:
            continue
        w = vc.physical_water(name)
        for p in e["points"]:
            ref = np.array(p["reference"])
            fast = vc.model_value(
                w, p["depth_m"], p["elevation_deg"], np.array(e["kappa"]), np.array(e["K_v"]), e["eta"]
            )
            iso = vc.model_value(w, p["depth_m"], p["elevation_deg"], 1.0, w.Kd)
            for ch, c in enumerate("RGB"):
                rows.append(
                    {
                        "preset": name,
                        "depth_m": p["depth_m"],
                        "elev_deg": p["elevation_deg"],
                        "ch": c,
                        "reference": ref[ch],
                        "fast": fast[ch],
                        "rel_err": (fast[ch] - ref[ch]) / ref[ch] if ref[ch] > 0 else float("nan"),
                        "rel_err_isotropic": (iso[ch] - ref[ch]) / ref[ch] if ref[ch] > 0 else float("nan"),
                    }
                )
    return pd.DataFrame(rows)


def ms_per_image(timing: dict, n_conditions_sharing: int) -> float:
    """Median ms to produce one camera image: render + read shared by the conditions
    of one clean render, plus the per-image post-processing and write."""
    shared = timing.get("render", 0.0) + timing.get("depth_to_range", 0.0)
    return 1e3 * (shared / n_conditions_sharing + timing.get("post_write", 0.0) / n_conditions_sharing)


def localization(ds_path: Path) -> pd.DataFrame:
    """Per (localizer, condition): P_succ and e_rel_mean over the held-in frames."""
    from evalkit import registry, runner
    from evalkit.dataset import Dataset
    from evalkit.metrics import core as metrics

    ds = Dataset.open(ds_path)
    df = runner.evaluate(ds, [(n, registry.resolve(n, {})) for n in LOCALIZERS], progress=False)
    trials, _ = metrics.summarize(df, d_min_rel=ds.d_min_rel_m)
    return trials.groupby(["localizer", "condition"])[["P_succ", "e_rel_mean"]].mean()


# fmt: off
def run_bench(out: Path, width: int, height: int, frames: int, ref_samples: int,
              ladder: list[dict] | None = None, conditions=CONDITIONS, echo=print, volume_bounces: int = 32,
              caustics: bool = False):
    """Render reference (``volume_bounces`` multiple scattering) and ladder, with ``caustics``
    in both or in neither; returns the table (also written to OUT/fidelity.csv)."""
    import pandas as pd

    from evalkit.dataset import Dataset
    out.mkdir(parents=True, exist_ok=True)
    ladder = ladder or default_ladder(width, height)
    echo(f"reference: {len(conditions)} conditions x {frames} frames at {width}x{height}, {ref_samples} spp, "
         f"{volume_bounces} volume bounces ...")
    ref_exp = held_in_experiment(width, height, frames, conditions, fidelity="reference", samples=ref_samples,
                                 volume_bounces=volume_bounces, caustics=caustics)
    tail = "-caustics" if caustics else ""
    ref_path, ref_t = render(ref_exp, out / f"reference-{width}x{height}-s{ref_samples}-vb{volume_bounces}{tail}")
    ref = load_frames(ref_path)
    markers = Dataset.open(ref_path).markers
    ref_loc = localization(ref_path)
    ref_ms = {}
    for p in (ref_path / ".work" / "timing").glob("*.json"):
        t = json.loads(p.read_text())
        cond = p.stem.rsplit("-", 1)[-1]
        ref_ms[cond] = 1e3 * float(np.median(np.add(np.add(t["render"], t["depth_to_range"]), t["post_write"])))
    rows = []
    for cond in conditions:
        rows.append({"setting": f"reference s{ref_samples} vb{volume_bounces}", "condition": cond,
                     "width": width, "height": height,
                     "ms_per_frame": ref_ms.get(cond, float("nan")), "psnr_db": float("inf"), "mae": 0.0,
                     **{f"{m}_{n}": ref_loc.loc[(n, cond), c] for n in LOCALIZERS
                        for m, c in (("P_succ", "P_succ"), ("e_rel", "e_rel_mean"))},
                     **{f"d{m}_{n}": 0.0 for n in LOCALIZERS for m in ("P_succ", "e_rel")}})
    for st in ladder:
        w, h = st["size"]
        echo(f"{st['setting']}: {w}x{h}, {st['samples']} spp ...")
        exp = held_in_experiment(w, h, frames, conditions, fidelity="fast", samples=st["samples"],
                                 water_opts={"calibrated": st["calibrated"], "blur": st["blur"]}, caustics=caustics)
        tag = f"{st['samples']}-{w}x{h}-b{int(st['blur'])}-c{int(st['calibrated'])}{tail}"
        path, t = render(exp, out / f"fast-{tag}", fresh=True)
        fast = load_frames(path)
        loc = localization(path)
        ms = ms_per_image(t, len(conditions))
        for cond in conditions:
            ps, ma = [], []
            for k in sorted(k for k in ref if k[0] == cond):
                mask = marker_region(ref[k]["index"], markers)
                p, a = image_errors(fast[k]["rgb"], ref[k]["rgb"], mask)
                ps.append(p)
                ma.append(a)
            row = {"setting": st["setting"], "condition": cond, "width": w, "height": h, "ms_per_frame": ms,
                   "psnr_db": float(np.mean(ps)), "mae": float(np.mean(ma))}
            for n in LOCALIZERS:
                P, E = loc.loc[(n, cond), "P_succ"], loc.loc[(n, cond), "e_rel_mean"]
                row.update({f"P_succ_{n}": P, f"e_rel_{n}": E,
                            f"dP_succ_{n}": P - ref_loc.loc[(n, cond), "P_succ"],
                            f"de_rel_{n}": E - ref_loc.loc[(n, cond), "e_rel_mean"]})
            rows.append(row)
    df = pd.DataFrame(rows)
    df.to_csv(out / "fidelity.csv", index=False)
    pareto_plot(df, out / "fidelity_pareto.png")
    return df
# fmt: on


def pareto_plot(df, path: Path) -> None:
    """ms/frame (log) against MAE over the marker region, one marker per setting, mean over
    the turbid conditions; the Pareto front is drawn as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fast = df[~df["setting"].str.startswith("reference")]
    turbid = fast[fast["condition"] != "clear"]
    agg = turbid.groupby("setting", sort=False).agg(ms=("ms_per_frame", "mean"), mae=("mae", "mean"))
    ref = df[df["setting"].str.startswith("reference") & (df["condition"] != "clear")]
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=110)
    for name, r in agg.iterrows():
        ax.scatter(r["ms"], r["mae"], s=30)
        ax.annotate(name, (r["ms"], r["mae"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    front = agg.sort_values("ms")
    front = front[front["mae"] <= front["mae"].cummin()]
    ax.plot(front["ms"], front["mae"], "k--", lw=0.8, label="Pareto front")
    if len(ref):
        ax.axvline(ref["ms_per_frame"].mean(), color="r", lw=0.8, label="reference ms/frame")
    ax.set_xscale("log")
    ax.set_xlabel("ms per camera image (median, 2 shared cores: noisy)")
    ax.set_ylabel("MAE vs reference, marker region (linear RGB)")
    ax.set_title("fast water model: time vs error (mean over turbid conditions)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# --------------------------------------------------------------------------- glow

GLOW_WATERS = ("mild", "moderate")
GLOW_RANGES = (2.0, 5.0, 8.0)
GLOW_RADII_PX = (3, 6, 12, 24, 40)


def glow_reference(
    water,
    range_m: float,
    out: Path,
    size: int = 96,
    hfov_deg: float = 40.0,
    samples: int = 64,
    power_w: float = 100.0,
    volume_bounces: int = 0,
) -> np.ndarray:
    """Render the reference glow of a point light ``range_m`` ahead (``blendgen.blender.glow_scene``,
    Blender in a subprocess); returns its linear RGB (size, size, 3)."""
    spec = {
        "water": _water_spec(water),
        "range_m": range_m,
        "power_w": power_w,
        "light_radius_m": 0.005,
        "hfov_deg": hfov_deg,
        "width": size,
        "height": size,
        "samples": samples,
        "seed": 1,
        "volume_bounces": int(volume_bounces),
    }
    return _glow_scene(spec, out, f"glow-{water.name}-{range_m:g}-b{int(volume_bounces)}", "glow")


def _water_spec(water) -> dict | None:
    """The glow scene's medium from a ``WaterOptics`` (None: no medium, air)."""
    if water is None:
        return None
    return {
        "sigma_a": water.sigma_a.tolist(),
        "sigma_s": water.sigma_s.tolist(),
        "phase": water.phase,
        "g": float(water.g),
        "ff_ior": float(water.ff_ior),
        "ff_backscatter": float(water.ff_backscatter),
    }


def _glow_scene(spec: dict, out: Path, tag: str, what: str) -> np.ndarray:
    """Render ``blendgen.blender.glow_scene`` for ``spec`` in a Blender subprocess (files
    ``out/tag.json|npy``); linear RGB (H, W, 3). RuntimeError naming ``what`` on failure."""
    import subprocess
    import sys

    out.mkdir(parents=True, exist_ok=True)
    sp, npy = out / f"{tag}.json", out / f"{tag}.npy"
    sp.write_text(json.dumps(spec))
    res = subprocess.run(
        [sys.executable, "-m", "blendgen.blender.glow_scene", str(sp), str(npy)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if res.returncode != 0:
        raise RuntimeError(f"{what} reference render failed: {res.stderr[-1500:]}")
    return np.load(npy)


def led_reference(
    water,
    range_m: float,
    radiance,
    radius_m: float,
    out: Path,
    size: int = 96,
    hfov_deg: float = 40.0,
    samples: int = 64,
    lights_scene: bool = True,
) -> np.ndarray:
    """Render the dataset's disc LED (radiance (3,), radius) ``range_m`` ahead, facing the camera,
    through ``water`` (None: no medium) with Blender in a subprocess; linear RGB (size, size, 3)."""
    spec = {
        "water": _water_spec(water),
        "range_m": range_m,
        "led": {"radiance": [float(v) for v in radiance], "radius_m": radius_m, "lights_scene": lights_scene},
        "hfov_deg": hfov_deg,
        "width": size,
        "height": size,
        "samples": samples,
        "seed": 1,
    }
    tag = f"led-{'air' if water is None else water.name}-{range_m:g}-{int(lights_scene)}"
    return _glow_scene(spec, out, tag, "LED")


def encircled_glow(img: np.ndarray, fx: float, radii_px) -> np.ndarray:
    """(len(radii), 3): sum of radiance x pixel solid angle within each radius of the image
    centre (pixel solid angle ``cos^3(theta) / fx^2``)."""
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    dx, dy = xx - (w - 1) / 2, yy - (h - 1) / 2
    rho = np.hypot(dx, dy)
    omega = (1.0 / (1.0 + (rho / fx) ** 2)) ** 1.5 / fx**2
    return np.array([(img * omega[..., None])[rho <= R].sum(axis=0) for R in radii_px])


def glow_radius_px(ee: np.ndarray, share: float = 0.5) -> float:
    """Radius (px, linear interpolation) holding ``share`` of the last value of the encircled
    energy ``ee`` (n,) sampled at radii 1..n px: the glow's size, independent of its level."""
    ee = np.asarray(ee, float)
    radii = np.arange(1, ee.size + 1, dtype=float)
    return float(np.interp(share * ee[-1], ee, radii))


def _fast_encircled(w, r: float, fx: float, radii, multiple: bool) -> np.ndarray:
    """(len(radii), 3) fast-model glow within each pixel radius, relative to the direct light:
    single scattering (analytic, without the multiple-scatter energy) or the widened kernel."""
    from blendgen.physics.water import optics

    radii = np.asarray(radii, float)
    if not multiple:
        single = optics.glow_encircled_energy(w, r, radii / fx)
        return single / (np.expm1(w.sigma_s * r) / (w.sigma_s * r))
    k = optics.glow_kernel_multiple(w, r, fx, keep_centre=True).astype(np.float64)
    R = k.shape[0] // 2
    rho = np.hypot(*np.mgrid[-R : R + 1, -R : R + 1])
    return np.array([k[rho <= q].sum(axis=0) for q in radii])


def glow_comparison(
    work: Path,
    waters=GLOW_WATERS,
    ranges=GLOW_RANGES,
    size: int = 96,
    samples: int = 64,
    power_w: float = 100.0,
    hfov_deg: float = 40.0,
    volume_bounces: int = 0,
):
    """Fast glow model vs the reference medium, per water, range and radius: encircled glow
    relative to the unscattered irradiance of the source, ``EE = sum(L Omega) / (I exp(-c r) / r^2)``
    with Cycles' point-light intensity ``I = P / (4 pi)`` W/sr, and the glow radius r50 (px
    holding half of the glow within 40 px). ``volume_bounces`` 0: the single-scatter model vs
    single-scatter Cycles; > 0: the multiple-scatter (widening) kernel vs Cycles with that many
    volume bounces. Returns a DataFrame (green channel)."""
    import pandas as pd

    from blendgen.config.models import Water, article_grey_spec
    from blendgen.physics.water import optics

    fx = (size / 2) / math.tan(math.radians(hfov_deg) / 2)
    fine = np.arange(1, max(GLOW_RADII_PX) + 1)
    rows = []
    for name in waters:  # an article level: its grey water (article_grey_spec)
        spec = article_grey_spec(name) if name in optics.ARTICLE_PRESETS else Water(preset=name)
        w = optics.water_for_mode(spec, "physical")
        for r in ranges:
            img = glow_reference(w, r, work, size, hfov_deg, samples, power_w, volume_bounces)
            direct = power_w / (4 * math.pi) * np.exp(-w.c * r) / r**2
            ref = encircled_glow(img.astype(np.float64), fx, fine)[:, 1] / direct[1]
            fast = _fast_encircled(w, r, fx, fine, volume_bounces > 0)[:, 1]
            r50_ref, r50_fast = glow_radius_px(ref), glow_radius_px(fast)
            for R in GLOW_RADII_PX:
                e_ref, e_fast = ref[R - 1], fast[R - 1]
                rows.append(
                    {
                        "water": name,
                        "range_m": r,
                        "radius_px": R,
                        "EE_reference": e_ref,
                        "EE_fast": e_fast,
                        "ratio": e_fast / e_ref if e_ref > 0 else float("nan"),
                        "r50_reference_px": r50_ref,
                        "r50_fast_px": r50_fast,
                    }
                )
    return pd.DataFrame(rows)
