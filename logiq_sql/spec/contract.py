"""The scenario contract, checked before any data is read (docs/scenarios.md, "Writing a scenario").

A scenario's SQL must fit what its TOML declares:
- every ``$name`` a query uses is a value the run binds (a parameter of the scenario, a run setting or a unit
  constant such as ``$mph_per_mps``);
- every phase query returns the phase contract's columns (PHASE_COLUMNS) and the condition and value columns its
  ``conditions`` name;
- every KPI query returns ``match_id``; every sample query ``match_id`` and ``sample``; every KPI and coverage
  column declared comes from exactly one of them.
The columns a query returns are read from its SQL with sqlglot, following ``*`` through its CTEs and through the
scenario's earlier steps (a phase query may read ``scenario_frames``).
"""

from __future__ import annotations

import sqlglot
from sqlglot import exp

from logiq_sql.core.errors import did_you_mean
from logiq_sql.core.sql import parsed, placeholders, shown_path, unit_constant
from logiq_sql.spec.scenario import FRAMES_TABLE, Scenario

# the columns every phase query returns (one row per pair and frame; rows where the phase does not hold may be
# left out): the pair by its ids (for people) and by its integer keys (what the match steps after it read)
PHASE_COLUMNS = ("drive_id", "ego_id", "actor_id", "drive_key", "ego_key", "actor_key", "frame", "t_s", "segment",
                 "holds")
# values every run binds besides the scenario's parameters (logiq_sql.spec.plan.run_values)
RUN_VALUES = (
    "max_gap_s", "phase_count", "ego_mode", "ego_every", "ego_actor_ids_csv", "ego_kinds_csv", "relation_range_m",
    "object_relation_range_m", "relation_kinds_csv", "lane_calculation_tolerance_length_m", "min_closing_speed_mps",
    "scenario", "scenario_version", "params_hash",
)
# what each phase i binds as phase_<i>_<value> (logiq_sql.spec.plan.phase_values, match/scenario_phases.sql)
PHASE_VALUES = ("name", "min_duration_s", "max_duration_s")


def _sources(select: exp.Select) -> dict[str, str | exp.Expression]:
    """alias -> table name (or subquery) for the FROM and JOIN sources of one SELECT."""
    out: dict[str, str | exp.Expression] = {}
    nodes = [select.args.get("from_", select.args.get("from"))] + list(select.args.get("joins") or [])
    for node in nodes:
        if node is None:
            continue
        source = node.this
        if isinstance(source, exp.Table):
            out[source.alias_or_name] = source.name
        elif isinstance(source, exp.Subquery):
            out[source.alias_or_name] = source.this
    return out


def _columns(node: exp.Expression, ctes: dict[str, exp.Expression],
             tables: dict[str, frozenset[str] | None]) -> frozenset[str] | None:
    """The names a query node returns; None when a ``*`` reaches a table whose columns are not known."""
    if isinstance(node, exp.Union):
        return _columns(node.left, ctes, tables)
    if isinstance(node, exp.Subquery):
        return _columns(node.this, ctes, tables)
    if not isinstance(node, exp.Select):
        return None
    inner = dict(ctes)
    with_ = node.args.get("with_", node.args.get("with"))
    if with_ is not None:
        for cte in with_.expressions:
            inner[cte.alias_or_name] = cte.this
    sources = _sources(node)
    out: set[str] = set()
    for projection in node.expressions:
        star_of: list[str | exp.Expression] | None = None
        if isinstance(projection, exp.Star):
            star_of = list(sources.values())
        elif isinstance(projection, exp.Column) and isinstance(projection.this, exp.Star):
            source = sources.get(projection.table)
            star_of = [source] if source is not None else [projection.table]
        if star_of is None:
            out.add(projection.alias_or_name)
            continue
        for source in star_of:
            if isinstance(source, exp.Expression):
                found = _columns(source, inner, tables)
            elif source in inner:
                found = _columns(inner[source], {k: v for k, v in inner.items() if k != source}, tables)
            else:
                found = tables.get(source)
            if found is None:
                return None
            out |= found
    return frozenset(out)


def output_columns(relative: str, tables: tuple[tuple[str, frozenset[str] | None], ...] = ()) -> frozenset[str] | None:
    """The columns query ``relative`` returns (None when they cannot be told from its text); ``tables`` gives the
    columns of the earlier steps it reads with ``*``."""
    return _columns(parsed(relative), {}, dict(tables))


