"""`-l led -l qr -l hybrid` runs LED and QR once per frame (evalkit.memo), and every
localizer's rows are exactly those of running it alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evalkit import assemble, memo, runner
from evalkit.dataset import Dataset
from evalkit.localizers.led import LedLocalizer
from evalkit.localizers.qr import QrLocalizer, QrTrackLocalizer

TINY = Path(__file__).parent / "data" / "tiny"
RESULT = ["sequence", "index", "detected", "d_est", "marker_id", "fail_reason", "T_cam_dock_est"]


def _rows(names, monkeypatch=None, counts=None):
    if counts is not None:
        for cls in (LedLocalizer, QrLocalizer):
            real = cls.localize

            def counted(self, image, _real=real, _cls=cls):
                counts[_cls.__name__] = counts.get(_cls.__name__, 0) + 1
                return _real(self, image)

            monkeypatch.setattr(cls, "localize", counted)
    df = runner.evaluate(Dataset.open(TINY), [(n, assemble.build(n)) for n in names], progress=False)
    return {n: df[df["localizer"] == n][RESULT].reset_index(drop=True) for n in names}


def _same(a, b):
    assert len(a) == len(b) and len(a) > 0
    for col in RESULT:
        for x, y in zip(a[col], b[col]):
            if isinstance(x, float) and np.isnan(x):
                assert isinstance(y, float) and np.isnan(y)
            else:
                assert x == y, (col, x, y)


@pytest.mark.parametrize("order", [("led", "qr", "hybrid"), ("hybrid", "qr", "led")])
def test_shared_calls_give_the_rows_of_each_localizer_alone(order, monkeypatch):
    alone = {n: _rows([n])[n] for n in order}
    counts: dict = {}
    together = _rows(list(order), monkeypatch, counts)
    for n in order:
        _same(together[n], alone[n])
    n_frames = len(alone["led"])
    assert counts["LedLocalizer"] == n_frames  # the hybrid's LED calls were all replayed
    assert counts["QrLocalizer"] < 2 * n_frames  # some of the hybrid's QR calls were too
    # the hybrid found the dock on some frames: the test compares real estimates
    assert together["hybrid"]["detected"].any() and together["qr"]["detected"].any()


class _Roi(QrLocalizer):
    """A subclass that does not name the hooks itself: never shared (it may keep more state)."""


def test_only_classes_that_opt_in_and_come_from_the_registry_are_shared():
    a, b = assemble.build("qr"), assemble.build("qr")
    assert memo.opted_in(a) and a.memo_config == b.memo_config
    assert not memo.opted_in(assemble.build("qr_track"))  # QrTrackLocalizer: more state
    assert not memo.opted_in(_Roi())  # no registry config, no own hooks
    assert not memo.opted_in(assemble.build("qr", preprocess="clahe"))  # wrapped: its own image
    assert assemble.build("qr", {"roi": False}).memo_config != a.memo_config
    locs = [("qr", a), ("qr2", QrTrackLocalizer())]
    assert memo.share(locs, memo.FrameMemo()) == locs  # nothing shares a config: unchanged


def test_a_hit_moves_the_roi_state_as_the_real_call_did():
    """Two QR localizers in different ROI states never share; equal states move alike,
    misses counted on from each one's own count, the quad dropped after roi_keep_frames."""
    m = memo.FrameMemo()
    a, b = assemble.build("qr"), assemble.build("qr")
    cam = {
        "width": 64,
        "height": 48,
        "K": np.eye(3),
        "dist": None,
        "markers": [{"id": "q", "kind": "qr", "size_m": 0.1, "payload": "X", "keypoints": [[0, 0, 0]] * 4}],
    }
    a.reset(cam)
    b.reset(cam)
    sa, sb = memo.SharedLocalizer(a, m), memo.SharedLocalizer(b, m)
    blank = np.zeros((48, 64, 3), np.uint8)
    b._misses = 3  # b missed 3 frames more; no quad: the result is the same
    m.begin(("s", 0))
    assert sa.localize(blank) is None and sb.localize(blank) is None
    assert m.hits == 1 and (a._misses, b._misses) == (1, 4)
    a._last_quad = np.array([[1.0, 1], [9, 1], [9, 9], [1, 9]])  # a has a ROI, b has none: different keys
    m.begin(("s", 1))
    sa.localize(blank)
    sb.localize(blank)
    assert m.hits == 1 and a._misses == 2 and b._misses == 5
