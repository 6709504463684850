"""Metrics beyond the article (evalkit.metrics.extra, truth, tables, plots, results)."""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from evalkit.metrics import core as metrics

from evalkit.metrics import extra as mx
from evalkit.reports import tables
from evalkit.dataset import Dataset
from evalkit.metrics.truth import as_matrices, frame_truth_table

from fake_dataset import write_fake_dataset

NAN = float("nan")


def _pose(R=np.eye(3), t=(0.0, 0.0, 5.0)) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T.ravel().tolist()


def _rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def _estimates(rows):
    """rows: (loc, seq, cond, index, d_true, in_view, success, d_est, marker_id, ms, T_est)."""
    df = pd.DataFrame(rows, columns=["localizer", "sequence", "condition", "index", "d_true", "in_view",
                                     "success", "d_est", "marker_id", "ms", "T_cam_dock_est"])
    df["trial"] = 0
    df["fail_reason"] = np.where(df["success"], "", "none")
    return df


@pytest.fixture
def frames():
    # truth: dock 5 m straight ahead (t = (0, 0, 5)), marker "m1" in view except frame 2
    est = _estimates([
        # lateral 0.4, range +0.3 -> e_trans 0.5, rotation 10 deg about z
        ("a", "s1", "c", 0, 5.0, True, True, 5.3, "m1", 1.0, _pose(_rot_z(10), (0.4, 0.0, 5.3))),
        ("a", "s1", "c", 1, 5.0, True, False, NAN, None, 2.0, None),          # failure
        ("a", "s1", "c", 2, 5.0, False, True, 4.0, "m1", 3.0, None),          # FP: nothing in view
        ("a", "s1", "c", 3, 5.0, True, True, 5.0, "m2", 4.0, _pose()),        # FP: wrong id, exact pose
        ("a", "s1", "c", 4, 5.0, True, True, 4.8, None, 100.0, None),         # no id, no pose: not FP
    ])
    truth = pd.DataFrame({"sequence": ["s1"] * 5, "index": range(5), "T_cam_dock": [_pose()] * 5,
                          "markers_in_fov": ["m1", "m1", "", "m1", "m1"]})
    return mx.attach_truth(est, truth)


def test_pose_errors_hand_computed(frames):
    e = mx.pose_errors(frames)
    assert e.loc[0].tolist() == pytest.approx([0.5, 10.0, 0.3, 0.4])
    assert e.loc[3].tolist() == pytest.approx([0.0, 0.0, 0.0, 0.0], abs=1e-9)
    assert e.loc[[1, 2, 4]].isna().all().all()          # failure / no pose


def test_range_lateral_decomposition_off_axis():
    # truth at (3, 0, 4) (|t| = 5, ray (0.6, 0, 0.8)); estimate moved 1 m along the ray and 2 m along y
    t_true = np.array([3.0, 0.0, 4.0])
    t_est = t_true + np.array([0.6, 0.0, 0.8]) * 1.0 + np.array([0.0, 2.0, 0.0])
    df = _estimates([("a", "s", "c", 0, 4.0, True, True, 4.0, None, 1.0, _pose(t=t_est))])
    df["T_cam_dock"] = [_pose(t=t_true)]
    e = mx.pose_errors(df).loc[0]
    assert e["e_range"] == pytest.approx(1.0)
    assert e["e_lateral"] == pytest.approx(2.0)
    assert e["e_trans"] == pytest.approx(math.sqrt(5.0))


def test_pose_errors_without_pose_column():
    df = _estimates([("a", "s", "c", 0, 4.0, True, True, 4.0, None, 1.0, None)]).drop(columns="T_cam_dock_est")
    assert mx.pose_errors(df).isna().all().all()


