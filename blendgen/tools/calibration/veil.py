"""Calibration of the physical veil (:mod:`blendgen.physics.water.veil`) against Cycles references.

For every preset (physical-mode coefficients, ``optics.water_for_mode``), the reference is
the Cycles medium of ``blendgen.blender.oracle_scenes`` (the project's water box, Blender
in a subprocess): an orthographic camera at depth ``h`` looking at elevation ``theta``
through a 400 m box of water at a black target 150 m away (``exp(-c 150)`` < 1e-6 for
every turbid preset), the sun straight down with irradiance 1 W/m^2, no sky, ``volume_bounces``
multiple scattering (32 reproduce 64 and 128 to 5 digits for ``mild``: see
:data:`CONVERGENCE`). The image mean is the veiling radiance per unit ``E_d0``.

One number per preset and channel, ``kappa``, is fitted by relative least squares over the
grid (:data:`GRID`); the file keeps the references, kappa, the model's values and the
relative residual per point, with the method, so ``dockbench bench fidelity`` can publish
them and a test can check that the stored calibration reproduces them.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

#: (camera depth m, view elevation deg) of the calibration references.
GRID = ((1.0, 0.0), (3.0, 0.0), (6.0, 0.0), (3.0, 30.0), (3.0, -30.0))
#: Volume bounces of the references, samples per pixel and image size (px).
BOUNCES, SPP, SIZE = 64, 1024, 16
#: Measured on ``mild`` at 2 m, horizontal (16 px, 1024 spp, seed 1): G-channel veil per unit E_d0.
CONVERGENCE = {0: 0.00333, 8: 0.01491, 16: 0.01575, 32: 0.01594, 64: 0.01594, 128: 0.01594}
TARGET_X_M, BOX_HALF_M = 150.0, 200.0
#: Presets measured; bare ``clear`` is Jerlov I in the physical mode and shares its entry.
PRESETS = (
    "mild",
    "moderate",
    "jerlov_I",
    "jerlov_IA",
    "jerlov_IB",
    "jerlov_II",
    "jerlov_III",
    "jerlov_1C",
    "jerlov_3C",
    "jerlov_5C",
    "jerlov_7C",
    "jerlov_9C",
)
ALIASES = {"clear": "jerlov_I"}


def physical_water(preset: str):
    """The water calibrated under ``preset``: a Jerlov type, or an article level's own grey
    water (``mild``, ``moderate``: beta given; a bare level in physical mode is its Jerlov
    type, calibrated under that type's name)."""
    from blendgen.config.models import Water, article_grey_spec
    from blendgen.physics.water import optics

    spec = article_grey_spec(preset) if preset in optics.ARTICLE_PRESETS else Water(preset=preset)
    return optics.water_for_mode(spec, "physical")


def reference_spec(
    water, depth_m: float, elevation_deg: float, bounces: int = BOUNCES, spp: int = SPP, size: int = SIZE, seed: int = 1
) -> dict:
    """oracle_scenes spec of one veil reference (module docstring)."""
    box = {"box_min": [-BOX_HALF_M] * 3, "box_max": [BOX_HALF_M, BOX_HALF_M, 0.0]}
    return {
        "water": {
            "sigma_a": water.sigma_a.tolist(),
            "sigma_s": water.sigma_s.tolist(),
            "phase": water.phase,
            "g": float(water.g),
            "ff_ior": float(water.ff_ior),
            "ff_backscatter": float(water.ff_backscatter),
            **box,
        },
        "camera": {"z": -float(depth_m), "clip_start": 0.001, "pitch_deg": float(elevation_deg)},
        "target": {"kind": "black", "x": TARGET_X_M},
        "sun": {"direction": [0, 0, -1], "strength": 1.0},
        "render": {"width": size, "height": size, "samples": spp, "volume_bounces": int(bounces), "seed": seed},
    }


def render_reference(spec: dict, work: Path) -> tuple[np.ndarray, float]:
    """Mean linear RGB (3,) of one oracle render and its wall time (s, Blender start included)."""
    work.mkdir(parents=True, exist_ok=True)
    p = work / f"veil-{time.time_ns()}.json"
    p.write_text(json.dumps(spec))
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-m", "blendgen.blender.oracle_scenes", str(p)], capture_output=True, text=True, timeout=900
    )
    if res.returncode != 0:
        raise RuntimeError(f"veil reference render failed: {res.stderr[-1500:]}")
    return np.array(json.loads(res.stdout.strip().splitlines()[-1])["mean"]), time.perf_counter() - t0


