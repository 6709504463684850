"""Water optical coefficients and the FAST underwater image-formation model.

Pure numpy (+ cv2 for the optional blur). Everything is per RGB channel, linear
radiance, metres. Two image-formation modes (``model=``, the experiment's
``image_formation``):

``physical`` (Akkaynak & Treibitz 2018 revised model with ``beta_D = beta_B = c``)::

    I = J_lit * exp(-c r) + B_inf E_d0 exp(-Kd h_cam) * (1 - exp(-c r))
    J_lit = J * exp(-Kd h)   on surfaces lit from above, h the SURFACE's own depth
    J_lit = J                on emitters (LEDs): dimmed only along their path

``article`` (the article's formulas, every pixel alike)::

    I = ((1 - w) J + w C) * exp(-k d),   w = 1 - exp(-beta r)

``J`` is the clean surfaces-only render lit by the sun and sky at their surface
strength, ``r`` the range along the pixel ray (``geometry.planar_depth_to_range``;
``inf`` where no surface is hit), ``c = sigma_a + sigma_s`` the beam attenuation,
``h`` (H, W) the depth of each surface below the water surface, ``h_cam`` the
camera's depth (the veiling light dims with it), ``E_d0`` the downwelling
irradiance just below the surface, ``d`` the dock's depth, ``C`` the water colour.

Conventions chosen here:

- A channel with ``c == 0`` is left untouched at every range, including
  background pixels (``r = inf``): clear water is the identity, whatever the
  renderer gave the background. For ``c > 0`` background pixels become the veil.
- ``B_inf`` is veiling radiance per unit downwelling irradiance. Unless the config
  gives it (or asks for the reference calibration), :func:`light_field_veil`
  estimates it from the single-scattering albedo.

What the fast model misses (docs/water.md), to be calibrated/published against the
reference Cycles renders:

- forward-scatter halo/blur energy (about +9% at 1 m with sigma_s 0.3): the
  optional blur here only redistributes the attenuated direct signal, it adds
  no forward-scattered energy;
- the veiling light is one colour per frame: the calibrated model of
  :mod:`blendgen.physics.water.veil` (physical mode, bare presets) evaluates it at the camera's
  depth and optical-axis elevation, not per pixel ray;
- depth falloff with ``Kd`` is the multiply-scattered limit; the reference with
  0 bounces attenuates the sun by ``c`` along its refracted path;
- volumetric shadows and light shafts (no 3-D light field here);
- the glow of emitters (both modes, :func:`glow_kernel_multiple`) is the
  small-angle approximation of multiple forward scattering (Poisson orders of the
  single-scatter point-spread, Wells 1973): it widens and grows with ``b r``; light
  scattered beyond 96 px of the emitter and large-angle (non-small-angle) paths are not
  modelled;
- backscatter cones from artificial lights (LEDs, AUV lamp): they light no water;
- the veil's change of depth along a slanted ray (it uses the camera's depth);
- ``beta_D != beta_B`` and their range/reflectance dependence (A&T 2018).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blendgen.physics.water import presets as wp

COEF_RANGE = (0.0, 5.0)  # sigma_a, sigma_s, beta, Kd (1/m)
G_RANGE = (-1.0, 1.0)  # open interval
COLOR_RANGE = (0.0, 1.0)  # water_color (linear RGB)
B_INF_RANGE = (0.0, 10.0)  # B_inf (radiance per unit surface irradiance)
FF_IOR_RANGE = (1.0, 1.5)  # Fournier-Forand relative particle index (open at 1)
FF_B_RANGE = (0.0, 0.5)  # Fournier-Forand backscatter fraction (open)
MODELS = ("physical", "article")
#: Mean cosine of downwelling light (Kirk 2011: about 0.7-0.9 near the surface; 0.75 here).
MEAN_COSINE_DOWN = 0.75
PHASES = ("hg", "ff")


@dataclass(frozen=True)
class WaterOptics:
    """Per-RGB water coefficients (1/m) and phase function.

    ``sigma_a``/``sigma_s`` absorption/scattering, ``Kd`` diffuse attenuation of
    downwelling light, ``B_inf`` veiling light (linear RGB, per unit surface
    irradiance), ``phase`` ``"hg"`` (Henyey-Greenstein ``g``) or ``"ff"``
    (Fournier-Forand ``ff_ior``, ``ff_backscatter``, as Blender's Volume Scatter
    node). The image-formation mode is not a property of the water: see
    :func:`apply_water`'s ``model``.
    """

    name: str
    sigma_a: np.ndarray
    sigma_s: np.ndarray
    Kd: np.ndarray
    B_inf: np.ndarray
    g: float = 0.9
    phase: str = "hg"
    ff_ior: float = 1.1
    ff_backscatter: float = 0.0183
    provenance: str = ""

    def __post_init__(self):
        for f in ("sigma_a", "sigma_s", "Kd", "B_inf"):
            v = np.array(getattr(self, f), dtype=float).reshape(-1)
            if v.size == 1:
                v = np.repeat(v, 3)
            v.setflags(write=False)
            object.__setattr__(self, f, v)
        _validate(self)

    @property
    def c(self) -> np.ndarray:
        """Beam attenuation ``sigma_a + sigma_s`` (3,), 1/m."""
        return self.sigma_a + self.sigma_s

    @property
    def albedo(self) -> np.ndarray:
        """Single-scattering albedo ``sigma_s / c`` (3,), 0 where c == 0."""
        c = self.c
        return np.divide(self.sigma_s, c, out=np.zeros(3), where=c > 0)

    @property
    def is_clear(self) -> bool:
        """True when the water neither attenuates nor scatters (c == 0)."""
        return not bool(np.any(self.c > 0))

    def replace(self, **kw) -> WaterOptics:
        return dataclasses.replace(self, **kw)

    def to_dict(self) -> dict:
        """JSON-friendly dict (for manifests); ``WaterOptics(**d)`` round-trips it."""
        return {
            "name": self.name,
            "sigma_a": self.sigma_a.tolist(),
            "sigma_s": self.sigma_s.tolist(),
            "Kd": self.Kd.tolist(),
            "B_inf": self.B_inf.tolist(),
            "g": self.g,
            "phase": self.phase,
            "ff_ior": self.ff_ior,
            "ff_backscatter": self.ff_backscatter,
            "provenance": self.provenance,
        }


# --------------------------------------------------------------------------- validation


def _vec3(name: str, value, lo: float, hi: float, unit: str = "") -> np.ndarray:
    try:
        v = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or 3 numbers in [{lo:g}, {hi:g}]{unit}, got {value!r}") from None
    if v.size == 1:
        v = np.repeat(v, 3)
    if v.size != 3:
        raise ValueError(f"{name} must be a number or 3 numbers (R, G, B), got {value!r}")
    if not np.all(np.isfinite(v)) or np.any(v < lo) or np.any(v > hi):
        raise ValueError(f"{name} must be in [{lo:g}, {hi:g}]{unit} per channel, got {v.tolist()}")
    return v


def _scalar(name: str, value, lo: float, hi: float, open_lo=True, open_hi=True) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    bad_lo = v <= lo if open_lo else v < lo
    bad_hi = v >= hi if open_hi else v > hi
    if not math.isfinite(v) or bad_lo or bad_hi:
        lb, rb = "(" if open_lo else "[", ")" if open_hi else "]"
        raise ValueError(f"{name} must be in {lb}{lo:g}, {hi:g}{rb}, got {value!r}")
    return v


def _validate(w: WaterOptics) -> None:
    _vec3("sigma_a", w.sigma_a, *COEF_RANGE, " 1/m")
    _vec3("sigma_s", w.sigma_s, *COEF_RANGE, " 1/m")
    _vec3("Kd", w.Kd, *COEF_RANGE, " 1/m")
    _vec3("B_inf", w.B_inf, *B_INF_RANGE)
    _scalar("g", w.g, *G_RANGE)
    _scalar("ff_ior", w.ff_ior, *FF_IOR_RANGE, open_hi=False)
    _scalar("ff_backscatter", w.ff_backscatter, *FF_B_RANGE)
    if w.phase not in PHASES:
        raise ValueError(f"phase must be one of {PHASES}, got {w.phase!r}")


# --------------------------------------------------------------------------- presets

ARTICLE_PRESETS = tuple(wp.ARTICLE_BETAS)
JERLOV_PRESETS = tuple(f"jerlov_{t}" for t in wp.JERLOV_TYPES)
PRESETS = ARTICLE_PRESETS + JERLOV_PRESETS


def article_water(
    beta=0.0, water_color=wp.ARTICLE_WATER_COLOR, k=wp.ARTICLE_K, albedo=None, name: str = "article", **kw
) -> WaterOptics:
    """The article's water: ``c = beta``, ``B_inf = water_color``, depth light ``k``."""
    beta = _vec3("beta", beta, *COEF_RANGE, " 1/m")
    color = _vec3("water_color", water_color, *COLOR_RANGE)
    k = _vec3("k", k, *COEF_RANGE, " 1/m")
    if albedo is not None:
        albedo = _vec3("albedo", albedo, 0.0, 1.0)
    d = wp.article_coefficients(beta, color, k, albedo)
    d.update(kw)
    return WaterOptics(name=name, **d)