def test_false_positives(frames):
    assert mx.false_positive_mask(frames).tolist() == [False, False, True, True, False]
    fp = mx.false_positive_table(frames).iloc[0]
    assert (fp["n_frames"], fp["n_est"], fp["n_fp"], fp["n_no_view"]) == (5, 4, 2, 1)
    assert fp["fp_rate"] == pytest.approx(0.5)
    assert fp["fp_rate_no_view"] == pytest.approx(1.0)
    # without truth only the no-view rule applies
    assert mx.false_positive_mask(frames.drop(columns="markers_in_fov")).tolist() == \
        [False, False, True, False, False]


def test_runtime(frames):
    rt = mx.runtime_table(frames).iloc[0]
    assert rt["n_calls"] == 5
    assert rt["ms_median"] == pytest.approx(3.0)
    assert rt["ms_p95"] == pytest.approx(np.quantile([1, 2, 3, 4, 100], 0.95))
    frames.loc[4, "fail_reason"] = "exception: X: y (in reset)"   # never called: excluded
    assert mx.runtime_table(frames).iloc[0]["n_calls"] == 4


def test_distance_bins_and_usable_range():
    rows = []
    # bin [0,1): 10/10 succ; [1,2): 9/10; [2,3): 5/10; [3,4): 10/10; d = 10 m -> last bin [9,10]
    for b, n_ok in ((0, 10), (1, 9), (2, 5), (3, 10)):
        for i in range(10):
            ok = i < n_ok
            rows.append(("a", "s", "c", len(rows), b + 0.05 * i + 0.01, True, ok, b + 0.5 if ok else NAN,
                         None, 1.0, None))
    rows.append(("a", "s", "c", len(rows), 10.0, True, False, NAN, None, 1.0, None))
    rows.append(("a", "s", "c", len(rows), 10.5, True, True, 10.5, None, 1.0, None))   # not counted
    bins = mx.distance_bins(_estimates(rows))
    assert len(bins) == 10
    assert bins["bin_lo"].tolist() == [float(i) for i in range(10)]
    assert bins["n_total"].tolist() == [10, 10, 10, 10, 0, 0, 0, 0, 0, 1]
    assert bins["P_succ"].iloc[:4].tolist() == pytest.approx([1.0, 0.9, 0.5, 1.0])
    assert math.isnan(bins["P_succ"].iloc[4]) and bins["P_succ"].iloc[9] == 0.0
    # e_abs of bin 0: |d - 0.5| for d = 0.01 .. 0.46
    d0 = np.array([0.05 * i + 0.01 for i in range(10)])
    assert bins["e_abs_mean"].iloc[0] == pytest.approx(np.mean(np.abs(d0 - 0.5)))
    usable = mx.max_usable_range(bins)
    assert usable["max_range_m"].iloc[0] == pytest.approx(4.0)          # farthest bin >= 0.9
    assert mx.max_usable_range(bins, threshold=1.01)["max_range_m"].isna().all()
    assert mx.max_usable_range(bins, min_frames=11)["max_range_m"].isna().all()


def test_bootstrap_ci_deterministic_and_contains_mean():
    rng = np.random.default_rng(1)
    for n in (3, 10, 50):
        v = rng.uniform(0.2, 1.0, n)
        a = mx.bootstrap_ci(v, n_boot=500, seed=7)
        assert a == mx.bootstrap_ci(v, n_boot=500, seed=7)
        assert a[0] <= v.mean() <= a[1]
        assert a[0] >= v.min() - 1e-12 and a[1] <= v.max() + 1e-12
    assert mx.bootstrap_ci([NAN, NAN]) == pytest.approx((NAN, NAN), nan_ok=True)
    assert mx.bootstrap_ci([0.3, NAN]) == (0.3, 0.3)
    wide = mx.bootstrap_ci(rng.uniform(0, 1, 10), n_boot=500, seed=0)
    narrow = mx.bootstrap_ci(rng.uniform(0, 1, 1000), n_boot=500, seed=0)
    assert narrow[1] - narrow[0] < wide[1] - wide[0]


