"""Range / index passes: the 1.1 uint16-millimetre PNG, reading 1.0 NPZ, and one copy per render.

Oracles: the documented quantisation (|error| <= 0.5 mm up to 65.534 m, 0 = no surface),
numpy's own NPZ writer for spec 1.0 files, and inode identity for shared passes.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from blendgen.pipeline.passstore import PassStore, job_entry
from blendgen.pipeline.writer import DatasetWriter
from datasets_spec import io as dsio

ranges = hnp.arrays(np.float64, (7, 9), elements=st.floats(0.0006, 65.534)).map(lambda a: a.astype(np.float32))


@settings(max_examples=60, deadline=None)
@given(ranges)
def test_range_png_within_half_a_millimetre(tmp_path_factory, r):
    p = tmp_path_factory.mktemp("r") / "r.png"
    dsio.save_range(p, r)
    back = dsio.load_range(p)
    assert back.dtype == np.float32 and back.shape == r.shape
    # half a millimetre of quantisation, plus the float32 spacing of the value read back
    # (a tie such as 48.5335 m rounds to 48.534, stored as float32 48.534004)
    assert np.all(np.abs(back.astype(np.float64) - r) <= 0.0005 + np.spacing(np.float32(65.535)))


def test_range_png_extremes(tmp_path):
    r = np.array(
        [[np.inf, np.nan, -1.0, 0.0, 0.0004, 0.0006], [65.534, 65.5344, 65.5346, 100.0, 1e30, 7.25]], np.float32
    )
    p = tmp_path / "r.png"
    dsio.save_range(p, r)
    units = dsio.range_to_units(r)
    assert units.tolist() == [[0, 0, 0, 0, 0, 1], [65534, 65534, 0, 0, 0, 7250]]
    back = dsio.load_range(p)
    assert np.isinf(back[0, :5]).all() and np.isinf(back[1, 2:5]).all()  # no surface / too far: inf
    assert back[0, 5] == pytest.approx(0.001) and back[1, 5] == pytest.approx(7.25)


def test_reads_spec_1_0_npz(tmp_path):
    r = np.random.default_rng(0).uniform(0.1, 30, (4, 5)).astype(np.float32)
    r[0, 0] = np.inf
    np.savez_compressed(tmp_path / "000000.npz", range_m=r)
    back = dsio.load_range(tmp_path / "000000.npz")
    assert np.array_equal(back, r)  # 1.0 files read exactly


def test_bad_range_files_are_dataset_errors(tmp_path):
    with pytest.raises(dsio.DatasetError, match="missing or unreadable"):
        dsio.load_range(tmp_path / "none.png")
    dsio.save_index(tmp_path / "i.png", np.zeros((3, 4), np.uint8))
    with pytest.raises(dsio.DatasetError, match="uint16"):
        dsio.load_range(tmp_path / "i.png")


def test_index_roundtrip(tmp_path):
    idx = np.random.default_rng(1).integers(0, 256, (6, 8), dtype=np.uint8)
    dsio.save_index(tmp_path / "i.png", idx)
    assert np.array_equal(dsio.load_index(tmp_path / "i.png"), idx)


def test_pass_store_writes_once_and_links_into_every_dataset(tmp_path):
    key = "ab" * 32
    a, b, c = (DatasetWriter(tmp_path / n) for n in "ABC")
    c.render_dir(key).mkdir(parents=True)  # C has the render already (resumed run)
    entry = job_entry(
        key, [(a.render_tmp_dir(key), True), (b.render_tmp_dir(key), True), (c.render_tmp_dir(key), False)], True, True
    )
    store = PassStore.from_job({"passes": entry})
    passes = {"range_m": np.full((4, 6), 2.5, np.float32), "index": np.full((4, 6), 10, np.uint8)}
    paths = store.write(7, passes)
    assert paths == {
        "depth": f"renders/{key[:16]}/depth/000007.png",
        "object_index": f"renders/{key[:16]}/index/000007.png",
    }
    for w in (a, b):
        w.commit_render(key)
        assert np.all(dsio.load_range(w.root / paths["depth"]) == np.float32(2.5))
    assert (a.root / paths["depth"]).stat().st_ino == (b.root / paths["depth"]).stat().st_ino
    assert not (c.root / paths["depth"]).exists() and not c.render_tmp_dir(key).exists()


def test_pass_store_off_when_no_pass_is_written():
    entry = job_entry("cd" * 32, [], False, False)
    assert PassStore.from_job({"passes": entry}) is None
    assert PassStore.from_job({}) is None
