"""Every shipped config, rendered small, gives the datasets recorded in tests/data/golden_hashes.json,
byte for byte (tests/golden_datasets.py: how they are shrunk, what is hashed, how to re-record).

Two of them are rendered here (quickstart: two paths, ROI renders; paper_occlusion: article mode,
particles); ``python -m tests.golden_datasets check OUT`` renders all of them. The images,
passes and frame records were recorded from the code before the frame loop moved into the
pipeline; the manifests were re-recorded once when they started to record the effective config
(``effective_config`` and each sequence's resolved ``sensor.noise``). A deliberate change of the
output re-records them (and says why in its commit)."""

from __future__ import annotations

import json

import pytest

from tests import golden_datasets as gd

pytestmark = pytest.mark.blender


@pytest.mark.parametrize("name", ["quickstart", "paper_occlusion"])
def test_dataset_bytes_as_recorded(tmp_path, name):
    expected = json.loads(gd.HASHES.read_text())[name]
    got = gd.content_hashes(gd.render(name, gd.configs()[name], tmp_path))
    assert any("/rgb/" in p for p in got)  # images were written
    assert gd.diff(expected, got) == []


def test_hashes_see_a_changed_byte(tmp_path):
    """The comparison is not vacuous: one changed byte of one file is reported; the volatile
    manifest fields are not."""
    root = tmp_path / "d"
    (root / "sequences" / "s").mkdir(parents=True)
    (root / "sequences" / "s" / "frames.jsonl").write_text('{"index": 0}\n')
    (root / "manifest.json").write_text(json.dumps({"name": "d", "created_utc": "a", "generator": {"x": 1}}))
    a = gd.content_hashes(root)
    (root / "manifest.json").write_text(json.dumps({"name": "d", "created_utc": "b", "generator": {"x": 2}}))
    assert gd.diff(a, gd.content_hashes(root)) == []
    (root / "sequences" / "s" / "frames.jsonl").write_text('{"index": 1}\n')
    assert gd.diff(a, gd.content_hashes(root)) == ["sequences/s/frames.jsonl"]