def model_value(water, depth_m: float, elevation_deg: float, kappa, K_v, eta: float = 0.0, parts: bool = False):
    """The veil model per unit E_d0 (3,) for the oracle geometry (sun overhead)."""
    from blendgen.physics.water import optics, veil

    return veil.veil_radiance(
        water.sigma_a,
        water.sigma_s,
        K_v,
        lambda t: optics.phase_value(water, t),
        kappa,
        depth_m,
        math.radians(elevation_deg),
        eta=eta,
        parts=parts,
    )


ETA_GRID = np.round(np.linspace(0.0, 1.0, 11), 2)


def fit_preset(water, points: list[dict]) -> tuple[np.ndarray, np.ndarray, float]:
    """(kappa, K_v) (3,) each and eta, fitted to ``points`` (their ``reference``): for each eta
    of :data:`ETA_GRID`, kappa and K_v channel by channel (K_v in [0, c]: a diffuse field cannot
    dim faster than the beam; the transient field above 6 m can dim slower than absorption); the eta with the least
    total squared relative residual."""
    from blendgen.physics.water import veil

    hs = [(p["depth_m"], p["elevation_deg"]) for p in points]
    ref = np.array([p["reference"] for p in points])
    beam = np.array([model_value(water, h, el, 0.0, 0.0) for h, el in hs])
    best = None
    for eta in ETA_GRID:
        kappa, K_v = np.ones(3), np.array(water.Kd, float)
        for ch in range(3):
            if water.sigma_s[ch] <= 0 or not np.all(ref[:, ch] > 0):
                continue

            def shape(K, ch=ch):
                return np.array([model_value(water, h, el, 1.0, np.full(3, K), eta, parts=True)[1][ch] for h, el in hs])

            kappa[ch], K_v[ch] = veil.fit_channel(beam[:, ch], ref[:, ch], shape, (0.0, float(water.c[ch])))
        fast = np.array([model_value(water, h, el, kappa, K_v, eta) for h, el in hs])
        err = float(np.sum((np.divide(fast - ref, ref, out=np.zeros_like(ref), where=ref > 0)) ** 2))
        if best is None or err < best[0]:
            best = (err, kappa, K_v, float(eta))
    return best[1], best[2], best[3]


def residuals(water, entry: dict) -> dict:
    """Fill ``entry``'s points with the model's value and relative residual; returns entry."""
    kappa, K_v, eta = np.array(entry["kappa"]), np.array(entry["K_v"]), float(entry["eta"])
    for p in entry["points"]:
        ref = np.array(p["reference"])
        fast = model_value(water, p["depth_m"], p["elevation_deg"], kappa, K_v, eta)
        p["fast"] = fast.round(7).tolist()
        p["rel_residual"] = np.divide(fast - ref, ref, out=np.zeros(3), where=ref > 0).round(4).tolist()
        p["fast_isotropic_estimate"] = (
            model_value(water, p["depth_m"], p["elevation_deg"], 1.0, water.Kd).round(7).tolist()
        )
    entry["max_abs_rel_residual"] = float(np.max(np.abs([p["rel_residual"] for p in entry["points"]])))
    return entry


