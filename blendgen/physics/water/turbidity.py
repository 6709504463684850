"""Water from a turbidity reading: a Secchi depth or a nephelometer's NTU (pure numpy + ``jerlov``).

A reading gives one number in the green, where both instruments look (the eye's photopic
peak; nephelometers are calibrated in formazin units, ISO 7027 / EPA 180.1). It is turned
into a green quantity by a cited rule (``c_G + Kd_G`` for a Secchi depth, ``b_G`` for
NTU), then into a whole RGB water by following the ladder of Jerlov types (:data:`LADDER`,
ordered by turbidity) to the place where that quantity has that value: every coefficient (a, b, Kd
per channel, and g) is interpolated between the two neighbouring types, geometrically for
the coefficients, with the weight at which the blend's green quantity is the reading's. The spectral shape is thus
that of real water of
about that clarity, not a grey scale.

Rules and their uncertainty (docs/waters.md):

- Secchi depth ``Z_SD`` (m): Tyler (1968), ``(c + Kd) Z_SD = Gamma`` with ``Gamma`` about
  8.7 (the disc's inherent contrast against the eye's threshold). Preisendorfer (1986)
  shows ``Gamma`` varies with the disc, the sun and the observer (about 6-9): ``c + Kd``
  is known to about +-30 %. (Poole & Atkins 1929, ``Kd Z_SD`` about 1.7, range 1.32-2.18,
  is the older rule for Kd alone; along the ladder it gives Secchi depths 10-40 % deeper.)
- Turbidity ``T_n`` (NTU): Kirk (1994, *Light and Photosynthesis in Aquatic Ecosystems*,
  sec. 4.2): in turbid waters ``b / T_n`` is about 1 m^-1 NTU^-1, so ``b_G = 1.0 T_n``. The
  ratio depends on the particles and the instrument: a factor of 2 either way.

Readings beyond the ladder (clearer than Jerlov I, more turbid than 9C) are refused with
the allowed range: the coefficients outside it are not tabulated.
"""

from __future__ import annotations

import functools

import numpy as np

from blendgen.physics.water import presets as wp

#: Jerlov types ordered by turbidity, strictly increasing green c and b (III, an oceanic type
#: as turbid as 3C, is left out so that the ladder is one line of waters).
LADDER = ("I", "IA", "IB", "II", "1C", "3C", "5C", "7C", "9C")
#: Tyler (1968): (c + Kd) Z_SD = Gamma.
SECCHI_GAMMA = 8.7
#: Kirk (1994): b / T_n in m^-1 NTU^-1.
NTU_B_PER_NTU = 1.0
GREEN = 1


def cKd_green_from_secchi(secchi_m: float) -> float:
    """Green c + Kd (1/m) of a Secchi depth (m): Gamma / Z_SD."""
    return SECCHI_GAMMA / float(secchi_m)


def b_green_from_ntu(ntu: float) -> float:
    """Green scattering coefficient b_G (1/m) of a nephelometric turbidity (NTU)."""
    return NTU_B_PER_NTU * float(ntu)


@functools.cache
def _ladder(quantity: str) -> np.ndarray:
    """(len(LADDER),) green c + Kd (``"cKd"``) or b (``"b"``) of each ladder type, 1/m."""
    return np.array([_green(wp.jerlov_coefficients(t), quantity) for t in LADDER])


def reading_range(kind: str) -> tuple[float, float]:
    """The readings (lo, hi) the ladder covers: ``secchi_m`` in m, ``ntu`` in NTU."""
    if kind == "secchi_m":
        q = _ladder("cKd")
        return SECCHI_GAMMA / q[-1], SECCHI_GAMMA / q[0]
    b = _ladder("b")
    return b[0] / NTU_B_PER_NTU, b[-1] / NTU_B_PER_NTU


def _blend(i: int, w: float) -> dict:
    """a, b, Kd (3,) geometric and g linear between ladder types i and i + 1 (weight w)."""
    lo_d, hi_d = (wp.jerlov_coefficients(t) for t in LADDER[i : i + 2])
    out = {k: np.exp((1 - w) * np.log(lo_d[k]) + w * np.log(hi_d[k])) for k in ("sigma_a", "sigma_s", "Kd")}
    out["g"] = (1 - w) * lo_d["g"] + w * hi_d["g"]
    return out


def _green(d: dict, quantity: str) -> float:
    v = d["sigma_a"] + d["sigma_s"] + d["Kd"] if quantity == "cKd" else d["sigma_s"]
    return float(v[GREEN])


def _interpolate(quantity: str, value: float) -> tuple[int, float]:
    """Index i and weight w in [0, 1] such that the blend of types i, i + 1 (:func:`_blend`)
    has exactly ``value`` as its green quantity (bisection: it grows with w)."""
    q = _ladder(quantity)
    i = int(np.clip(np.searchsorted(q, value) - 1, 0, len(q) - 2))
    lo, hi = 0.0, 1.0
    for _ in range(50):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if _green(_blend(i, mid), quantity) < value else (lo, mid)
    return i, (lo + hi) / 2


def _target(kind: str, value: float) -> tuple[str, float]:
    """(ladder quantity, its green value in 1/m) of a reading."""
    if kind == "secchi_m":
        return "cKd", cKd_green_from_secchi(value)
    return "b", b_green_from_ntu(value)


def ladder_type(kind: str, value: float) -> str:
    """The clearer of the two ladder types a reading lies between."""
    return LADDER[_interpolate(*_target(kind, value))[0]]


def water_from_reading(kind: str, value: float) -> dict:
    """sigma_a, sigma_s, Kd (3,), g, B_inf (3,), provenance of a ``secchi_m`` or ``ntu`` reading.

    Raises ValueError naming the allowed range when the reading is beyond the ladder."""
    lo, hi = reading_range(kind)
    if not lo <= value <= hi:
        unit = "m" if kind == "secchi_m" else "NTU"
        raise ValueError(
            f"{kind} {value:g} is outside the Jerlov ladder I..9C; allowed {lo:.3g} <= {kind} <= {hi:.3g} {unit}"
        )
    quantity, target = _target(kind, value)
    rule = (
        f"(c + Kd)_G = {SECCHI_GAMMA:g} / Z_SD (Tyler 1968; +-30 %)"
        if kind == "secchi_m"
        else f"b_G = {NTU_B_PER_NTU:g} x NTU (Kirk 1994; factor 2)"
    )
    i, w = _interpolate(quantity, target)
    out = _blend(i, w)
    out["B_inf"] = out["sigma_s"] * wp.hg_phase_90(out["g"]) / (out["sigma_a"] + out["sigma_s"])
    out["provenance"] = (
        f"{kind} {value:g}: {rule} = {target:.3g} 1/m; between Jerlov {LADDER[i]} and "
        f"{LADDER[i + 1]} (weight {w:.2f}, geometric in a, b, Kd)"
    )
    return out
