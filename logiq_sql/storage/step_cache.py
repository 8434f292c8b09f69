"""The step cache: every step's output kept per drive, and read back instead of recomputed.

The cache is a DuckDB file of its own beside the file it serves (``<file>.step_cache``), attached to the writer's
connection as the catalog ``cache``. Only the process that holds the file's writer lock opens it (``db.Writer``,
``logiq-sql cache``), so it is written in place, and a run's working copy of the file (db.Writer) does not copy it:
inside the file it was most of the file's size, copied at the start of every run. It needs none of the file's
publish protocol: an entry holds for one ingest version of a drive, a fresh random id per ingest, so an entry that a
run wrote and never published is read only for the rows it was computed from.

A step's key is a digest of what its rows depend on: the query text it runs, the values it binds, the keys of the
step tables it reads (so a changed step changes every step downstream of it), the DuckDB version and CACHE_FORMAT.
What it reads of the canonical tables is the drive's: the index (``cache.step_cache``) records, per scenario, step and
drive, the key and the drive's ``ingest_versions.ingest_version`` it was computed from. A batch of drives reads a
step from the cache only when every drive of the batch has an entry of that key for its current ingest version;
else the step runs and its rows replace the batch's entry. The rows of one key live in ``step_cache_<key>``. A
step whose rows carry the drive only by its integer key (``drive_key``: the match steps after the phases) is kept
with the drive's id beside each row (``cached_drive_id``), by which its rows are read and dropped like the others.

Size stays bounded: each scenario keeps one entry per step and drive (its latest), and rows no scenario refers to
any more are deleted, a table with none dropped. Re-ingesting a drive (or another drive on its map) gives it a new
ingest version and drops its entries (``drop_drives``). Drives with no ingest version (files written before the
cache, datasets attached as views) are never cached. The Spark and Polars engines do not use the cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import os
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import duckdb

from logiq_sql.core.errors import LogiqError
from logiq_sql.core.sql import sql_literal
from logiq_sql.storage import locking, tables

CACHE_FORMAT = "1"  # bump when what a key covers changes
SUFFIX = ".step_cache"  # the cache's own DuckDB file: <file>.step_cache
CATALOG = "cache"  # the name it is attached under
STORED = f"{CATALOG}.main"
INDEX = f"{STORED}.{tables.STEP_CACHE.name}"
# the drive of each row of a step that carries only drive_key, added when its rows are kept
DRIVE_ID_KEPT = "cached_drive_id"
# every step is kept until this many cells were written in the run: a write has a fixed cost, so the cost per cell
# of a few small tables would make every large one look too dear to keep
CALIBRATION_CELLS = 1_000_000


def cache_key(text: str, bound: dict[str, object], inputs: dict[str, str]) -> str:
    """The key of a step: its query text (or a Python step's source), its bound values and its inputs' keys."""
    payload = json.dumps([CACHE_FORMAT, duckdb.__version__, text,
                          sorted((k, type(v).__name__, repr(v)) for k, v in bound.items()),
                          sorted(inputs.items())])
    return hashlib.sha256(payload.encode()).hexdigest()[:24]


def source_text(function) -> str:
    """The source of the module that defines ``function``: a Python step's 'query text'."""
    return inspect.getsource(sys.modules[function.__module__])


MODE_ENV = "LOGIQ_SQL_STEP_CACHE"
MODES = ("auto", "all", "off")  # keep the steps worth keeping (the default), keep every step, no cache


def mode(chosen: str | None = None) -> str:
    """``chosen`` (match's ``step_cache``, ``--step-cache``), else $LOGIQ_SQL_STEP_CACHE, else auto; checked."""
    value = chosen if chosen is not None else os.environ.get(MODE_ENV, "auto")
    if value not in MODES:
        where = f"step cache mode '{value}'" if chosen is not None else f"${MODE_ENV}={value}"
        raise LogiqError(f"{where}: choose one of {', '.join(MODES)} (auto keeps the steps that cost more to "
                         "compute than to keep, all keeps every step, off uses no cache).")
    return value


def path_of(db_path: str | Path) -> Path:
    """The step cache file of the DuckDB file ``db_path``."""
    return Path(f"{db_path}{SUFFIX}")


def attach(con: duckdb.DuckDBPyConnection, db_path: str | Path, create: bool = True) -> None:
    """Attach the step cache of the file ``db_path`` to ``con`` as ``cache``, for the process holding that file's
    writer lock (DuckDB lets one process at a time open a file for writing). ``create``: make the cache's file when
    there is none (a match that keeps steps); else only one that exists is attached (ingest drops entries of it)."""
    if attached(con) or (not create and not path_of(db_path).is_file()):
        return  # already attached: by the run's writer, when the file had a cache
    con.execute(f"attach {sql_literal(str(path_of(db_path)))} as {CATALOG}")
    tables.create_table(con, tables.STEP_CACHE, catalog=CATALOG)


def attached(con: duckdb.DuckDBPyConnection) -> bool:
    """Whether ``con`` has the step cache attached (a writer's, when the file has one; never a reader's)."""
    return con.execute("select count(*) from duckdb_databases() where database_name = $c",
                       {"c": CATALOG}).fetchall()[0][0] > 0


@contextlib.contextmanager
def opened(db_path: str | Path, wait_s: float = 0.0,
           progress: Callable[[str], None] | None = None) -> Iterator[duckdb.DuckDBPyConnection]:
    """A connection with the step cache of the file ``db_path`` attached, under the file's writer lock (a run that
    writes the file holds its cache open): for ``logiq-sql cache``."""
    lock = locking.acquire(db_path, wait_s, progress)
    try:
        with duckdb.connect() as con:
            attach(con, db_path)
            yield con
    finally:
        lock.release()


def new_version() -> str:
    return uuid.uuid4().hex


def set_versions(con: duckdb.DuckDBPyConnection, drives: str) -> None:
    """Give every drive of the query ``drives`` (a select of drive_id) a new ingest version; called by ingest inside
    its transaction, after ``drop_drives`` of the same drives outside it (a DuckDB transaction writes one file)."""
    con.execute(f"create or replace temp table _versioned as select distinct drive_id from ({drives})")
    con.execute("delete from ingest_versions where drive_id in (select drive_id from _versioned)")
    con.execute("insert into ingest_versions select drive_id, $v || '-' || drive_id from _versioned",
                {"v": new_version()})
    con.execute("drop table _versioned")


def cache_tables(con: duckdb.DuckDBPyConnection) -> list[str]:
    return [r[0] for r in con.execute(
        "select table_name from duckdb_tables() where starts_with(table_name, $p) and database_name = $c "
        "order by table_name", {"p": tables.STEP_CACHE_PREFIX, "c": CATALOG}).fetchall()]


def drive_column(con: duckdb.DuckDBPyConnection, table: str) -> str:
    """The column that names the drive of each row of the cache table ``table``."""
    (kept,) = con.execute("select count(*) from duckdb_columns() where table_name = $t and column_name = $c "
                          "and database_name = $d", {"t": table, "c": DRIVE_ID_KEPT, "d": CATALOG}).fetchall()[0]
    return DRIVE_ID_KEPT if kept else "drive_id"


def drop_drives(con: duckdb.DuckDBPyConnection, drives: str) -> None:
    """Drop every cache entry of the drives of the query ``drives`` (a select of drive_id); nothing to do on a
    connection without the cache."""
    if not attached(con):
        return
    con.execute("begin transaction")  # one commit, and the index never names rows that are gone
    try:
        for table in cache_tables(con):
            con.execute(f"delete from {STORED}.{table} where {drive_column(con, table)} in ({drives})")
        con.execute(f"delete from {INDEX} where drive_id in ({drives})")
        _drop_unreferenced(con)
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise


def clear(con: duckdb.DuckDBPyConnection) -> None:
    for table in cache_tables(con):
        con.execute(f"drop table {STORED}.{table}")
    con.execute(f"delete from {INDEX}")


def _drop_unreferenced(con: duckdb.DuckDBPyConnection) -> None:
    used = {r[0] for r in con.execute(f"select distinct table_name from {INDEX}").fetchall()}
    for table in cache_tables(con):
        if table not in used:
            con.execute(f"drop table {STORED}.{table}")


def size(con: duckdb.DuckDBPyConnection, storage: bool = True) -> dict[str, int]:
    """The cache's tables, rows, index entries and bytes (DuckDB's blocks of those tables; 0 without ``storage``,
    which reads every column's segments)."""
    tables = cache_tables(con)
    rows = sum(con.execute(f"select count(*) from {STORED}.{t}").fetchall()[0][0] for t in tables)
    blocks: set[int] = set()  # small tables share blocks
    for t in tables if storage else ():
        blocks |= {r[0] for r in con.execute(f"select distinct block_id from pragma_storage_info('{STORED}.{t}') "
                                             "where block_id is not null").fetchall()}
    (block_size,) = con.execute("select block_size from pragma_database_size() where database_name = $c",
                                {"c": CATALOG}).fetchall()[0]
    (entries,) = con.execute(f"select count(*) from {INDEX}").fetchall()[0]
    return {"tables": len(tables), "rows": rows, "entries": entries, "bytes": len(blocks) * block_size}


def describe(sizes: dict[str, int]) -> str:
    return (f"{sizes['rows']:,} rows in {sizes['tables']} table(s), {sizes['entries']:,} index entries, "
            f"about {sizes['bytes'] / 1e6:,.1f} MB")


@dataclass
class StepCache:
    """The cache of one match run, on its connection. ``read`` False (``match --force``): every step runs, and its
    rows still replace the cache's."""

    con: duckdb.DuckDBPyConnection
    read: bool = True
    keep_all: bool = False  # keep every computed step, not only those that cost more to compute than to keep
    reused: int = 0
    computed: int = 0
    uncached: int = 0
    not_kept: int = 0
    _write_s: float = 0.0  # what keeping steps cost in this run, and how many cells they had
    _cells: int = 0
    # (the batch's drives, the scenarios, step, 'reused' | 'computed'), in order
    steps: list[tuple[tuple[str, ...], tuple[str, ...], str, str]] = field(default_factory=list)
    _batch: tuple[str, ...] = ()
    _usable: bool = False
    _outside: set[str] = field(default_factory=set)  # the keys that entries of drives outside the batch name
    _columns: dict[str, str] = field(default_factory=dict)  # cache table -> the column naming each row's drive
    _owners: tuple[str, ...] = ()  # the scenarios the temp table _owners lists

    key = staticmethod(cache_key)
    source_text = staticmethod(source_text)

    def start_batch(self) -> None:
        """The batch's drives (``run_drives``) with their ingest versions; the cache is off for the batch when a
        drive has none. The index's entries of the batch's drives are copied into ``_batch_entries`` (kept in step
        with the index while the batch runs) and the keys that entries of other drives name are noted, so that
        the look-ups of each step cost what the batch holds, not what the whole index holds (the index grows with
        every drive of the file)."""
        self.con.execute("create or replace temp table _batch_versions as select r.drive_id, v.ingest_version, "
                         "d.drive_key from run_drives as r left join ingest_versions as v using (drive_id) "
                         "left join (select distinct drive_id, drive_key from drive_inputs) as d using (drive_id)")
        (missing, n) = self.con.execute("select count(*) filter (where ingest_version is null or drive_key is null), "
                                        "count(*) from _batch_versions").fetchall()[0]
        self._usable = n > 0 and missing == 0
        self._batch = tuple(r[0] for r in self.con.execute("select drive_id from _batch_versions "
                                                             "order by drive_id").fetchall())
        self.con.execute(f"create or replace temp table _batch_entries as select * from {INDEX} "
                         "where drive_id in (select drive_id from _batch_versions)")
        # (entries of other drives do not change while the batch runs: match writes only the batch's)
        self._outside = {r[0] for r in self.con.execute(
            f"select distinct step_key from {INDEX} where drive_id not in (select drive_id from _batch_versions)"
        ).fetchall()}

    @property
    def usable(self) -> bool:
        return self._usable

    def _holds(self, key: str) -> bool:
        """Whether every drive of the batch has an entry of ``key`` for its current ingest version."""
        (n,) = self.con.execute(
            "select count(distinct c.drive_id) from _batch_entries as c join _batch_versions as b "
            "on c.drive_id = b.drive_id and c.ingest_version = b.ingest_version where c.step_key = $k",
            {"k": key}).fetchall()[0]
        return n == len(self._batch)

    def _entries(self, step: str, key: str) -> int:
        """How many (owner, drive) entries of the batch name ``key`` for ``step`` at the current ingest version."""
        return self.con.execute(
            "select count(*) from _batch_entries as c join _batch_versions as b on c.drive_id = b.drive_id "
            "and c.ingest_version = b.ingest_version where c.step = $s and c.step_key = $k "
            "and c.scenario in (select scenario from _owners)", {"s": step, "k": key}).fetchall()[0][0]

    def _drive_column(self, table: str) -> str:
        if table not in self._columns:
            self._columns[table] = drive_column(self.con, table)
        return self._columns[table]

    def load(self, table: str, key: str) -> bool:
        """Make the temp view ``table`` the cached rows of ``key`` for the batch, if every drive has them (no temp
        table or view may have that name). A view, not a copy: the steps that read it scan the kept rows once
        each, where a copy scanned them and wrote them again; valid until the next batch."""
        if not (self._usable and self.read):
            return False
        if not self._holds(key):
            return False
        self._view(table, key)
        return True

    def _view(self, table: str, key: str) -> None:
        """The temp view ``table``: the rows the cache keeps under ``key`` for the batch's drives."""
        data = f"{tables.STEP_CACHE_PREFIX}{key}"
        column = self._drive_column(data)
        columns = "*" if column == "drive_id" else f"* exclude ({column})"
        # a table holds only the rows of the drives whose entries name it: when those are all of the batch, no
        # row needs filtering out
        where = f" where {column} in (select drive_id from _batch_versions)" if key in self._outside else ""
        self.con.execute(f"create temp view {table} as select {columns} from {STORED}.{data}{where}")

    def compute_into(self, owners: tuple[str, ...], step: str, table: str, key: str, query: str,
                     params: dict[str, object]) -> bool:
        """A step the cache always keeps (``record``'s ``keep``), computed straight into the cache, and ``table``
        made a view of its rows as a reused step's is: its rows are written once, where a temp table and then its
        copy in the cache wrote them twice (relations: benchmarks/README.md). False, with nothing done, when the
        cache keeps no rows of it here: the batch is not cacheable, the cache holds the rows already (match --force
        computes them again, as a temp table), or they are not per drive (a map's)."""
        if not (self._usable and owners) or self._holds(key):
            return False
        query = f"(\n{query}\n)"  # on lines of its own: the query may end in a comment
        columns = {d[0] for d in self.con.execute(f"select * from {query} as step limit 0", params).description}
        if not columns & {"drive_id", "drive_key"}:
            return False
        data = f"{tables.STEP_CACHE_PREFIX}{key}"
        rows_of = query if "drive_id" in columns else self._with_drive_id(query)
        self._create(data, rows_of, step, params)
        self._count(owners, step, "computed")
        self._point_entries(step, key, rows_of, data, write=True, params=params)
        self._view(table, key)
        return True

    @staticmethod
    def _with_drive_id(rows_of: str) -> str:
        """The rows of a step that carries only drive_key, with the drive's id beside each (``DRIVE_ID_KEPT``)."""
        return (f"(select b.drive_id as {DRIVE_ID_KEPT}, t.* from {rows_of} as t "
                "inner join _batch_versions as b on t.drive_key = b.drive_key)")

    def _create(self, data: str, rows_of: str, step: str, params: dict[str, object] | None = None) -> None:
        """The cache table ``data``, empty, shaped as ``rows_of``, if there is none yet."""
        if data in cache_tables(self.con):
            return
        # created empty in a transaction of its own: a DuckDB 2.0 table created and filled in one transaction
        # keeps the empty table's statistics, and later filters on drive_id skip its rows (logiq_sql/storage/store.py)
        self.con.execute(f"create table {STORED}.{data} as select * from {rows_of} as step limit 0", params)
        tables.comment_derived(self.con, f"{STORED}.{data}", data,
                               f"Step cache: rows of the step {step}, for the drives whose step_cache entries "
                               "name this table (logiq_sql/storage/step_cache.py).", {},
                               "As the step's query returns it (step_cache.step names the query; its header "
                               "describes the column).")

    def _count(self, owners: tuple[str, ...], step: str, how: str) -> None:
        """A step of the batch ``computed`` or ``reused`` for ``owners``, noted; ``_owners`` made those owners."""
        self.steps.append((self._batch, owners, step, how))
        if how == "computed":
            self.computed += 1
        else:
            self.reused += 1
        if owners != self._owners:  # a temp table, made again only when the owners change (once per scenario)
            self.con.execute("create or replace temp table _owners as select unnest($o::varchar[]) as scenario",
                             {"o": list(owners)})
            self._owners = owners

    def record(self, owners: tuple[str, ...], step: str, table: str, key: str, computed: bool,
               compute_s: float = 0.0, keep: bool = False) -> None:
        """After ``table`` was computed in ``compute_s`` seconds (``computed``) or loaded: the batch's rows kept
        under ``key`` and each owner's entry for the step pointed at it; rows no entry refers to any more go.
        A computed step is kept only when computing it took at least what keeping as many cells has cost so far
        in this run, both in CPU seconds of the process (steadier than wall time on a shared machine; writing a
        wide per-frame table can cost more than its query), unless ``keep_all`` or ``keep`` (the engine's
        ``_kept_always``: a shared step, since a re-match that recomputes one, however cheap, first copies the
        batch's inputs for it, though the steps reading it come from the cache, actor_lanes: 14 s of a 59 s
        re-match at tier L; and a scenario's frames step, which its phases read again after any parameter
        change)."""
        if not (self._usable and owners):
            self.uncached += 1
            return
        con, data = self.con, f"{tables.STEP_CACHE_PREFIX}{key}"
        if computed:
            columns = {r[0] for r in con.execute(
                "select column_name from duckdb_columns() where table_name = $t and database_name = 'temp'",
                {"t": table}).fetchall()}
            if not columns & {"drive_id", "drive_key"}:  # rows not per drive (a map's lanes, a KPI's): no entry
                self.uncached += 1
                return
            # the rows to keep: with the drive's id beside them when they carry only its key
            rows_of = f"temp.main.{table}" if "drive_id" in columns else self._with_drive_id(f"temp.main.{table}")
        self._count(owners, step, "computed" if computed else "reused")
        write = computed and not self._holds(key)  # match --force recomputes rows the cache already holds
        if write:
            (rows,) = con.execute(f"select count(*) from temp.main.{table}").fetchall()[0]
            cells = rows * len(columns)
            if (not (self.keep_all or keep) and self._cells >= CALIBRATION_CELLS
                    and compute_s < cells * self._write_s / self._cells):
                self.not_kept += 1
                return
            started = time.process_time()
            self._create(data, rows_of, step)
        if not write and self._entries(step, key) == len(owners) * len(self._batch):
            return  # each owner's entry already names this key for every drive of the batch
        self._point_entries(step, key, rows_of if write else "", data, write)
        if write:
            self._write_s += time.process_time() - started
            self._cells += cells

    def _point_entries(self, step: str, key: str, rows_of: str, data: str, write: bool,
                       params: dict[str, object] | None = None) -> None:
        """In one transaction: the batch's rows (``rows_of``, a table or a subquery binding ``params``) written to
        ``data`` (``write``), the entries of the owners (``_owners``) for the batch's drives pointed at ``key``, and
        the rows no entry refers to any more removed."""
        con = self.con
        con.execute("begin transaction")
        try:
            if write:
                con.execute(f"delete from {STORED}.{data} where {self._drive_column(data)} in "
                            "(select drive_id from _batch_versions)")
                con.execute(f"insert into {STORED}.{data} select * from {rows_of} as step", params)
            con.execute("create or replace temp table _replaced as select step_key, table_name, drive_id "
                        "from _batch_entries where step = $s and step_key <> $k and scenario in (select scenario "
                        "from _owners)", {"s": step, "k": key})
            for index in (INDEX, "_batch_entries"):  # the batch's entries are all in both
                con.execute(f"delete from {index} where step = $s and scenario in (select scenario from _owners) "
                            "and drive_id in (select drive_id from _batch_versions)", {"s": step})
                con.execute(f"insert into {index} select o.scenario, $s, b.drive_id, $k, $t, b.ingest_version "
                            "from _owners as o, _batch_versions as b", {"s": step, "k": key, "t": data})
            for (old, old_table) in con.execute("select distinct step_key, table_name from _replaced").fetchall():
                # the drives whose rows of the old key no entry refers to any more (the replaced entries are the
                # batch's, so only the batch's entries can still refer to those drives' rows)
                column = self._drive_column(old_table)
                con.execute(f"delete from {STORED}.{old_table} where {column} in (select drive_id from _replaced "
                            f"where step_key = $o) and {column} not in (select drive_id from _batch_entries where "
                            "step_key = $o)", {"o": old})
                if old not in self._outside and not con.execute(
                        "select count(*) from _batch_entries where step_key = $o", {"o": old}).fetchall()[0][0]:
                    con.execute(f"drop table {STORED}.{old_table}")
                    self._columns.pop(old_table, None)
            con.execute("commit")
        except BaseException:
            con.execute("rollback")
            raise

    def summary(self) -> str:
        return (f"step cache: {self.reused} step(s) reused, {self.computed} computed"
                + (f" ({self.not_kept} of them cheaper to recompute than to keep)" if self.not_kept else "")
                + (f", {self.uncached} not cacheable" if self.uncached else ""))