def holds_terms(relative: str) -> list[str] | None:
    """The condition columns a phase query's ``holds`` is the AND of, in order; None when ``holds`` is not one plain
    AND of columns (or is defined more than once), so that no condition can hide in it unnamed."""
    defined = [a for a in parsed(relative).find_all(exp.Alias) if a.alias == "holds"]
    if len(defined) != 1:
        return None
    terms, todo = [], [defined[0].this]
    while todo:
        node = todo.pop()
        if isinstance(node, exp.Paren):
            todo.append(node.this)
        elif isinstance(node, exp.And):
            todo += [node.right, node.left]
        elif isinstance(node, exp.Column) and not node.table:
            terms.append(node.name)
        else:
            return None
    return terms


def _holds(relative: str, declared: list[str], where: str) -> list[str]:
    terms = holds_terms(relative)
    if terms is None:
        return [f"{where}: holds must be the AND of the condition columns, e.g. `select *, a and b as holds from "
                f"conditions` (docs/scenarios.md), so that explain can name every condition that failed."]
    extra = [t for t in terms if t not in declared]
    missing = [c for c in declared if c not in terms]
    return ([f"{where}: holds ANDs '{t}', which conditions does not list: add it there (explain names only the "
             f"conditions listed)." for t in extra]
            + [f"{where}: conditions lists '{c}', which holds does not AND: add it to holds or drop it from "
               f"conditions." for c in missing])


def _missing(have: frozenset[str] | None, wanted: list[str], where: str, what: str) -> list[str]:
    if have is None:
        return []
    return [f"{where}: does not return column '{c}' ({what}).{did_you_mean(c, sorted(have))}"
            for c in wanted if c not in have]


def check_scenario(s: Scenario, queries: list[str]) -> list[str]:
    """Every mismatch between scenario ``s`` and its SQL (``queries``: every file a run of it executes), as
    messages naming the file and key (empty when none)."""
    problems: list[str] = []
    bound = set(s.bindings()) | set(RUN_VALUES) | {f"phase_{i}_{what}" for i in range(1, len(s.phases) + 1)
                                                    for what in PHASE_VALUES}
    for rel in dict.fromkeys(queries):
        try:
            used = placeholders(rel)
        except sqlglot.errors.ParseError as exc:
            problems.append(f"{shown_path(rel)}: does not parse as DuckDB SQL: {str(exc).splitlines()[0]}")
            continue
        for name in used:
            if name not in bound and unit_constant(name) is None:
                problems.append(f"{shown_path(rel)} uses ${name}, which no parameter of scenario {s.name} "
                                f"({s.path}) provides.{did_you_mean(name, sorted(bound))}")
    if problems:
        return problems
    frames = () if s.frames_query is None else ((FRAMES_TABLE, output_columns(s.frames_query)),)
    for phase in s.phases:
        have = output_columns(phase.query, frames)
        where = f"{s.path} [[phases]] {phase.name}: {shown_path(phase.query)}"
        problems += _missing(have, list(PHASE_COLUMNS), where, "the phase contract, docs/scenarios.md")
        problems += _missing(have, [c.name for c in phase.conditions], where, "a condition named in conditions")
        problems += _missing(have, [c.value for c in phase.conditions], where, "a value named in conditions")
        problems += _holds(phase.query, [c.name for c in phase.conditions], where)
    produced: dict[str, list[str]] = {}
    for rel in s.kpi_queries:
        have = output_columns(rel)
        problems += _missing(have, ["match_id"], shown_path(rel), "every KPI query returns one row per match_id")
        for column in (have or ()):
            produced.setdefault(column, []).append(rel)
    for rel in s.sample_queries:
        have = output_columns(rel)
        problems += _missing(have, ["match_id", "sample"], shown_path(rel),
                             "a sample query returns one row per match_id and sample")
        for column in (have or ()):
            produced.setdefault(column, []).append(rel)
    declared = [(f"[[kpis]] {k.name}", k.column) for k in s.kpis]
    declared += [(f"[[coverage]] {c.name}", c.column) for c in s.coverage]
    for key, column in declared:
        sources = [r for r in produced.get(column, []) if r in s.kpi_queries or r in s.sample_queries]
        if not sources:
            problems.append(f"{s.path} {key}: column '{column}' is returned by none of the scenario's kpi_queries "
                            f"or sample_queries ({', '.join(map(shown_path, s.kpi_queries + s.sample_queries))})."
                            f"{did_you_mean(column, sorted(produced))}")
        elif len(sources) > 1:
            problems.append(f"{s.path} {key}: column '{column}' is returned by more than one query "
                            f"({', '.join(map(shown_path, sources))}); one must provide it.")
    return problems


def sample_columns(s: Scenario) -> dict[str, str]:
    """Column -> the sample query that returns it (values at each sampling event)."""
    out: dict[str, str] = {}
    for rel in s.sample_queries:
        for column in output_columns(rel) or ():
            if column not in ("match_id", "sample"):
                out[column] = rel
    return out
