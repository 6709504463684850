"""Water optical coefficients and the FAST underwater image-formation model.

Pure numpy (+ cv2 for the optional blur). Everything is per RGB channel, linear
radiance, metres.

Model (Akkaynak & Treibitz 2018 revised model with ``beta_D = beta_B = c``)::

    I = J_lit * exp(-c r) + B_depth * (1 - exp(-c r))
    J_lit   = J * exp(-Kd * depth)     on sunlit pixels, J on emissive pixels
    B_depth = B_inf * exp(-Kd * depth) (veiling light of sunlight at depth)

``J`` is the clean surfaces-only render with the sun at its surface-level
strength, ``r`` the range along the pixel ray (``geometry.planar_depth_to_range``;
``inf`` where no surface is hit), ``c = sigma_a + sigma_s`` the beam attenuation.
``model="article"`` is the article's form
``I = (1-w) J exp(-k depth) + w water_colour`` with ``w = 1 - exp(-beta r)``: the
same formula except that the water colour does not dim with depth.

Conventions chosen here:

- A channel with ``c == 0`` is left untouched at every range, including
  background pixels (``r = inf``): clear water is the identity, whatever the
  renderer gave the background. For ``c > 0`` background pixels become
  ``B_depth``.
- ``B_inf`` is in the units of ``J`` per unit surface irradiance; pass
  ``irradiance=`` (default 1) if ``J`` was rendered with another sun strength.
  For the article presets it is the water colour itself.

What the fast model misses (OPTICS.md), to be calibrated/published against the
reference Cycles renders:

- forward-scatter halo/blur energy (about +9% at 1 m with sigma_s 0.3): the
  optional blur here only redistributes the attenuated direct signal, it adds
  no forward-scattered energy;
- the multiple-scattering level of the veiling light (1.5-7x single scatter) and
  its dependence on view direction / sun elevation (``B_inf`` is one colour);
- depth falloff with ``Kd`` is the multiply-scattered limit; the reference with
  0 bounces attenuates the sun by ``c`` along its refracted path;
- volumetric shadows and light shafts (no 3-D light field here);
- backscatter cones/glow around artificial lights (LEDs, AUV lamp): emissive
  pixels are only attenuated along the camera ray;
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

from blendgen.physics import water_presets as wp

COEF_RANGE = (0.0, 5.0)          # sigma_a, sigma_s, beta, Kd (1/m)
G_RANGE = (-1.0, 1.0)            # open interval
COLOR_RANGE = (0.0, 1.0)         # water_color (linear RGB)
B_INF_RANGE = (0.0, 10.0)        # B_inf (radiance per unit surface irradiance)
FF_IOR_RANGE = (1.0, 1.5)        # Fournier-Forand relative particle index (open at 1)
FF_B_RANGE = (0.0, 0.5)          # Fournier-Forand backscatter fraction (open)
MODELS = ("revised", "article")
PHASES = ("hg", "ff")


@dataclass(frozen=True)
class WaterOptics:
    """Per-RGB water coefficients (1/m) and phase function.

    ``sigma_a``/``sigma_s`` absorption/scattering, ``Kd`` diffuse attenuation of
    downwelling light, ``B_inf`` veiling light (linear RGB, per unit surface
    irradiance), ``phase`` ``"hg"`` (Henyey-Greenstein ``g``) or ``"ff"``
    (Fournier-Forand ``ff_ior``, ``ff_backscatter``, as Blender's Volume Scatter
    node), ``model`` the default form used by :func:`apply_water`.
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
    model: str = "revised"
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

    def replace(self, **kw) -> "WaterOptics":
        return dataclasses.replace(self, **kw)

    def to_dict(self) -> dict:
        """JSON-friendly dict (for manifests); round-trips via water_from_config."""
        return {"name": self.name, "sigma_a": self.sigma_a.tolist(),
                "sigma_s": self.sigma_s.tolist(), "Kd": self.Kd.tolist(),
                "B_inf": self.B_inf.tolist(), "g": self.g, "phase": self.phase,
                "ff_ior": self.ff_ior, "ff_backscatter": self.ff_backscatter,
                "model": self.model, "provenance": self.provenance}


# --------------------------------------------------------------------------- validation

def _vec3(name: str, value, lo: float, hi: float, unit: str = "") -> np.ndarray:
    try:
        v = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or 3 numbers in [{lo:g}, {hi:g}]{unit}, "
                         f"got {value!r}") from None
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
    if w.model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {w.model!r}")


# --------------------------------------------------------------------------- presets

