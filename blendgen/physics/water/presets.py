"""Per-RGB water coefficients for the named presets (pure numpy + ``jerlov``).

Two families, both returned as plain dicts that :mod:`blendgen.physics.water.optics` turns into
:class:`~blendgen.physics.water.optics.WaterOptics`:

**The article's levels** (``clear`` / ``mild`` / ``moderate``): a single
turbidity ``beta`` (0, 0.2, 0.5 1/m) blended toward a greenish water colour,
``w = 1 - exp(-beta d)``, plus depth light ``exp(-k depth)`` with ``k = 0.2``.
Mapped to the physical model as ``c = beta`` in every channel and
``B_inf = water colour``. So that the reference Cycles medium can be built from
the same numbers, ``beta`` is split into scattering and absorption with a
per-channel single-scattering albedo proportional to the water colour:
``omega_c = ARTICLE_ALBEDO_MAX * colour_c / max(colour)``,
``sigma_s = omega * beta``, ``sigma_a = (1 - omega) * beta``. With a white sun,
single-scattered veiling light is then proportional to ``sigma_s/c = omega``,
i.e. it has the water's colour, while ``c`` stays ``beta`` in all channels.
``ARTICLE_ALBEDO_MAX = 0.8`` is our choice (turbid coastal/harbour water has
``b/c`` about 0.7-0.9); the article gives no albedo. The numeric water colour is
also our choice (the article only says "greenish"): linear RGB
``ARTICLE_WATER_COLOR``.

**Jerlov types** (``jerlov_I`` ... ``jerlov_9C``): spectra from the ``jerlov``
package (v0.22.0), reduced to RGB with a *band-sampled* camera response: each
channel is the equal-weight mean of the coefficient at Jerlov's printed
wavelengths R = 600/625/650 nm, G = 525/550 nm, B = 450/475 nm (exactly the
convention of Jerlov's printed Kd table; a comb response, no interpolation between
tabulated points). Sources:

- ``Kd``: Jerlov (1976) *Marine Optics* Table XXVII (``source="jerlov1976"``,
  measured).
- ``sigma_a = a``, ``sigma_s = b``: Solonenko & Mobley (2015)
  (``source="solonenko2015"``: a and b inverted from Kd, all ten types). Their
  Table 7 has no ``a`` for 5C at 600-700 nm; for 5C red we use the *measured*
  ``a`` of Williamson & Hollins (2022) (``source="williamson2022"``) and record
  it in ``provenance``.
- phase: Henyey-Greenstein with ``g = PARTICLE_G * b_p / b`` (summed over the
  three channels), ``b_p = b - b_w`` with ``b_w`` pure sea-water scattering
  (``jerlov.pure_water_scattering``, Morel, nearly isotropic): clear ocean water
  scatters mostly like pure water (g ~ 0.3 for type I), turbid water like
  particles (g -> 0.92, Petzold's mean cosine).
- ``B_inf``: single-scattering veiling light per unit surface irradiance for a
  horizontal view with the sun straight down, ``sigma_s p_HG(90 deg) / c``
  (see :func:`blendgen.physics.water.optics.single_scatter_backscatter`). This is what the
  reference medium gives with 0 volume bounces; multiple scattering raises it
  1.5-7x (docs/water.md). Calibrate it against reference renders before use.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np

#: Jerlov's printed wavelengths used for each channel (nm) (Jerlov 1976, Table XXVII).
RGB_BANDS_NM = {"R": (600.0, 625.0, 650.0), "G": (525.0, 550.0), "B": (450.0, 475.0)}

JERLOV_TYPES = ("I", "IA", "IB", "II", "III", "1C", "3C", "5C", "7C", "9C")

#: Petzold average-particle mean scattering cosine (Petzold 1972: about 0.92).
PARTICLE_G = 0.92

#: The article's levels: turbidity beta (1/m) for each named condition.
ARTICLE_BETAS = {"clear": 0.0, "mild": 0.2, "moderate": 0.5}
#: The article's typical depth-light coefficient k (1/m).
ARTICLE_K = 0.2
#: The real water each article level is in the ``physical`` mode: the Jerlov type whose
#: per-channel beam attenuation c (RGB band means) is nearest the article's grey ``beta``
#: (:func:`nearest_jerlov_type`: RMS of ln(c_type / beta) over R, G, B; mild -> IB at 0.65,
#: moderate -> II at 0.12, 1C next at 0.14). The article's clear (beta 0, no water at all) is
#: the clearest type, I. A bare article preset in physical mode is that type's water (a, b,
#: Kd, g), so a red LED fades as in real water; docs/waters.md has the table.
ARTICLE_JERLOV = {"clear": "I", "mild": "IB", "moderate": "II"}
#: Depth light (per-channel Kd) of an article level whose coefficients are given (``beta`` or
#: ``sigma_a``/``sigma_s``: the article's grey water kept) in the ``physical`` mode: the Jerlov
#: type of about its beam attenuation and colour (our choice, by c and the greenish colour:
#: clear -> oceanic I, mild (0.2/m) -> oceanic II, moderate (0.5/m) -> coastal 1C).
ARTICLE_KD_JERLOV = {"clear": "I", "mild": "II", "moderate": "1C"}
#: Greenish water colour, linear RGB (our choice; the article names no numbers).
ARTICLE_WATER_COLOR = (0.03, 0.20, 0.15)
#: Single-scattering albedo of the brightest channel of the article's water.
ARTICLE_ALBEDO_MAX = 0.8


def article_coefficients(beta, water_color=ARTICLE_WATER_COLOR, k=ARTICLE_K, albedo=None) -> dict:
    """sigma_a, sigma_s, Kd, B_inf (3,) for the article's model.

    ``beta`` scalar or (3,) in 1/m; ``albedo`` None -> proportional to the water
    colour with maximum :data:`ARTICLE_ALBEDO_MAX`, else scalar or (3,) in [0, 1].
    """
    beta = np.broadcast_to(np.asarray(beta, float), (3,)).copy()
    color = np.broadcast_to(np.asarray(water_color, float), (3,)).copy()
    if albedo is None:
        peak = float(color.max())
        omega = ARTICLE_ALBEDO_MAX * color / peak if peak > 0 else np.zeros(3)
    else:
        omega = np.broadcast_to(np.asarray(albedo, float), (3,)).copy()
    kd = np.broadcast_to(np.asarray(k, float), (3,)).copy()
    return {
        "sigma_a": (1.0 - omega) * beta,
        "sigma_s": omega * beta,
        "Kd": kd,
        "B_inf": color,
        "g": 0.9,
        "provenance": "article: c = beta, B_inf = water colour, "
        "sigma_s = albedo*beta with albedo ~ colour (max "
        f"{ARTICLE_ALBEDO_MAX})",
    }


def _band_means(fn) -> np.ndarray:
    """(3,) equal-weight means of fn(wavelengths) over :data:`RGB_BANDS_NM`."""
    return np.array([float(np.mean(fn(np.array(wl)))) for wl in RGB_BANDS_NM.values()])


def nearest_jerlov_type(c_rgb) -> tuple[str, float]:
    """The Jerlov type whose beam attenuation c (3,) is nearest ``c_rgb`` (3,), 1/m, > 0, and
    the distance: RMS over R, G, B of ln(c_type / c_rgb) (logarithms, as
    ``jerlov.classify_kd`` ranks Kd spectra: 10 % counts alike in clear and turbid water)."""
    target = np.broadcast_to(np.asarray(c_rgb, float), (3,))
    if not np.all(target > 0):
        raise ValueError(f"c must be > 0 in every channel to compare on a log scale, got {target}")
    best = min(
        (float(np.sqrt(np.mean(np.log((d["sigma_a"] + d["sigma_s"]) / target) ** 2))), t)
        for t, d in ((t, jerlov_coefficients(t)) for t in JERLOV_TYPES)
    )
    return best[1], best[0]


def hg_phase_90(g: float) -> float:
    """Henyey-Greenstein phase (1/sr, normalised over 4 pi) at 90 degrees."""
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g) ** 1.5)


@functools.cache
def jerlov_coefficients(water_type: str) -> dict:
    """RGB sigma_a, sigma_s, Kd, g, B_inf for a Jerlov type (see module docstring)."""
    import jerlov  # lazy: ~50 ms of CSV parsing, only when a Jerlov preset is used

    if water_type not in JERLOV_TYPES:
        raise KeyError(f"unknown Jerlov type {water_type!r} (known: {', '.join(JERLOV_TYPES)})")
    notes = ["Kd: jerlov1976 (Jerlov 1976 Table XXVII)", "a, b: solonenko2015 (Solonenko & Mobley 2015)"]
    with warnings.catch_warnings():
        # Provenance warnings are about flagged samples; the ones we use are
        # recorded below from the sources' caveats instead.
        warnings.simplefilter("ignore", jerlov.ProvenanceWarning)
        kd = _band_means(jerlov.water(water_type, "jerlov1976").kd)
        sm = jerlov.water(water_type, "solonenko2015")
        a = _band_means(sm.a)
        b = _band_means(sm.b)
        if np.isnan(a).any():
            wh = jerlov.water(water_type, "williamson2022")
            a_w = _band_means(wh.a)
            for i in np.flatnonzero(np.isnan(a)):
                a[i] = a_w[i]
                notes.append(f"a[{'RGB'[i]}]: williamson2022 (measured; solonenko2015 has no a there)")
        b_w = _band_means(jerlov.pure_water_scattering)
    if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(kd).all()):
        raise RuntimeError(f"Jerlov {water_type}: missing coefficients a={a} b={b} Kd={kd}")
    b_p = np.clip(b - b_w, 0.0, None)
    g = PARTICLE_G * float(b_p.sum() / b.sum())
    c = a + b
    b_inf = b * hg_phase_90(g) / c
    return {
        "sigma_a": a,
        "sigma_s": b,
        "Kd": kd,
        "g": g,
        "B_inf": b_inf,
        "provenance": "; ".join(notes) + "; RGB = mean at R 600/625/650, "
        "G 525/550, B 450/475 nm; g = 0.92*b_p/b; "
        "B_inf = single-scatter sigma_s p_HG(90)/c per unit sun",
    }


#: Every preset name, as :func:`preset_key` spells it.
PRESETS = tuple(ARTICLE_BETAS) + tuple(f"jerlov_{t}" for t in JERLOV_TYPES)


def preset_key(name) -> str:
    """Canonical preset name: 'clear' | 'mild' | 'moderate' | 'jerlov_<type>' (case and
    'Jerlov II' / 'jerlov-ii' spellings accepted). Raises ValueError listing the known ones."""
    low = str(name).strip().lower()
    if low in ARTICLE_BETAS:
        return low
    t = low.replace("jerlov", "").strip(" _-").upper()
    if t in JERLOV_TYPES:
        return f"jerlov_{t}"
    raise ValueError(f"unknown water preset {name!r}; known: {', '.join(PRESETS)}")
