"""Lint: scenarios against their SQL (``logiq-sql lint``), and the SQL tree's portability.

``lint_scenarios`` loads each scenario (every key of every TOML table is checked, with a did-you-mean), checks it
against its SQL (``logiq_sql.spec.contract``: placeholders, the columns each phase, KPI and sample query returns) and
lints every query file it runs for portability. Portability: sqlglot transpiles DuckDB SQL to Spark, but passes
some constructs through unchanged or changes their meaning (see the team's engine notes). Each rule names the
construct and the portable alternative.
"""

from __future__ import annotations

import re
from pathlib import Path

import polars as pl
import sqlglot
from sqlglot import exp
from sqlglot.errors import ErrorLevel

from logiq_sql.core.paths import data_dir
from logiq_sql.core.sql import header
from logiq_sql.engines.polars_engine import OVERRIDES, POLARS_UNSUPPORTED, digests_after, override

# function names (as sqlglot spells the node class) that do not carry over to Spark
_NOT_PORTABLE_FUNCS = {
    "Columns": "COLUMNS() is DuckDB-only; name the columns",
    "Length": "len() becomes a string function on Spark; use length() on strings only",
    "UnixToTime": "to_timestamp() / epoch_ms() drop fractional seconds or become their inverse on Spark; keep time "
                  "as t_s / frame numbers",
    "TimeToUnix": "epoch() drops fractional seconds on Spark; keep time as t_s / frame numbers",
    "PercentileCont": "quantile_cont(x, p) gets the wrong argument count on Spark; rank with row_number() instead",
}


def polars_findings(tree: exp.Expression) -> list[str]:
    """Constructs Polars SQL (polars 2.1) does not run, each with the portable way around it."""
    found = []
    for spec in tree.find_all(exp.WindowSpec):
        if (spec.args.get("kind") or "").upper() == "RANGE":
            found.append("RANGE window frames do not run on Polars; use ROWS over frames")
    if tree.find(exp.IgnoreNulls):
        found.append("last_value/first_value(... ignore nulls) does not run on Polars; take the running max of the "
                     "frame that has a value and join back")
    if tree.find(exp.LogicalOr):
        found.append("bool_or() does not run on Polars; use max(case when ... then 1 else 0 end) = 1")
    for join in tree.find_all(exp.Join):
        on = join.args.get("on")
        if join.args.get("side") and on is not None and on.find(exp.Or):
            found.append("an OR in the ON of an outer join does not run on Polars; join once per alternative "
                         "and union")
    outer = tree.copy()
    digests_after(outer)  # md5(x) as an output column: the Polars engine hashes it afterwards
    if outer.find(exp.MD5):
        found.append("md5() inside an expression does not run on Polars; only md5(x) as an output column does")
    return found


def lint_sql(text: str, where: str, polars_override: bool = False, polars_refused: bool = False) -> list[str]:
    """Problems found in one query (empty when portable). What does not run on Polars SQL is a problem unless
    the file has a Polars override (``polars_override``) or the Polars engine refuses it by name
    (``polars_refused``: engines.polars_engine.POLARS_UNSUPPORTED, tested to fail there)."""
    problems = []
    try:
        tree = sqlglot.parse_one(text, read="duckdb")
    except sqlglot.errors.ParseError as exc:
        return [f"{where}: does not parse as DuckDB SQL: {exc}"]
    for join in tree.find_all(exp.Join):
        if (join.args.get("kind") or "").upper() == "ASOF" or "ASOF" in join.sql("duckdb").upper()[:20]:
            problems.append(f"{where}: ASOF JOIN runs only on DuckDB; use a range join with row_number() = 1")
    if not (polars_override or polars_refused):
        problems += [f"{where}: {finding}" for finding in polars_findings(tree)]
    for node in tree.find_all(exp.Func):
        reason = _NOT_PORTABLE_FUNCS.get(type(node).__name__)
        if reason:
            problems.append(f"{where}: {reason}")
    for agg in tree.find_all(exp.ArrayAgg):
        if agg.find(exp.Order):
            problems.append(f"{where}: list(... order by ...) becomes collect_list on Spark and loses its order; "
                            "aggregate without ordering or join instead")
    for bracket in tree.find_all(exp.Bracket):
        if bracket.find(exp.Slice):
            problems.append(f"{where}: list slices x[a:b] do not run on Spark; keep lists out of the SQL")
    for node in tree.find_all(exp.Div):
        if not _guarded(node):
            problems.append(f"{where}: division '{node.sql('duckdb')}' is not guarded; Spark raises on division by "
                            "zero where DuckDB returns inf: divide by nullif(x, 0) or inside a CASE that excludes 0")
    try:
        sqlglot.transpile(text, read="duckdb", write="spark", unsupported_level=ErrorLevel.RAISE)
    except sqlglot.errors.SqlglotError as exc:
        problems.append(f"{where}: does not transpile to Spark: {exc}")
    return problems


