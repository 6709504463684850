"""Contact sheets of the world around the dock (docs/evidence/README.md; run with PYTHONPATH=.)."""

import os
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

from blendgen.config.bundled import bundled_file
from blendgen.config.models import Condition, Pose, Water, WorldLook, load_experiment
from blendgen.pipeline.generate import generate
from evalkit.dataset import Dataset

OUT = Path(os.environ.get("EV_OUT", "out/evidence"))  # EV_OUT: where the sheets go
W, H = int(sys.argv[2]) if len(sys.argv) > 2 else 320, int(sys.argv[3]) if len(sys.argv) > 3 else 240
VIEWS = (8.0, 5.0, 2.0)


def exp_for(name, world_on: bool, waters, depths, fidelity="fast", pitch=0.0, views=VIEWS, samples=4, wind=1.0):
    exp = load_experiment(bundled_file("configs", "quickstart.yaml"))
    traj = exp.trajectories[0]
    lead = exp.camera.T_body_cam.xyz[0]
    traj.start_range_m, traj.end_range_m = views[0] + lead, views[-1] + lead
    traj.speed_mps = (views[0] - views[1]) * exp.camera.fps
    exp.trajectories = [traj]
    exp.image_formation = "physical"
    exp.camera.width, exp.camera.height = W, H
    exp.camera.T_body_cam = Pose(xyz=[0.65, 0, 0], rpy_deg=[0, pitch, 0])
    exp.render.fidelity = fidelity
    exp.render.samples = 4
    exp.render.reference_samples = samples
    v = None if world_on else False
    exp.scene.world = WorldLook(surface=v, caustics=v, textures=v, wind_mps=wind)
    exp.conditions = [
        Condition(label=f"{w}-d{d:g}", water=Water(preset=w), dock_water_depth_m=d) for w in waters for d in depths
    ]
    exp.scene.dock.water_depth_m = max(depths)  # the deepest condition's surface at the pool rim
    exp.name = name
    return exp


def sheet(rows):
    """rows: list of (label, [images]) -> one image with labels."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    n = max(len(r[1]) for r in rows)
    out = np.full((len(rows) * H, n * W, 3), 255, np.uint8)
    for i, (lab, imgs) in enumerate(rows):
        for j, img in enumerate(imgs):
            out[i * H : (i + 1) * H, j * W : (j + 1) * W] = img
            out[i * H : (i + 1) * H, j * W : j * W + 1] = 255
        cv2.putText(out, lab, (4, i * H + 14), font, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def run(exp):
    work = OUT / exp.name
    shutil.rmtree(work, ignore_errors=True)
    generate(exp, work, workers=1, progress=False)
    return images(work)


def images(path):
    """{condition: [frame images]} of a dataset."""
    ds = Dataset.open(path)
    return {s["condition"]: [ds.load_image(f) for f in ds.iter_frames(s["id"])] for s in ds.sequences}


def save(name, img):
    p = OUT / f"{name}.jpg"
    cv2.imwrite(str(p), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 82])
    print("wrote", p, p.stat().st_size // 1024, "kB")


def dock_views():
    waters, depths = ("clear", "mild", "moderate"), (2.0,)
    on = run(exp_for("dock_on", True, waters, depths))
    off = run(exp_for("dock_off", False, waters, depths))
    rows = []
    for w in waters:
        rows.append((f"{w}, before (flat, no surface)", off[f"{w}-d2"]))
        rows.append((f"{w}, after (world on)", on[f"{w}-d2"]))
    save("dock_8_5_2m_before_after", sheet(rows))


def caustics():
    waters, depths = ("clear", "mild"), (1.0, 3.0, 6.0)
    on = run(exp_for("caustics", True, waters, depths, views=(6.0, 4.0, 2.0)))
    rows = [(f"{w}, dock {d:g} m deep", on[f"{w}-d{d:g}"]) for w in waters for d in depths]
    save("caustics_shallow_vs_deep", sheet(rows))


def caustics_fast_vs_reference(samples=16):
    """Rows in pairs: the fast path, then the Cycles reference with its caustic spot
    (blendgen/blender/caustic_sun.py); same waves, times and views."""
    waters, depths = ("clear", "mild"), (1.0, 3.0, 6.0)
    fast = run(exp_for("caustics_fast", True, waters, depths, views=(6.0, 4.0, 2.0)))
    ref = run(
        exp_for("caustics_ref", True, waters, depths, views=(6.0, 4.0, 2.0), fidelity="reference", samples=samples)
    )
    rows = []
    for w in waters:
        for d in depths:
            rows += [
                (f"{w}, dock {d:g} m deep, fast", fast[f"{w}-d{d:g}"]),
                (f"{w}, dock {d:g} m deep, reference", ref[f"{w}-d{d:g}"]),
            ]
    save("caustics_fast_vs_reference", sheet(rows))


def caustics_before_after(before: Path):
    """Rows in threes from two ``causticsref`` runs: ``before``'s fast path (EV_OUT of a run on
    an older tree), this EV_OUT's fast path, this EV_OUT's reference."""
    old, new, ref = images(before / "caustics_fast"), images(OUT / "caustics_fast"), images(OUT / "caustics_ref")
    rows = []
    for c in old:
        rows += [(f"{c}, fast before", old[c]), (f"{c}, fast now", new[c]), (f"{c}, reference", ref[c])]
    save("caustics_before_after_reference", sheet(rows))


def looking_up(fid="fast", samples=4):
    on = run(exp_for(f"up_{fid}", True, ("clear", "mild"), (3.0,), fidelity=fid, pitch=-70.0, samples=samples))
    return [(f"{k} looking up 70 deg, {fid}", v) for k, v in on.items()]


def open_water():
    rows = []
    for pitch in (0.0, 25.0):
        exp = exp_for("open", True, ("clear", "mild"), (6.0,), pitch=pitch)
        exp.scene.kind = "open_water"
        exp.scene.world.seabed_depth_m = 9.0
        exp.name = f"open_p{pitch:g}"
        on = run(exp)
        rows += [(f"open water {k}, seabed 9 m, pitch down {pitch:g}", v) for k, v in on.items()]
    save("open_water_seabed", sheet(rows))


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    what = sys.argv[1]
    if what == "dock":
        dock_views()
    elif what == "caustics":
        caustics()
    elif what == "causticsref":
        caustics_fast_vs_reference()
    elif what == "causticsfast":  # the fast half of causticsref (for an older tree's run)
        run(exp_for("caustics_fast", True, ("clear", "mild"), (1.0, 3.0, 6.0), views=(6.0, 4.0, 2.0)))
    elif what == "causticsba":  # argv[4]: the EV_OUT of a causticsref run on the older tree
        caustics_before_after(Path(sys.argv[4]))
    elif what == "up":
        save("looking_up_fast", sheet(looking_up("fast")))
    elif what == "open":
        open_water()
    elif what == "upref":
        save("looking_up_fast_vs_reference", sheet(looking_up("fast") + looking_up("reference", 16)))
