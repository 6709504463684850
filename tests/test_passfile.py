"""The closed loop's pass hand-over file (blendgen/passfile.py): the arrays come back as written.

Oracle: the arrays written (values, dtypes, shapes compared exactly), and the file's bytes
before and after a reader writes into what it read (copy-on-write: unchanged)."""

import numpy as np

from blendgen import passfile


def _passes(rng):
    return {
        "rgb": rng.random((5, 7, 3), dtype=np.float32),
        "depth_z": np.where(rng.random((5, 7)) < 0.2, np.inf, rng.random((5, 7))).astype(np.float32),
        "index": rng.integers(0, 256, (5, 7), dtype=np.uint8),
        "normal": rng.random((7, 5, 3), dtype=np.float32).transpose(1, 0, 2),  # not contiguous
        "empty": np.zeros((0, 3), np.float32),
    }


def test_passes_come_back_exactly(tmp_path):
    written = _passes(np.random.default_rng(0))
    path = str(tmp_path / "frame.passes")
    passfile.write_passes(path, written)
    back = passfile.read_passes(path)
    assert list(back) == list(written)
    for k, a in written.items():
        assert back[k].dtype == a.dtype and back[k].shape == a.shape, k
        np.testing.assert_array_equal(back[k], a, err_msg=k)
    assert [p.name for p in tmp_path.iterdir()] == ["frame.passes"]  # the temporary file renamed


def test_writing_into_read_arrays_leaves_the_file_unchanged(tmp_path):
    written = _passes(np.random.default_rng(1))
    path = str(tmp_path / "frame.passes")
    passfile.write_passes(path, written)
    before = (tmp_path / "frame.passes").read_bytes()
    back = passfile.read_passes(path)
    back["rgb"] += 1.0  # a stage adding a term in place
    back["index"][:] = 0
    assert (tmp_path / "frame.passes").read_bytes() == before
    np.testing.assert_array_equal(passfile.read_passes(path)["rgb"], written["rgb"])
    np.testing.assert_array_equal(back["rgb"], written["rgb"] + 1.0)


def test_arrays_read_stay_valid_after_the_next_frame_replaces_the_file(tmp_path):
    path = str(tmp_path / "frame.passes")
    first, second = _passes(np.random.default_rng(2)), _passes(np.random.default_rng(3))
    passfile.write_passes(path, first)
    back = passfile.read_passes(path)
    passfile.write_passes(path, second)
    np.testing.assert_array_equal(back["rgb"], first["rgb"])
    np.testing.assert_array_equal(passfile.read_passes(path)["rgb"], second["rgb"])