def test_condition_cis_independent_of_row_order():
    trials = pd.DataFrame({"localizer": ["a"] * 6 + ["b"] * 6, "sequence": [f"s{i}" for i in range(12)],
                           "condition": ["c"] * 12, "n_total": [10] * 12,
                           "P_succ": np.linspace(0.1, 0.9, 12), "e_rel_mean": np.linspace(0.01, 0.1, 12)})
    a = mx.condition_cis(trials, n_boot=300, seed=3)
    b = mx.condition_cis(trials.iloc[::-1].reset_index(drop=True), n_boot=300, seed=3)
    b = b.sort_values("localizer").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)
    for _, r in a.iterrows():
        g = trials[trials.localizer == r["localizer"]]
        assert r["P_succ_lo"] <= g["P_succ"].mean() <= r["P_succ_hi"]
        assert r["E_rel_lo"] <= g["e_rel_mean"].mean() <= r["E_rel_hi"]


def test_compute_all_metrics_row(frames):
    res = mx.compute_all(frames.drop(columns=["T_cam_dock", "markers_in_fov"]),
                         pd.DataFrame({"sequence": ["s1"] * 5, "index": range(5),
                                       "T_cam_dock": [_pose()] * 5,
                                       "markers_in_fov": ["m1", "m1", "", "m1", "m1"]}), n_boot=200)
    m = res["metrics"].iloc[0]
    assert list(res["metrics"].columns) == mx.METRIC_COLUMNS
    assert m["P_succ_mean"] == pytest.approx(0.8)
    # e_abs over successes: .3, 1, 0, .2 -> e_rel /5
    assert m["E_rel_mean"] == pytest.approx(np.mean([0.3, 1.0, 0.0, 0.2]) / 5)
    assert m["e_trans_mean"] == pytest.approx(0.25)      # frames 0 and 3 have poses
    assert m["e_rot_deg_mean"] == pytest.approx(5.0)
    assert m["e_range_abs_mean"] == pytest.approx(0.15)
    assert m["e_lateral_mean"] == pytest.approx(0.2)
    assert (m["n_est"], m["n_fp"]) == (4, 2)
    assert m["ms_median"] == pytest.approx(3.0)
    assert np.isnan(m["max_range_m"])                   # 5 m bin has P_succ 0.8 < 0.9


def test_truth_table_from_fake_dataset(tmp_path):
    ds = Dataset.open(write_fake_dataset(tmp_path / "ds"))
    truth = frame_truth_table(ds)
    assert len(truth) == 12
    assert {"in_fov:0", "visible_fraction:0", "T_cam_dock", "markers_in_fov"} <= set(truth.columns)
    row = truth[(truth.sequence == "clear_000") & (truth["index"] == 5)].iloc[0]
    assert not row["in_view"] and row["markers_in_fov"] == "" and row["visible_fraction:0"] == 0.0
    mats = as_matrices(truth["T_cam_dock"])
    assert mats.shape == (12, 4, 4)
    assert mats[:, 2, 3].tolist() == pytest.approx(truth["d_true"].tolist())
    assert len(frame_truth_table(ds, ["clear_001"])) == 6


def test_article_tables(frames):
    res = mx.compute_all(frames, None, n_boot=100)
    art = tables.article_table(res["metrics"])
    assert list(art.columns) == ["localizer", "condition", tables.ARTICLE_ERROR, tables.ARTICLE_SUCCESS]
    assert art.iloc[0][tables.ARTICLE_SUCCESS].startswith("80.00")
    md = tables.article_markdown(res["metrics"])
    tex = tables.article_latex(res["metrics"], caption="x", label="tab:x")
    assert "successful docking location rate (%)" in md
    assert r"\begin{tabular}{llrr}" in tex and r"(\%)" in tex and r"\label{tab:x}" in tex
    plain = tables.article_table(res["conditions"])       # article-only columns: no CI
    assert "[" not in plain.iloc[0][tables.ARTICLE_SUCCESS]


