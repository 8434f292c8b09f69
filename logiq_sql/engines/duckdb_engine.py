"""The DuckDB engine, the reference: every step a temp table of the DuckDB file's connection."""

from __future__ import annotations

import time

import duckdb
import polars as pl

from logiq_sql.core.sql import bind, cte_names, materialise, query_text, step_key, step_query, tables_read
from logiq_sql.engines.base import DRIVE_INPUT_NAMES, PARTITIONED_BY_DRIVE, Engine, Reads, as_query, copy_into_duckdb
from logiq_sql.spec.scenario import FRAMES_TABLE
from logiq_sql.storage.db import stored_schema


class DuckEngine(Engine):
    """The reference: every step is a temp table of the DuckDB file's connection."""

    name = "duckdb"

    def __init__(self, con: duckdb.DuckDBPyConnection, cache=None):
        self.con = con
        self.cache = cache  # a logiq_sql.storage.step_cache.StepCache, or None: every step runs
        self._shared: frozenset[tuple[str, tuple]] = frozenset()
        self._kept: dict[tuple[str, tuple], str] = {}  # a shared step -> the temp table holding its rows
        self._views: set[str] = set()  # step tables that are views of a kept table
        self._loaded: set[str] = set()  # step tables that are views of the step cache's rows
        self._keys: dict[str, str | None] = {}  # the batch's step tables -> their cache keys (None: not cacheable)
        self._narrowed: set[str] = set()  # per-drive input tables that are views of the batch's rows, not copies

    def _cache_key(self, text: str, bound: dict[str, object], reads: frozenset[str]) -> str | None:
        """The step's cache key, or None when the cache is off or the step reads a table of unknown content."""
        if self.cache is None or not self.cache.usable:
            return None
        inputs: dict[str, str] = {}
        for name in reads:
            if name in self._keys:
                if self._keys[name] is None:
                    return None
                inputs[name] = self._keys[name]
            elif name not in DRIVE_INPUT_NAMES:
                return None
        return self.cache.key(text, bound, inputs)

    def _clear(self, table: str) -> None:
        """Make way for a new ``table``: a view of that name (a shared step's, or the cache's rows) is dropped."""
        if table in self._views or table in self._loaded:
            self.con.execute(f"drop view if exists temp.main.{table}")
            self._views.discard(table)
            self._loaded.discard(table)

    def _cached(self, table: str, step: str, key: str | None, compute, into=None) -> None:
        """``table`` from the cache under ``key`` if it holds the batch's rows, else ``compute()``d (and kept).
        ``into()``: a step the cache always keeps computed straight into it, True when it was."""
        self._clear(table)
        if key is not None:
            self.con.execute(f"drop table if exists temp.main.{table}")
        if key is not None and self.cache.load(table, key):
            self._loaded.add(table)
            self._keys[table] = key
            self.cache.record(self.owners, step, table, key, computed=False)
            return
        if key is not None and into is not None and self._kept_always(table) and into():
            self._loaded.add(table)
            self._keys[table] = key
            return
        started = time.process_time()
        compute()
        self._keys[table] = key
        if key is not None:
            self.cache.record(self.owners, step, table, key, computed=True,
                              compute_s=time.process_time() - started, keep=self._kept_always(table))

    def _kept_always(self, table: str) -> bool:
        """Whether the cache keeps ``table`` whatever writing it costs (``StepCache.record``'s ``keep``): a shared
        step (relations, junctions), which a re-match would otherwise recompute after copying the batch's inputs in
        though every step reading it comes from the cache, and a scenario's frames step, which binds no parameter
        and which the scenario's phases read again after any change of one."""
        return self.shared or table == FRAMES_TABLE

    def materialise(self, table: str, relative: str, values: dict[str, object], kept: str | None = None) -> None:
        text = query_text(relative) + (f"\n-- only the rows where {kept}" if kept else "")  # other rows, other key
        reads = tables_read(relative) - cte_names(relative)
        key = self._cache_key(text, bind(relative, values), reads)
        if not reads:  # rows of the bound values alone (a scenario's phase limits): keyed, never worth keeping
            self._clear(table)
            self._compute(table, relative, values, kept)
            self._keys[table] = key
            return
        step = f"{table} {relative}"

        def into() -> bool:
            self._copy_inputs(reads)
            return self.cache.compute_into(self.owners, step, table, key, step_query(relative, kept),
                                           bind(relative, values))

        self._cached(table, step, key, lambda: self._compute(table, relative, values, kept), into)

    def derive(self, table: str, compute, reads: Reads, schema: dict[str, pl.DataType]) -> None:
        key = None if self.cache is None else self._cache_key(self.cache.source_text(compute), {}, frozenset(reads))
        def run() -> None:
            self._copy_inputs(reads)
            self.register(table, compute(self))

        self._cached(table, f"{table} {compute.__module__}", key, run)

    def _compute(self, table: str, relative: str, values: dict[str, object], kept: str | None) -> None:
        self._copy_inputs(tables_read(relative))
        key = step_key(relative, values) if any(relative == rel for rel, _ in self._shared) else None
        if key not in self._shared:
            materialise(self.con, table, relative, values, kept)
            return
        # computed once, read by each scenario through a view: copying a shared step's rows costs a fraction of
        # computing them again (benchmarks/README.md, "Figures behind the code's comments")
        if key not in self._kept:  # (shared steps are phase steps of a match: each reader asks for the same rows)
            self._kept[key] = f"_shared_step_{len(self._kept) + 1}"
            materialise(self.con, self._kept[key], relative, values, kept)
        self.con.execute(f"drop table if exists temp.main.{table}")
        self.con.execute(f"create temp view {table} as select * from {self._kept[key]}")
        self._views.add(table)

    def share(self, steps: frozenset[tuple[str, tuple]]) -> None:
        self._forget_shared()
        self._shared = steps

    def _forget_shared(self) -> None:
        for view in self._views:
            self.con.execute(f"drop view if exists temp.main.{view}")
        for kept in self._kept.values():
            self.con.execute(f"drop table if exists {kept}")
        self._shared, self._kept, self._views = frozenset(), {}, set()

    def frame(self, sql: str) -> pl.DataFrame:
        return self.con.sql(as_query(sql)).pl()

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self._clear(table)
        copy_into_duckdb(self.con, table, frame)
        self._keys[table] = None  # rows from elsewhere: steps reading them are not cached

    def select_drives(self) -> None:
        self._keys = {}
        if self.cache is not None:
            self.cache.start_batch()
        # a temp view shadows the stored table of the same name, so every query of the batch reads the batch's
        # rows: a batch then costs what its drives hold, not what the whole file holds (queries reading the whole
        # track_lanes per batch made matching grow with batches x file size). Views, copied only when a shared step,
        # which reads them widely, runs (``shared``): a re-match whose steps come from the step cache, or that reruns
        # only steps reading a few of the batch's rows, copies nothing
        stored = stored_schema(self.con)
        (others,) = self.con.execute(f"select count(*) from {stored}.drive_inputs where status = 'ingested' and "
                                     "drive_id not in (select drive_id from run_drives)").fetchall()[0]
        if not others:  # the batch is every drive of the file: its tables already hold just the batch's rows
            return
        for table in PARTITIONED_BY_DRIVE:
            self.con.execute(f"create or replace temp view {table} as select * from {stored}.{table} "
                             "where drive_id in (select drive_id from run_drives)")
        self._narrowed = set(PARTITIONED_BY_DRIVE)

    def _copy_inputs(self, reads) -> None:
        """While the shared steps run (``shared``): the batch's rows of the per-drive input tables in ``reads``
        copied into temp tables (once per batch), since such steps scan them several times over."""
        if not self.shared:
            return
        stored = stored_schema(self.con)
        for table in self._narrowed & set(reads):
            self.con.execute(f"drop view temp.main.{table}")
            self.con.execute(f"create temp table {table} as select * from {stored}.{table} "
                             "where drive_id in (select drive_id from run_drives)")
            self._narrowed.discard(table)

    def release_drives(self) -> None:
        self._forget_shared()
        self._keys = {}
        for table in PARTITIONED_BY_DRIVE:
            kind = "view" if table in self._narrowed else "table"
            self.con.execute(f"drop {kind} if exists temp.main.{table}")
        self._narrowed = set()