def get_preset(name: str) -> WaterOptics:
    """A named preset: 'clear', 'mild', 'moderate' or 'jerlov_<type>' (I..9C)."""
    key = wp.preset_key(name)
    if key in ARTICLE_PRESETS:
        return article_water(wp.ARTICLE_BETAS[key], name=key)
    d = dict(wp.jerlov_coefficients(key.split("_", 1)[1]))
    return WaterOptics(name=key, **d)


def _first(*values):
    return next((v for v in values if v is not None), None)


def water_optics(spec) -> WaterOptics:
    """:class:`WaterOptics` of a validated water section (``blendgen.config.models.Water``).

    The preset (or a turbidity reading, ``secchi_m`` / ``ntu``) gives every coefficient; the
    section's non-null fields override them. Article presets take ``beta``, ``water_color``, ``k``/``Kd`` and
    ``albedo`` through
    :func:`article_water`; a Jerlov preset takes ``water_color`` as its ``B_inf``."""
    key = spec.preset
    reading = _reading(spec)
    if key in ARTICLE_PRESETS and reading is None:
        w = article_water(
            _first(spec.beta, wp.ARTICLE_BETAS[key]),
            _first(spec.water_color, wp.ARTICLE_WATER_COLOR),
            _first(spec.k, spec.Kd, wp.ARTICLE_K),
            spec.albedo,
            name=key,
        )
    else:
        w = get_preset(key) if reading is None else reading_water(*reading)
        if spec.water_color is not None:
            w = w.replace(B_inf=spec.water_color)
        if _first(spec.k, spec.Kd) is not None:
            w = w.replace(Kd=_first(spec.k, spec.Kd))
    upd = {
        f: getattr(spec, f)
        for f in ("sigma_a", "sigma_s", "B_inf", "g", "phase", "ff_ior", "ff_backscatter", "name", "provenance")
        if getattr(spec, f) is not None
    }
    if any(f in upd for f in ("sigma_a", "sigma_s", "B_inf")):
        upd.setdefault("name", f"{key}+custom")
        upd.setdefault("provenance", f"config: explicit coefficients over preset {key!r}")
    return w.replace(**upd)


# --------------------------------------------------------------------------- calibration

#: Fast-model calibration against reference renders (``dockbench calibrate-water``).
CALIBRATION_PATH = Path(__file__).resolve().parents[2] / "data" / "water_calibration.json"
#: Forward-scatter blur of the fast model, as an angle: 2 px per unit scattering optical
#: depth, at most 3 px, at the default 640 px / 60 deg camera (fx = 554.26 px).
BLUR_RAD_PER_TAU, BLUR_MAX_RAD = 2.0 / 554.256, 3.0 / 554.256


@functools.lru_cache(maxsize=8)
def _read_calibration(path: str, mtime: float) -> dict:
    return json.loads(Path(path).read_text())


def load_calibration(path: Path | str | None = None) -> dict:
    """The calibration file as a dict (``{}`` when absent)."""
    p = Path(path) if path is not None else CALIBRATION_PATH
    if not p.exists():
        return {}
    return _read_calibration(str(p), p.stat().st_mtime)


