"""The DuckDB engine, the reference: every step a temp table of the DuckDB file's connection."""

from __future__ import annotations

import duckdb
import polars as pl

from logiq_sql.core.sql import materialise, step_key
from logiq_sql.engines.base import PARTITIONED_BY_DRIVE, Engine, as_query
from logiq_sql.storage.db import stored_schema


class DuckEngine(Engine):
    """The reference: every step is a temp table of the DuckDB file's connection."""

    name = "duckdb"

    def __init__(self, con: duckdb.DuckDBPyConnection):
        self.con = con
        self._shared: frozenset[tuple[str, tuple]] = frozenset()
        self._kept: dict[tuple[str, tuple], str] = {}  # a shared step -> the temp table holding its rows
        self._views: set[str] = set()  # step tables that are views of a kept table

    def materialise(self, table: str, relative: str, values: dict[str, object]) -> None:
        if table in self._views:  # a table cannot replace a view
            self.con.execute(f"drop view {table}")
            self._views.discard(table)
        key = step_key(relative, values) if any(relative == rel for rel, _ in self._shared) else None
        if key not in self._shared:
            materialise(self.con, table, relative, values)
            return
        # computed once, read by each scenario through a view: at tier S ego_on_same_lane.sql costs about 2 CPU s,
        # a copy of its 1.1 M rows 0.6
        if key not in self._kept:
            self._kept[key] = f"_shared_step_{len(self._kept) + 1}"
            materialise(self.con, self._kept[key], relative, values)
        self.con.execute(f"drop table if exists temp.main.{table}")
        self.con.execute(f"create temp view {table} as select * from {self._kept[key]}")
        self._views.add(table)

    def share(self, steps: frozenset[tuple[str, tuple]]) -> None:
        self._forget_shared()
        self._shared = steps

    def _forget_shared(self) -> None:
        for view in self._views:
            self.con.execute(f"drop view if exists {view}")
        for kept in self._kept.values():
            self.con.execute(f"drop table if exists {kept}")
        self._shared, self._kept, self._views = frozenset(), {}, set()

    def frame(self, sql: str) -> pl.DataFrame:
        return self.con.sql(as_query(sql)).pl()

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self.con.register(f"_{table}", frame)
        self.con.execute(f"create or replace temp table {table} as select * from _{table}")
        self.con.unregister(f"_{table}")

    def select_drives(self) -> None:
        # a temp table shadows the stored table of the same name, so every query of the batch reads the batch's
        # rows: a batch then costs what its drives hold, not what the whole file holds (at 10 M rows, queries
        # reading the whole track_lanes per batch made matching grow with batches x file size)
        stored = stored_schema(self.con)
        (others,) = self.con.execute(f"select count(*) from {stored}.drive_inputs where status = 'ingested' and "
                                     "drive_id not in (select drive_id from run_drives)").fetchall()[0]
        if not others:  # the batch is every drive of the file: its tables already hold just the batch's rows
            return
        for table in PARTITIONED_BY_DRIVE:
            self.con.execute(f"create or replace temp table {table} as select * from {stored}.{table} "
                             "where drive_id in (select drive_id from run_drives)")

    def release_drives(self) -> None:
        self._forget_shared()
        for table in PARTITIONED_BY_DRIVE:
            self.con.execute(f"drop table if exists temp.main.{table}")