ARTICLE_PRESETS = tuple(wp.ARTICLE_BETAS)
JERLOV_PRESETS = tuple(f"jerlov_{t}" for t in wp.JERLOV_TYPES)
PRESETS = ARTICLE_PRESETS + JERLOV_PRESETS


def article_water(beta=0.0, water_color=wp.ARTICLE_WATER_COLOR, k=wp.ARTICLE_K,
                  albedo=None, name: str = "article", **kw) -> WaterOptics:
    """The article's water: ``c = beta``, ``B_inf = water_color``, depth light ``k``."""
    beta = _vec3("beta", beta, *COEF_RANGE, " 1/m")
    color = _vec3("water_color", water_color, *COLOR_RANGE)
    k = _vec3("k", k, *COEF_RANGE, " 1/m")
    if albedo is not None:
        albedo = _vec3("albedo", albedo, 0.0, 1.0)
    d = wp.article_coefficients(beta, color, k, albedo)
    d.setdefault("model", "article")
    d.update(kw)
    return WaterOptics(name=name, **d)


def _preset_key(name: str) -> str:
    s = str(name).strip()
    low = s.lower()
    if low in ARTICLE_PRESETS:
        return low
    t = low.replace("jerlov", "").strip(" _-").upper()
    if t in wp.JERLOV_TYPES:
        return f"jerlov_{t}"
    raise ValueError(f"unknown water preset {name!r}; known: {', '.join(PRESETS)}")


def get_preset(name: str) -> WaterOptics:
    """A named preset: 'clear', 'mild', 'moderate' or 'jerlov_<type>' (I..9C)."""
    key = _preset_key(name)
    if key in ARTICLE_PRESETS:
        return article_water(wp.ARTICLE_BETAS[key], name=key)
    d = dict(wp.jerlov_coefficients(key.split("_", 1)[1]))
    return WaterOptics(name=key, **d)


_CONFIG_KEYS = {"preset", "name", "sigma_a", "sigma_s", "beta", "albedo", "g", "phase",
                "ff_ior", "ff_backscatter", "water_color", "B_inf", "k", "Kd", "model",
                "provenance"} | {"calibrated", "blur"}   # the last two: fast-model options


def water_from_config(cfg: dict | None) -> WaterOptics:
    """Build :class:`WaterOptics` from a config mapping.

    ``{"preset": name}`` with optional overrides, or explicit coefficients:
    ``sigma_a``, ``sigma_s`` (3 or 1 numbers, [0, 5] 1/m), ``g`` in (-1, 1),
    ``phase`` ('hg'|'ff', with ``ff_ior`` (1, 1.5], ``ff_backscatter`` (0, 0.5)),
    ``water_color`` ([0, 1]) or ``B_inf`` ([0, 10]), ``k`` or ``Kd`` ([0, 5] 1/m),
    ``model`` ('revised'|'article'). The article's shorthand ``beta`` ([0, 5] 1/m,
    optional ``albedo`` in [0, 1]) builds ``c = beta`` with B_inf = water colour.
    Without a preset the base is 'clear'. Raises ValueError naming the key and
    its allowed range.
    """
    cfg = dict(cfg or {})
    unknown = sorted(set(cfg) - _CONFIG_KEYS)
    if unknown:
        raise ValueError(f"unknown water key(s) {unknown}; allowed: {sorted(_CONFIG_KEYS)}")
    for f in ("calibrated", "blur"):            # fast-model options (see fast_water)
        if f in cfg and not isinstance(cfg.pop(f), bool):
            raise ValueError(f"{f} must be true or false")
    for a, b in (("water_color", "B_inf"), ("k", "Kd"), ("beta", "sigma_a"), ("beta", "sigma_s")):
        if a in cfg and b in cfg:
            raise ValueError(f"give either {a!r} or {b!r}, not both")
    preset = cfg.get("preset") or "clear"
    key = _preset_key(preset)
    explicit = any(k in cfg for k in ("sigma_a", "sigma_s", "B_inf"))
    if "beta" in cfg and key not in ARTICLE_PRESETS:
        raise ValueError(f"'beta' applies to the article presets {ARTICLE_PRESETS}, not {key!r}; "
                         "give sigma_a/sigma_s instead")
    if key in ARTICLE_PRESETS:
        w = article_water(cfg.get("beta", wp.ARTICLE_BETAS[key]),
                          cfg.get("water_color", wp.ARTICLE_WATER_COLOR),
                          cfg.get("k", cfg.get("Kd", wp.ARTICLE_K)), cfg.get("albedo"), name=key)
    else:
        if "albedo" in cfg:
            raise ValueError("'albedo' only applies with 'beta' or an article preset")
        w = get_preset(key)
        if "water_color" in cfg:
            w = w.replace(B_inf=_vec3("water_color", cfg["water_color"], *COLOR_RANGE))
        if "k" in cfg or "Kd" in cfg:
            w = w.replace(Kd=_vec3("k" if "k" in cfg else "Kd", cfg.get("k", cfg.get("Kd")),
                                   *COEF_RANGE, " 1/m"))
    upd = {}
    for f in ("sigma_a", "sigma_s"):
        if f in cfg:
            upd[f] = _vec3(f, cfg[f], *COEF_RANGE, " 1/m")
    if "B_inf" in cfg:
        upd["B_inf"] = _vec3("B_inf", cfg["B_inf"], *B_INF_RANGE)
    for f in ("g", "phase", "ff_ior", "ff_backscatter", "name", "provenance"):
        if f in cfg:
            upd[f] = cfg[f]
    upd["model"] = cfg.get("model", "revised" if explicit else w.model)
    if explicit:
        upd.setdefault("name", f"{key}+custom" if cfg.get("preset") else "custom")
        upd.setdefault("provenance", f"config: explicit coefficients over preset {key!r}")
    if "g" in upd:
        upd["g"] = _scalar("g", upd["g"], *G_RANGE)
    return w.replace(**upd)