def light_field_veil(water: WaterOptics, mean_cosine_down: float = MEAN_COSINE_DOWN) -> np.ndarray:
    """Veiling radiance per unit downwelling irradiance (3,), 1/sr.

    Far from any surface, path radiance balances attenuation and in-scattering:
    ``L_inf = (b / c) L_mean`` when the light field is treated as isotropic-equivalent,
    with the mean radiance ``L_mean = E_0 / (4 pi)`` and the scalar irradiance
    ``E_0 = E_d / mu_d`` (mean cosine of downwelling light). It includes multiple
    scattering, which the 0-bounce reference medium leaves out (docs/water.md: 1.5-7x
    single scatter). Zero where the water is clear.

    Measured residual (2026-11-23, ``blendgen.blender.oracle_scenes``, physical ``mild``:
    sigma_a (.176, .04, .08), sigma_s (.024, .16, .12), HG g .9; sun 3 W/m^2 overhead,
    horizontal view at 2 m depth, black target at 40 m, 512 spp): the reference gives
    (.0015, .0100, .0110) with 0 volume bounces and (.0018, .045, .041) with 64; this
    estimate gives (.020, .216, .168), 4-5x the multiple-scattering reference in G and B
    (11x in R): the isotropic-equivalent light field overstates the horizontal radiance
    when scattering is forward-peaked. In ``physical`` mode a bare preset now uses the
    calibrated beam + diffuse model instead (:mod:`blendgen.physics.water.veil`,
    :func:`veil_parameters`); this estimate remains for waters with overridden coefficients."""
    return water.albedo / (4.0 * math.pi * float(mean_cosine_down))


def reading_water(kind: str, value: float) -> WaterOptics:
    """The water of a turbidity reading (``secchi_m`` m or ``ntu``; :mod:`physics.water.turbidity`)."""
    from blendgen.physics.water import turbidity

    return WaterOptics(name=f"{kind}={value:g}", **turbidity.water_from_reading(kind, value))


def _reading(spec):
    """(kind, value) of a water section's turbidity reading, or None."""
    for kind in ("secchi_m", "ntu"):
        v = getattr(spec, kind, None)
        if v is not None:
            return kind, float(v)
    return None


def effective_preset(spec, mode: str) -> str:
    """The preset whose coefficients a water section has in ``mode``: in ``physical`` mode a
    bare article level is its Jerlov type (``water_presets.ARTICLE_JERLOV``)."""
    if mode == "physical" and spec.preset in ARTICLE_PRESETS and spec.is_bare:
        return f"jerlov_{wp.ARTICLE_JERLOV[spec.preset]}"
    return spec.preset


def water_for_mode(spec, mode: str) -> WaterOptics:
    """The water's coefficients in an image-formation mode (both fidelities use these).

    ``article``: :func:`water_optics` as configured. ``physical``: a bare article level is
    the water of the Jerlov type ``water_presets.ARTICLE_JERLOV`` names (per-channel a, b,
    Kd: real water absorbs red even when clear); an article level with overridden
    coefficients (the article's grey water, e.g. ``beta`` given) keeps them and takes the
    per-channel Kd of ``water_presets.ARTICLE_KD_JERLOV`` (unless ``k``/``Kd`` is given)."""
    water = water_optics(spec)
    if mode != "physical" or spec.preset not in ARTICLE_PRESETS:
        return water
    if spec.is_bare:
        jerlov = get_preset(effective_preset(spec, mode))
        beta = wp.ARTICLE_BETAS[spec.preset]
        return jerlov.replace(
            name=spec.preset,
            provenance=f"physical {spec.preset} (article beta {beta:g} 1/m) = "
            f"{jerlov.name}, the type of nearest per-channel c: " + jerlov.provenance,
        )
    jerlov = get_preset(f"jerlov_{wp.ARTICLE_KD_JERLOV[spec.preset]}")
    if spec.k is None and spec.Kd is None:
        water = water.replace(Kd=jerlov.Kd, provenance=water.provenance + f"; Kd: {jerlov.name} (physical mode)")
    return water


def fast_water(
    spec, mode: str, irradiance: float, calibration: dict | None = None, veil: dict | None = None
) -> tuple[WaterOptics, dict]:
    """Water and ``apply_water`` options for the fast fidelity of one condition.

    ``spec`` a validated water section (``config.models.Water``); ``mode`` 'physical'
    or 'article'; ``irradiance`` the downwelling irradiance just below the surface
    (W/m^2, sun + sky on a horizontal plane). The veiling light is, in this order: the
    config's ``B_inf`` (per unit irradiance); the reference calibration when
    ``calibrated`` is set and the preset is bare and listed; the calibrated veil model
    ``veil`` (:func:`veil_parameters`; returned as ``opts["veil"]`` and evaluated per frame
    by :func:`veil_radiance_at` at the camera's depth and view elevation, ``B_inf`` then
    holds its value at the surface, horizontal, for the record); else :func:`light_field_veil`. In ``article`` mode
    it is the water colour ``C`` (the
    article presets' colour, or the veil above times the irradiance) and is used as is.
    Coefficients: :func:`water_for_mode`.
    Returns ``(water, {"irradiance", "blur", "calibrated", "veil", "glow"})``."""
    water = water_for_mode(spec, mode)
    cal = calibration if calibration is not None else (load_calibration() if spec.calibrated else {})
    entry = (cal.get("presets") or {}).get(effective_preset(spec, mode))
    use = bool(spec.calibrated and entry and spec.is_bare and not water.is_clear)
    article_colour = mode == "article" and spec.preset in ARTICLE_PRESETS and spec.B_inf is None
    if use:
        # the calibration's B_inf is per unit sun strength at its sun elevation
        per_ed = np.asarray(entry["B_inf"], float) / math.sin(math.radians(cal.get("sun_elevation_deg", 90.0)))
        water = water.replace(B_inf=per_ed, provenance=water.provenance + "; calibrated: " + str(cal.get("method", "")))
    elif veil is not None and mode == "physical" and spec.B_inf is None:
        water = water.replace(
            B_inf=np.clip(veil_radiance_at(water, veil, 0.0), *B_INF_RANGE),
            provenance=water.provenance + "; B_inf: calibrated beam + diffuse veil model "
            "(physics.water.veil, water_calibration.json 'veil')",
        )
    elif spec.B_inf is None and not article_colour:
        water = water.replace(
            B_inf=light_field_veil(water),
            provenance=water.provenance + "; B_inf: light-field estimate (b/c)/(4 pi mu_d)",
        )
    irr = float(irradiance)
    if mode == "article" and not article_colour:
        water = water.replace(B_inf=water.B_inf * irr)  # a colour, used as is
    on = veil is not None and mode == "physical" and spec.B_inf is None and not use
    return water, {
        "irradiance": 1.0 if mode == "article" else irr,
        "blur": bool(spec.blur),
        "calibrated": use,
        "veil": veil if on else None,
        "glow": bool(getattr(spec, "glow", True)),
    }


