"""Read query files, find their parameters, bind them, run them, and render them for people."""

from __future__ import annotations

import contextlib
import functools
import itertools
import re
from collections.abc import Iterator
from dataclasses import dataclass

import duckdb
import sqlglot
from sqlglot import exp

from logiq_sql.core import units
from logiq_sql.core.errors import ScenarioError
from logiq_sql.core.paths import query_path

_UNIT_CONSTANT = re.compile(r"^([a-z0-9]+)_per_([a-z0-9]+)$")
_HEADER_FIELD = re.compile(r" (\w+): ?(.*)")  # after the "--"
_HEADER_COLUMN = re.compile(r"(\s{2,})([a-z_][a-z0-9_]*(?:,\s*[a-z_][a-z0-9_]*)*)(\s{2,})(\S.*)")


def shown_path(relative: str) -> str:
    """A query as people know it: ``queries/<relative>`` for a built-in one, the path of a user's file."""
    return relative if relative.startswith("/") else f"queries/{relative}"


# a query file written for phase 1 and run once per phase of a scenario (``per_phase``): its relative name
PER_PHASE = "#phases="


def per_phase(relative: str, phases: int) -> str:
    """The name under which queries/<relative>, a select written for phase 1 of a scenario, runs for each of its
    ``phases`` phases, joined by ``union all`` (``query_text`` expands it; ``logiq-sql render`` shows it)."""
    return f"{relative}{PER_PHASE}{phases}"


def _for_phase(tree: exp.Expression, k: int) -> exp.Expression:
    """The select written for phase 1, for phase ``k``: it reads phase_<k>, binds $phase_<k>_..., and its
    ``phase_index`` column is k."""
    def renamed(node: exp.Expression) -> exp.Expression:
        if isinstance(node, exp.Table) and node.name == "phase_1":
            table = node.copy()
            table.set("this", exp.to_identifier(f"phase_{k}"))
            return table
        if isinstance(node, exp.Placeholder) and node.name.startswith("phase_1_"):
            return exp.Placeholder(this=f"phase_{k}_" + node.name.removeprefix("phase_1_"))
        if isinstance(node, exp.Alias) and node.alias == "phase_index":
            return exp.Literal.number(k).as_("phase_index")
        return node

    return tree.copy().transform(renamed)


def _expanded(relative: str) -> str:
    """queries/<file> run for phases 1..n (``per_phase``): its header, then its select for each phase, joined by
    union all. Only names change (tables, parameters) and the phase_index literal; no value enters the text."""
    template, phases = relative.rsplit(PER_PHASE, 1)
    text, tree = query_text(template), _parse(template)
    header = "".join(line + "\n" for line in itertools.takewhile(lambda x: x.startswith("--"), text.splitlines()))
    union = "\nunion all\n".join(_for_phase(tree, k).sql("duckdb", pretty=True, comments=False) for k in range(1, int(phases) + 1))
    return f"{header}-- run for phases 1 .. {phases}\n{union}\n"


@functools.cache
def query_text(relative: str) -> str:
    if PER_PHASE in relative:
        return _expanded(relative)
    path = query_path(relative)
    if not path.is_file():
        raise ScenarioError(f"query file {shown_path(relative)} not found.")
    return path.read_text()


@dataclass(frozen=True)
class Header:
    """A query file's header: its comment lines up to the first line that is not one.

    ``fields``: the ``-- name: value`` lines (reads, params, grain, ...), a value continuing on the lines right
    below it indented by two spaces or more. ``columns``: the ``--   name[, name]   description`` lines, a
    description continuing on the lines below it indented as deep."""

    fields: dict[str, str]
    columns: dict[str, str]


def header(text: str) -> Header:
    """The header of a query file's text (``Header``)."""
    fields: dict[str, str] = {}
    columns: dict[str, str] = {}
    field, names, indent = None, [], 0
    for line in text.splitlines():
        if not line.startswith("--"):
            break
        body = line[2:]
        if field and body.startswith("  ") and body.strip():
            fields[field] += " " + body.strip()
            continue
        field = None
        if m := _HEADER_FIELD.fullmatch(body):
            field, names = m.group(1), []
            fields[field] = m.group(2)
        elif m := _HEADER_COLUMN.fullmatch(body):
            names = [name.strip() for name in m.group(2).split(",")]
            indent = len(m.group(1)) + len(m.group(2)) + len(m.group(3))
            columns.update({name: m.group(4).strip() for name in names})
        elif names and body.strip() and len(body) - len(body.lstrip()) >= indent:
            columns.update({name: columns[name] + " " + body.strip() for name in names})
        else:
            names = []
    return Header(fields, columns)


@functools.cache
def _parse(relative: str) -> exp.Expression:
    return sqlglot.parse_one(query_text(relative), read="duckdb")