# --------------------------------------------------------------------------- calibration

#: Fast-model calibration against reference renders (``dockbench calibrate-water``).
CALIBRATION_PATH = Path(__file__).resolve().parents[1] / "data" / "water_calibration.json"
#: Sun irradiance assumed when a condition does not state it (spec.Scene default, W/m^2).
DEFAULT_IRRADIANCE = 3.0
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


def fast_water(cfg: dict | None, irradiance: float | None = None,
               calibration: dict | None = None) -> tuple[WaterOptics, dict]:
    """Water and ``apply_water`` options for the fast fidelity of one condition.

    A bare preset (``{"preset": name}`` plus the fast options) that the calibration
    lists gets the calibrated ``B_inf`` (per unit sun irradiance) and ``Kd``
    (effective depth-light coefficient) and the ``revised`` model, unless the config
    says ``calibrated: false``. ``blur: true|false`` switches the forward-scatter blur
    (default: the calibration's choice, else off). ``irradiance`` (the scene's sun,
    W/m^2; default :data:`DEFAULT_IRRADIANCE`) scales physical ``B_inf``; the
    article model's ``B_inf`` is a water colour and is used as is (irradiance 1).
    Returns ``(water, {"irradiance", "blur", "blur_rad_per_tau", "blur_max_rad",
    "calibrated"})``."""
    cfg = dict(cfg or {})
    want_cal = cfg.get("calibrated", True)
    water = water_from_config(cfg)
    cal = calibration if calibration is not None else load_calibration()
    entry = (cal.get("presets") or {}).get(_preset_key(cfg.get("preset") or "clear"))
    bare = set(cfg) <= {"preset", "calibrated", "blur"}
    use = bool(want_cal and entry and bare and not water.is_clear)
    if use:
        water = water.replace(B_inf=np.asarray(entry["B_inf"], float), Kd=np.asarray(entry["Kd"], float),
                              model="revised",
                              provenance=water.provenance + "; calibrated: " + str(cal.get("method", "")))
    blur_default = bool(entry.get("blur", False)) if use else False
    irr = DEFAULT_IRRADIANCE if irradiance is None else float(irradiance)
    return water, {"irradiance": 1.0 if water.model == "article" else irr,
                   "blur": bool(cfg.get("blur", blur_default)), "calibrated": use,
                   "blur_rad_per_tau": BLUR_RAD_PER_TAU, "blur_max_rad": BLUR_MAX_RAD}


# --------------------------------------------------------------------------- phase functions

def hg_phase(cos_theta, g: float):
    """Henyey-Greenstein phase function (1/sr, integrates to 1 over 4 pi)."""
    mu = np.asarray(cos_theta, float)
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def _ff_delta(theta, n):
    return 4.0 / (3.0 * (n - 1.0) ** 2) * np.sin(np.asarray(theta, float) / 2.0) ** 2


def _ff_backscatter_fraction(nu: float, n: float) -> float:
    d90 = float(_ff_delta(np.pi / 2, n))
    return 1.0 - (1.0 - d90 ** (nu + 1) - 0.5 * (1.0 - d90 ** nu)) / ((1.0 - d90) * d90 ** nu)