def veil_parameters(spec, mode: str, calibration: dict | None = None) -> dict | None:
    """The calibrated veil model's numbers for a water section in ``physical`` mode:
    ``{"kappa", "K_v", "eta", "max_abs_rel_residual", "method"}`` from the calibration
    file's ``"veil"`` section (``dockbench calibrate-veil``), or None: another mode, an
    explicit ``B_inf``, the older ``calibrated`` flag, coefficients overridden (the fit
    belongs to the preset's own coefficients), clear water, or no entry for the preset."""
    if mode != "physical" or spec.B_inf is not None or spec.calibrated or not spec.is_bare:
        return None
    cal = calibration if calibration is not None else load_calibration()
    section = cal.get("veil") or {}
    entry = (section.get("presets") or {}).get(effective_preset(spec, mode))
    if not entry or water_for_mode(spec, mode).is_clear:
        return None
    return {
        "kappa": list(entry["kappa"]),
        "K_v": list(entry["K_v"]),
        "eta": float(entry["eta"]),
        "max_abs_rel_residual": float(entry.get("max_abs_rel_residual", float("nan"))),
        "method": f"{section.get('method', '')} ({section.get('date', '')})",
    }


def veil_radiance_at(
    water: WaterOptics,
    veil: dict,
    depth_m: float,
    view_elevation_rad: float = 0.0,
    sun_elevation_deg: float = 90.0,
    sun_share: float = 1.0,
) -> np.ndarray:
    """Veiling radiance per unit ``E_d0`` (3,) of the calibrated model (:mod:`physics.water.veil`)
    for a camera at ``depth_m`` looking at ``view_elevation_rad``: the sun's beam term (its
    share ``sun_share`` of ``E_d0``, at ``sun_elevation_deg``, 90 deg of azimuth from the
    view) plus the fitted diffuse term (sky light joins the diffuse field)."""
    from blendgen.physics.water import veil as vm

    beam, diffuse = vm.veil_radiance(
        water.sigma_a,
        water.sigma_s,
        veil["K_v"],
        lambda t: phase_value(water, t),
        veil["kappa"],
        depth_m,
        view_elevation_rad,
        eta=veil["eta"],
        sun_elevation_rad=math.radians(sun_elevation_deg),
        parts=True,
    )
    return float(sun_share) * beam + diffuse


# --------------------------------------------------------------------------- phase functions


def hg_phase(cos_theta, g: float):
    """Henyey-Greenstein phase function (1/sr, integrates to 1 over 4 pi)."""
    mu = np.asarray(cos_theta, float)
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def _ff_delta(theta, n):
    return 4.0 / (3.0 * (n - 1.0) ** 2) * np.sin(np.asarray(theta, float) / 2.0) ** 2


def _ff_backscatter_fraction(nu: float, n: float) -> float:
    d90 = float(_ff_delta(np.pi / 2, n))
    return 1.0 - (1.0 - d90 ** (nu + 1) - 0.5 * (1.0 - d90**nu)) / ((1.0 - d90) * d90**nu)


def ff_nu(ior: float, backscatter: float) -> float:
    """Fournier-Forand slope parameter nu = (3 - mu)/2 giving ``backscatter`` at ``ior``."""
    from scipy.optimize import brentq

    f = lambda nu: _ff_backscatter_fraction(nu, ior) - backscatter  # noqa: E731
    lo, hi = -0.9999, -1e-6  # nu < 0 for Junge slopes mu in (3, 5)
    if f(lo) * f(hi) > 0:
        raise ValueError(f"no Fournier-Forand slope gives backscatter {backscatter} at IOR {ior}")
    return brentq(f, lo, hi, xtol=1e-12)


def ff_phase(theta, ior: float = 1.1, backscatter: float = 0.0183):
    """Fournier-Forand phase function (Mobley et al. 2002 form), 1/sr, at angle theta (rad)."""
    nu = ff_nu(ior, backscatter)
    th = np.clip(np.asarray(theta, float), 1e-9, np.pi)
    d = _ff_delta(th, ior)
    d180 = float(_ff_delta(np.pi, ior))
    dn = d**nu
    s2 = np.sin(th / 2.0) ** 2
    p = (nu * (1 - d) - (1 - dn) + (d * (1 - dn) - nu * (1 - d)) / s2) / (4 * np.pi * (1 - d) ** 2 * dn)
    p += (1 - d180**nu) / (16 * np.pi * (d180 - 1) * d180**nu) * (3 * np.cos(th) ** 2 - 1)
    return p


def phase_value(water: WaterOptics, theta_rad: float) -> float:
    """The water's phase function (1/sr) at scattering angle ``theta_rad``."""
    if water.phase == "ff":
        return float(ff_phase(theta_rad, water.ff_ior, water.ff_backscatter))
    return float(hg_phase(math.cos(theta_rad), water.g))


def hg_cumulative(theta, g: float):
    """Share of Henyey-Greenstein scattering within angle ``theta`` (rad) of forward:
    ``int_0^theta p(t) 2 pi sin t dt`` (1 at pi)."""
    th = np.clip(np.asarray(theta, float), 0.0, np.pi)
    if abs(g) < 1e-9:
        return (1.0 - np.cos(th)) / 2.0
    return (1.0 - g * g) / (2.0 * g) * (1.0 / (1.0 - g) - 1.0 / np.sqrt(1.0 + g * g - 2.0 * g * np.cos(th)))


