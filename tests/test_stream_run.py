"""`dockbench run`: generate and evaluate in one pass. What it evaluated is the dataset
`dockbench generate` writes from the same config (every file's sha256, content hash),
its metrics are those of generate + evaluate, only the sampled images stay on disk, and
an interrupted run resumes to the same results."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml

pytestmark = pytest.mark.integration  # `dockbench run` end to end

ROOT = Path(__file__).resolve().parent.parent

# 160x120 at 1 spp, two camera paths x two image-space conditions: 4 sequences, 2 renders
TINY = {
    "name": "tiny-run",
    "version": "1.0.0",
    "seed": 11,
    "scene": {"template": "pool_15x5x8"},
    "camera": {"width": 160, "height": 120, "hfov_deg": 60, "fps": 5},
    "render": {"fidelity": "fast", "samples": 1},
    "water": {"preset": "clear"},
    "trajectories": [
        {"kind": "linear", "id": "a", "start_range_m": 3.0, "end_range_m": 1.0, "speed_mps": 2.0},
        {"kind": "linear", "id": "b", "start_range_m": 2.5, "end_range_m": 0.8, "speed_mps": 2.0, "lateral_m": 0.2},
    ],
    "conditions": [
        {"label": "clear", "water": {"preset": "clear"}},
        {"label": "murky", "water": {"preset": "moderate"}},
    ],
}
LOCS = ["-l", "led", "-l", "qr", "-l", "hybrid"]


def _cmd(*args) -> list[str]:
    return [sys.executable, "-c", "import cli; cli.main()", *map(str, args)]


def _ok(*args) -> subprocess.CompletedProcess:
    r = subprocess.run(_cmd(*args), cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    return r


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One `run --images sample:2`, and generate + evaluate of the same config."""
    d = tmp_path_factory.mktemp("stream")
    cfg = d / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    _ok("run", cfg, *LOCS, "-o", d / "run", "--images", "sample:2", "-q")
    _ok("generate", cfg, "-o", d / "gen")
    _ok("evaluate", d / "gen", *LOCS, "-o", d / "ev", "-q")
    return cfg, d


def _stream(run: Path) -> dict:
    return json.loads((run / "stream.json").read_text())


@pytest.mark.blender
def test_run_evaluated_the_dataset_generate_writes(runs):
    cfg, d = runs
    from evalkit.stream import check_against

    st, man = _stream(d / "run"), json.loads((d / "gen" / "manifest.json").read_text())
    assert set(st["files"]) | set(st["pixels"]) == set(man["files"])  # every file of the dataset
    assert all(st["files"][p] == man["files"][p] for p in st["files"])  # hashed by its bytes...
    pngs = sorted(p.relative_to(d / "gen").as_posix() for p in (d / "gen").glob("[sr]*/*/*/*.png"))
    assert sorted(st["pixels"]) == [p for p in pngs if p not in st["files"]]  # images and passes
    assert len(st["pixels"]) == len(pngs) - 4 * 2 - 2 * 2 * 2  # all but sample:2 (images; range, index)
    assert check_against(st, d / "gen") == []  # ...or, never encoded, by its decoded pixels
    run_json = json.loads((d / "run" / "results" / "run.json").read_text())
    assert run_json["dataset"]["content_hash"] == st["content_hash"]


@pytest.mark.blender
@pytest.mark.parametrize("kind", ["/rgb/", "/depth/", "/index/"])
def test_a_changed_pixel_of_an_image_never_encoded_is_caught(runs, tmp_path, kind):
    import shutil

    import cv2

    from evalkit.stream import check_against

    cfg, d = runs
    st = _stream(d / "run")
    gen = tmp_path / "gen"
    shutil.copytree(d / "gen", gen)
    p = next(p for p in sorted(st["pixels"]) if kind in p)
    img = cv2.imread(str(gen / p), cv2.IMREAD_UNCHANGED)
    img[(0,) * img.ndim] ^= 1
    cv2.imwrite(str(gen / p), img)
    assert check_against(st, gen) == [f"{p}: pixels differ"]
    assert subprocess.run(_cmd("verify", d / "gen", "--stream", d / "run" / "stream.json"), cwd=ROOT).returncode == 0


@pytest.mark.blender
def test_images_all_hashes_every_file_like_generate(runs, tmp_path):
    cfg, d = runs
    _ok("run", cfg, "-l", "led", "-o", tmp_path / "run", "--images", "all", "-q")
    st, man = _stream(tmp_path / "run"), json.loads((d / "gen" / "manifest.json").read_text())
    assert st["pixels"] == {} and st["files"] == man["files"] and st["content_hash"] == man["content_hash"]
    assert not list((tmp_path / "run").rglob(".*.npy"))


@pytest.mark.blender
def test_the_metrics_of_run_are_those_of_generate_then_evaluate(runs):
    cfg, d = runs
    for f in ("metrics.csv", "summary.csv", "bins.csv"):  # no timings in these: byte-identical
        assert (d / "run" / "results" / f).read_bytes() == (d / "ev" / f).read_bytes(), f
    a = pd.read_parquet(d / "run" / "results" / "estimates.parquet").drop(columns=["ms"])
    b = pd.read_parquet(d / "ev" / "estimates.parquet").drop(columns=["ms"])
    pd.testing.assert_frame_equal(a, b)


