"""Evaluation split over processes by sequence gives the serial per-frame table (no Blender)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from fake_dataset import write_fake_dataset  # noqa: E402

from evalkit import assemble, parallel, runner  # noqa: E402
from evalkit.dataset import Dataset  # noqa: E402

pytestmark = pytest.mark.integration  # a pool of evaluation processes

PLUGIN = """
import numpy as np
from fake_dataset import decode_distance

class Oracle:
    def reset(self, camera):
        self.n = 0
    def localize(self, image):
        self.n += 1                       # state within a sequence: reset must come first
        d = decode_distance(image)
        T = np.eye(4); T[2, 3] = d
        return {"distance": d if self.n > 1 else d + 1.0, "T_cam_dock": T, "marker_id": 0}

class Faulty:
    def reset(self, camera):
        pass
    def localize(self, image):
        d = decode_distance(image)
        if d == 0.5:
            raise ZeroDivisionError("boom")
        return None if d == 3.0 else {"distance": d}
"""


def test_parallel_equals_serial(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    plugin = tmp_path / "plug.py"
    plugin.write_text(PLUGIN)
    names = [f"{plugin}:Oracle", f"{plugin}:Faulty"]
    serial = runner.evaluate(Dataset.open(root), [(n, assemble.build(n, {})) for n in names], progress=False)
    par = parallel.evaluate_frames(root, names, workers=2)
    assert len(par) == len(serial) > 0
    cols = [c for c in runner.COLUMNS if c not in ("ms", "T_cam_dock_est")]
    pd.testing.assert_frame_equal(par[cols], serial[cols])
    same_pose = [
        np.array_equal(np.asarray(a, float), np.asarray(b, float)) if a is not None else b is None
        for a, b in zip(par["T_cam_dock_est"], serial["T_cam_dock_est"])
    ]
    assert all(same_pose)
    assert par.attrs == serial.attrs
    assert set(par["fail_reason"]) >= {"", "none"} and par["fail_reason"].str.startswith("exception").any()


def test_parallel_run_record(tmp_path):
    root = write_fake_dataset(tmp_path / "ds")
    plugin = tmp_path / "plug.py"
    plugin.write_text(PLUGIN)
    from evalkit.reports.results import EvalRequest, evaluate_dataset

    _, paths, _ = evaluate_dataset(EvalRequest(root, [f"{plugin}:Oracle"], tmp_path / "run", workers=2))
    assert paths["summary"].is_file() and (tmp_path / "run" / "run.json").is_file()
