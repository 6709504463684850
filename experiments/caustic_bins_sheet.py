"""Contact sheet: the held-in clear approach (bench fidelity's set) in rows, one per dataset,
at four frames, each row labelled with its name and the LED localizer's verdict per frame.

    python experiments/caustic_bins_sheet.py OUT.jpg FRAMES NAME=DATASET [NAME=DATASET ...]

FRAMES: comma-separated frame indices (e.g. 0,3,6,9). The datasets: the fast path and the
reference renders of ``tools/bench/fidelity.held_in_experiment(320, 240, 12, ["clear"], ...)``."""

import sys
from pathlib import Path

import cv2
import numpy as np

from evalkit import registry, runner
from evalkit.dataset import Dataset


def row(name: str, path: Path, frames: list[int]) -> np.ndarray:
    ds = Dataset.open(path)
    seq = next(s for s in ds.sequences if s["condition"] == "clear")
    recs = list(ds.iter_frames(seq["id"]))
    df = runner.evaluate(ds, [("led", registry.resolve("led", {}))], progress=False)
    ok = df[df["condition"] == "clear"].set_index("index")["success"]
    tiles = []
    for f in frames:
        img = cv2.cvtColor(ds.load_image(recs[f]), cv2.COLOR_RGB2BGR)
        label = f"{name}  {recs[f]['d_true']:.1f} m  LED {'ok' if ok.get(recs[f]['index'], False) else 'fail'}"
        cv2.putText(img, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(img)
    return np.hstack(tiles)


def main(argv: list[str]) -> None:
    out, frames = argv[1], [int(x) for x in argv[2].split(",")]
    rows = [row(*a.split("=", 1)[:1], Path(a.split("=", 1)[1]), frames) for a in argv[3:]]
    cv2.imwrite(out, np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 88])


if __name__ == "__main__":
    main(sys.argv)
