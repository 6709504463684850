"""BOP19 AR as the BOP toolkit computes it (pinned toolkit outputs) and the BOP results writer."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from bop_fixture import RESULTS_NAME, write_fixture

from evalkit.dataset import Dataset
from evalkit.reports import bop
from evalkit.reports.bop_results import HEADER, method_name, write_results
from evalkit.reports.bop_score import bop19_scores, target_errors

PINNED = json.loads((Path(__file__).parent / "data" / "bop19_toolkit_scores.json").read_text())


@pytest.fixture(scope="module")
def fixture(tmp_path_factory):
    return write_fixture(tmp_path_factory.mktemp("bop19"))


def test_scores_equal_the_toolkits(fixture):
    """eval_bop19_pose.py's AR_VSD / AR_MSSD / AR_MSPD / AR on the fixture (run once with the real toolkit,
    tests/data/bop19_toolkit_scores.json has the command), reproduced without the toolkit."""
    s = bop19_scores(*fixture)
    want = PINNED["scores"]
    assert s["AR_VSD"] == pytest.approx(want["bop19_average_recall_vsd"], abs=1e-12)
    assert s["AR_MSSD"] == pytest.approx(want["bop19_average_recall_mssd"], abs=1e-12)
    assert s["AR_MSPD"] == pytest.approx(want["bop19_average_recall_mspd"], abs=1e-12)
    assert s["AR_BOP19"] == pytest.approx(want["bop19_average_recall"], abs=1e-12)
    assert 0.3 < s["AR_BOP19"] < 0.9  # the fixture is neither all right nor all wrong


def test_per_target_errors_equal_the_toolkits(fixture):
    export, csv = fixture
    diam = json.loads((export / "models_eval" / "models_info.json").read_text())["1"]["diameter"]
    rows = {f"{r['scene_id']}/{r['im_id']}/{r['obj_id']}": r for r in target_errors(export, csv)}
    errors = PINNED["errors"]
    assert set(errors["mssd_mm"]) == {k for k, r in rows.items() if r["mssd"] is not None}
    for key, mssd in errors["mssd_mm"].items():
        assert rows[key]["mssd"] * diam == pytest.approx(mssd, rel=1e-6)
        assert rows[key]["mspd"] * 64 / 640 == pytest.approx(errors["mspd_px"][key], rel=1e-6)  # 64 px wide
        np.testing.assert_allclose(rows[key]["vsd"], errors["vsd_by_tau"][key], atol=1e-9)
    assert any(0 < e < 1 for v in errors["vsd_by_tau"].values() for e in v)  # partial overlaps too


def _run_estimates(ds: Dataset, shift_m: float) -> pd.DataFrame:
    """A run's estimates: every frame answered with the true dock pose shifted by ``shift_m`` along x."""
    rows = []
    for seq in ds.sequences:
        for f in ds.iter_frames(seq["id"]):
            T = np.array(f["T_cam_dock"], float)
            T[0, 3] += shift_m
            rows.append(
                {
                    "localizer": "qr_track",
                    "sequence": seq["id"],
                    "index": f["index"],
                    "detected": True,
                    "d_est": 1.0,
                    "ms": 12.5,
                    "T_cam_dock_est": T.ravel().tolist(),
                }
            )
    return pd.DataFrame(rows)


def test_results_writer_round_trip(fixture, tmp_path):
    """The true dock pose written as results gives the export's GT pose per object (so every error is 0
    and AR_BOP19 = 1); a 1 m shift misses everything (AR 0)."""
    export = fixture[0]
    ds = Dataset.open(export.parent / "ds")
    paths = write_results(_run_estimates(ds, 0.0), ds.markers, export, tmp_path / "exact")
    path = paths["qr_track"]
    assert path.name == "qr-track_dockbench-test.csv" and method_name("a_b_c") == "a-b-c"
    lines = path.read_text().splitlines()
    assert lines[0] == HEADER and len(lines) == 1 + 12  # one object, 12 images
    s, i, o, score, R, t, time_s = lines[1].split(",")
    gt = json.loads((export / "test" / f"{int(s):06d}" / "scene_gt.json").read_text())[i][0]
    np.testing.assert_allclose(np.array(R.split(), float), gt["cam_R_m2c"], atol=1e-8)
    np.testing.assert_allclose(np.array(t.split(), float), gt["cam_t_m2c"], atol=1e-5)
    assert (int(o), float(score), float(time_s)) == (1, 1.0, 0.0125)
    assert bop19_scores(export, path)["AR_BOP19"] == pytest.approx(1.0)
    far = write_results(_run_estimates(ds, 1.0), ds.markers, export, tmp_path / "far")["qr_track"]
    miss = bop19_scores(export, far)
    assert miss["AR_MSSD"] == 0.0 and miss["AR_MSPD"] < 0.02 and miss["AR_VSD"] < 0.01  # 1 m: far off