def phase_cumulative(water: WaterOptics, theta):
    """Share of the water's scattering within ``theta`` (rad) of forward (HG analytic, FF numeric)."""
    if water.phase != "ff":
        return hg_cumulative(theta, water.g)
    grid = np.concatenate([np.geomspace(1e-6, 1e-2, 400), np.linspace(1e-2, np.pi, 2000)])
    dens = ff_phase(grid, water.ff_ior, water.ff_backscatter) * 2 * np.pi * np.sin(grid)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(grid))])
    return np.interp(np.asarray(theta, float), grid, cum / cum[-1])


def glow_encircled_energy(water: WaterOptics, range_m: float, psi, n_steps: int = 64) -> np.ndarray:
    """Forward-scattered light of a point source at ``range_m`` within angle ``psi`` (rad) of it,
    relative to its unscattered (attenuated) light, per channel: (..., 3).

    Single small-angle scattering (Mobley's Ocean Optics Web Book, "Beam and Point Spread
    Functions"): a photon scattered by theta at distance u from the source is seen at
    ``psi = theta u / r``, so ``EE(psi) = b int_0^r P(psi r / u) du`` with P the phase
    function's cumulative share; ``EE(pi) = b r``. Scaled by ``(exp(b r) - 1) / (b r)`` so the
    total is all light scattered but not absorbed, ``exp(-a r) (1 - exp(-b r))`` over the
    direct ``exp(-c r)`` (multiple forward scattering keeps the single-scatter shape here)."""
    r = float(range_m)
    psi = np.asarray(psi, float)
    b = water.sigma_s
    if r <= 0 or not np.any(b > 0):
        return np.zeros(psi.shape + (3,))
    u = (np.arange(n_steps) + 0.5) / n_steps * r  # midpoints along the path
    P = phase_cumulative(water, np.minimum(psi[..., None] * r / u, np.pi))  # (..., n)
    single = P.mean(axis=-1)[..., None] * (b * r)  # (..., 3)
    br = b * r
    boost = np.where(br > 0, np.expm1(br) / np.where(br > 0, br, 1.0), 1.0)
    return single * boost


def _ring_kernel(ring_energy: np.ndarray, R: int) -> np.ndarray:
    """(2R+1, 2R+1, C) kernel spreading ``ring_energy[k]`` (K, C) evenly over the pixels whose
    rounded distance from the centre is k (k = 0..R)."""
    yy, xx = np.mgrid[-R : R + 1, -R : R + 1]
    ring = np.rint(np.hypot(xx, yy)).astype(int)
    counts = np.bincount(ring.ravel(), minlength=R + 2)[: R + 1]
    k = np.zeros(ring.shape + (ring_energy.shape[1],))
    ok = ring <= R
    k[ok] = ring_energy[ring[ok]] / counts[ring[ok], None]
    return k


def glow_kernel_multiple(
    water: WaterOptics, range_m: float, fx: float, max_radius_px: int = 96, keep_centre: bool = False
) -> np.ndarray:
    """Like :func:`glow_kernel`, but the glow widens with ``b r`` by multiple forward scattering.

    Small-angle approximation (Wells 1973; Mobley's Ocean Optics Web Book, "The small-angle
    approximation"): tracing a camera ray back to the source, each scattering at distance u from
    the source moves the apparent direction by ``theta u / r``; the n scatterings along the path
    form a Poisson process (positions iid uniform on [0, r]), so the n-th order's apparent-angle
    distribution is the n-fold 2-D convolution of the single-scatter one ``k1`` (unit mass) and
    its energy relative to the direct light is ``(b r)^n / n!``. Summed over n >= 1 in Fourier
    space: ``PSF = F^-1[exp(b r F[k1]) - 1]``, total ``exp(b r) - 1`` (what :func:`glow_kernel`
    puts in the single-scatter shape). The centre pixel is 0 (the direct term keeps it); light
    scattered beyond ``max_radius_px`` is dropped."""
    b = np.asarray(water.sigma_s, float)
    r = float(range_m)
    if r <= 0 or not np.any(b > 0):
        return np.zeros((1, 1, 3), np.float32)
    R = int(max_radius_px)
    edges = glow_encircled_energy(water, r, (np.arange(R + 2) - 0.5).clip(0) / float(fx))  # (R+2, 3)
    br = b * r
    single = edges / np.where(br > 0, np.expm1(br), 1.0)  # unit-mass single scatter (CDF)
    k1 = _ring_kernel(np.diff(single, axis=0), R)  # (2R+1, 2R+1, 3)
    from scipy import fft as sfft

    n = sfft.next_fast_len(3 * R + 2, real=True)  # what wraps around comes from > 2R px away
    pad = np.zeros((3, n, n), np.float32)
    for c in range(3):  # centre at (0, 0)
        pad[c][np.ix_(np.arange(-R, R + 1) % n, np.arange(-R, R + 1) % n)] = k1[..., c]
    F = sfft.rfft2(pad, axes=(1, 2))
    F *= br.astype(np.float32)[:, None, None]
    psf = sfft.irfft2(np.expm1(F), s=(n, n), axes=(1, 2))
    idx = np.arange(-R, R + 1) % n
    psf = np.moveaxis(psf[:, idx][:, :, idx], 0, -1).astype(np.float64)
    psf = np.clip(psf, 0.0, None)
    if keep_centre:  # the glow inside the emitter's own pixel (for checks)
        return psf.astype(np.float32)
    psf[R, R] = 0.0
    ring = np.ceil(np.hypot(*np.mgrid[-R : R + 1, -R : R + 1])).astype(int).ravel()
    enc = np.cumsum(
        np.stack([np.bincount(ring, psf[..., c].ravel(), minlength=2 * R + 2) for c in range(3)], axis=-1), axis=0
    )[: R + 1]  # energy within radius q
    inside = np.nonzero(np.all(enc >= 0.99 * psf.sum(axis=(0, 1)), axis=-1))[0]
    Rk = max(int(inside[0]) if inside.size else R, 1)
    return psf[R - Rk : R + Rk + 1, R - Rk : R + Rk + 1].astype(np.float32)


#: Ranges are binned in steps of this fraction (log scale) for the kernel cache: the glow's
#: shape and energy change slowly with range (b r changes by < 5 % within a bin).
GLOW_RANGE_BIN = 0.05


