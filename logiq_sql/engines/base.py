"""The interface every engine implements (DuckDB, the reference, Spark and Polars SQL), and what they share.

The matcher (``logiq_sql/matching/match.py``) orchestrates the steps; an engine only executes them:

    materialise(table, relative, values)   run queries/<relative> with its parameters bound, keep it as <table>
    frame(sql)                             a query (DuckDB dialect) or a table name -> Polars frame
    register(table, frame)                 make a Polars frame a table the next steps can read
    persist(tables)                        copy the named step tables into the DuckDB file's temp schema, where
                                           the matcher stores them from, and forget them (a no-op for DuckDB)

Every engine reads the same ``queries/`` text, written in DuckDB dialect. Parameters stay bound: DuckDB binds
``$name`` natively, Spark gets the sqlglot transpile with ``:name`` markers and ``args=``, and Polars SQL (which
has no placeholders) gets literals put into the sqlglot tree, never into the text. Decisions, the per-query
Polars verdicts and how to run on a Spark cluster: docs/engines.md.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import duckdb
import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.errors import LogiqError
from logiq_sql.core.sql import registered

# the canonical tables a match reads; Spark's Parquet copies of the per-drive ones are partitioned by drive_id
INPUT_TABLES = (*schema.ALL_INPUT_TABLES, schema.STORED_TRACK_LANES)
PARTITIONED_BY_DRIVE = ("tracks", "track_lanes", "traffic_light_states")
# what a step may read besides other steps: the canonical tables (a drive's rows and its map's, versioned by
# ingest_versions) and the batch's drive ids
DRIVE_INPUT_NAMES = frozenset({*(t.name for t in INPUT_TABLES), "run_drives"})


# the tables a Python step (Engine.derive) reads, each with the columns it reads of it (None: every column)
Reads = Mapping[str, tuple[str, ...] | None]


class EngineError(LogiqError):
    """An engine is not installed, or cannot run a query."""


class Engine:
    """What the matcher needs from an engine (module docstring); DuckEngine is the reference."""

    name = "engine"
    owners: tuple[str, ...] = ()  # the scenarios the next steps are run for (the step cache's entries)
    # the next steps are the shared ones (the relations and junctions): they scan the batch's per-drive input tables
    # several times over, so the DuckDB engine copies the batch's rows before such a step runs, where other steps
    # read them through views; and the step cache keeps each of them, however cheap (StepCache.record's ``keep``)
    shared: bool = False

    def materialise(self, table: str, relative: str, values: dict[str, object], kept: str | None = None) -> None:
        """queries/<relative> with ``values`` bound, kept as ``table``; ``kept``: only its rows whose boolean column
        of that name is true (a phase or frames step in a match, where nothing reads the others:
        ``runner.kept_rows``)."""
        raise NotImplementedError

    def frame(self, sql: str) -> pl.DataFrame:
        raise NotImplementedError

    def register(self, table: str, frame: pl.DataFrame) -> None:
        raise NotImplementedError

    def share(self, steps: frozenset[tuple[str, tuple]]) -> None:
        """``steps`` (``sql.step_key``s) are phase steps that several scenarios of the group about to run compute
        with the same values from the group's shared tables: an engine may compute each once (DuckEngine does),
        until ``release_drives``."""

    def select_drives(self) -> None:
        """From now on the per-drive input tables hold only the drives of ``run_drives`` (the batch)."""

    def release_drives(self) -> None:
        """Undo ``select_drives``."""

    def derive(self, table: str, compute, reads: Reads, schema: dict[str, pl.DataType]) -> None:
        """Make ``table`` from ``compute(con)``, a Python step (shapely) that queries the tables of ``reads`` (all
        keyed by drive_id; each with the columns it reads, None for every one) through a DuckDB connection and
        returns a Polars frame of ``schema``. Here it runs once over the whole batch; Spark runs it per drive on
        the executors, for the drives with rows in the first table, with only those columns."""
        self.register(table, compute(self))

    def persist(self, tables: tuple[str, ...]) -> None:
        """Copy the step tables among ``tables`` that this group made into DuckDB temp tables, then forget them."""

    def close(self) -> None:
        """Release what the engine holds (Spark views, exported Parquet)."""


def as_query(sql: str) -> str:
    return f"select * from {sql}" if re.fullmatch(r"\w+", sql) else sql


def copy_into_duckdb(con: duckdb.DuckDBPyConnection, table: str, frame: pl.DataFrame) -> None:
    """``frame`` as the temp table ``table`` of ``con``, replacing one of that name."""
    with registered(con, "_engine_copy", frame):
        con.execute(f"create or replace temp table {table} as select * from _engine_copy")