def measure_preset(name: str, work: Path, echo=print) -> dict:
    """References on :data:`GRID` plus one 0-bounce check at 3 m horizontal; fit and residuals."""
    w = physical_water(name)
    points = []
    for h, el in GRID:
        ref, sec = render_reference(reference_spec(w, h, el), work)
        points.append({"depth_m": h, "elevation_deg": el, "reference": ref.round(7).tolist(), "seconds": round(sec, 1)})
        echo(f"veil {name}: h {h:g} m, elevation {el:+g} deg: reference {np.round(ref, 5).tolist()} ({sec:.1f} s)")
    ss, sec = render_reference(reference_spec(w, 3.0, 0.0, bounces=0), work)
    entry = {
        "points": points,
        "single_scatter_check": {
            "depth_m": 3.0,
            "elevation_deg": 0.0,
            "reference_0_bounces": ss.round(7).tolist(),
            "beam_term": model_value(w, 3.0, 0.0, 0.0, 0.0).round(7).tolist(),
            "seconds": round(sec, 1),
        },
    }
    return refit(name, entry)


def refit(name: str, entry: dict) -> dict:
    """Fit kappa and K_v of one preset's stored references and recompute the residuals."""
    w = physical_water(name)
    kappa, K_v, eta = fit_preset(w, entry["points"])
    entry.update(kappa=kappa.round(4).tolist(), K_v=K_v.round(5).tolist(), eta=eta)
    return residuals(w, entry)


CALIBRATION_KEYS = ("version", "method", "sun_strength", "light_depth_m", "sun_elevation_deg", "presets", "veil")
MAX_CALIBRATION_BYTES = 4 << 20


def check_data_file(path: Path) -> dict:
    """The calibration file ``path`` as it will be merged into, checked before any render:
    absent (a new file, seeded from the package's), or a UTF-8 JSON object of at most 4 MiB
    whose keys are those of blendgen/data/water_calibration.json; else
    :class:`~blendgen.config.models.ConfigError` (one line: file, what, the allowed form)."""
    from blendgen.config.models import ConfigError
    from blendgen.physics.water import optics

    path = Path(path)
    if not path.exists():
        return dict(optics.load_calibration()) or {"version": 1}
    allowed = f"a JSON object with keys among {', '.join(CALIBRATION_KEYS)}"
    if not path.is_file() or path.stat().st_size > MAX_CALIBRATION_BYTES:
        raise ConfigError(f"--data {path}: not a regular file of at most 4 MiB (expected {allowed})")
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ConfigError(f"--data {path}: not JSON ({type(exc).__name__}); expected {allowed}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"--data {path}: top level is {type(data).__name__}; expected {allowed}")
    unknown = sorted(set(data) - set(CALIBRATION_KEYS))
    if unknown:
        raise ConfigError(
            f"--data {path}: unknown key {unknown[0]!r} (not a dockbench calibration file?); expected {allowed}"
        )
    return data


def run(work: Path, data_path: Path, presets=PRESETS, echo=print) -> dict:
    """Measure and fit every preset; merge the ``"veil"`` section into ``data_path`` (checked by
    :func:`check_data_file` before the first render)."""
    data = check_data_file(data_path)
    entries = {}
    for name in presets:
        entries[name] = measure_preset(name, Path(work), echo)
    for alias, src in ALIASES.items():
        if src in entries:
            entries[alias] = entries[src]
    old = (data.get("veil") or {}).get("presets", {})
    data["veil"] = {
        "method": (
            f"kappa, K_v per preset and channel: relative least squares of reference = beam + diffuse(kappa, K_v) "
            f"(blendgen.physics.water.veil) over depth/elevation {list(GRID)}; reference: Cycles medium "
            f"(blendgen.blender.oracle_scenes) with {BOUNCES} volume bounces, {SPP} spp, {SIZE}x{SIZE} px, "
            f"ortho camera, black target at {TARGET_X_M:g} m, sun overhead 1 W/m^2, no sky; "
            f"coefficients: optics.water_for_mode(preset, 'physical')"
        ),
        "date": _dt.date.today().isoformat(),
        "convergence_mild_2m_G": CONVERGENCE,
        "presets": {**old, **entries},
    }
    from datasets_spec.io import save_json_atomic

    data_path.parent.mkdir(parents=True, exist_ok=True)
    save_json_atomic(data_path, data)
    return data["veil"]
