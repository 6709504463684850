"""Smoke test of the experiment scripts (experiments/*.py): every project import they make resolves.

They render or run for minutes, so they are not run here; this catches a script left behind by a
rename or a move (module gone, name gone) without running it. Scripts with a ``__main__`` guard
are also imported (their top level only defines functions)."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted((ROOT / "experiments").glob("*.py"))
PROJECT = ("blendgen", "evalkit", "datasets_spec", "cli")


def _project_imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names) of every import of a project module in the script."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names if a.name.split(".")[0] in PROJECT]
        elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] in PROJECT:
            out.append((node.module, [a.name for a in node.names]))
    return out


def _has_main_guard(path: Path) -> bool:
    return any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in ast.parse(path.read_text()).body)


def test_there_are_experiments():
    assert SCRIPTS, "experiments/ holds no script"


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: p.name)
def test_project_imports_resolve(path):
    for module, names in _project_imports(path):
        if module.startswith("blendgen.blender") and importlib.util.find_spec("bpy") is None:
            continue
        mod = importlib.import_module(module)
        for name in names:
            assert hasattr(mod, name) or importlib.util.find_spec(f"{module}.{name}") is not None, (
                f"{path.name}: {module} has no {name}"
            )


@pytest.mark.parametrize("path", [p for p in SCRIPTS if _has_main_guard(p)], ids=lambda p: p.name)
def test_guarded_scripts_import(path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "tests"))
    monkeypatch.setattr(sys, "argv", [str(path)])  # some read their arguments at import
    spec = importlib.util.spec_from_file_location(f"experiment_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