def _named(field: str, pattern: str) -> set[str]:
    """The names a header field lists, parenthesised remarks dropped."""
    while True:
        shorter = re.sub(r"\([^()]*\)", "", field)
        if shorter == field:
            break
        field = shorter
    return set(re.findall(pattern, field))


def header_findings(text: str, where: str) -> list[str]:
    """A built-in query's ``-- reads:`` and ``-- params:`` headers against what its SQL reads and binds: a header
    is what an analyst reads first, so it must not drift from the query."""
    fields = header(text).fields
    tree = sqlglot.parse_one(text, read="duckdb")
    problems = [f"{where}: no '-- {key}:' header line ({what}; 'none' when there is none)"
                for key, what in (("reads", "the tables it reads"), ("params", "the $parameters it binds"))
                if key not in fields]
    bound = {node.name for node in tree.find_all(exp.Placeholder)}
    read = {t.name for t in tree.find_all(exp.Table)} - {c.alias for c in tree.find_all(exp.CTE)}
    for key, found, pattern in (("params", bound, r"\$(\w+)"), ("reads", read, r"(?:^|,)\s*(\w+)\s*(?=,|$)")):
        if key not in fields:
            continue
        listed = _named(fields[key], pattern) - {"none"}
        problems += [f"{where}: '-- {key}:' lists {name}, which the query does not use; drop it from the header"
                     for name in sorted(listed - found)]
        problems += [f"{where}: the query uses {name}, which '-- {key}:' does not list; add it to the header"
                     for name in sorted(found - listed)]
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


def portable_files(root: Path) -> list[Path]:
    """The query files every engine runs, the engine overrides left out."""
    return [p for p in sorted(root.rglob("*.sql")) if p.relative_to(root).parts[0] != OVERRIDES]


def lint_scenarios(names: list[str] | None = None, scenario_path: Path | str | None = None) -> list[str]:
    """Every problem of the named scenarios (default: every scenario, built-in and in ``scenario_path``), each
    naming the file and key; empty when they are fine. Nothing reads data."""
    from logiq_sql.core.errors import LogiqError
    from logiq_sql.core.sql import query_text, shown_path
    from logiq_sql.spec.contract import check_scenario
    from logiq_sql.spec.plan import scenario_queries
    from logiq_sql.spec.scenario import load_scenario, scenario_files

    problems: list[str] = []
    files = scenario_files(scenario_path)
    for name in names or list(files):
        try:
            s = load_scenario(name, scenario_path)
        except LogiqError as exc:
            problems.append(str(exc))
            continue
        if s.abstract:
            continue
        found = check_scenario(s, scenario_queries(s))
        problems += found
        if not found:
            for rel in dict.fromkeys(scenario_queries(s)):
                problems += lint_sql(query_text(rel), shown_path(rel), polars_override=override("polars", rel) is not None,
                                     polars_refused=rel in POLARS_UNSUPPORTED)
    return list(dict.fromkeys(problems))


def lint_tree(root: Path | None = None) -> list[str]:
    """Every portable query file, knowing which have a Polars override (queries/overrides/README.md); every
    override, which must replace a portable file, bind the same parameters and itself run on Polars."""
    root = root or data_dir("queries")
    problems: list[str] = []
    polars = root / OVERRIDES / "polars"
    for path in portable_files(root):
        relative = str(path.relative_to(root))
        where = str(path.relative_to(root.parent))
        problems += lint_sql(path.read_text(), where, polars_override=(polars / relative).is_file(),
                             polars_refused=relative in POLARS_UNSUPPORTED)
        problems += header_findings(path.read_text(), where)
    for path in sorted(polars.rglob("*.sql")) if polars.is_dir() else []:
        where = str(path.relative_to(root.parent))
        twin = root / path.relative_to(polars)
        if not twin.is_file():
            problems.append(f"{where}: overrides queries/{twin.relative_to(root)}, which does not exist; remove it")
            continue
        problems += [f"{where}: {finding}" for finding in polars_findings(sqlglot.parse_one(path.read_text(),
                                                                                           read="duckdb"))]
        if _parameters(path) != _parameters(twin):
            problems.append(f"{where}: binds {sorted(_parameters(path))}, but queries/{twin.relative_to(root)} binds "
                            f"{sorted(_parameters(twin))}; an override takes the same parameters")
    return problems