def ff_nu(ior: float, backscatter: float) -> float:
    """Fournier-Forand slope parameter nu = (3 - mu)/2 giving ``backscatter`` at ``ior``."""
    from scipy.optimize import brentq
    f = lambda nu: _ff_backscatter_fraction(nu, ior) - backscatter  # noqa: E731
    lo, hi = -0.9999, -1e-6     # nu < 0 for Junge slopes mu in (3, 5)
    if f(lo) * f(hi) > 0:
        raise ValueError(f"no Fournier-Forand slope gives backscatter {backscatter} at IOR {ior}")
    return brentq(f, lo, hi, xtol=1e-12)


def ff_phase(theta, ior: float = 1.1, backscatter: float = 0.0183):
    """Fournier-Forand phase function (Mobley et al. 2002 form), 1/sr, at angle theta (rad)."""
    nu = ff_nu(ior, backscatter)
    th = np.clip(np.asarray(theta, float), 1e-9, np.pi)
    d = _ff_delta(th, ior)
    d180 = float(_ff_delta(np.pi, ior))
    dn = d ** nu
    s2 = np.sin(th / 2.0) ** 2
    p = (nu * (1 - d) - (1 - dn) + (d * (1 - dn) - nu * (1 - d)) / s2) / (4 * np.pi * (1 - d) ** 2 * dn)
    p += (1 - d180 ** nu) / (16 * np.pi * (d180 - 1) * d180 ** nu) * (3 * np.cos(th) ** 2 - 1)
    return p


def phase_value(water: WaterOptics, theta_rad: float) -> float:
    """The water's phase function (1/sr) at scattering angle ``theta_rad``."""
    if water.phase == "ff":
        return float(ff_phase(theta_rad, water.ff_ior, water.ff_backscatter))
    return float(hg_phase(math.cos(theta_rad), water.g))


# --------------------------------------------------------------------------- analytic scatter

def single_scatter_backscatter(sigma_a, sigma_s, g: float = 0.0, E=1.0, depth_m=0.0,
                               range_m=np.inf, theta_deg: float = 90.0, sun_c=None,
                               phase_fn=None):
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
    grow = np.where(c > 0, -np.expm1(-c * zf) / safe_c, zf)   # (1 - e^{-cz})/c, -> z as c -> 0
    grow = np.where(np.isinf(z), np.where(c > 0, 1.0 / safe_c, 0.0), grow)
    return ss * p * np.asarray(E, float) * np.exp(-c_sun * depth_m) * grow


def veiling_light(water: WaterOptics, E=1.0, depth_m=0.0, theta_deg: float = 90.0, sun_c=None):
    """Single-scatter ``B_inf`` (3,) of ``water`` (its own phase function)."""
    return single_scatter_backscatter(water.sigma_a, water.sigma_s, water.g, E, depth_m,
                                      np.inf, theta_deg, sun_c,
                                      phase_fn=lambda t: phase_value(water, t))


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
        r = np.fmin(r, dtype(big))                   # NaN, +inf -> big; -inf -> 0 below
    if (r < 0).any():
        r = np.maximum(r, dtype(0))
    return r


def depth_light(water: WaterOptics, depth_m) -> np.ndarray:
    """Downwelling light fraction ``exp(-Kd depth)``: (3,) for scalar depth, (..., 3) else."""
    d = np.asarray(depth_m, float)
    if np.any(d < 0) or np.any(~np.isfinite(d)):
        raise ValueError(f"depth_m must be finite and >= 0 (metres below the surface)")
    return np.exp(-water.Kd * d[..., None]) if d.ndim else np.exp(-water.Kd * float(d))


def transmittance(water: WaterOptics, range_m: np.ndarray, dtype=np.float32) -> np.ndarray:
    """``exp(-c r)`` (H, W, 3); exactly 1 in channels with c == 0 (inf range included)."""
    r = _clean_range(range_m, dtype)
    h, w = r.shape
    x = _gray3(r)
    with np.errstate(over="ignore"):           # huge range * c -> -inf -> exp 0
        x *= _row(-water.c, w, dtype)
        np.exp(x, out=x)
    return x.reshape(h, w, 3)