def cached_glow_kernel(water: WaterOptics, range_m: float, fx: float) -> np.ndarray:
    """:func:`glow_kernel_multiple` at ``range_m`` rounded to a ``GLOW_RANGE_BIN`` log step, cached
    per scattering (``sigma_s`` and phase function: all the glow depends on, so a frame's veil
    ``B_inf``, which changes with the camera's depth and view, does not miss the cache), range bin
    and focal length (read-only array)."""
    rbin = round(math.log(max(float(range_m), 1e-3)) / math.log1p(GLOW_RANGE_BIN))
    scatter = (tuple(water.sigma_s.tolist()), water.phase, water.g, water.ff_ior, water.ff_backscatter)
    key = (scatter, rbin, round(float(fx), 3))
    k = _GLOW_CACHE.get(key)
    if k is None:
        if len(_GLOW_CACHE) >= 512:
            _GLOW_CACHE.clear()
        k = _GLOW_CACHE[key] = glow_kernel_multiple(water, math.exp(rbin * math.log1p(GLOW_RANGE_BIN)), fx)
        k.setflags(write=False)
    return k


_GLOW_CACHE: dict = {}


def glow_kernel(water: WaterOptics, range_m: float, fx: float, max_radius_px: int = 96) -> np.ndarray:
    """(2R+1, 2R+1, 3) float32 point-spread of the forward-scattered glow around an emitter at
    ``range_m`` (camera ``fx`` px/rad): pixel weights relative to the emitter's direct image
    (a direct image of total 1 gets a glow of total ``kernel.sum()``). The centre pixel is 0
    (the direct term keeps it). R grows with range until 99 % of the glow is inside, at most
    ``max_radius_px``. Single-scatter shape (see :func:`glow_kernel_multiple` for the widening)."""
    rad = np.arange(0.0, max_radius_px + 1.5)
    ee = glow_encircled_energy(water, range_m, rad / float(fx))  # (R+2, 3) at ring edges
    total = glow_encircled_energy(water, range_m, np.array(np.pi))
    if not np.any(total > 0):
        return np.zeros((1, 1, 3), np.float32)
    inside = np.nonzero(np.all(ee >= 0.99 * total, axis=-1))[0]
    R = int(min(max_radius_px, inside[0] if inside.size else max_radius_px))
    R = max(R, 1)
    yy, xx = np.mgrid[-R : R + 1, -R : R + 1]
    rho = np.hypot(xx, yy)
    ring = np.rint(rho).astype(int)
    edges = glow_encircled_energy(water, range_m, (np.arange(R + 2) - 0.5).clip(0) / float(fx))
    ring_energy = np.diff(edges, axis=0)  # energy in ring k = [k-.5, k+.5)
    counts = np.bincount(ring.ravel(), minlength=R + 2)[: R + 1]
    k = np.zeros(rho.shape + (3,))
    ok = (ring >= 1) & (ring <= R)
    k[ok] = ring_energy[ring[ok]] / counts[ring[ok], None]
    return k.astype(np.float32)


# --------------------------------------------------------------------------- analytic scatter


def single_scatter_backscatter(
    sigma_a,
    sigma_s,
    g: float = 0.0,
    E=1.0,
    depth_m=0.0,
    range_m=np.inf,
    theta_deg: float = 90.0,
    sun_c=None,
    phase_fn=None,
):
    """Single-scattered path radiance for a horizontal view at depth H, sun straight down.

    ``L = sigma_s p(theta) E exp(-c_sun H) / c * (1 - exp(-c z))`` per channel, with
    ``c = sigma_a + sigma_s`` along the horizontal view ray of length ``z =
    range_m``, the sun reaching depth H along a vertical path attenuated by
    ``c_sun`` (default ``c``: unscattered sun beam, as Cycles with 0 volume
    bounces; pass ``Kd`` for the diffuse limit), and ``p`` the HG phase function
    (normalised over 4 pi) at scattering angle ``theta`` (90 deg for sun straight
    down and a horizontal view), or ``phase_fn(theta_rad)``. ``range_m = inf``
    gives the veiling light ``B_inf``. Broadcasts ``range_m`` (...,) -> (..., 3).
    """
    sa = np.broadcast_to(np.asarray(sigma_a, float), (3,))
    ss = np.broadcast_to(np.asarray(sigma_s, float), (3,))
    c = sa + ss
    c_sun = c if sun_c is None else np.broadcast_to(np.asarray(sun_c, float), (3,))
    th = math.radians(theta_deg)
    p = phase_fn(th) if phase_fn is not None else float(hg_phase(math.cos(th), g))
    z = np.asarray(range_m, float)[..., None]
    safe_c = np.where(c > 0, c, 1.0)
    zf = np.where(np.isinf(z), 0.0, z)
    grow = np.where(c > 0, -np.expm1(-c * zf) / safe_c, zf)  # (1 - e^{-cz})/c, -> z as c -> 0
    grow = np.where(np.isinf(z), np.where(c > 0, 1.0 / safe_c, 0.0), grow)
    return ss * p * np.asarray(E, float) * np.exp(-c_sun * depth_m) * grow


def veiling_light(water: WaterOptics, E=1.0, depth_m=0.0, theta_deg: float = 90.0, sun_c=None):
    """Single-scatter ``B_inf`` (3,) of ``water`` (its own phase function)."""
    return single_scatter_backscatter(
        water.sigma_a,
        water.sigma_s,
        water.g,
        E,
        depth_m,
        np.inf,
        theta_deg,
        sun_c,
        phase_fn=lambda t: phase_value(water, t),
    )


# --------------------------------------------------------------------------- fast model
#
# Speed: numpy broadcasting a (3,) vector over an (H, W, 3) array is ~20x slower
# than a same-shape or row-broadcast op. Every image is therefore processed as an
# (H, 3W) view, per-channel constants as a (1, 3W) tiled row, and per-pixel
# scalars (range, depth, weights) are expanded to 3 channels with cv2.cvtColor.

_FMAX32 = float(np.finfo(np.float32).max)


def _row(v, width: int, dtype) -> np.ndarray:
    """Per-channel constant (3,) -> (1, 3*width) row matching an (H, 3W) view."""
    return np.tile(np.asarray(v, dtype=dtype).reshape(3), width)[None, :]


