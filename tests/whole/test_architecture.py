"""The house rules of docs/architecture.md, read from the source: the package's layers (core, spec, storage,
ingestion, engines, matching, outputs, evaluation, cli) import downwards only and the harness never imports the
matcher (imports inside functions count); module-level imports form no cycle (imports inside functions, made to
defer a heavy dependency, are not counted); no module imports another module's private (`_name`) names, at any
level."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.source_imports import logiq_imports, package_modules


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 on the current path, 2 done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                stack = path + [node]
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt, path + [node])):
                return cycle
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start, [])):
            return cycle
    return None


def test_module_level_imports_form_no_cycle():
    trees = package_modules()
    graph = {name: {m for m, _ in logiq_imports(tree.body, set(trees)) if m in trees and m != name}
             for name, tree in trees.items()}
    assert graph["logiq_sql.matching.match"], "the walk sees the matcher's imports"
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_the_cycle_check_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) is not None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_module_imports_another_modules_private_names():
    trees = package_modules()  # imports inside functions count too
    private = [f"{name}: from {module} import {n}" for name, tree in trees.items()
               for module, names in logiq_imports(ast.walk(tree), set(trees)) for n in names if n.startswith("_")]
    assert not private, private


# The layers of docs/architecture.md, lowest first: a module imports only from its own layer and those below it,
# at module level or inside a function. logiq_sql/__init__.py, the front door, re-exports from any layer.
LAYERS = ("core", "spec", "storage", "ingestion", "engines", "matching", "outputs", "evaluation", "cli")


def layer_of(module: str) -> str:
    return module.split(".")[1]


def upward_imports(trees: dict[str, ast.Module]) -> list[str]:
    found = []
    for name, tree in trees.items():
        if name == "logiq_sql":
            continue
        for module, _ in logiq_imports(ast.walk(tree), set(trees)):
            if module != "logiq_sql" and LAYERS.index(layer_of(module)) > LAYERS.index(layer_of(name)):
                found.append(f"{name} ({layer_of(name)}) imports {module} ({layer_of(module)})")
    return found


def test_every_module_sits_in_a_layer():
    trees = package_modules()
    assert {layer_of(name) for name in trees if name != "logiq_sql"} == set(LAYERS)


def test_layers_import_downwards_only():
    assert not upward_imports(package_modules()), upward_imports(package_modules())


def test_the_layer_check_finds_an_upward_import():
    trees = {name: ast.parse(text) for name, text in {
        "logiq_sql.core.units": "", "logiq_sql.spec.scenario": "def f():\n    from logiq_sql.matching import match\n",
        "logiq_sql.matching.match": "from logiq_sql.core import units\n"}.items()}
    assert upward_imports(trees) == ["logiq_sql.spec.scenario (spec) imports logiq_sql.matching.match (matching)"]


def test_the_harness_never_imports_the_matcher():
    """The evaluation's ground truth must not depend on the matcher it judges (docs/evaluation.md)."""
    trees = package_modules()
    found = [f"{name} imports {module}" for name, tree in trees.items() if name.startswith("logiq_sql.evaluation")
             for module, _ in logiq_imports(ast.walk(tree), set(trees)) if module.startswith("logiq_sql.matching")]
    assert not found, found


# The tests mirror the package: tests/<layer>/ holds the tests of the layer they exercise first, tests/whole/ the
# end-to-end checks of every layer, so a change in a layer names its tests: python -m pytest -p no:xdist tests/<layer>.
TEST_FOLDERS = (*LAYERS, "whole")
TESTS = Path(__file__).resolve().parents[1]


def layer_of_test(path: Path) -> str | None:
    """The layer a test file tests: the folder of tests/ it sits in (None outside a layer folder)."""
    relative = path.resolve().relative_to(TESTS)
    return relative.parts[0] if len(relative.parts) == 2 and relative.parts[0] in TEST_FOLDERS else None


def test_every_test_file_sits_in_its_layers_folder():
    files = [p for p in TESTS.rglob("test_*.py") if not {"data", "golden"} & set(p.relative_to(TESTS).parts)]
    outside = sorted(str(p.relative_to(TESTS)) for p in files if layer_of_test(p) is None)
    assert not outside, f"move these into tests/<layer>/, the layer each tests ({', '.join(TEST_FOLDERS)}): {outside}"
    assert {layer_of_test(p) for p in files} == set(TEST_FOLDERS), "every layer has its tests"


def test_the_folder_check_finds_a_test_outside_a_layer_folder():
    assert layer_of_test(TESTS / "matching" / "test_phases.py") == "matching"
    assert layer_of_test(TESTS / "test_phases.py") is None
    assert layer_of_test(TESTS / "helpers" / "test_phases.py") is None
    assert layer_of_test(TESTS / "matching" / "deeper" / "test_phases.py") is None
