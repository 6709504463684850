"""The package as a user installs it: wheel contents, a non-editable install outside the source tree
(generate -> verify -> evaluate -> leaderboard from a temporary directory), and the evaluation-only base
package on another Python (no bpy), evaluating the dataset checked in at tests/data/tiny.

The install tests build real virtual environments from the package registry (pip's cache makes them
cheap after the first run); they are marked ``install``.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "tests" / "data" / "tiny"


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_package_list_matches_the_tree():
    """pyproject lists packages by hand (bundled data is mapped in): every package dir is listed,
    and so is every data folder inside a package (a folder with package data and no __init__.py)."""
    tool = _pyproject()["tool"]["setuptools"]
    listed = set(tool["packages"])
    found = {
        str(p.parent.relative_to(ROOT)).replace(os.sep, ".")
        for top in ("blendgen", "evalkit", "datasets_spec")
        for p in (ROOT / top).rglob("__init__.py")
        if p.parent.name != "testing"
    }  # probes and oracles for the tests stay out of the wheel
    mapped = set(tool["package-dir"])
    data_dirs = set(tool["package-data"]) - found - mapped
    assert all((ROOT / d.replace(".", os.sep)).is_dir() for d in data_dirs), data_dirs
    assert found | mapped | data_dirs == listed


def test_bundled_data_resolves_in_the_source_tree():
    from blendgen.config.bundled import bundled_file, bundled_names
    from datasets_spec.io import doc_path, load_schema

    assert {"pool_15x5x8", "open_water"} <= set(bundled_names("templates"))
    assert {"quickstart", "paper_turbidity", "calibration"} <= set(bundled_names("configs"))
    assert bundled_file("configs", "quickstart.yaml").is_file()
    assert load_schema("manifest.schema.json")["type"] == "object"
    assert doc_path("FORMAT.md").is_file()


def _env() -> dict:
    """The environment without anything that would let the source tree shadow the install."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}


def _run(cmd: list, cwd: Path, check: bool = True, timeout: float = 900) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=timeout)
    if check and r.returncode != 0:
        raise AssertionError(f"{' '.join(map(str, cmd))} -> {r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return r


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel, built from a copy of the tracked sources (the build writes nothing into the tree)."""
    out = tmp_path_factory.mktemp("wheel")
    src = out / "src"
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for rel in filter(None, tracked.decode().split("\0")):
        if (ROOT / rel).is_file() and not rel.startswith("tests/"):
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, src / rel)
    _run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", out, src], cwd=out)
    (whl,) = out.glob("dockbench-*.whl")
    return whl


@pytest.mark.install
def test_wheel_holds_every_data_file_the_commands_need(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for need in (
        "cli.py",
        "datasets_spec/FORMAT.md",
        "datasets_spec/LOCALIZER_PROTOCOL.md",
        "datasets_spec/manifest.schema.json",
        "datasets_spec/frame.schema.json",
        "blendgen/bundled/templates/pool_15x5x8.yaml",
        "blendgen/bundled/templates/open_water.yaml",
        "blendgen/bundled/configs/quickstart.yaml",
        "blendgen/bundled/configs/paper_occlusion.yaml",
        "blendgen/bundled/configs/calibration.yaml",
        "blendgen/data/water_calibration.json",
    ):
        assert need in names, need
    assert not any(n.startswith(("tests/", "out/")) for n in names)


def _venv(python: str, where: Path) -> Path:
    _run([python, "-m", "venv", where], cwd=where.parent)
    _run([where / "bin" / "python", "-m", "pip", "install", "--quiet", "--upgrade", "pip"], cwd=where.parent)
    return where / "bin"


@pytest.mark.install
@pytest.mark.blender
def test_non_editable_install_runs_the_whole_job_from_elsewhere(wheel, tmp_path):
    """Render, verify, evaluate and rank from a folder that is not the source tree."""
    bin_ = _venv(sys.executable, tmp_path / "venv")
    _run(
        [
            bin_ / "python",
            "-m",
            "pip",
            "install",
            "--quiet",
            "-c",
            ROOT / "constraints" / "py313.txt",
            f"{wheel}[render]",
        ],
        cwd=tmp_path,
    )
    work = tmp_path / "work"
    work.mkdir()
    cfg = work / "tiny.yaml"
    cfg.write_text((ROOT / "tests" / "data" / "tiny.yaml").read_text())  # names a bundled template
    db = bin_ / "dockbench"
    _run([db, "generate", cfg, "-o", "ds"], cwd=work)
    assert "ok" in _run([db, "verify", "ds"], cwd=work).stdout
    _run([db, "evaluate", "ds", "-l", "led", "-l", "aruco", "-o", "res"], cwd=work)
    assert (work / "res" / "run.json").is_file()
    _run([db, "leaderboard", "res", "-o", "board.html"], cwd=work)
    assert (work / "board.html").stat().st_size > 1000
    assert "Usage" in _run([db, "reproduce", "--help"], cwd=work).stdout


def _other_python() -> str | None:
    """A supported Python other than this one (3.11 or 3.12), if the machine has one."""
    mine = f"{sys.version_info.major}.{sys.version_info.minor}"
    for ver in ("3.11", "3.12"):
        if ver == mine:
            continue
        for cand in [
            f"python{ver}",
            *sorted(glob.glob(os.path.expanduser(f"~/.pyenv/versions/{ver}*/bin/python{ver}"))),
        ]:
            r = subprocess.run([cand, "-c", "import sys; print(sys.version_info[:2])"], capture_output=True)
            if r.returncode == 0:
                return cand
    return None


@pytest.mark.install
def test_evaluation_only_install_on_another_python(wheel, tmp_path):
    """The base package (no render extra, no bpy) evaluates a dataset on Python 3.11/3.12; rendering
    commands say what to install instead of a traceback."""
    python = _other_python()
    if python is None:
        pytest.skip("no second supported Python (3.11 or 3.12) on this machine")
    bin_ = _venv(python, tmp_path / "venv")
    _run(
        [bin_ / "python", "-m", "pip", "install", "--quiet", "-c", ROOT / "constraints" / "base-py311.txt", wheel],
        cwd=tmp_path,
    )
    assert (
        _run(
            [bin_ / "python", "-c", "import importlib.util as u; print(u.find_spec('bpy') is None)"], cwd=tmp_path
        ).stdout.strip()
        == "True"
    )
    db = bin_ / "dockbench"
    _run([db, "evaluate", TINY, "-l", "led", "-l", "aruco", "-o", "res"], cwd=tmp_path)
    run = json.loads((tmp_path / "res" / "run.json").read_text())
    assert run["dataset"]["content_hash"] == json.loads((TINY / "manifest.json").read_text())["content_hash"]
    r = _run([db, "generate", ROOT / "tests" / "data" / "tiny.yaml", "-o", "ds"], cwd=tmp_path, check=False)
    assert r.returncode == 2 and "dockbench[render]" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "ds" / "manifest.json").exists()
