"""The house rules of docs/architecture.md, read from the source: the package's layers (core, spec, storage,
ingestion, engines, matching, outputs, evaluation, cli) import downwards only and the harness never imports the
matcher (imports inside functions count); module-level imports form no cycle (imports inside functions, made to
defer a heavy dependency, are not counted); no module imports another module's private (`_name`) names, at any
level."""

from __future__ import annotations

import ast

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


# The tests by the layer they exercise first (the package's folders; "whole" for end-to-end checks of every layer),
# so a change in a layer names its tests: python -m pytest -p no:xdist $(the files of that layer).
TESTS_BY_LAYER = {
    "core": ("test_errors", "test_sql"),
    "spec": ("test_contract",),
    "storage": ("test_concurrency", "test_interrupted", "test_step_cache", "test_keep"),
    "ingestion": ("test_bad_input", "test_ingest_av2", "test_ingest_batch", "test_ingest_commonroad",
                  "test_ingest_scenarionet", "test_ingest_sumo", "test_formats_opendrive", "test_formats_osi",
                  "test_formats_sumo_folders", "test_localise", "test_localise_join", "test_accounting", "test_keys"),
    "engines": ("test_polars", "test_spark", "test_spark_cluster", "test_spark_dataset", "test_shared_steps"),
    "matching": ("test_phases", "test_relations", "test_relations_of", "test_relations_prune", "test_cut_out",
                 "test_left_turn", "test_left_turn_real", "test_manoeuvres", "test_interval_oracle", "test_properties",
                 "test_frames", "test_incremental", "test_determinism", "test_real_cases", "test_real_data"),
    "outputs": ("test_replay", "test_pictures", "test_formats_export", "test_analysts"),
    "evaluation": ("test_evaluate", "test_labels", "test_conflict_labels", "test_junction_regimes",
                   "test_sumo_evaluation"),
    "cli": ("test_cli_docs", "test_front_door", "test_scheduling"),
    "whole": ("test_architecture", "test_golden", "test_baseline", "test_notebooks", "test_wheel"),
}


def test_every_test_file_names_its_layer():
    from pathlib import Path

    files = sorted(p.stem for p in Path(__file__).parent.glob("test_*.py"))
    listed = sorted(name for names in TESTS_BY_LAYER.values() for name in names)
    assert listed == files, "add the new test file to TESTS_BY_LAYER under the layer it tests"
    assert set(TESTS_BY_LAYER) == {*LAYERS, "whole"}