def _parameters(path: Path) -> set[str]:
    return {node.name for node in sqlglot.parse_one(path.read_text(), read="duckdb").find_all(exp.Placeholder)}


# tables the queries read that are not canonical inputs: what the matcher registers or stores around the steps
def _side_tables():
    from logiq_sql.core.schema import TRACKS
    from logiq_sql.matching.encroachment import ENCROACHMENTS_SCHEMA
    from logiq_sql.storage.tables import COVERAGE_BUCKETS, COVERAGE_SAMPLES, MATCHES

    return {"run_drives": {"drive_id": pl.String}, "tracks_raw": TRACKS.polars_schema,
            "encroachments": ENCROACHMENTS_SCHEMA, "coverage_samples": COVERAGE_SAMPLES.polars_schema,
            "coverage_buckets": COVERAGE_BUCKETS.polars_schema, "matches": MATCHES.polars_schema,
            "replay_ids": {"match_id": pl.String}}


def spark_problems(spark, root: Path | None = None) -> list[str]:
    """Every query file, transpiled to Spark with its parameters bound, put through Spark's analyser over empty
    canonical tables: in each scenario's step order (a step's view is what the next steps read), then the
    staging and coverage queries. Catches what sqlglot passes through but Spark cannot run. Needs a Spark
    session (tests/engines/test_spark.py)."""
    from pyspark.sql import types as T

    from logiq_sql.core.schema import spark_type
    from logiq_sql.core.sql import PER_PHASE, bind
    from logiq_sql.engines.base import INPUT_TABLES
    from logiq_sql.engines.spark_engine import spark_text
    from logiq_sql.outputs import replay
    from logiq_sql.spec.plan import parse_ego, result_steps, run_values, scenario_steps
    from logiq_sql.spec.scenario import list_scenarios

    tables = {t.name: t.polars_schema for t in INPUT_TABLES} | _side_tables()
    for name, columns in tables.items():
        struct = T.StructType([T.StructField(c, spark_type(d), True) for c, d in columns.items()])
        spark.createDataFrame([], struct).createOrReplaceTempView(name)
    runs: list[tuple[str, str, dict[str, object]]] = []
    for s in list_scenarios():
        values = run_values(s, parse_ego("auto"), 200.0)
        runs += [(t, rel, values) for t, rel in [*scenario_steps(s), *result_steps(s)]]
    runs += [("_coverage", "coverage/histogram.sql", {})]
    runs += [(t, rel, values | replay.PARAMS) for t, rel in replay.STEPS]  # after the relations steps it reads
    # staging/tracks.sql runs at ingest, on DuckDB only: its windows run over the input order, which Spark does
    # not keep (the file's header)
    problems, seen = [], {"staging/tracks.sql"}
    for table, rel, values in runs:
        seen.add(rel.split(PER_PHASE)[0])  # a file run for each phase (sql.per_phase) is that file
        problems += spark_problems_in(spark, rel, spark_text(rel), bind(rel, values), table)
    root = root or data_dir("queries")
    for path in portable_files(root):  # overrides run on their engine only (tests/engines/test_polars.py)
        rel = str(path.relative_to(root))
        if rel not in seen:
            problems.append(f"queries/{rel}: no scenario step runs it, so it was not checked on Spark")
    return problems


def _first_line(exc: Exception) -> str:
    java = getattr(exc, "java_exception", None)  # py4j errors carry the JVM's message there
    text = str(java.toString()) if java is not None else str(exc)
    return text.strip().splitlines()[0]


def spark_problems_in(spark, relative: str, spark_text: str, args: dict[str, object],
                      table: str | None = None) -> list[str]:
    """Spark's analyser on one transpiled query (nothing runs). On success the step's schema becomes an empty
    view ``table``, so the next steps are analysed against it and each query on its own."""
    try:
        analysed = spark.sql(spark_text, args=args)
    except Exception as exc:  # noqa: BLE001 - Spark raises its own classes; the message is the finding
        return [f"queries/{relative}: does not run on Spark: {_first_line(exc)}"]
    if table is not None:
        spark.createDataFrame([], analysed.schema).createOrReplaceTempView(table)
    return []