_PARAMS = (
    '    obj_ids = {\n        "lm": list(range(1, 16)),\n    }\n    symmetric_obj_ids = {\n'
    '        "lm": [3, 7, 10, 11],\n    }\n    if dataset_name == "lm":\n        pass\n'
    '    else:\n        raise ValueError("Unknown BOP dataset ({}).".format(dataset_name))\n'
)


def _toolkit_tree(root: Path) -> Path:
    """The lines of a BOP toolkit clone that registration touches (a stand-in for a clone)."""
    (root / "bop_toolkit_lib").mkdir(parents=True)
    (root / "scripts").mkdir()
    (root / "bop_toolkit_lib" / "dataset_params.py").write_text(_PARAMS)
    (root / "scripts" / "eval_bop19_pose.py").write_text('            "vsd_deltas": {\n                "hb": 15,\n')
    return root


def test_registration_script(fixture, tmp_path):
    """register_bop_toolkit.py adds the export to a clone, replaces an earlier registration (run twice:
    one entry each), and refuses a toolkit whose anchors changed; the edited module still parses."""
    import ast
    import subprocess
    import sys
    import textwrap

    tk = _toolkit_tree(tmp_path / "tk")
    script = fixture[0] / "register_bop_toolkit.py"
    for _ in range(2):
        res = subprocess.run([sys.executable, str(script), str(tk)], check=False, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
    text = (tk / "bop_toolkit_lib" / "dataset_params.py").read_text()
    ast.parse(textwrap.dedent(text))
    assert text.count("'dockbench': [1],") == 1 and text.count("'dockbench': [],") == 1
    assert text.count("elif dataset_name == 'dockbench':") == 1 and 'p["im_size"] = (64, 48)' in text
    assert 'p["scene_ids"] = [0, 1]' in text
    assert "".join(x for x in text.splitlines(True) if "registered by dockbench" not in x) == _PARAMS
    assert "'dockbench': 15," in (tk / "scripts" / "eval_bop19_pose.py").read_text()
    (tk / "scripts" / "eval_bop19_pose.py").write_text("changed\n")
    res = subprocess.run([sys.executable, str(script), str(tk)], check=False, capture_output=True, text=True)
    assert res.returncode != 0 and "another toolkit version" in res.stderr


def test_fixture_name_is_the_results_name():
    assert RESULTS_NAME.split("_")[1].split("-")[0] == bop.BOP_DATASET_NAME


def test_export_bop_results_cli(tmp_path):
    """export-bop --results: one CSV per pose localizer, the table names both recalls; the exact oracle
    scores 1 on every MSSD/MSPD threshold; a run of another dataset is refused (exit 2)."""
    from click.testing import CliRunner
    from fake_dataset import write_fake_dataset
    from test_metrics_extra import Oracle, run_fake

    import cli
    from evalkit.metrics.extra import EvalSettings
    from evalkit.reports import results

    ds = Dataset.open(write_fake_dataset(tmp_path / "ds"))
    est = run_fake(ds, [("oracle", Oracle())])
    results.save_run(
        est, tmp_path / "run", results.RunRecord(ds, ["oracle"], EvalSettings(n_boot=50), make_plots=False)
    )
    res = CliRunner().invoke(
        cli.main,
        ["export-bop", str(ds.root), "-o", str(tmp_path / "b" / "dockbench"), "--results", str(tmp_path / "run")],
    )
    assert res.exit_code == 0, res.output
    csv = tmp_path / "b" / "dockbench" / "results" / "oracle_dockbench-test.csv"
    assert csv.is_file() and "AR_BOP19" in res.output and "AR_dock" in res.output
    s = bop19_scores(tmp_path / "b" / "dockbench", csv)
    assert s["AR_MSSD"] == s["AR_MSPD"] == 1.0
    other = write_fake_dataset(tmp_path / "ds2", sequences=[("x", "murky", 0, [1.0, 2.0])])
    res = CliRunner().invoke(
        cli.main, ["export-bop", str(other), "-o", str(tmp_path / "c"), "--results", str(tmp_path / "run")]
    )
    assert res.exit_code == 2 and "evaluated another dataset" in res.output and not (tmp_path / "c").exists()