def parsed(relative: str) -> exp.Expression:
    """queries/<relative> as a sqlglot tree (DuckDB dialect), parsed once per process; each caller gets its own
    copy, free to change."""
    return _parse(relative).copy()


@contextlib.contextmanager
def registered(con: duckdb.DuckDBPyConnection, name: str, frame) -> Iterator[str]:
    """``frame`` (Polars or Arrow) readable as the table ``name`` on ``con`` inside the block, and unregistered after
    it, also when the block fails."""
    con.register(name, frame)
    try:
        yield name
    finally:
        con.unregister(name)


@functools.cache
def placeholders(relative: str) -> tuple[str, ...]:
    """The ``$name`` parameters a query file uses, in order of first use."""
    tree = _parse(relative)
    seen: dict[str, None] = {}
    for node in tree.find_all(exp.Placeholder):
        seen[node.name] = None
    return tuple(seen)


@functools.cache
def tables_read(relative: str) -> frozenset[str]:
    """The names of the tables a query file reads (its CTEs' names included: a superset)."""
    return frozenset(t.name for t in _parse(relative).find_all(exp.Table))


@functools.cache
def cte_names(relative: str) -> frozenset[str]:
    """The names of the CTEs a query file defines."""
    return frozenset(c.alias for c in _parse(relative).find_all(exp.CTE))


def unit_constant(name: str) -> float | None:
    """``mph_per_mps`` -> how many mph one m/s is. None if ``name`` is not such a constant."""
    m = _UNIT_CONSTANT.match(name)
    if not m or m.group(1) not in units.UNITS or m.group(2) not in units.UNITS:
        return None
    return units.factor(m.group(2)) / units.factor(m.group(1))


def bind(relative: str, values: dict[str, object]) -> dict[str, object]:
    """The values for exactly the parameters ``relative`` uses; unit constants are computed."""
    out: dict[str, object] = {}
    for name in placeholders(relative):
        if name in values:
            out[name] = values[name]
        elif (const := unit_constant(name)) is not None:
            out[name] = const
        else:
            raise ScenarioError(f"{shown_path(relative)} uses ${name}, which no scenario parameter provides.")
    return out


def step_key(relative: str, values: dict[str, object]) -> tuple[str, tuple]:
    """A step as its query file and the values it binds: two steps with one key compute the same rows from the
    same tables."""
    return relative, tuple(sorted(bind(relative, values).items()))


def materialise(con: duckdb.DuckDBPyConnection, table: str, relative: str, values: dict[str, object],
                kept: str | None = None) -> None:
    """``create or replace temp table <table> as <query>`` with bound parameters (table names are ours);
    ``kept``: only the rows whose boolean column of that name is true (``Engine.materialise``)."""
    con.execute(f"create or replace temp table {table} as " + step_query(relative, kept), bind(relative, values))


def step_query(relative: str, kept: str | None = None) -> str:
    """The query of a step: the file's text, or with ``kept`` only the rows whose boolean column of that name is
    true."""
    query = query_text(relative)
    return f"select * from (\n{query}\n) as step where {kept}" if kept else query


def drop_temp(con: duckdb.DuckDBPyConnection, name: str) -> None:
    """Drop the temp table or view ``name`` if there is one (a step's rows are either: the step cache's are
    views)."""
    (views,) = con.execute("select count(*) from duckdb_views() where temporary and view_name = $n",
                           {"n": name}).fetchall()[0]
    con.execute(f"drop {'view' if views else 'table'} if exists temp.main.{name}")


def recount_coverage(con: duckdb.DuckDBPyConnection) -> None:
    """Rebuild the coverage histograms from every stored coverage sample (after matches were added or removed)."""
    con.execute("delete from coverage")
    con.execute("insert into coverage select * from (" + query_text("coverage/histogram.sql") + ")")


def sql_literal(value: object) -> str:
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if value is None:
        return "null"
    return repr(float(value)) if isinstance(value, float) else str(value)


def used_values(steps: list[tuple[str, str]], values: dict[str, object]) -> dict[str, object]:
    used: dict[str, object] = {}
    for _, rel in steps:
        used.update(bind(rel, values))
    return used


def render_steps(steps: list[tuple[str, str]], values: dict[str, object]) -> str:
    """One statement a person can read and run in DuckDB: ``SET VARIABLE`` lines for the bound values, then
    the steps as CTEs ending in the last one. DuckDB reads ``$name`` as ``getvariable('name')``."""
    lines = [f"set variable {name} = {sql_literal(v)};" for name, v in used_values(steps, values).items()]
    ctes = []
    for name, rel in steps[:-1]:
        body = "\n".join("    " + line if line else "" for line in query_text(rel).rstrip().splitlines())
        ctes.append(f"{name} as (\n{body}\n)")
    last = query_text(steps[-1][1]).rstrip()
    return "\n".join(lines) + "\n\nwith\n\n" + ",\n\n".join(ctes) + "\n\n" + "select * from (\n" + last + "\n);\n"
