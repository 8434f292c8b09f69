"""The Polars engine: Polars' SQLContext over the canonical tables, parameters inlined as literals into the sqlglot
tree; which query files it cannot run, and the overrides it runs instead."""

from __future__ import annotations

import duckdb
import polars as pl
from sqlglot import exp

from logiq_sql.core.errors import arg
from logiq_sql.core.paths import query_path
from logiq_sql.core.sql import bind, parsed, registered
from logiq_sql.engines.base import INPUT_TABLES, PARTITIONED_BY_DRIVE, Engine, EngineError, as_query, copy_into_duckdb

OVERRIDES = "overrides"  # queries/overrides/<engine>/<relative>: an engine's own text of a portable query file


def override(engine: str, relative: str) -> str | None:
    """queries/overrides/<engine>/<relative> when that file exists (queries/overrides/README.md), else None."""
    candidate = f"{OVERRIDES}/{engine}/{relative}"
    return candidate if query_path(candidate).is_file() else None


def inline_parameters(relative: str, values: dict[str, object]) -> exp.Expression:
    """queries/<relative> parsed, with every ``$name`` replaced by its value as a literal node of the sqlglot tree
    (Polars SQL has no placeholders); strings stay quoted literals, so a value can never become SQL."""
    bound = bind(relative, values)
    tree = parsed(relative)

    def literal(node: exp.Expression) -> exp.Expression:
        if isinstance(node, exp.Placeholder) and node.name in bound:
            return exp.convert(bound[node.name])
        return node

    return tree.transform(literal)


def digests_after(tree: exp.Expression) -> list[str]:
    """Polars has no md5: each output column ``md5(x) as c`` of the outer select becomes ``x as c`` (in place),
    and the engine hashes those columns afterwards. Returns their names; an md5 elsewhere stays and fails."""
    names = []
    for projection in getattr(tree, "expressions", []):
        if isinstance(projection, exp.Alias) and isinstance(projection.this, exp.MD5):
            projection.set("this", projection.this.this)
            names.append(projection.alias)
    return names


def polars_text(relative: str, values: dict[str, object], portable: bool = False) -> tuple[str, list[str]]:
    """The Polars SQL the engine runs for queries/<relative>: its Polars override, if any (unless ``portable``),
    with the values inlined; and the columns to hash with md5 afterwards (none when ``portable``)."""
    chosen = relative if portable else (override("polars", relative) or relative)
    tree = inline_parameters(chosen, values)
    digests = [] if portable else digests_after(tree)
    return tree.sql("duckdb"), digests


def check_runs(relative: str) -> None:
    """Raise before anything runs if queries/<relative> cannot run on the Polars engine."""
    if reason := polars_blocker(relative):
        raise EngineError(f"{arg('engine', 'polars')}: queries/{relative} cannot run on Polars SQL: {reason}. "
                          "Run this scenario on the duckdb or spark engine (docs/engines.md: what runs where).")


def polars_blocker(relative: str) -> str | None:
    """Why the Polars engine cannot run queries/<relative> (Polars SQL's error on the portable text), or None:
    the file runs as it is, has an override, or needs only the md5 the engine computes afterwards."""
    reason = POLARS_UNSUPPORTED.get(relative)
    if reason is None or override("polars", relative) is not None:
        return None
    if reason == POLARS_MD5:
        tree = parsed(relative)
        digests_after(tree)
        return reason if tree.find(exp.MD5) is not None else None
    return reason


class PolarsEngine(Engine):
    """Polars' SQLContext over the canonical tables (read from the DuckDB file). A query file runs as its Polars
    override where queries/overrides/polars/ has one; the match ids' md5 is DuckDB's, over the key text Polars
    built (Polars has no md5, and the ids must stay those of every other engine); files that polars_blocker
    names do not run."""

    name = "polars"

    def __init__(self, con: duckdb.DuckDBPyConnection):
        self.con = con
        self.ctx = pl.SQLContext()
        self.inputs = {table.name: con.sql(f"select * from {table.name}").pl().lazy() for table in INPUT_TABLES}
        for name, frame in self.inputs.items():
            self.ctx.register(name, frame)

    def run(self, relative: str, values: dict[str, object], portable: bool = False) -> pl.DataFrame:
        """queries/<relative> on Polars SQL as the engine runs it; ``portable``: the portable text as it is, with
        no override and no md5 afterwards (the verdict tests)."""
        text, digests = polars_text(relative, values, portable)
        result = self.ctx.execute(text, eager=True)
        for column in digests:
            result = self._md5(result, column)
        return result

    def _md5(self, frame: pl.DataFrame, column: str) -> pl.DataFrame:
        """``column`` replaced by DuckDB's md5 of it, over its distinct values and joined back (row order kept)."""
        keys = frame.select(pl.col(column).unique())
        with registered(self.con, "_md5_keys", keys):
            digests = self.con.sql(f'select "{column}", md5("{column}") as _md5 from _md5_keys').pl()
        return (frame.join(digests, on=column, how="left", nulls_equal=True, maintain_order="left")
                .with_columns(pl.col("_md5").alias(column)).drop("_md5"))

    def materialise(self, table: str, relative: str, values: dict[str, object], kept: str | None = None) -> None:
        check_runs(relative)
        rows = self.run(relative, values)
        self.ctx.register(table, (rows.filter(pl.col(kept)) if kept else rows).lazy())

    def frame(self, sql: str) -> pl.DataFrame:
        return self.ctx.execute(as_query(sql), eager=True)

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self.ctx.register(table, frame.lazy())

    def select_drives(self) -> None:
        batch = self.ctx.execute("select drive_id from run_drives")
        for table in PARTITIONED_BY_DRIVE:
            self.ctx.register(table, self.inputs[table].join(batch, on="drive_id", how="semi"))

    def release_drives(self) -> None:
        for table in PARTITIONED_BY_DRIVE:
            self.ctx.register(table, self.inputs[table])

    def persist(self, tables: tuple[str, ...]) -> None:
        registered = set(self.ctx.tables())
        for table in tables:
            if table in registered:
                copy_into_duckdb(self.con, table, self.frame(table))
                self.ctx.unregister(table)


POLARS_MD5 = "unsupported function 'md5'"
# The query files whose portable text Polars SQL (polars 2.1) cannot run, with the error it gives. Every other
# query file runs there and gives DuckDB's rows: tests/engines/test_polars.py runs each file on both over the same
# inputs and checks this table both ways, and checks that each Polars override (and the md5 afterwards) gives
# DuckDB's rows. polars_blocker says which of these the engine still runs (docs/engines.md has the table).
POLARS_UNSUPPORTED: dict[str, str] = {
    "match/identify.sql": POLARS_MD5,
    # windows over the input order (an empty OVER ()), which DuckDB keeps and the other engines do not: ingest
    # runs on DuckDB only
    "staging/tracks.sql": "LAG requires an ORDER BY in the OVER clause",
}
