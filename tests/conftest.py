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
