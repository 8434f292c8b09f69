"""The house rules of docs/architecture.md, read from the source: module-level imports inside logiq_sql form no
cycle (imports inside functions, made to defer a heavy dependency, are not counted), and no module imports another
module's private (`_name`) names, at any level."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "logiq_sql"


def modules() -> dict[str, ast.Module]:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found[name] = ast.parse(path.read_text(), str(path))
    return found


def imports(nodes, known: set[str]) -> list[tuple[str, list[str]]]:
    """(module, names) of every ``from logiq_sql... import`` or ``import logiq_sql...`` among ``nodes``; a name
    that is itself a submodule is an import of that submodule (Python loads the package first, but finishes it
    first)."""
    found = []
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "logiq_sql":
            names = [a.name for a in node.names]
            subs = [f"{node.module}.{n}" for n in names if f"{node.module}.{n}" in known]
            found += [(s, []) for s in subs]
            rest = [n for n in names if f"{node.module}.{n}" not in known]
            if rest:
                found.append((node.module, rest))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.split(".")[0] == "logiq_sql"]
    return found


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
    trees = modules()
    graph = {name: {m for m, _ in imports(tree.body, set(trees)) if m in trees and m != name}
             for name, tree in trees.items()}
    assert graph["logiq_sql.match"], "the walk sees the matcher's imports"
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_the_cycle_check_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) is not None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_module_imports_another_modules_private_names():
    trees = modules()  # imports inside functions count too
    private = [f"{name}: from {module} import {n}" for name, tree in trees.items()
               for module, names in imports(ast.walk(tree), set(trees)) for n in names if n.startswith("_")]
    assert not private, private
