"""The layout's rules, read from the source (function-local imports included):

- no import cycle between project modules;
- blendgen and evalkit never import each other, except blendgen.tools (bench, fidelity, reproduce, ...),
  which sits on top of both halves; datasets_spec imports neither;
- bpy/mathutils only under blendgen/blender/;
- no function longer than 80 lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("blendgen", "evalkit", "datasets_spec")
MAX_FUNCTION_LINES = 80


def _modules() -> dict[str, Path]:
    mods = {}
    for top in PACKAGES:
        for p in (ROOT / top).rglob("*.py"):
            name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
            mods[name.removesuffix(".__init__")] = p
    return mods


def _imported_names(module: str, path: Path, node: ast.AST) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    if node.level:
        base = base[: len(base) - node.level + 1]
        prefix = ".".join(base + ([node.module] if node.module else []))
    else:
        prefix = node.module or ""
    return [prefix] + [f"{prefix}.{a.name}" for a in node.names]


def _graph() -> tuple[dict[str, Path], dict[str, set[str]], dict[str, set[str]]]:
    """(modules, project edges, all imported top-level names) per module."""
    mods = _modules()
    edges: dict[str, set[str]] = {m: set() for m in mods}
    external: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        for node in ast.walk(ast.parse(p.read_text())):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for name in _imported_names(m, p, node):
                external[m].add(name.split(".")[0])
                while name and name not in mods:
                    name = name.rpartition(".")[0]
                if name and name != m:
                    edges[m].add(name)
    return mods, edges, external


def test_no_import_cycles():
    mods, edges, _ = _graph()
    names = sorted(mods)
    idx = {n: i for i, n in enumerate(names)}
    rows = [idx[a] for a in names for b in edges[a]]
    cols = [idx[b] for a in names for b in edges[a]]
    g = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names), len(names)))
    _, labels = connected_components(g, directed=True, connection="strong")
    cycles = [[n for n in names if labels[idx[n]] == lab] for lab in set(labels) if (labels == lab).sum() > 1]
    assert cycles == []


def test_generator_and_evaluator_meet_only_in_the_contract():
    mods, edges, _ = _graph()
    bad = []
    for m, targets in edges.items():
        for t in targets:
            top_m, top_t = m.split(".")[0], t.split(".")[0]
            if top_m == "datasets_spec" and top_t != "datasets_spec":
                bad.append(f"{m} -> {t}")
            elif {top_m, top_t} == {"blendgen", "evalkit"} and not m.startswith("blendgen.tools"):
                bad.append(f"{m} -> {t}")
    assert bad == []


def test_bpy_only_under_blendgen_blender():
    _, _, external = _graph()
    bad = [m for m, tops in external.items() if tops & {"bpy", "mathutils"} and not m.startswith("blendgen.blender")]
    assert bad == []


def test_functions_fit_on_a_screen():
    long = []
    for p in _modules().values():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name} {n}")
    assert long == []


def _subpackage(module: str) -> str | None:
    """``blendgen.<sub>`` of a module two levels down (``blendgen.pipeline.plan`` -> ``pipeline``)."""
    parts = module.split(".")
    return parts[1] if parts[0] == "blendgen" and len(parts) >= 3 else None


def package_cycles(edges: dict[str, set[str]]) -> list[str]:
    """Pairs of blendgen subpackages that import each other, e.g. ``blender<->pipeline``."""
    pairs = {(_subpackage(a), _subpackage(b)) for a, targets in edges.items() for b in targets}
    pairs = {(a, b) for a, b in pairs if a and b and a != b}
    return sorted(f"{a}<->{b}" for a, b in pairs if (b, a) in pairs and a < b)


def test_no_package_cycles():
    """Subpackages layer too: blender (the renderer) imports nothing from pipeline (which drives it)."""
    _, edges, _ = _graph()
    assert package_cycles(edges) == []


def test_package_cycles_are_seen():
    edges = {
        "blendgen.pipeline.frameloop": {"blendgen.blender.renderer"},
        "blendgen.blender.renderer": {"blendgen.pipeline.plan"},
        "blendgen.geometry": {"blendgen.physics.water.optics"},
    }
    assert package_cycles(edges) == ["blender<->pipeline"]
    edges["blendgen.blender.renderer"] = set()
    assert package_cycles(edges) == []
