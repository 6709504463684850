"""Contact sheet of `dockbench bench caustics` maps: Cycles photon map | fast caustics, per water and depth.

Usage: PYTHONPATH=. python experiments/caustics_reference_sheet.py OUT_DIR_OF_BENCH SHEET.jpg
(E / mean E, gamma 1/2.2, 0..3 mapped to black..white; 96 x 96 bins of the 2 x 2 m floor patch)."""

import json
import sys

import cv2
import numpy as np

from blendgen.tools.bench import caustic_bench as cb


def tile(M):
    u = (np.clip(M / 3.0, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)[::-1]  # +y up
    return cv2.resize(u, (192, 192), interpolation=cv2.INTER_NEAREST)


def main(src: str, out: str, waters=("IB", "1C"), depths=(1.0, 2.0, 4.0, 8.0)) -> None:
    rows = []
    for name in waters:
        wat, cells = cb.water_of(name), []
        for h in depths:
            ref = np.load(f"{src}/ref-{name}-{h:g}m.npz")
            spec = json.loads(str(ref["spec"]))
            pair = np.hstack(
                [
                    tile(ref["E"] / ref["E"].mean()),
                    np.full((192, 4), 255, np.uint8),
                    tile(cb.fast_map(spec, wat["sigma_s"], wat["g"])),
                ]
            )
            pair = cv2.copyMakeBorder(pair, 22, 6, 6, 6, cv2.BORDER_CONSTANT, value=255)
            cv2.putText(pair, f"{name} {h:g} m: Cycles | fast", (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, 0, 1)
            cells.append(pair)
        rows.append(np.hstack(cells))
    cv2.imwrite(out, np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 85])


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