def _gray3(x: np.ndarray) -> np.ndarray:
    """(H, W) -> (H, 3W): each pixel's value repeated for its 3 channels."""
    h, w = x.shape
    if x.dtype == np.float32:
        import cv2

        return cv2.cvtColor(x, cv2.COLOR_GRAY2BGR).reshape(h, 3 * w)
    return np.repeat(x, 3, axis=1)


def _clean_range(range_m, dtype) -> np.ndarray:
    """Range as ``dtype``; NaN/inf -> the largest finite value, negatives -> 0.

    A huge finite range keeps ``exp(-c r)`` exactly 0 for c > 0 and exactly 1 for
    c == 0 (inf would give 0 * inf = NaN)."""
    r = np.asarray(range_m).astype(dtype, copy=False)
    big = _FMAX32 if dtype == np.float32 else float(np.finfo(np.float64).max)
    if not np.isfinite(r).all():
        r = np.fmin(r, dtype(big))  # NaN, +inf -> big; -inf -> 0 below
    if (r < 0).any():
        r = np.maximum(r, dtype(0))
    return r


def depth_light(water: WaterOptics, depth_m) -> np.ndarray:
    """Downwelling light fraction ``exp(-Kd depth)``: (3,) for scalar depth, (..., 3) else."""
    d = np.asarray(depth_m, float)
    if np.any(d < 0) or np.any(~np.isfinite(d)):
        raise ValueError("depth_m must be finite and >= 0 (metres below the surface)")
    return np.exp(-water.Kd * d[..., None]) if d.ndim else np.exp(-water.Kd * float(d))


def transmittance(water: WaterOptics, range_m: np.ndarray, dtype=np.float32) -> np.ndarray:
    """``exp(-c r)`` (H, W, 3); exactly 1 in channels with c == 0 (inf range included)."""
    r = _clean_range(range_m, dtype)
    h, w = r.shape
    x = _gray3(r)
    with np.errstate(over="ignore"):  # huge range * c -> -inf -> exp 0
        x *= _row(-water.c, w, dtype)
        np.exp(x, out=x)
    return x.reshape(h, w, 3)


def _depth_factor(water: WaterOptics, depth_m, h: int, w: int, dtype) -> np.ndarray:
    """``exp(-Kd depth)`` as a (1, 3W) row (scalar depth) or (H, 3W) (per-pixel depth)."""
    depth = np.asarray(depth_m, float)
    if depth.ndim == 0:
        return _row(depth_light(water, float(depth)), w, dtype)
    if depth.shape != (h, w):
        raise ValueError(f"depth_m must be a scalar or {(h, w)}, got {depth.shape}")
    if np.any(depth < 0) or not np.isfinite(depth).all():
        raise ValueError("depth_m must be finite and >= 0 (metres below the surface)")
    D = _gray3(depth.astype(dtype)) * _row(-water.Kd, w, dtype)
    return np.exp(D, out=D)


# fmt: off
def apply_water(J: np.ndarray, range_m: np.ndarray, emissive_mask=None,
                water: WaterOptics | None = None, depth_m=0.0, *, model: str = "physical",
                veil_depth_m: float | None = None, irradiance=1.0, blur: bool = False,
                blur_px_per_tau: float = 2.0, blur_max_px: float = 3.0, blur_levels: int = 4,
                glow_fx: float | None = None) -> np.ndarray:
    """Fast underwater image formation (module docstring) on a clean render.

    J (H, W, 3) float32/float64 linear; range_m (H, W) metres along the ray (inf or
    NaN: no surface); emissive_mask (H, W) bool or None (emitters: not dimmed by depth
    in ``physical`` mode); depth_m water depth of the lit surfaces, scalar or (H, W)
    (``article`` mode: the scalar dock depth d, or the (H, W) map's value is used per
    pixel); veil_depth_m the camera's depth (physical veil; default: depth_m when
    scalar, else 0); model 'physical' | 'article'; irradiance scales B_inf (physical).
    blur: range-dependent forward-scatter Gaussian on the direct term, sigma_px =
    min(blur_max_px, blur_px_per_tau * mean(sigma_s) * r), ``blur_levels``
    precomputed cv2.GaussianBlur levels blended linearly by sigma.
    glow_fx: camera focal length (px); the emitters' forward-scattered glow
    (:func:`glow_kernel_multiple` at their median range) is added around them, in both modes (in
    ``article`` mode from the article water's ``sigma_s = albedo * beta`` and ``g``, before the
    final ``exp(-k d)``); None: no glow.
    Returns a new (H, W, 3) array of J's dtype (float32 unless J is float64).
    """
    water = water if water is not None else get_preset("clear")
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    J = np.asarray(J)
    dtype = np.float64 if J.dtype == np.float64 else np.float32
    if J.ndim != 3 or J.shape[2] != 3:
        raise ValueError(f"J must be (H, W, 3), got {J.shape}")
    h, w = J.shape[:2]
    if np.shape(range_m) != (h, w):
        raise ValueError(f"range_m must be {(h, w)}, got {np.shape(range_m)}")
    irr = float(irradiance)
    if not (math.isfinite(irr) and irr >= 0):
        raise ValueError(f"irradiance must be finite and >= 0, got {irradiance!r}")
    em = None if emissive_mask is None else np.asarray(emissive_mask, bool)
    if em is not None and em.shape != (h, w):
        raise ValueError(f"emissive_mask must be {(h, w)}, got {em.shape}")
    J2 = np.ascontiguousarray(J, dtype=dtype).reshape(h, 3 * w)
    t = transmittance(water, range_m, dtype).reshape(h, 3 * w)
    D = _depth_factor(water, depth_m, h, w, dtype)
    if model == "physical":
        direct = J2 * D                                   # J_lit: each surface dims by its own depth
        if em is not None and em.any():
            direct.reshape(h, w, 3)[em] = J2.reshape(h, w, 3)[em]   # emitters: only their path
        if veil_depth_m is None:
            veil_depth_m = float(depth_m) if np.ndim(depth_m) == 0 else 0.0
        B = _row(water.B_inf * irr * depth_light(water, float(veil_depth_m)), w, dtype)
    else:
        direct = J2.copy()                                # the article: scale everything at the end
        B = _row(water.B_inf, w, dtype)
    direct *= t                                           # J_lit exp(-c r)
    if blur and np.any(water.sigma_s > 0) and blur_max_px > 0:
        direct = _forward_scatter_blur(direct.reshape(h, w, 3), range_m, float(np.mean(water.sigma_s)),
                                       blur_px_per_tau, blur_max_px, blur_levels
                                       ).astype(dtype, copy=False).reshape(h, 3 * w)
    if glow_fx and em is not None and em.any() and np.any(water.sigma_s > 0):     # both modes
        direct = add_emitter_glow(direct.reshape(h, w, 3), em, range_m, water, float(glow_fx)).reshape(h, 3 * w)
    if bool(np.any(B != 0)):
        np.subtract(dtype(1), t, out=t)                   # 1 - exp(-c r), in place
        t *= B
        direct += t                                       # + B (1 - exp(-c r)); exact J at c = 0
    if model == "article":
        direct *= D                                       # every pixel times exp(-k d)
    return direct.reshape(h, w, 3)
