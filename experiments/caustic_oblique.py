"""Fast caustics vs the Cycles photon map under an oblique sun, clear water, floor 1 m down
(docs/evidence/README.md, "Oblique sun"): mean irradiance, contrast, correlation and cell size
at sun zenith angles 0, 20, 40, 60 deg (768 px x 2 renders each; maps cached in WORK_DIR).

    python experiments/caustic_oblique.py WORK_DIR   (~1 min)"""

import sys
from pathlib import Path

from blendgen.tools.bench import caustic_bench as cb


def main(work: Path) -> None:
    water = cb.water_of(None)
    for zenith in (0.0, 20.0, 40.0, 60.0):
        spec = cb.reference_spec(1.0, water, 768, 2, sun_zenith_deg=zenith)
        r = cb.compare(cb.run_reference(spec, work / f"ref-sun{zenith:g}.npz"), spec, water)
        print(
            f"zenith {zenith:4.0f} deg: mean E ref {r['meanE_ref']:.4f} fast {r['meanE_fast']:.4f}  contrast ref "
            f"{r['contrast_ref']:.3f} fast {r['contrast_fast']:.3f}  corr {r['corr']:.2f}  cell ref "
            f"{r['cell_m_ref']:.3f} fast {r['cell_m_fast']:.3f} m",
            flush=True,
        )


if __name__ == "__main__":
    main(Path(sys.argv[1]))