def _oracle_estimates(ds: Dataset, sigma: float = 0.05, seed: int = 0) -> pd.DataFrame:
    """Runner-shaped estimates from the truth with noise; one failure per sequence."""
    rng = np.random.default_rng(seed)
    truth = frame_truth_table(ds)
    rows = []
    for loc in ("oracle", "noisy"):
        for _, f in truth.iterrows():
            ok = bool(f["in_view"]) and not (loc == "noisy" and f["index"] == 2)
            T = np.asarray(f["T_cam_dock"]).reshape(4, 4).copy()
            if loc == "noisy":
                T[:3, 3] += rng.normal(0, sigma, 3)
            rows.append({"localizer": loc, "sequence": f["sequence"], "condition": f["condition"],
                         "trial": f["trial"], "index": f["index"], "t": f["t"], "d_true": f["d_true"],
                         "in_view": f["in_view"], "success": ok,
                         "d_est": float(T[2, 3]) if ok else NAN, "marker_id": "0" if ok else None,
                         "ms": 1.0 + rng.random(), "fail_reason": "" if ok else "none",
                         "T_cam_dock_est": T.ravel().tolist() if ok else None})
    df = pd.DataFrame(rows).astype({"d_true": float, "d_est": float, "success": bool, "in_view": bool})
    df[["e_abs", "e_rel"]] = metrics.frame_errors(df, ds.d_min_rel_m)
    df.attrs.update({"d_min_rel_m": ds.d_min_rel_m, "d_max_m": metrics.D_MAX_M})
    return df


def test_save_and_load_run(tmp_path):
    from evalkit.reports import results
    ds = Dataset.open(write_fake_dataset(tmp_path / "ds"))
    est = _oracle_estimates(ds)
    paths = results.save_run(est, tmp_path / "run", ds, ["oracle", "noisy"], extra={"params": ["k=1"]},
                             n_boot=200)
    for key in ("estimates", "summary", "conditions", "metrics", "bins", "article_md", "article_tex",
                "plot_error", "plot_success", "run"):
        assert paths[key].is_file(), key
    assert paths["plot_error"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    run = json.loads(paths["run"].read_text())
    assert run["dataset"] == {**run["dataset"], "name": "fake", "version": "0.0.1",
                              "content_hash": ds.manifest["content_hash"]}
    assert [loc["name"] for loc in run["localizers"]] == ["oracle", "noisy"]
    assert run["extra"] == {"params": ["k=1"]} and run["timestamp"] and run["dockbench_version"]
    loaded = results.load_run(tmp_path / "run")
    m = loaded.metrics.set_index("localizer")
    assert m.loc["oracle", "e_trans_mean"] == pytest.approx(0.0, abs=1e-12)
    assert m.loc["oracle", "n_fp"] == 0
    assert m.loc["noisy", "P_succ_mean"] < m.loc["oracle", "P_succ_mean"]
    assert loaded.estimates["T_cam_dock_est"].notna().any()
    assert len(results.compare_runs([loaded, tmp_path / "run"])) == 4


def test_compare_runs_refuses_mixed_datasets(tmp_path):
    from evalkit.reports import results
    dirs = []
    for i, seqs in enumerate(([("a", "clear", 0, [1.0, 2.0])], [("a", "clear", 0, [1.0, 3.0])])):
        ds = Dataset.open(write_fake_dataset(tmp_path / f"ds{i}", sequences=seqs))
        results.save_run(_oracle_estimates(ds), tmp_path / f"run{i}", ds, ["oracle", "noisy"],
                         n_boot=50, make_plots=False)
        dirs.append(tmp_path / f"run{i}")
    with pytest.raises(results.ResultsError, match="different datasets"):
        results.compare_runs(dirs)
    with pytest.raises(results.ResultsError, match="not a dockbench results directory"):
        results.load_run(tmp_path)