# fmt: on


def add_emitter_glow(
    img: np.ndarray, emissive: np.ndarray, range_m: np.ndarray, water: WaterOptics, fx: float
) -> np.ndarray:
    """``img`` (H, W, 3) plus the forward-scattered glow of its emitter pixels (``emissive``
    (H, W) bool; their values in ``img`` are the attenuated direct radiance): the emitters'
    image convolved with :func:`glow_kernel` at their median range, in the box they and the
    kernel cover (:func:`spread`). Returns a new array (the input when nothing glows)."""
    r = np.asarray(range_m, float)[emissive]
    r = r[np.isfinite(r)]
    if r.size == 0:
        return img
    k = cached_glow_kernel(water, float(np.median(r)), fx)
    R = k.shape[0] // 2
    if R == 0 or not np.any(k):
        return img
    h, w = emissive.shape
    ys, xs = np.nonzero(emissive)
    y0, y1 = max(ys.min() - R, 0), min(ys.max() + R + 1, h)
    x0, x1 = max(xs.min() - R, 0), min(xs.max() + R + 1, w)
    src = np.where(emissive[y0:y1, x0:x1, None], img[y0:y1, x0:x1], 0).astype(np.float32)
    out = img.copy()
    out[y0:y1, x0:x1] += spread(src, k)
    return out


#: FFT sizes of :func:`spread` are rounded up to a multiple of this (px), so consecutive frames
#: reuse a kernel's spectrum (:data:`_SPECTRA`).
SPREAD_SIZE_STEP = 64


def spread(src: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """(h, w, 3) float32: each channel of ``src`` (h, w, 3), zero outside it, correlated with
    the same channel of ``kernel`` (2R+1, 2R+1, 3) (what ``cv2.filter2D`` with a constant 0
    border gives, to float32 rounding). By real FFTs padded by R (no wrap-around into the
    output), all three channels at once, the kernel's spectrum kept per kernel and size."""
    from scipy import fft as sfft

    h, w = src.shape[:2]
    R = kernel.shape[0] // 2
    step = SPREAD_SIZE_STEP
    shape = tuple(sfft.next_fast_len(-(-(n + R) // step) * step, real=True) for n in (h, w))
    spec = sfft.rfft2(np.moveaxis(src, -1, 0), s=shape, axes=(1, 2), workers=1)
    spec *= _kernel_spectrum(kernel, shape)
    out = sfft.irfft2(spec, s=shape, axes=(1, 2), workers=1)[:, :h, :w]
    return np.ascontiguousarray(np.moveaxis(out, 0, -1), dtype=np.float32)


def _kernel_spectrum(kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(3, shape[0], shape[1] // 2 + 1) complex: rfft2 of the kernel flipped (correlation as a
    convolution) with its centre at (0, 0), per channel; the last few kept (:data:`_SPECTRA`,
    keyed by the kernel's identity: :func:`cached_glow_kernel` hands out the same read-only array)."""
    from scipy import fft as sfft

    key = (id(kernel), shape)
    hit = _SPECTRA.get(key)
    if hit is not None and hit[0] is kernel:
        return hit[1]
    R = kernel.shape[0] // 2
    pad = np.zeros((3, *shape), np.float32)
    rows, cols = np.arange(-R, R + 1) % shape[0], np.arange(-R, R + 1) % shape[1]
    pad[:, rows[:, None], cols[None, :]] = np.moveaxis(kernel[::-1, ::-1], -1, 0)
    spectrum = sfft.rfft2(pad, axes=(1, 2), workers=1)
    if len(_SPECTRA) >= 8:
        _SPECTRA.pop(next(iter(_SPECTRA)))
    _SPECTRA[key] = (kernel, spectrum)
    return spectrum


_SPECTRA: dict = {}


def _forward_scatter_blur(
    img: np.ndarray, range_m, sigma_s_mean: float, px_per_tau: float, max_px: float, levels: int
) -> np.ndarray:
    """Blend ``levels`` Gaussian blurs of ``img`` (H, W, 3) by per-pixel sigma (hat weights).

    Level i has sigma ``i * max_px / (levels - 1)`` (level 0 = unblurred), each blurred
    from the previous one by the incremental sigma; kernels span +-3 sigma."""
    import cv2

    img = np.ascontiguousarray(img, dtype=np.float32)
    levels = max(2, int(levels))
    r = _clean_range(range_m, np.float32)
    sig = np.minimum(np.float32(max_px), np.float32(px_per_tau * sigma_s_mean) * r)
    step = max_px / (levels - 1)
    pos = sig / np.float32(step)  # fractional level index
    out = np.zeros_like(img)
    src, s_prev = img, 0.0
    for i in range(levels):
        s = i * step
        if s > 0:
            ds = math.sqrt(s * s - s_prev * s_prev)
            k = 2 * int(math.ceil(3 * ds)) + 1
            src = cv2.GaussianBlur(src, (k, k), ds, borderType=cv2.BORDER_REFLECT)
            s_prev = s
        wgt = 1 - np.abs(pos - np.float32(i))
        np.maximum(wgt, 0, out=wgt)
        if not wgt.any():
            continue
        cv2.accumulateProduct(src, cv2.cvtColor(wgt, cv2.COLOR_GRAY2BGR), out)
    return out