@pytest.mark.blender
def test_only_the_sample_stays_and_what_stays_is_a_valid_dataset(runs):
    cfg, d = runs
    ds = d / "run" / "dataset"
    man = json.loads((ds / "manifest.json").read_text())
    rgb = sorted(p.relative_to(ds).as_posix() for p in ds.glob("sequences/*/rgb/*.png"))
    assert len(rgb) == 4 * 2  # 4 sequences x sample:2
    assert all(_stream(d / "run")["files"][p] == man["files"][p] for p in rgb)
    passes = list(ds.glob("renders/*/*/*.png"))
    assert len(passes) == 2 * 2 * 2  # 2 renders x 2 frames x (range, index)
    assert subprocess.run(_cmd("verify", ds), cwd=ROOT).returncode == 0


def _start(cfg: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        _cmd("run", cfg, *LOCS, "-o", out, "--images", "none", "-q", "--workers", "1"),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


@pytest.mark.blender
def test_a_run_killed_after_its_first_evaluated_sequence_resumes_to_the_same_results(runs, tmp_path):
    from evalkit.stream import check_against, done

    cfg, d = runs
    out = tmp_path / "run"

    def finished() -> list[Path]:  # estimates saved and recorded (a bare .parquet may not be yet)
        return [q for q in out.glob(".stream/*/*.parquet") if done(q.parent, q.stem)]

    p = _start(cfg, out)
    t_end = time.monotonic() + 300
    while not finished() and p.poll() is None and time.monotonic() < t_end:
        time.sleep(0.05)
    assert p.poll() is None, "the run ended before it could be interrupted"
    os.killpg(p.pid, signal.SIGKILL)  # the parent, render and evaluation workers
    p.wait()
    done_before = {q.name: q.stat().st_mtime_ns for q in finished()}
    assert done_before
    _ok("run", cfg, *LOCS, "-o", out, "--images", "none", "-q")
    st, first = _stream(out), _stream(d / "run")  # --images none: no image encoded
    assert set(st["files"]) | set(st["pixels"]) == set(first["files"]) | set(first["pixels"])
    assert not [p for p in st["files"] if p.endswith(".png") and not p.startswith("assets/")]
    assert all(st["pixels"][p] == h for p, h in first["pixels"].items())
    assert all(st["files"][p] == first["files"][p] for p in st["files"])
    assert check_against(st, d / "gen") == []
    assert (out / "results" / "metrics.csv").read_bytes() == (d / "ev" / "metrics.csv").read_bytes()
    assert {
        q.name: q.stat().st_mtime_ns for q in out.glob(".stream/*/*.parquet") if q.name in done_before
    } == done_before  # finished sequences were not evaluated again
    assert not list((out / "dataset").glob("sequences/*/rgb/*.png"))  # --images none
    assert not list((out / "dataset").rglob(".*.npy"))  # raw pixels gone once evaluated


@pytest.mark.parametrize(
    "args, says",
    [
        (["--images", "some"], "--images 'some'"),
        (["--images", "sample:0"], "sample:N with N >= 1"),
        (["-l", "nosuch"], "nosuch"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, says):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    locs = [] if "-l" in args else ["-l", "led"]
    r = subprocess.run(
        _cmd("run", cfg, *locs, *args, "-o", tmp_path / "out"), cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_the_images_policy_keeps_evenly_spaced_frames_first_and_last_included():
    from evalkit.stream import ImagesPolicyError, kept_indices, parse_images

    idx = list(range(10, 20))
    assert kept_indices(idx, "all") is None and kept_indices(idx, "none") == []
    assert kept_indices(idx, "sample:3") == [10, 14, 19] or kept_indices(idx, "sample:3") == [10, 15, 19]
    assert kept_indices(idx, "sample:2") == [10, 19]
    assert kept_indices(idx, "sample:50") == idx  # more than there are: all of them
    assert kept_indices([], "sample:4") == []
    for bad in ("sample", "sample:-1", "sample:x", "some", ""):
        with pytest.raises(ImagesPolicyError):
            parse_images(bad)


@pytest.mark.blender
def test_a_run_folder_of_other_localizers_is_refused_not_mixed(runs):
    cfg, d = runs
    before = (d / "run" / "stream.json").read_bytes()
    r = subprocess.run(
        _cmd("run", cfg, "-l", "led", "-o", d / "run", "-q"), cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2 and "other localizers" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert (d / "run" / "stream.json").read_bytes() == before


@pytest.mark.blender
def test_a_truncated_cache_is_refused_on_resume_naming_the_file(runs, tmp_path):
    """A run folder's cache cut short (or edited) is a one-line error on resume, rc 2."""
    import shutil

    cfg, d = runs
    out = tmp_path / "run"
    shutil.copytree(d / "run", out)
    pq = sorted(out.glob(".stream/*/*.parquet"))[0]
    pq.write_bytes(pq.read_bytes()[:100])
    r = subprocess.run(
        _cmd("run", cfg, *LOCS, "-o", out, "--images", "sample:2", "-q"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert str(pq) in r.stderr and "sha256 differs" in r.stderr, r.stderr
