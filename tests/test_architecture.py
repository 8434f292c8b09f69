"""The house rules of docs/architecture.md, read from the source: module-level imports inside logiq_sql form no
cycle (imports inside functions, made to defer a heavy dependency, are not counted), and no module imports another
module's private (`_name`) names, at any level."""

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
