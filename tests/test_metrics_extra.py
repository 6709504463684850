"""The one metrics path (evalkit.metrics.extra.compute_all), pose recall, tables, plots, results."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from fake_dataset import decode_distance, write_fake_dataset

from evalkit import runner
from evalkit.dataset import Dataset
from evalkit.metrics import core
from evalkit.metrics import extra as mx
from evalkit.metrics import recall as rec
from evalkit.metrics.truth import as_matrices, frame_truth_table
from evalkit.reports import tables

NAN = float("nan")


def _pose(R=None, t=(0.0, 0.0, 5.0)) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = np.eye(3) if R is None else R
    T[:3, 3] = t
    return T.ravel().tolist()


def _rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def _estimates(rows, truth_pose=None, fov="m1"):
    """rows: (loc, seq, cond, index, d_true, in_view, detected, d_est, marker_id, ms, T_est)."""
    df = pd.DataFrame(
        rows,
        columns=[
            "localizer",
            "sequence",
            "condition",
            "index",
            "d_true",
            "in_view",
            "detected",
            "d_est",
            "marker_id",
            "ms",
            "T_cam_dock_est",
        ],
    )
    df["trial"], df["trajectory"] = 0, "straight"
    df["fail_reason"] = np.where(df["detected"], "", "none")
    df["T_cam_dock"] = [truth_pose or _pose()] * len(df)
    df["markers_in_fov"] = np.where(df["in_view"], fov, "")
    return df


@pytest.fixture
def frames():
    # truth: dock 5 m straight ahead (t = (0, 0, 5)), marker "m1" in view except frame 2
    return _estimates(
        [
            # lateral 0.4, range +0.3 -> e_trans 0.5, rotation 10 deg about z
            ("a", "s1", "c", 0, 5.0, True, True, 5.3, "m1", 1.0, _pose(_rot_z(10), (0.4, 0.0, 5.3))),
            ("a", "s1", "c", 1, 5.0, True, False, NAN, None, 2.0, None),  # failure
            ("a", "s1", "c", 2, 5.0, False, True, 4.0, "m1", 3.0, None),  # FP: nothing in view
            ("a", "s1", "c", 3, 5.0, True, True, 5.0, "m2", 4.0, _pose()),  # FP: wrong id, exact pose
            ("a", "s1", "c", 4, 5.0, True, True, 4.8, None, 100.0, None),  # no id, no pose: success
        ]
    )


def test_pose_errors_hand_computed(frames):
    e = core.pose_errors(frames)
    assert e.loc[0].tolist() == pytest.approx([0.5, 10.0, 0.3, 0.4])
    assert e.loc[3].tolist() == pytest.approx([0.0, 0.0, 0.0, 0.0], abs=1e-9)
    assert e.loc[[1, 2, 4]].isna().all().all()  # failure / no pose


def test_range_lateral_decomposition_off_axis():
    # truth at (3, 0, 4) (|t| = 5, ray (0.6, 0, 0.8)); estimate moved 1 m along the ray and 2 m along y
    t_true = np.array([3.0, 0.0, 4.0])
    t_est = t_true + np.array([0.6, 0.0, 0.8]) * 1.0 + np.array([0.0, 2.0, 0.0])
    df = _estimates([("a", "s", "c", 0, 4.0, True, True, 4.0, None, 1.0, _pose(t=t_est))], truth_pose=_pose(t=t_true))
    e = core.pose_errors(df).loc[0]
    assert e["e_range"] == pytest.approx(1.0)
    assert e["e_lateral"] == pytest.approx(2.0)
    assert e["e_trans"] == pytest.approx(math.sqrt(5.0))


def test_false_positives_and_success(frames):
    s = core.score_frames(frames)
    assert s["fp"].tolist() == [False, False, True, True, False]
    # frame 0: distance error 0.3 <= 0.5 but e_trans 0.5 at the bound, rotation 10 deg at the bound
    assert s["success"].tolist() == [True, False, False, False, True]
    fp = mx.false_positive_table(pd.concat([frames, s], axis=1)).iloc[0]
    assert (fp["n_frames"], fp["n_est"], fp["n_fp"], fp["n_no_view"]) == (5, 4, 2, 1)
    assert fp["fp_rate"] == pytest.approx(0.5)
    assert fp["fp_rate_no_view"] == pytest.approx(1.0)
    # without markers_in_fov only the no-view rule applies
    assert core.false_positive_mask(frames.drop(columns="markers_in_fov")).tolist() == [
        False,
        False,
        True,
        False,
        False,
    ]


def test_runtime(frames):
    rt = mx.runtime_table(frames).iloc[0]
    assert rt["n_calls"] == 5
    assert rt["ms_median"] == pytest.approx(3.0)
    assert rt["ms_p95"] == pytest.approx(np.quantile([1, 2, 3, 4, 100], 0.95))
    frames.loc[4, "fail_reason"] = "exception: X: y (in reset)"  # never called: excluded
    assert mx.runtime_table(frames).iloc[0]["n_calls"] == 4


def test_distance_bins_and_usable_range():
    rows = []
    # bin [0,1): 10/10 succ; [1,2): 9/10; [2,3): 5/10; [3,4): 10/10; d = 10 m -> last bin [9,10]
    for b, n_ok in ((0, 10), (1, 9), (2, 5), (3, 10)):
        for i in range(10):
            ok = i < n_ok
            d = b + 0.05 * i + 0.01
            rows.append(("a", "s", "c", len(rows), d, True, ok, d + 0.01 if ok else NAN, None, 1.0, None))
    rows.append(("a", "s", "c", len(rows), 10.0, True, False, NAN, None, 1.0, None))
    rows.append(("a", "s", "c", len(rows), 10.5, True, True, 10.5, None, 1.0, None))  # not counted
    scored = mx.score(_estimates(rows), mx.EvalSettings())
    bins = mx.distance_bins(scored)
    assert len(bins) == 10
    assert bins["bin_lo"].tolist() == [float(i) for i in range(10)]
    assert bins["n_total"].tolist() == [10, 10, 10, 10, 0, 0, 0, 0, 0, 1]
    assert bins["P_succ"].iloc[:4].tolist() == pytest.approx([1.0, 0.9, 0.5, 1.0])
    assert math.isnan(bins["P_succ"].iloc[4]) and bins["P_succ"].iloc[9] == 0.0
    assert bins["e_abs_mean"].iloc[0] == pytest.approx(0.01)
    usable = mx.max_usable_range(bins)
    assert usable["max_range_m"].iloc[0] == pytest.approx(4.0)  # farthest bin >= 0.9
    assert mx.max_usable_range(bins, threshold=1.01)["max_range_m"].isna().all()
    assert mx.max_usable_range(bins, min_frames=11)["max_range_m"].isna().all()


def test_bootstrap_ci_scipy_deterministic_and_contains_mean():
    from scipy import stats

    rng = np.random.default_rng(1)
    for n in (3, 10, 50):
        v = rng.uniform(0.2, 1.0, n)
        a = mx.bootstrap_ci(v, n_boot=500, seed=7)
        assert a == mx.bootstrap_ci(v, n_boot=500, seed=7)
        assert a[0] <= v.mean() <= a[1]
        ref = stats.bootstrap(
            (v,), np.mean, n_resamples=500, method="BCa", rng=np.random.default_rng(7)
        ).confidence_interval
        assert a == pytest.approx((ref.low, ref.high))  # it is scipy's BCa interval
    assert mx.bootstrap_ci([NAN, NAN]) == pytest.approx((NAN, NAN), nan_ok=True)
    assert mx.bootstrap_ci([0.3, NAN]) == pytest.approx((NAN, NAN), nan_ok=True)  # one trial: no CI
    assert mx.bootstrap_ci([0.3, 0.3, 0.3]) == (0.3, 0.3)
    wide = mx.bootstrap_ci(rng.uniform(0, 1, 10), n_boot=500, seed=0)
    narrow = mx.bootstrap_ci(rng.uniform(0, 1, 1000), n_boot=500, seed=0)
    assert narrow[1] - narrow[0] < wide[1] - wide[0]


def test_condition_cis_independent_of_row_order():
    trials = pd.DataFrame(
        {
            "localizer": ["a"] * 6 + ["b"] * 6,
            "sequence": [f"s{i}" for i in range(12)],
            "trajectory": ["x"] * 12,
            "condition": ["c"] * 12,
            "n_total": [10] * 12,
            "P_succ": np.linspace(0.1, 0.9, 12),
            "P_detect": np.linspace(0.2, 1.0, 12),
            "e_rel_mean": np.linspace(0.01, 0.1, 12),
        }
    )
    s = mx.EvalSettings(n_boot=300, seed=3)
    a = mx.condition_cis(trials, s)
    b = mx.condition_cis(trials.iloc[::-1].reset_index(drop=True), s)
    pd.testing.assert_frame_equal(a, b.sort_values("localizer").reset_index(drop=True))


def test_trials_are_per_trajectory_and_few_trials_flagged():
    """Two trajectories with 3 trials each: M = 3 per trajectory, never 6 pooled."""
    rows = []
    for traj in ("approach", "circle"):
        for trial in range(3):
            for i in range(4):
                d = 1.0 + i
                rows.append(
                    {
                        "localizer": "a",
                        "sequence": f"{traj}-t{trial}",
                        "trajectory": traj,
                        "condition": "clear",
                        "trial": trial,
                        "index": i,
                        "d_true": d,
                        "in_view": True,
                        "detected": i <= trial,
                        "d_est": d if i <= trial else NAN,
                        "ms": 1.0,
                    }
                )
    m = mx.compute_all(pd.DataFrame(rows), mx.EvalSettings(n_boot=200))["metrics"].set_index("trajectory")
    assert m["n_trials"].tolist() == [3, 3] and m["few_trials"].all()
    assert m.loc["approach", "P_succ_mean"] == pytest.approx(np.mean([0.25, 0.5, 0.75]))
    assert m.loc["approach", "P_succ_lo"] <= m.loc["approach", "P_succ_mean"] <= m.loc["approach", "P_succ_hi"]


def test_mssd_mspd_hand_computed():
    # a 0.2 m square marker at the dock origin (model box 5 mm deep), camera 5 m away, f = 500 px
    marker = {"id": "m", "keypoints": [[-0.1, 0.1, 0], [0.1, 0.1, 0], [0.1, -0.1, 0], [-0.1, -0.1, 0]]}
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    model = rec.DockModel.from_markers([marker], K, 640)
    assert model.points.shape == (8, 3)
    assert model.diameter_m == pytest.approx(math.sqrt(0.2**2 + 0.2**2 + 0.005**2))
    shifted = _pose(t=(0.05, 0.0, 5.0))  # 5 cm sideways: MSSD 0.05, MSPD ~5 px
    rotated = _pose(_rot_z(90))  # 90 deg about the axis: corners move 0.2 m
    df = _estimates(
        [("a", "s", "c", i, 5.0, True, True, 5.0, None, 1.0, T) for i, T in enumerate([_pose(), shifted, rotated])]
    )
    e = rec.mssd_mspd(df, model)
    assert e["mssd_m"].tolist() == pytest.approx([0.0, 0.05, 0.2], abs=1e-9)
    # the box's back face is at z = 4.995 m in this pose: its shift in pixels is the largest
    assert e["mspd_px"].iloc[:2].tolist() == pytest.approx([0.0, 0.05 * 500 / 4.995], abs=1e-9)
    assert e["mspd_px"].iloc[2] == pytest.approx(0.2 * 500 / 5.0, rel=2e-3)  # ~20 px (depth 5 or 4.995 m)
    # AR: thresholds 0.05..0.5 x diameter (0.2829 m) = 0.0141 .. 0.1414 m: error 0 passes all 10,
    # 0.05 m passes the 7 thresholds from 0.0566 m up, 0.2 m none
    ar = rec.average_recall(e["mssd_m"].to_numpy(), model.mssd_thresholds())
    assert ar == pytest.approx((10 + 7 + 0) / 30)
    assert rec.average_recall(np.array([NAN]), model.mssd_thresholds()) == 0.0  # a miss


def test_truth_table_from_fake_dataset(tmp_path):
    ds = Dataset.open(write_fake_dataset(tmp_path / "ds"))
    truth = frame_truth_table(ds)
    assert len(truth) == 12
    row = truth[(truth.sequence == "clear_000") & (truth["index"] == 5)].iloc[0]
    assert not row["in_view"] and row["markers_in_fov"] == "" and row["visible_fraction:0"] == 0.0
    assert as_matrices(truth["T_cam_dock"])[:, 2, 3].tolist() == pytest.approx(truth["d_true"].tolist())


class Oracle:
    """Reads d_true from the pixels; exact pose (the fake dataset's dock is straight ahead)."""

    def __init__(self, sigma: float = 0.0, seed: int = 0):
        self.sigma, self.rng = sigma, np.random.default_rng(seed)

    def reset(self, camera):
        pass

    def localize(self, image):
        d = decode_distance(image) + self.sigma * self.rng.normal()
        T = np.eye(4)
        T[2, 3] = d
        return {"distance": d, "T_cam_dock": T, "marker_id": "0"}


class Constant:
    """Always 4.2 m, on every frame (the localizer that must never win)."""

    def reset(self, camera):
        pass

    def localize(self, image):
        return {"distance": 4.2}


def run_fake(ds: Dataset, localizers=None):
    """The real runner on the fake dataset."""
    localizers = localizers or [("oracle", Oracle()), ("noisy", Oracle(0.3)), ("constant", Constant())]
    return runner.evaluate(ds, localizers, progress=False)


def test_article_tables(tmp_path):
    ds = Dataset.open(write_fake_dataset(tmp_path / "ds"))
    res = mx.compute_all(run_fake(ds), mx.EvalSettings(n_boot=100))
    art = tables.article_table(res["metrics"])
    assert list(art.columns) == [
        "trajectory",
        "condition",
        "localizer",
        "M",
        tables.ARTICLE_SUCCESS,
        tables.ARTICLE_DETECT,
        tables.ARTICLE_ERROR,
        tables.ARTICLE_MATCHED,
        tables.ARTICLE_MATCHED_RANGE,
    ]
    oracle = art[art.localizer == "oracle"].iloc[0]
    assert oracle[tables.ARTICLE_SUCCESS].startswith("100.0 [100.0, 100.0]") and oracle["M"] == "2*"
    md = tables.article_markdown(res["metrics"])
    tex = tables.article_latex(res["metrics"], caption="x", label="tab:x")
    assert "### trajectory straight" in md and "M < 10 trials" in md
    assert r"\begin{tabular}{lllrrrrrl}" in tex and r"(\%)" in tex and r"\label{tab:x}" in tex


def _request(ds_path, out, **kw):
    from evalkit.reports import results

    return results.EvalRequest(ds_path, ["led"], out, **kw)


def test_save_and_load_run(tmp_path):
    from evalkit.reports import results

    ds = Dataset.open(write_fake_dataset(tmp_path / "ds"))
    est = run_fake(ds)
    record = results.RunRecord(
        ds, ["oracle", "noisy", "constant"], mx.EvalSettings(n_boot=200), command=["dockbench", "evaluate"]
    )
    paths, _ = results.save_run(est, tmp_path / "run", record)
    for key in (
        "estimates",
        "summary",
        "metrics",
        "bins",
        "recall",
        "runtime",
        "article_md",
        "article_tex",
        "plot_error",
        "plot_success",
        "run",
    ):
        assert paths[key].is_file(), key
    assert paths["plot_error"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    run = json.loads(paths["run"].read_text())
    assert run["dataset"]["content_hash"] == ds.manifest["content_hash"] and run["dataset"]["verified"]
    assert [loc["name"] for loc in run["localizers"]] == ["oracle", "noisy", "constant"]
    assert run["environment"]["packages"]["numpy"] == np.__version__
    assert run["settings"]["success"] == core.SuccessCriteria().as_dict()
    loaded = results.load_run(tmp_path / "run")
    m = loaded.metrics.set_index("localizer")
    assert m.loc["oracle", "e_trans_mean"] == pytest.approx(0.0, abs=1e-12)
    assert m.loc["oracle", "AR_dock"] == pytest.approx(1.0) and math.isnan(m.loc["constant", "AR_dock"])
    assert m.loc["constant", "P_detect_mean"] == 1.0 and m.loc["constant", "P_succ_mean"] < 0.2
    assert m.loc["constant", "n_fp"] == 1  # the out-of-view frame
    assert loaded.estimates["T_cam_dock_est"].notna().any()
    assert len(results.compare_runs([loaded, tmp_path / "run"])) == 6


def test_compare_runs_refuses_mixed_datasets(tmp_path):
    from evalkit.reports import results

    dirs = []
    for i, seqs in enumerate(([("a", "clear", 0, [1.0, 2.0])], [("a", "clear", 0, [1.0, 3.0])])):
        ds = Dataset.open(write_fake_dataset(tmp_path / f"ds{i}", sequences=seqs))
        results.save_run(
            run_fake(ds),
            tmp_path / f"run{i}",
            results.RunRecord(ds, ["oracle"], mx.EvalSettings(n_boot=50), make_plots=False),
        )
        dirs.append(tmp_path / f"run{i}")
    with pytest.raises(results.ResultsError, match="different datasets"):
        results.compare_runs(dirs)
    with pytest.raises(results.ResultsError, match="not a dockbench results directory"):
        results.load_run(tmp_path)


def test_representative_trial_is_shared_by_every_localizer_and_panels_have_own_axes(tmp_path):
    from evalkit.reports import plots

    # trial P_succ per localizer: t1 is the median trial for the mean over localizers
    trials = pd.DataFrame(
        {
            "localizer": ["a", "a", "a", "b", "b", "b"],
            "trajectory": "x",
            "condition": "c",
            "sequence": ["t0", "t1", "t2"] * 2,
            "P_succ": [0.1, 0.5, 0.9, 0.9, 0.4, 0.0],
        }
    )
    reps = plots.representative_trials(trials)
    assert reps.to_dict("records") == [{"trajectory": "x", "condition": "c", "sequence": "t1"}]
    plt = plots._pyplot()
    fig, axes = plots._panels(plt, 2)
    axes[0].plot([0, 1], [0, 100])
    axes[1].plot([0, 1], [0, 0.01])
    assert axes[1].get_ylim()[1] < 1.0  # not squashed by the other panel
    plt.close(fig)


def test_old_results_format_is_refused(tmp_path):
    from evalkit.reports import results

    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "run.json").write_text(json.dumps({"format": "dockbench-results", "format_version": "1"}))
    with pytest.raises(results.ResultsError, match="format 1 counted any answer as a success"):
        results.load_run(tmp_path / "old")
