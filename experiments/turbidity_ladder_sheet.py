"""Contact sheet of a turbidity-ladder dataset: rows = waters (Jerlov I ... 9C), columns = the
camera images kept of trial 0 (``--images sample:3``), labelled with frame index and range.

Usage: python experiments/turbidity_ladder_sheet.py OUT/<run>/dataset sheet.png
"""

import json
import sys
from pathlib import Path

import cv2
import numpy as np

ds = Path(sys.argv[1])
out = sys.argv[2]
order = ["jerlov_I", "jerlov_II", "jerlov_1C", "jerlov_3C", "jerlov_5C", "jerlov_7C", "jerlov_9C"]
rows = []
for w in order:
    seq = ds / "sequences" / f"dock-t000-{w}"
    pngs = sorted((seq / "rgb").glob("*.png"))
    frames = {
        json.loads(l)["index"]: json.loads(l) for l in (seq / "frames.jsonl").read_text().splitlines() if l.strip()
    }
    tiles = []
    for p in pngs:
        im = cv2.imread(str(p))
        idx = int(p.stem)
        d = frames.get(idx, {}).get("d_true")
        txt = f"{w} #{idx}" + (f" d={d:.1f}m" if isinstance(d, (int, float)) else "")
        cv2.putText(im, txt, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(im)
    rows.append(np.hstack(tiles))
w = max(r.shape[1] for r in rows)
rows = [np.pad(r, ((0, 0), (0, w - r.shape[1]), (0, 0))) for r in rows]
cv2.imwrite(out, np.vstack(rows))
print(out)
