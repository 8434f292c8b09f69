"""logiq_sql's own imports, read from the source with ast (no module is imported): for the tests of the house
rules (tests/whole/test_architecture.py) and of what the labeller may import (tests/evaluation/test_labels.py)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "logiq_sql"


def package_modules() -> dict[str, ast.Module]:
    """Every module of logiq_sql by its dotted name (a package by its own name), parsed."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found[name] = ast.parse(path.read_text(), str(path))
    return found


def logiq_imports(nodes, known: set[str]) -> list[tuple[str, list[str]]]:
    """(module, names) of every ``from logiq_sql... import`` or ``import logiq_sql...`` among ``nodes``. A name
    that is itself a submodule (in ``known``) is an import of that submodule: ``from logiq_sql.core import schema``
    depends on ``schema``, not on the package's __init__ (which Python runs for any import of the package and
    which re-exports the matcher for users)."""
    found = []
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "logiq_sql":
            names = [a.name for a in node.names]
            found += [(f"{node.module}.{n}", []) for n in names if f"{node.module}.{n}" in known]
            rest = [n for n in names if f"{node.module}.{n}" not in known]
            if rest:  # names defined in the module (or package) itself
                found.append((node.module, rest))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.split(".")[0] == "logiq_sql"]
    return found
