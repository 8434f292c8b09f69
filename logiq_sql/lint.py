"""Portability lint for the SQL tree: constructs that parse in DuckDB but do not run the same elsewhere.

sqlglot transpiles DuckDB SQL to Spark, but passes some constructs through unchanged or changes their meaning
(see the team's engine notes). Each rule names the construct and the portable alternative.
"""

from __future__ import annotations

from pathlib import Path

import sqlglot
from sqlglot import exp
from sqlglot.errors import ErrorLevel

from logiq_sql.paths import data_dir

# function names (as sqlglot spells the node class) that do not carry over to Spark
_NOT_PORTABLE_FUNCS = {
    "List": "list(... order by ...) loses its order on Spark; aggregate without ordering or join instead",
    "Columns": "COLUMNS() is DuckDB-only; name the columns",
    "Length": "len() becomes a string function on Spark; use length() on strings only",
    "EpochMs": "epoch_ms() becomes its inverse on Spark; keep time as t_s / frame numbers",
}


def lint_sql(text: str, where: str) -> list[str]:
    """Problems found in one query (empty when portable)."""
    problems = []
    try:
        tree = sqlglot.parse_one(text, read="duckdb")
    except sqlglot.errors.ParseError as exc:
        return [f"{where}: does not parse as DuckDB SQL: {exc}"]
    for join in tree.find_all(exp.Join):
        if (join.args.get("kind") or "").upper() == "ASOF" or "ASOF" in join.sql("duckdb").upper()[:20]:
            problems.append(f"{where}: ASOF JOIN runs only on DuckDB; use a range join with row_number() = 1")
    for spec in tree.find_all(exp.WindowSpec):
        if (spec.args.get("kind") or "").upper() == "RANGE":
            problems.append(f"{where}: RANGE window frames do not run on Polars; use ROWS over frames")
    for node in tree.find_all(exp.Func):
        reason = _NOT_PORTABLE_FUNCS.get(type(node).__name__)
        if reason:
            problems.append(f"{where}: {reason}")
    for node in tree.find_all(exp.Div):
        if not _guarded(node):
            problems.append(f"{where}: division '{node.sql('duckdb')}' is not guarded; Spark raises on division by "
                            "zero where DuckDB returns inf: divide by nullif(x, 0) or inside a CASE that excludes 0")
    try:
        sqlglot.transpile(text, read="duckdb", write="spark", unsupported_level=ErrorLevel.RAISE)
    except sqlglot.errors.SqlglotError as exc:
        problems.append(f"{where}: does not transpile to Spark: {exc}")
    return problems


def _guarded(div: exp.Div) -> bool:
    """True when the divisor cannot be 0 at run time: a non-zero literal, nullif(), or a CASE branch."""
    divisor = div.expression
    while isinstance(divisor, exp.Paren):
        divisor = divisor.this
    if isinstance(divisor, exp.Literal) and divisor.is_number and float(divisor.this) != 0:
        return True
    if isinstance(divisor, exp.Nullif):
        return True
    if isinstance(divisor, exp.Add) and any(isinstance(x, exp.Literal) for x in (divisor.this, divisor.expression)):
        return True  # floor(...) + 1 and the like
    return div.find_ancestor(exp.If, exp.Case) is not None


def lint_tree(root: Path | None = None) -> list[str]:
    root = root or data_dir("queries")
    problems: list[str] = []
    for path in sorted(root.rglob("*.sql")):
        problems += lint_sql(path.read_text(), str(path.relative_to(root.parent)))
    return problems
