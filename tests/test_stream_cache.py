"""The run folder's resume caches (evalkit.stream): data formats only, each file checked
against the work manifest's sha256 before it is read back."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pandas as pd
import pytest

from evalkit import stream
from tests.fake_dataset import write_fake_dataset


def _evaluated(tmp_path: Path) -> tuple[Path, Path]:
    root = write_fake_dataset(tmp_path / "ds")
    manifest = json.loads((root / "manifest.json").read_text())
    work = tmp_path / "work"
    task = stream.SequenceTask(str(root), manifest, "clear_000", str(work), ["aruco"], [])
    assert stream.evaluate_sequence(task) == 6
    return root, work


def test_a_sequence_is_cached_as_parquet_and_recorded_by_sha256(tmp_path):
    import hashlib

    root, work = _evaluated(tmp_path)
    assert stream.done(work, "clear_000") and not stream.done(work, "clear_001")
    recorded = stream.recorded_files(work)
    assert set(recorded) == {
        "clear_000.parquet",
        "clear_000.hashes.json",
        "clear_000.cost.json",
        "clear_000.pixels.json",
    }
    for name, h in recorded.items():  # independent oracle: hashlib over the bytes on disk
        assert hashlib.sha256((work / name).read_bytes()).hexdigest() == h
    df, hashes = stream.load_results(work, ["clear_000"])
    assert len(df) == 6 and set(df["sequence"]) == {"clear_000"}
    assert df.attrs["d_min_rel_m"] == pytest.approx(0.2)
    assert hashes == {
        f"sequences/clear_000/rgb/{i:06d}.png": hashlib.sha256(
            (root / f"sequences/clear_000/rgb/{i:06d}.png").read_bytes()
        ).hexdigest()
        for i in range(6)
    }


@pytest.mark.parametrize("damage", ["truncate", "edit_json", "unrecorded"])
def test_a_changed_cache_is_a_user_error_naming_the_file(tmp_path, damage):
    _, work = _evaluated(tmp_path)
    pq = work / "clear_000.parquet"
    if damage == "truncate":
        pq.write_bytes(pq.read_bytes()[: pq.stat().st_size // 2])
        bad = pq
    elif damage == "edit_json":
        bad = work / "clear_000.hashes.json"
        bad.write_text(json.dumps({"sequences/clear_000/rgb/000000.png": "0" * 64}))
    else:
        (work / stream.WORK_MANIFEST).write_text("")
        bad = pq
    with pytest.raises(stream.StreamCacheError, match=str(bad)):
        stream.load_results(work, ["clear_000"])


def test_a_pickled_cache_is_never_loaded(tmp_path):
    """A crafted pickle in a run folder would run code when unpickled: it is refused unread."""
    work = tmp_path / "work"
    work.mkdir()
    marker = tmp_path / "pwned"

    class Payload:
        def __reduce__(self):
            return (Path.touch, (marker,))

    (work / "clear_000.pkl.gz").write_bytes(pickle.dumps(Payload()))
    with pytest.raises(stream.StreamCacheError, match="pickled cache"):
        stream.refuse_legacy(work)
    assert not stream.done(work, "clear_000")
    with pytest.raises(stream.StreamCacheError, match="not in the run folder"):
        stream.load_results(work, ["clear_000"])
    assert not marker.exists()


def test_a_manifest_line_cut_by_a_crash_counts_as_not_written(tmp_path):
    _, work = _evaluated(tmp_path)
    with open(work / stream.WORK_MANIFEST, "a") as fh:
        fh.write('{"files": {"clear_001.parquet": "ab')  # kill -9 mid-line (never seen; tolerated)
    assert stream.done(work, "clear_000") and not stream.done(work, "clear_001")
    assert isinstance(stream.load_results(work, ["clear_000"])[0], pd.DataFrame)