def apply_water(J: np.ndarray, range_m: np.ndarray, emissive_mask=None,
                water: WaterOptics | None = None, depth_m=0.0, *, model: str | None = None,
                irradiance=1.0, blur: bool = False, blur_px_per_tau: float = 2.0,
                blur_max_px: float = 3.0, blur_levels: int = 4) -> np.ndarray:
    """Fast underwater image formation (module docstring) on a clean render.

    J (H, W, 3) float32/float64 linear; range_m (H, W) metres along the ray (inf or
    NaN: no surface); emissive_mask (H, W) bool or None (self-lit pixels keep their
    brightness at depth); depth_m water depth of the lit surfaces, scalar or (H, W);
    model 'revised' | 'article' (default ``water.model``); irradiance scales B_inf.
    blur: range-dependent forward-scatter Gaussian on the direct term, sigma_px =
    min(blur_max_px, blur_px_per_tau * mean(sigma_s) * r), ``blur_levels``
    precomputed cv2.GaussianBlur levels blended linearly by sigma.
    Returns a new (H, W, 3) array of J's dtype (float32 unless J is float64).
    """
    water = water if water is not None else get_preset("clear")
    model = model or water.model
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    J = np.asarray(J)
    dtype = np.float64 if J.dtype == np.float64 else np.float32
    if J.ndim != 3 or J.shape[2] != 3:
        raise ValueError(f"J must be (H, W, 3), got {J.shape}")
    h, w = J.shape[:2]
    if np.shape(range_m) != (h, w):
        raise ValueError(f"range_m must be {(h, w)}, got {np.shape(range_m)}")
    J2 = np.ascontiguousarray(J, dtype=dtype).reshape(h, 3 * w)
    t = transmittance(water, range_m, dtype).reshape(h, 3 * w)

    depth = np.asarray(depth_m, float)
    if depth.ndim == 0:
        D = _row(depth_light(water, float(depth)), w, dtype)             # (1, 3W)
    else:
        if depth.shape != (h, w):
            raise ValueError(f"depth_m must be a scalar or {(h, w)}, got {depth.shape}")
        if np.any(depth < 0) or not np.isfinite(depth).all():
            raise ValueError("depth_m must be finite and >= 0 (metres below the surface)")
        D = _gray3(depth.astype(dtype)) * _row(-water.Kd, w, dtype)
        np.exp(D, out=D)                                                   # (H, 3W)

    em = None if emissive_mask is None else np.asarray(emissive_mask, bool)
    if em is not None and em.shape != (h, w):
        raise ValueError(f"emissive_mask must be {(h, w)}, got {em.shape}")
    direct = J2 * D                                   # J_lit: sunlit surfaces dim with depth
    if em is not None and em.any():
        direct.reshape(h, w, 3)[em] = J2.reshape(h, w, 3)[em]   # self-lit: not dimmed
    irr = float(irradiance)
    if not (math.isfinite(irr) and irr >= 0):
        raise ValueError(f"irradiance must be finite and >= 0, got {irradiance!r}")
    B = _row(water.B_inf * irr, w, dtype)
    if model == "revised":
        B = B * D                                     # veiling light dims with depth
    has_b = bool(np.any(B != 0))
    if blur and np.any(water.sigma_s > 0) and blur_max_px > 0:
        direct *= t                                   # J_lit exp(-c r), then blurred
        direct = _forward_scatter_blur(direct.reshape(h, w, 3), range_m,
                                       float(np.mean(water.sigma_s)), blur_px_per_tau,
                                       blur_max_px, blur_levels
                                       ).astype(dtype, copy=False).reshape(h, 3 * w)
        if has_b:
            np.subtract(dtype(1), t, out=t)
            t *= B
            direct += t                               # + B (1 - exp(-c r))
    elif has_b:
        direct *= t                                   # J_lit exp(-c r)
        np.subtract(dtype(1), t, out=t)               # 1 - exp(-c r), in place
        t *= B
        direct += t                                   # + B (1 - exp(-c r)); exact J at c = 0
    else:
        direct *= t
    out = direct
    return out.reshape(h, w, 3)


def _forward_scatter_blur(img: np.ndarray, range_m, sigma_s_mean: float, px_per_tau: float,
                          max_px: float, levels: int) -> np.ndarray:
    """Blend ``levels`` Gaussian blurs of ``img`` (H, W, 3) by per-pixel sigma (hat weights).

    Level i has sigma ``i * max_px / (levels - 1)`` (level 0 = unblurred), each blurred
    from the previous one by the incremental sigma; kernels span +-3 sigma."""
    import cv2

    img = np.ascontiguousarray(img, dtype=np.float32)
    levels = max(2, int(levels))
    r = _clean_range(range_m, np.float32)
    sig = np.minimum(np.float32(max_px), np.float32(px_per_tau * sigma_s_mean) * r)
    step = max_px / (levels - 1)
    pos = sig / np.float32(step)                      # fractional level index
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
