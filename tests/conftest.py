"""Shared pytest set-up: the --slow profile and the Blender availability marker."""

import importlib.util
import os

import pytest
from hypothesis import settings

settings.register_profile("ci", max_examples=60, deadline=None)
settings.register_profile("slow", max_examples=2000, deadline=None)


def pytest_addoption(parser):
    parser.addoption("--slow", action="store_true", help="run slow stress tests and long hypothesis runs")


def pytest_configure(config):
    settings.load_profile("slow" if config.getoption("--slow") else os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_collection_modifyitems(config, items):
    have_bpy = importlib.util.find_spec("bpy") is not None
    for item in items:
        if "slow" in item.keywords and not config.getoption("--slow"):
            item.add_marker(pytest.mark.skip(reason="slow: run with --slow"))
        if "blender" in item.keywords and not have_bpy:
            item.add_marker(pytest.mark.skip(reason="bpy not installed"))


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """Print the hostile corpus table (tests/test_hostile.py: case | rc | message) at the end of
    every run that ran hostile cases, so CI logs show it without ``-s``."""
    import sys

    mod = sys.modules.get("tests.test_hostile") or sys.modules.get("test_hostile")
    rows = getattr(mod, "SUMMARY", None)
    if not rows:
        return
    width = max(len(n) for n, _, _ in rows)
    terminalreporter.section(f"hostile corpus: {len(rows)} cases")
    terminalreporter.write_line(f"{'case':{width}s} | rc | message")
    for name, rc, msg in rows:
        terminalreporter.write_line(f"{name:{width}s} | {rc:2d} | {msg}")
