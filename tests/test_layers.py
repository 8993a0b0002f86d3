"""The import layering of the architecture (README, docs/architecture.md), checked on the
source: a package imports only itself and packages above it, no stage imports the sample
world, and no file imports back into a file that imports it (no import cycle, counting the
imports inside functions too)."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1]
NAMESPACE = "care_maps"
"""The one top-level package; the layers are its subpackages."""
ORDER = [
    "core", "runtime", "geometry", "ingest", "truth", "world", "fuse", "query", "replan",
    "evaluate", "research", "cli",
]  # fmt: skip
"""Upstream first: a subpackage may import only itself and subpackages before it."""
STAGES = ("ingest", "truth", "fuse", "query", "replan", "evaluate")
"""The product's stages: none imports ``world`` (the sample world), which only the CLI's
``care sample`` and the research code use."""


def _layer(module: str) -> str:
    """The subpackage (layer) of a module of the namespace: ``care_maps.fuse.grid`` -> fuse."""
    return module.split(".")[1] if module.count(".") else ""


def _modules() -> dict[str, Path]:
    found = {}
    for package in ORDER:
        for path in (ROOT / NAMESPACE / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _imported(path: Path, module: str) -> set[str]:
    """Every module name ``path`` imports, anywhere in it (absolute, relative made absolute;
    ``from a import b`` counts both ``a`` and ``a.b``)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*parent, *([node.module] if node.module else [])])
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


@functools.cache
def _graph() -> nx.DiGraph:
    """The import graph of every module, parsed once for all the tests (read, not changed)."""
    modules = _modules()
    graph = nx.DiGraph()
    for module, path in modules.items():
        graph.add_node(module)
        for name in _imported(path, module):
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name != module:
                graph.add_edge(module, name)
    return graph


@pytest.mark.parametrize("package", ORDER)
def test_package_imports_only_upstream(package: str) -> None:
    allowed = set(ORDER[: ORDER.index(package) + 1])
    bad = sorted(
        (a, b) for a, b in _graph().edges if _layer(a) == package and _layer(b) not in allowed
    )
    assert not bad, f"imports against the layering: {bad}"


def test_no_stage_imports_the_sample_world() -> None:
    bad = sorted((a, b) for a, b in _graph().edges if _layer(a) in STAGES and _layer(b) == "world")
    assert not bad, f"stages importing the sample world: {bad}"


def test_no_import_cycle_between_files() -> None:
    graph = _graph().copy()
    # a package's __init__ re-exporting its modules is not a cycle of responsibilities
    graph.remove_edges_from([(a, b) for a, b in graph.edges if b == a.rpartition(".")[0]])
    cycles = [sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]
    assert not cycles, f"import cycles: {cycles}"


def test_one_top_level_package() -> None:
    """Nothing importable beside the namespace: every product module lives under it."""
    tops = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert tops == {NAMESPACE}, tops


CONCURRENCY = ("concurrent.futures", "threading", "multiprocessing")
"""The standard library's threads and processes."""
OWN_THREADS = {
    "care_maps.core.store": "the store writer's one encoding thread (core is below runtime)",
    "care_maps.cli.main": "the interruption's line and its watchdog (the program's, on top)",
}
"""The modules outside ``runtime`` allowed a thread of their own, and why."""


def test_only_runtime_starts_threads_and_processes() -> None:
    """Thread pools, processes, read-ahead: ``care_maps.runtime``'s (the maths modules ask
    it, ``runtime.background``, ``runtime.parallel``), but for :data:`OWN_THREADS`."""
    bad = sorted(
        module
        for module, path in _modules().items()
        if _layer(module) != "runtime"
        and module not in OWN_THREADS
        and any(name.startswith(CONCURRENCY) for name in _imported(path, module))
    )
    assert not bad, f"threads or processes outside runtime: {bad}"
