"""The article's hybrid localizer: LED far, QR near, switching with hysteresis, state per sequence."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import synth_images as synth  # noqa: E402
from test_localizers import led_marker, square_marker  # noqa: E402

from evalkit import registry  # noqa: E402
from evalkit.localizers.hybrid import HybridLocalizer  # noqa: E402


class Script:
    """Stub sub-localizer: returns the next scripted distance (None = nothing found)."""

    def __init__(self, marker_id):
        self.marker_id = marker_id
        self.values, self.calls, self.resets = [], 0, 0

    def reset(self, camera):
        self.resets += 1

    def localize(self, image):
        self.calls += 1
        d = self.values.pop(0) if self.values else None
        return None if d is None else {"distance": d, "marker_id": self.marker_id}


def stubbed(**kw):
    h = HybridLocalizer(**kw)
    h.subs = {"near": Script("qr"), "far": Script("led")}
    h.reset({})
    return h


def run(h, truth):
    """Feed frames where both stubs see the true distance; (mode, marker) per frame."""
    out = []
    for d in truth:
        h.subs["near"].values = [d]
        h.subs["far"].values = [d]
        est = h.localize(None)
        out.append((est["mode"], est["marker_id"]))
    return out


def test_hysteresis_band_prevents_flicker():
    h = stubbed(switch_m=5.0, hysteresis_m=0.5)
    assert h.band == (4.75, 5.25)
    truth = [8.0, 6.0, 5.2, 4.8, 5.1, 4.7, 4.9, 5.2, 5.24, 5.3, 5.0, 4.76, 4.74, 3.0]
    modes = [m for m, _ in run(h, truth)]
    assert modes == ["far"] * 5 + ["near"] * 4 + ["far"] * 3 + ["near"] * 2
    # without hysteresis it would flip at every crossing of 5 m
    h0 = stubbed(switch_m=5.0, hysteresis_m=0.0)
    assert [m for m, _ in run(h0, [5.2, 4.8, 5.1, 4.9])] == ["far", "near", "far", "near"]


def test_immediate_switch_returns_the_marker_actually_used():
    h = stubbed()
    h.subs["far"].values = [4.0]       # LED says 4 m: below the band ...
    h.subs["near"].values = [4.1]      # ... so QR is tried on the same frame
    est = h.localize(None)
    assert (est["marker_id"], est["source"], est["mode"], est["distance"]) == ("qr", "near", "near", 4.1)
    h2 = stubbed(immediate=False)
    h2.subs["far"].values = [4.0]
    est = h2.localize(None)
    assert (est["marker_id"], est["mode"]) == ("led", "near") and h2.subs["near"].calls == 0


def test_fallback_and_reset_clears_state():
    h = stubbed()
    run(h, [3.0])
    assert h.mode == "near"
    h.subs["near"].values = [None]     # QR lost: LED answers, the mode stays (3.1 m < band)
    h.subs["far"].values = [3.1]
    est = h.localize(None)
    assert (est["marker_id"], est["source"], est["mode"]) == ("led", "far", "near")
    h.subs["near"].values, h.subs["far"].values = [None], [None]
    assert h.localize(None) is None and h.mode == "near"   # nothing found: state kept
    h.reset({})
    assert h.mode == "far" and h.subs["near"].resets == 2 and h.subs["far"].resets == 2
    h3 = stubbed(fallback=False)
    h3.subs["far"].values = [None]
    h3.subs["near"].values = [2.0]
    assert h3.localize(None) is None and h3.subs["near"].calls == 0


def test_params_and_sub_localizer_choice():
    h = registry.resolve("hybrid", {"near": "aruco", "switch_m": 3, "hysteresis_m": 1,
                                    "near_params": {"refine": "none"}, "far_marker_id": "led"})
    assert type(h.subs["near"]).__name__ == "ArucoLocalizer" and h.subs["near"].refine == "none"
    assert h.subs["far"].marker_id == "led" and h.band == (2.5, 3.5)
    with pytest.raises(registry.RegistryError, match="hysteresis_m"):
        registry.resolve("hybrid", {"hysteresis_m": 20})


# -- on rendered images ------------------------------------------------------------
W, H = 640, 480
K = synth.k_from_hfov(W, H, 35.0)   # narrow lens: the 0.4 m QR decodes out to ~7 m
LED = led_marker(size=1.2)
QR = square_marker("qr", 0.4, payload="DOCK-01")
TRUTH = [8.0, 6.5, 5.15, 4.9, 5.1, 4.5, 4.9, 5.15, 5.6, 4.85, 3.0, 2.0]
MODES = ["far"] * 5 + ["near"] * 3 + ["far"] * 2 + ["near"] * 2


@pytest.fixture(scope="module")
def frames():
    return [synth.render(K, synth.pose_looking_at_dock(d, 10.0, 5.0, 15.0), [LED, QR], W, H, ss=2,
                         noise_std=2.0, seed=i) for i, d in enumerate(TRUTH)]


def _run_rendered(frames):
    h = registry.resolve("hybrid", {})
    h.reset(synth.camera_dict(K, W, H, [LED, QR]))
    return [h.localize(img) for img in frames]


def test_rendered_sequence_switches_led_to_qr(frames):
    ests = _run_rendered(frames)
    assert all(e is not None for e in ests)
    assert [e["mode"] for e in ests] == MODES
    for d, e in zip(TRUTH, ests):
        assert e["distance"] == pytest.approx(d, rel=0.03)
        if d > 5.25 or (e["mode"] == "far" and d > 4.75):
            assert e["marker_id"] == "led"      # far away / far mode: the LED array
    assert ests[5]["marker_id"] == "qr"          # 4.5 m: switched within the frame
    assert [e["marker_id"] for e in ests[-2:]] == ["qr", "qr"]


def test_identical_inputs_give_identical_results(frames):
    a, b = _run_rendered(frames), _run_rendered(frames)
    for x, y in zip(a, b):
        assert x.keys() == y.keys()
        assert all(np.array_equal(x[k], y[k]) for k in x)
