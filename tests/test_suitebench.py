"""The measuring helpers of `dockbench bench suite` (no Blender, nothing timed)."""

import os
import subprocess
import sys

import pytest

from blendgen.tools.bench import suitebench as sb


def test_disk_counts_hard_links_once_and_splits_images(tmp_path):
    rgb = tmp_path / "A" / "sequences" / "s1" / "rgb"
    rnd = tmp_path / "A" / "renders" / "k" / "depth"
    for d in (rgb, rnd, tmp_path / "B" / "renders" / "k" / "depth"):
        d.mkdir(parents=True)
    (rgb / "0.png").write_bytes(os.urandom(64_000))
    (rnd / "0.png").write_bytes(os.urandom(128_000))
    os.link(rnd / "0.png", tmp_path / "B" / "renders" / "k" / "depth" / "0.png")
    d = sb.disk_mb(tmp_path)
    blocks = lambda p: p.stat().st_blocks * 512 / 1e6  # noqa: E731
    assert d["images"] == pytest.approx(blocks(rgb / "0.png"))
    assert d["passes"] == pytest.approx(blocks(rnd / "0.png"))  # the link is not counted twice
    assert d["total"] == pytest.approx(d["images"] + d["passes"])
    assert d["without_images"] == pytest.approx(d["passes"])


def test_tree_rss_includes_children():
    alone = sb.tree_rss_mb(os.getpid())
    child = subprocess.Popen([sys.executable, "-c", "import time; b = bytearray(200_000_000); time.sleep(30)"])
    try:
        for _ in range(100):
            with_child = sb.tree_rss_mb(os.getpid())
            if with_child > alone + 150:
                break
            subprocess.run(["sleep", "0.1"])
        assert with_child > alone + 150  # the child's 200 MB are in the tree's sum
    finally:
        child.kill()
        child.wait()


def test_extrapolation_is_linear_in_trials():
    run = sb.SuiteRun(
        "x",
        2,
        640,
        480,
        "-",
        "turbidity",
        cpu={"generate": 300.0, "evaluate": 60.0},
        wall={"generate": 500.0, "evaluate": 100.0},
        peak_rss_mb=700.0,
        disk={"total": 100.0, "without_images": 20.0},
    )
    x = sb.extrapolate(run, trials=100, cores=2)
    assert x["cpu_h"] == pytest.approx(360 * 50 / 3600)
    assert x["cpu_bound_wall_h"] == pytest.approx(x["cpu_h"] / 2)
    assert x["measured_wall_scaled_h"] == pytest.approx(600 * 50 / 3600)
    assert x["disk_gb"] == pytest.approx(5.0) and x["disk_without_images_gb"] == pytest.approx(1.0)


def test_configure_overrides_size_and_particles():
    exps = sb.configure(("turbidity", "occlusion"), 2, sb.Overrides((1280, 720), 6000, 4.0, 2))
    assert all(e.render.samples == 2 and e.render.max_distance_m == 4.0 for e in exps)
    assert [e.trials for e in exps] == [2, 2]
    assert all((e.camera.width, e.camera.height) == (1280, 720) for e in exps)
    assert [c.occlusion.n_total for c in exps[1].conditions] == [6000]
    assert len(exps[0].conditions) == 3 and len({e.name for e in exps}) == 2
