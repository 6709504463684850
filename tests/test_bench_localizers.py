"""`dockbench bench localizers`: the LED centroid table runs on LED frames (it crashed on a changed
private LED API) and finds the true LED centres to sub-pixel accuracy."""

from __future__ import annotations

import numpy as np
from synth_images import k_from_hfov, pose_looking_at_dock, render
from test_localizers import led_marker

from blendgen.tools.bench import stages as bench

W, H = 320, 240


def test_led_centroid_table_on_synthetic_frames(monkeypatch):
    K = k_from_hfov(W, H, 60.0)
    led = led_marker()
    frames = []
    for i, d in enumerate((2.0, 3.0, 4.0)):
        T = pose_looking_at_dock(d)
        frames.append(({"index": i, "d_true": d, "T_cam_dock": np.asarray(T).tolist()}, render(K, T, [led], W, H)))

    from types import SimpleNamespace

    ds = SimpleNamespace(markers=[led])
    camera = {"K": K, "dist": None, "width": W, "height": H, "markers": [led]}
    monkeypatch.setattr(bench, "load_sequences", lambda dataset: (ds, camera, [("s", frames)]))
    table = bench.led_centroid_table("unused")
    every = table[table["d_true"] == "0-inf m"].iloc[0]
    assert every["core_n"] == every["weighted_n"] == 4 * len(frames)  # every LED matched
    assert every["weighted_median_px"] < 0.5 and every["core_p95_px"] < 1.5
