"""The water presets beside their source's numbers: ``python -m blendgen.tools.apps.water_table``.

For every Jerlov type, the source spectra (``jerlov`` package: Kd of Jerlov 1976, a and b of
Solonenko & Mobley 2015, a of Williamson & Hollins 2022 where Solonenko & Mobley have none)
at the printed wavelengths each RGB channel averages (``water_presets.RGB_BANDS_NM``), then
the preset's channel values; then the article levels and the Jerlov type each is in the
physical mode. Markdown on stdout.
"""

from __future__ import annotations

import warnings

import numpy as np

from blendgen.physics.water import presets as wp

WAVELENGTHS_NM = sorted({w for band in wp.RGB_BANDS_NM.values() for w in band})


def _source_rows(t: str) -> list[str]:
    """Source values (1/m) at :data:`WAVELENGTHS_NM` of Kd, a, b for type ``t``."""
    import jerlov

    wl = np.array(WAVELENGTHS_NM)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jerlov.ProvenanceWarning)
        kd = jerlov.water(t, "jerlov1976").kd(wl)
        sm = jerlov.water(t, "solonenko2015")
        a, b = sm.a(wl), sm.b(wl)
    fmt = lambda v: " ".join("  nan" if np.isnan(x) else f"{x:5.3f}" for x in v)  # noqa: E731
    return [f"| {t} | Kd | {fmt(kd)} |", f"| {t} | a | {fmt(a)} |", f"| {t} | b | {fmt(b)} |"]


def source_table() -> str:
    """Markdown: the source spectra at the channel wavelengths."""
    head = "| type | quantity | " + " ".join(f"{w:.0f}" for w in WAVELENGTHS_NM) + " nm |"
    lines = [head, "|---|---|---|"]
    for t in wp.JERLOV_TYPES:
        lines += _source_rows(t)
    return "\n".join(lines)


def preset_table() -> str:
    """Markdown: each preset's R/G/B a, b, c, Kd and g (what dockbench uses)."""
    lines = ["| preset | a R/G/B | b R/G/B | c R/G/B | Kd R/G/B | g |", "|---|---|---|---|---|---|"]
    f3 = lambda v: "/".join(f"{x:.3f}" for x in v)  # noqa: E731
    for t in wp.JERLOV_TYPES:
        d = wp.jerlov_coefficients(t)
        lines.append(
            f"| jerlov_{t} | {f3(d['sigma_a'])} | {f3(d['sigma_s'])} | {f3(d['sigma_a'] + d['sigma_s'])} "
            f"| {f3(d['Kd'])} | {d['g']:.2f} |"
        )
    return "\n".join(lines)


def article_table() -> str:
    """Markdown: the article levels, their grey c and the Jerlov type of nearest per-channel c."""
    lines = [
        "| article level | beta (1/m, grey) | physical mode: Jerlov type | RMS ln(c_type / beta) | runner-up |",
        "|---|---|---|---|---|",
    ]
    for name, beta in wp.ARTICLE_BETAS.items():
        t = wp.ARTICLE_JERLOV[name]
        if beta <= 0:
            lines.append(f"| {name} | 0 | {t} (the clearest type: beta 0 is no water) | - | - |")
            continue
        ranked = sorted(
            (float(np.sqrt(np.mean(np.log((d["sigma_a"] + d["sigma_s"]) / beta) ** 2))), k)
            for k, d in ((k, wp.jerlov_coefficients(k)) for k in wp.JERLOV_TYPES)
        )
        lines.append(f"| {name} | {beta:g} | {t} | {ranked[0][0]:.2f} | {ranked[1][1]} ({ranked[1][0]:.2f}) |")
    return "\n".join(lines)


def main() -> None:
    print("## Source spectra (jerlov package) at the channel wavelengths, 1/m\n")
    print(source_table())
    print("\n## Presets: R = mean of 600/625/650 nm, G = 525/550, B = 450/475\n")
    print(preset_table())
    print("\n## Article levels in physical mode\n")
    print(article_table())


if __name__ == "__main__":
    main()
